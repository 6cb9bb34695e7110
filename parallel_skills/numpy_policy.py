"""JAX-free forward pass of a saved Gaussian-MLP skill (``Skill.save`` format): NumPy only.

    policy = NumpyGaussianPolicy.load("runs/<run>/new_skill.npz")
    action = policy(obs)          # obs [..., O] -> mean action [..., A] in (-1, 1)

Mirrors ``networks.GaussianPolicy`` (Acme-style LayerNormMLP torso: Dense → LayerNorm → tanh, then
Dense → elu; head → (tanh(mean), softplus(std))) and the skill's observation normalisation. The module
itself uses NumPy only (importing it through the package still loads JAX via ``parallel_skills/__init__``;
a JAX-free import path is issue #5's work).
"""

from __future__ import annotations

import json
import os

import numpy as np

LAYER_NORM_EPS = 1e-6  # flax.linen.LayerNorm default
CLIP = 10.0


def _elu(x):
    return np.where(x > 0, x, np.expm1(np.minimum(x, 0.0)))


def _softplus(x):
    return np.logaddexp(x, 0.0)


class NumpyGaussianPolicy:
    """Deterministic (mean) action of a saved new-skill network, in NumPy (float64 internally)."""

    def __init__(self, arrays: dict, hidden, action_size: int):
        self.a = {k: np.asarray(v, np.float64) for k, v in arrays.items()}
        self.hidden = [int(h) for h in hidden]
        self.action_size = int(action_size)
        p = "policy/params/"
        for n in range(len(self.hidden)):
            if f"{p}torso/dense_{n}/kernel" not in self.a:
                raise ValueError(f"skill parameters lack layer torso/dense_{n} (hidden={self.hidden})")
        self._p = p

    @staticmethod
    def load(path: str) -> "NumpyGaussianPolicy":
        base = path[:-4] if path.endswith(".npz") else path
        if not os.path.exists(base + ".npz") or not os.path.exists(base + ".json"):
            raise ValueError(f"skill {base}.npz needs both the .npz and its .json sidecar")
        try:
            with open(base + ".json") as f:
                meta = json.load(f)
            with np.load(base + ".npz") as data:
                arrays = {k: data[k] for k in data.files}
        except Exception as e:
            raise ValueError(f"cannot read skill {base}.npz/.json: {type(e).__name__}: {e}") from None
        return NumpyGaussianPolicy(arrays, meta["hidden"], meta["action_size"])

    def _dense(self, name, x):
        return x @ self.a[f"{self._p}{name}/kernel"] + self.a[f"{self._p}{name}/bias"]

    def distribution(self, obs):
        """(mean [..., A], std [..., A]) for obs [..., O]."""
        x = np.clip((np.asarray(obs, np.float64) - self.a["obs_mean"]) / self.a["obs_std"], -CLIP, CLIP)
        for n in range(len(self.hidden)):
            x = self._dense(f"torso/dense_{n}", x)
            if n == 0:
                mu = x.mean(-1, keepdims=True)
                var = np.square(x - mu).mean(-1, keepdims=True)
                x = (x - mu) / np.sqrt(var + LAYER_NORM_EPS)
                x = x * self.a[f"{self._p}torso/layer_norm/scale"] + self.a[f"{self._p}torso/layer_norm/bias"]
                x = np.tanh(x)
            else:
                x = _elu(x)
        out = self._dense("head", x)
        raw_mean, raw_std = out[..., : self.action_size], out[..., self.action_size:]
        return np.tanh(raw_mean), _softplus(raw_std)

    def __call__(self, obs):
        return self.distribution(obs)[0]
