"""Skills: frozen pretrained behaviours the scheduler sequences (paper §4, set S).

A ``Skill`` is a pure function ``apply(params, obs [O], key) -> action [A]`` plus its (possibly
empty) parameters. ``Skill.from_fn`` wraps any pure ``fn(obs, key) -> action`` (scripted
controllers, other libraries' policies); ``Skill.load`` / ``Skill.save`` read and write the
project's ``.npz`` + JSON sidecar format for Gaussian-MLP skills (the new-skill network).

``SkillSet`` runs the N frozen skills and the new skill for a batch and selects per env: skills
with the same network architecture are stacked and run with one ``vmap`` over their parameters.
"""

from __future__ import annotations

import dataclasses
import json
import os
from typing import Any, Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from flax import struct

from parallel_skills.normalization import CLIP
from parallel_skills.numpy_policy import read_npz_json

Params = Any


@struct.dataclass
class GaussianSkillParams:
    """A Gaussian-MLP skill's parameters: the policy's flax variables and the observation
    statistics it normalises with, obs_mean / obs_std [O] (``(obs − mean) / std``, clipped)."""

    policy: Params
    obs_mean: jax.Array
    obs_std: jax.Array

    @classmethod
    def from_normalizer(cls, policy: Params, stats) -> "GaussianSkillParams":
        """The params of a trained policy and its run's ``normalization.RunningStats``."""
        from parallel_skills.normalization import std

        return cls(policy=policy, obs_mean=stats.mean, obs_std=std(stats))

    @classmethod
    def of(cls, params) -> "GaussianSkillParams":
        """``params`` as GaussianSkillParams: itself, or a {"policy", "obs_mean", "obs_std"}
        mapping (the layout of the saved files, ``flatten_params``)."""
        if isinstance(params, cls):
            return params
        try:
            return cls(policy=params["policy"], obs_mean=params["obs_mean"], obs_std=params["obs_std"])
        except (KeyError, TypeError):
            raise ValueError("Gaussian-MLP skill parameters need policy, obs_mean and obs_std") from None

    def as_dict(self) -> dict:
        """{"policy", "obs_mean", "obs_std"}: the layout ``Skill.save`` flattens."""
        return {"policy": self.policy, "obs_mean": self.obs_mean, "obs_std": self.obs_std}


def gaussian_mlp_apply(action_size: int, hidden: Sequence[int], sampled: bool = False,
                       min_std: Optional[float] = None, std_scale: float = 1.0):
    """``apply(params: GaussianSkillParams, obs [O], key) -> action [A]`` of a Gaussian-MLP skill:
    observations normalised with the run's statistics (clipped), then the policy's mean action, or
    with ``sampled`` an action drawn from its Gaussian (``networks.sample_action``; ``min_std`` its
    std floor, default ``GaussianPolicy.min_std``) with its std times ``std_scale`` (1: the policy's
    own Gaussian, as the trainer collects; 0 would be the mean)."""
    from parallel_skills import networks

    kwargs = {} if min_std is None else {"min_std": float(min_std)}
    net = networks.GaussianPolicy(action_size=int(action_size), hidden=tuple(hidden), **kwargs)

    def apply(p: GaussianSkillParams, obs, key):
        x = jnp.clip((obs - p.obs_mean) / p.obs_std, -CLIP, CLIP)
        mean, std = net.apply(p.policy, x)
        return networks.sample_action(mean, std * std_scale, key) if sampled else mean

    return apply


def _no_params_apply(fn):
    def apply(params, obs, key):
        del params
        return fn(obs, key)

    return apply


@dataclasses.dataclass(frozen=True)
class Skill:
    """A frozen skill. ``apply(params, obs [O], key) -> action [A]`` acts on one observation.

    ``arch`` names the network architecture (skills with equal non-empty ``arch`` and parameter
    shapes are stacked and vmapped together); ``metadata`` is the JSON sidecar content.
    ``collection_noise``: whether the trainer adds its collection noise (``TrainConfig.
    skill_noise_std``) to this skill's actions while collecting. False for controllers that keep
    state in their own previous action, which noise would scramble (the OP3 controllers' phase
    codes in the head actions, tasks/locomotion/controllers.py).
    """

    name: str
    apply: Callable[[Params, jax.Array, jax.Array], jax.Array]
    params: Params = None
    arch: Optional[str] = None
    metadata: dict = dataclasses.field(default_factory=dict)
    collection_noise: bool = True

    @staticmethod
    def from_fn(name: str, fn: Callable[[jax.Array, jax.Array], jax.Array], collection_noise: bool = True,
                **metadata) -> "Skill":
        """Wrap a pure ``fn(obs, key) -> action`` (one observation) as a skill."""
        return Skill(name=name, apply=_no_params_apply(fn), params=None, arch=None, metadata=dict(metadata),
                     collection_noise=bool(collection_noise))

    @staticmethod
    def gaussian_mlp(name: str, params: Params, action_size: int, hidden: Sequence[int], **metadata) -> "Skill":
        """A skill from new-skill (Gaussian MLP) parameters; acts with the mean action.

        ``params``: ``GaussianSkillParams`` (or a {"policy", "obs_mean", "obs_std"} mapping):
        observations are normalised with the training run's statistics before the network.
        ``None``: the architecture alone, whose ``apply`` takes the params at call time."""
        apply = gaussian_mlp_apply(action_size, hidden)
        meta = dict(metadata, action_size=int(action_size), hidden=[int(h) for h in hidden])
        params = None if params is None else GaussianSkillParams.of(params)
        return Skill(name=name, apply=apply, params=params, arch=f"gaussian_mlp{tuple(hidden)}->{action_size}",
                     metadata=meta)

    def save(self, path: str, **metadata) -> None:
        """Write ``path`` (.npz of the parameter leaves) and ``path`` with .json (the sidecar).

        Writes to temporary files and renames them, so an existing skill is never left half
        written."""
        if self.params is None:
            raise ValueError(f"skill {self.name!r} has no parameters to save (scripted skills are code, not files)")
        flat = flatten_params(self.params.as_dict() if isinstance(self.params, GaussianSkillParams) else self.params)
        meta = dict(self.metadata, **metadata, name=self.name, arch=self.arch)
        base = path[:-4] if path.endswith(".npz") else path
        tmp = base + ".tmp.npz"
        np.savez(tmp, **flat)
        with open(base + ".json.tmp", "w") as f:
            json.dump(meta, f, indent=2, sort_keys=True)
        os.replace(tmp, base + ".npz")
        os.replace(base + ".json.tmp", base + ".json")

    @staticmethod
    def load(path: str, obs_size: Optional[int] = None, action_size: Optional[int] = None) -> "Skill":
        """Load a Gaussian-MLP skill saved by ``save``; check sizes against a task if given
        (``obs_size`` / ``action_size``: the env's ``observation_size`` / ``action_size``).

        Every array's shape is checked against the sidecar's sizes (``obs_size``, ``hidden``,
        ``action_size``), so the observation size is known even if the sidecar omits it. Any problem
        (missing, corrupt or mismatched files, sizes that differ from the task's) is a ValueError
        with a one-line message naming the file."""
        from parallel_skills.numpy_policy import EXPORT_FORMAT, NumpyGaussianPolicy

        base = path[:-4] if path.endswith(".npz") else path
        flat, meta = read_npz_json(path)  # ValueError if missing, truncated or corrupt
        if meta.get("format") == EXPORT_FORMAT:
            raise ValueError(f"{base}.npz is an export, not a single skill (load it with "
                             f"parallel_skills.numpy_policy.load_export)")
        hidden, a_size = meta.get("hidden"), meta.get("action_size")
        if hidden is None or a_size is None:
            raise ValueError(f"skill sidecar {base}.json lacks 'hidden' or 'action_size'")
        try:
            hidden, a_size = [int(h) for h in hidden], int(a_size)
            o_meta = None if meta.get("obs_size") is None else int(meta["obs_size"])
            # Shapes of every array against the recorded sizes (obs_size from obs_mean if unrecorded).
            o_size = NumpyGaussianPolicy(flat, hidden, a_size, obs_size=o_meta).obs_size
        except (TypeError, ValueError) as e:
            raise ValueError(f"skill {base}.npz: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
        if obs_size is not None and o_size != int(obs_size):
            raise ValueError(f"skill {base}.npz expects observations of size {o_size}, the task gives {obs_size}")
        if action_size is not None and a_size != int(action_size):
            raise ValueError(f"skill {base}.npz produces actions of size {a_size}, the task takes {action_size}")
        params = GaussianSkillParams.of(unflatten_params(flat))
        rest = {k: v for k, v in meta.items() if k not in ("hidden", "action_size", "name", "arch", "obs_size")}
        return Skill.gaussian_mlp(meta.get("name", os.path.basename(base)), jax.tree.map(jnp.asarray, params),
                                  a_size, hidden, obs_size=o_size, **rest)


def flatten_params(params: Params) -> dict:
    """A nested dict of arrays as ``{"a/b/c": numpy array}`` (the .npz layout of skills and exports)."""
    out = {}

    def rec(prefix, node):
        if isinstance(node, dict):
            for k, v in node.items():
                rec(f"{prefix}/{k}" if prefix else str(k), v)
        else:
            out[prefix] = np.asarray(node)

    rec("", jax.tree.map(np.asarray, _to_dict(params)))
    return out


def _to_dict(params):
    try:
        from flax.core import unfreeze

        return unfreeze(params)
    except Exception:
        return params


def unflatten_params(flat: dict) -> dict:
    """The inverse of ``flatten_params``: ``{"a/b/c": x}`` -> ``{"a": {"b": {"c": x}}}``."""
    root: dict = {}
    for key, value in flat.items():
        node = root
        parts = key.split("/")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = value
    return root


class SkillSet:
    """The N frozen skills and the new skill, run for a batch and selected per env.

    ``actions(new_skill_action [B, A], obs [B, O], skill_index [B], key) -> action [B, A]``:
    index N is the new skill (its action is computed by the caller, e.g. sampled from the
    learner's current policy). Frozen skills with the same ``arch`` and parameter shapes are
    stacked and evaluated with one vmap over their parameters.
    """

    def __init__(self, skills: Sequence[Skill]):
        self.skills = list(skills)
        self.num_frozen = len(self.skills)
        groups: dict = {}
        for idx, s in enumerate(self.skills):
            if s.arch is not None and s.params is not None:
                sig = (s.arch, jax.tree.structure(s.params),
                       tuple(np.shape(x) for x in jax.tree.leaves(s.params)))
                groups.setdefault(sig, []).append(idx)
        self._stacked = []  # (indices, apply, stacked params)
        grouped = set()
        for sig, idxs in groups.items():
            if len(idxs) > 1:
                stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *[self.skills[i].params for i in idxs])
                self._stacked.append((idxs, self.skills[idxs[0]].apply, stacked))
                grouped.update(idxs)
        self._single = [i for i in range(self.num_frozen) if i not in grouped]

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.skills]

    @property
    def vmapped_groups(self) -> list[list[int]]:
        """The indices of the skills run together in one vmap (same architecture and shapes)."""
        return [list(idxs) for idxs, _, _ in self._stacked]

    @property
    def unstacked(self) -> list[int]:
        """The indices of the skills run one by one."""
        return list(self._single)

    @property
    def collection_noise(self) -> np.ndarray:
        """[N + 1] bool: which skills take the trainer's collection noise (the new skill, index N,
        never: it samples from its own Gaussian)."""
        return np.array([s.collection_noise for s in self.skills] + [False])

    def frozen_actions(self, obs: jax.Array, key: jax.Array) -> jax.Array:
        """Actions of every frozen skill for every env: [N, B, A]."""
        batch = obs.shape[0]
        keys = jax.random.split(key, self.num_frozen)
        out: list = [None] * self.num_frozen
        for i in self._single:
            s = self.skills[i]
            out[i] = jax.vmap(s.apply, in_axes=(None, 0, 0))(s.params, obs, jax.random.split(keys[i], batch))
        for idxs, apply, stacked in self._stacked:
            acts = jax.vmap(
                lambda p, k: jax.vmap(apply, in_axes=(None, 0, 0))(p, obs, jax.random.split(k, batch))
            )(stacked, keys[jnp.asarray(idxs)])
            for j, i in enumerate(idxs):
                out[i] = acts[j]
        return jnp.stack(out).astype(jnp.float32)

    def actions(self, new_skill_action: jax.Array, obs: jax.Array, skill_index: jax.Array, key: jax.Array):
        """Per-env action of the selected skill (index N = the new skill): [B, A]."""
        if self.num_frozen == 0:
            return new_skill_action
        frozen = self.frozen_actions(obs, key)  # [N, B, A]
        every = jnp.concatenate([frozen, new_skill_action[None].astype(jnp.float32)], axis=0)  # [N+1, B, A]
        return jnp.take_along_axis(every, skill_index[None, :, None], axis=0)[0]
