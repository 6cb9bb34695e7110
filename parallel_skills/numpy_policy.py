"""JAX-free forward passes of saved policies, NumPy only.

* ``NumpyGaussianPolicy``: a saved Gaussian-MLP skill (``Skill.save`` format) or an export's new
  skill: ``policy(obs)`` -> mean action in (-1, 1).
* ``NumpySchedulerPolicy``: an export's scheduler: ``choose(obs, rng=None)`` -> (i, k_idx), greedy
  (argmax of each head) or sampled.
* ``ScheduledPolicy``: the scheduler acting through its skills with the counters of docs/design.md "Scheduler and counters"
  ("Scheduler and counters"): at a decision pick (i, k), then run skill i for K[k] steps.
* ``load_export(path)``: an ``export.npz`` + ``export.json`` written by ``training.export``.

    policy = NumpyGaussianPolicy.load("runs/<run>/new_skill.npz")
    action = policy(obs)          # obs [..., O] -> mean action [..., A] in (-1, 1)
    export = load_export("runs/<run>/export.npz")
    i, k_idx = export.scheduler.choose(obs)

Mirrors ``networks.GaussianPolicy`` / ``networks.SchedulerPolicy`` (Acme-style LayerNormMLP torso:
Dense → LayerNorm → tanh, then Dense → elu; Gaussian head → (tanh(mean), softplus(std) + min_std);
scheduler heads → (logits_i, logits_k)) and the observation normalisation folded into the saved
arrays (``obs_mean``, ``obs_std``; normalised observations clipped to ±10). Importing this module
imports no JAX (``parallel_skills/__init__`` loads its public names lazily).
"""

from __future__ import annotations

import json
import os
from typing import Callable, Optional, Sequence

import numpy as np

LAYER_NORM_EPS = 1e-6  # flax.linen.LayerNorm default
CLIP = 10.0
MIN_STD = 0.05  # networks.GaussianPolicy / NewSkillConfig default
EXPORT_FORMAT = "parallel_skills.export"
EXPORT_VERSION = 1
POLICY_PREFIX = "policy/params/"


def _elu(x):
    return np.where(x > 0, x, np.expm1(np.minimum(x, 0.0)))


def _softplus(x):
    return np.logaddexp(x, 0.0)


def read_npz_json(path: str, what: str = "skill") -> tuple[dict, dict]:
    """(arrays, sidecar) of ``BASE.npz`` + ``BASE.json``; ValueError naming the problem if either
    is missing, truncated or corrupt."""
    base = path[:-4] if path.endswith(".npz") else path
    for ext in (".npz", ".json"):
        if not os.path.exists(base + ext):
            raise ValueError(f"{what} file {base + ext} does not exist ({what} {base}.npz needs both the .npz "
                             f"and its .json sidecar)")
    try:
        with open(base + ".json") as f:
            meta = json.load(f)
        with np.load(base + ".npz") as data:
            arrays = {k: np.asarray(data[k]) for k in data.files}
    except Exception as e:  # corrupt or truncated files
        detail = str(e).splitlines()[0] if str(e) else ""
        raise ValueError(f"cannot read {what} {base}.npz/.json (corrupt or truncated): {type(e).__name__}: {detail}") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{what} sidecar {base}.json must hold a JSON object")
    return arrays, meta


def check_shapes(arrays: dict, expected: dict, where: str) -> None:
    """ValueError if an expected array is missing or has another shape (one line)."""
    for key, shape in expected.items():
        if key not in arrays:
            raise ValueError(f"{where} lacks the array {key!r} (a mismatched or corrupt file)")
        if tuple(arrays[key].shape) != tuple(shape):
            raise ValueError(f"{where}: array {key!r} has shape {tuple(arrays[key].shape)}, the sizes recorded "
                             f"with it need {tuple(shape)} (a mismatched file)")


def _torso_shapes(prefix: str, obs_size: int, hidden: Sequence[int]) -> dict:
    shapes, fan_in = {}, obs_size
    for n, width in enumerate(hidden):
        shapes[f"{prefix}torso/dense_{n}/kernel"] = (fan_in, width)
        shapes[f"{prefix}torso/dense_{n}/bias"] = (width,)
        fan_in = width
    shapes[f"{prefix}torso/layer_norm/scale"] = (hidden[0],)
    shapes[f"{prefix}torso/layer_norm/bias"] = (hidden[0],)
    return shapes


def _dense_shapes(prefix: str, name: str, fan_in: int, width: int) -> dict:
    return {f"{prefix}{name}/kernel": (fan_in, width), f"{prefix}{name}/bias": (width,)}


class _NumpyMLP:
    """Observation normalisation + LayerNormMLP torso + named dense heads, float64."""

    def __init__(self, arrays: dict, hidden, obs_size: Optional[int] = None):
        self.a = {k: np.asarray(v, np.float64) for k, v in arrays.items()}
        self.hidden = [int(h) for h in hidden]
        if not self.hidden:
            raise ValueError("a policy network needs at least one hidden layer")
        if "obs_mean" not in self.a:
            raise ValueError("policy parameters lack the observation statistics 'obs_mean' / 'obs_std'")
        self.obs_size = int(self.a["obs_mean"].shape[-1]) if obs_size is None else int(obs_size)
        check_shapes(self.a, {"obs_mean": (self.obs_size,), "obs_std": (self.obs_size,),
                              **_torso_shapes(POLICY_PREFIX, self.obs_size, self.hidden)},
                     f"policy network (hidden={self.hidden})")

    def _dense(self, name, x):
        return x @ self.a[f"{POLICY_PREFIX}{name}/kernel"] + self.a[f"{POLICY_PREFIX}{name}/bias"]

    def features(self, obs):
        """Torso output [..., hidden[-1]] for raw observations [..., O]."""
        x = np.clip((np.asarray(obs, np.float64) - self.a["obs_mean"]) / self.a["obs_std"], -CLIP, CLIP)
        for n in range(len(self.hidden)):
            x = self._dense(f"torso/dense_{n}", x)
            if n == 0:
                mu = x.mean(-1, keepdims=True)
                var = np.square(x - mu).mean(-1, keepdims=True)
                x = (x - mu) / np.sqrt(var + LAYER_NORM_EPS)
                x = x * self.a[f"{POLICY_PREFIX}torso/layer_norm/scale"] + self.a[f"{POLICY_PREFIX}torso/layer_norm/bias"]
                x = np.tanh(x)
            else:
                x = _elu(x)
        return x


class NumpyGaussianPolicy(_NumpyMLP):
    """Deterministic (mean) action of a saved new-skill network, in NumPy (float64 internally).

    ``arrays``: {"policy/params/...": flax leaves, "obs_mean": [O], "obs_std": [O]} (``Skill.save``)."""

    def __init__(self, arrays: dict, hidden, action_size: int, min_std: float = MIN_STD, obs_size: Optional[int] = None):
        super().__init__(arrays, hidden, obs_size)
        self.action_size = int(action_size)
        self.min_std = float(min_std)
        check_shapes(self.a, _dense_shapes(POLICY_PREFIX, "head", self.hidden[-1], 2 * self.action_size),
                     f"new-skill network (action_size={self.action_size})")

    @staticmethod
    def load(path: str, obs_size: Optional[int] = None, action_size: Optional[int] = None) -> "NumpyGaussianPolicy":
        """Load a ``Skill.save`` file; check its sizes against a task's if given."""
        arrays, meta = read_npz_json(path)
        if meta.get("format") == EXPORT_FORMAT:
            raise ValueError(f"{path} is an export, not a single skill: load it with load_export")
        if meta.get("hidden") is None or meta.get("action_size") is None:
            raise ValueError(f"skill sidecar of {path} lacks 'hidden' or 'action_size'")
        policy = NumpyGaussianPolicy(arrays, meta["hidden"], meta["action_size"], meta.get("min_std", MIN_STD))
        check_task_sizes(path, policy.obs_size, policy.action_size, obs_size, action_size)
        return policy

    def distribution(self, obs):
        """(mean [..., A], std [..., A]) for obs [..., O]."""
        out = self._dense("head", self.features(obs))
        raw_mean, raw_std = out[..., : self.action_size], out[..., self.action_size:]
        return np.tanh(raw_mean), _softplus(raw_std) + self.min_std

    def sample(self, obs, rng: np.random.Generator):
        """a = clip(mean + std·ε, −1, 1), ε ~ N(0, I) (``networks.sample_action``)."""
        mean, std = self.distribution(obs)
        return np.clip(mean + std * rng.standard_normal(mean.shape), -1.0, 1.0)

    def __call__(self, obs):
        return self.distribution(obs)[0]


def check_task_sizes(path: str, obs_size: int, action_size: int, task_obs: Optional[int], task_action: Optional[int]):
    if task_obs is not None and int(obs_size) != int(task_obs):
        raise ValueError(f"{path} expects observations of size {obs_size}, the task gives {task_obs}")
    if task_action is not None and int(action_size) != int(task_action):
        raise ValueError(f"{path} produces actions of size {action_size}, the task takes {task_action}")


def _categorical(logits, rng: np.random.Generator):
    """One sample per row of logits [..., C] (inverse CDF)."""
    p = np.exp(logits - logits.max(-1, keepdims=True))
    cdf = np.cumsum(p / p.sum(-1, keepdims=True), axis=-1)
    u = rng.random(logits.shape[:-1] + (1,))
    return np.minimum((cdf < u).sum(-1), logits.shape[-1] - 1)


class NumpySchedulerPolicy(_NumpyMLP):
    """The scheduler π_S(i, k | s) of an export: two categorical heads on a LayerNormMLP torso.

    ``arrays``: {"policy/params/{torso,head_i,head_k}/...", "obs_mean", "obs_std"}."""

    def __init__(self, arrays: dict, hidden, num_skills: int, skill_lengths: Sequence[int],
                 obs_size: Optional[int] = None):
        super().__init__(arrays, hidden, obs_size)
        self.num_skills = int(num_skills)
        self.skill_lengths = np.asarray([int(k) for k in skill_lengths], np.int64)
        h = self.hidden[-1]
        check_shapes(self.a, {**_dense_shapes(POLICY_PREFIX, "head_i", h, self.num_skills),
                              **_dense_shapes(POLICY_PREFIX, "head_k", h, len(self.skill_lengths))},
                     f"scheduler network (skills={self.num_skills}, lengths={len(self.skill_lengths)})")

    def logits(self, obs):
        """(logits_i [..., N+1], logits_k [..., M]) for raw obs [..., O]."""
        x = self.features(obs)
        return self._dense("head_i", x), self._dense("head_k", x)

    def choose(self, obs, rng: Optional[np.random.Generator] = None):
        """(i [...], k_idx [...]) int64: argmax of each head, or sampled with ``rng``."""
        li, lk = self.logits(obs)
        if rng is None:
            return np.argmax(li, -1), np.argmax(lk, -1)
        return _categorical(li, rng), _categorical(lk, rng)

    def __call__(self, obs, rng: Optional[np.random.Generator] = None):
        """z = (i, K[k]) [..., 2], as ``make_policy(params, "scheduler")`` returns it."""
        i, k_idx = self.choose(obs, rng)
        return np.stack([i, self.skill_lengths[k_idx]], axis=-1)


class ScheduledPolicy:
    """The scheduler running its skills for a batch of envs, with per-env counters (docs/design.md "Scheduler and counters"):
    c_t = steps left for the current skill including step t; a decision happens at episode start
    or when the previous c was 1, and sets (c, i, k) = (K[k], i, k) from a fresh scheduler choice;
    otherwise c counts down and the skill keeps acting.

    ``skills(obs [B, O]) -> actions [N+1, B, A]``: every skill's action (index N = the new skill).
    ``scheduler``: anything with ``choose(obs [B, O], rng) -> (i [B], k_idx [B])``.
    """

    def __init__(self, scheduler, skills: Callable, skill_lengths: Sequence[int],
                 rng: Optional[np.random.Generator] = None):
        self.scheduler = scheduler
        self.skills = skills
        self.lengths = np.asarray(skill_lengths, np.int64)
        self.rng = rng  # None: greedy choices
        self.usage = np.zeros(0, np.int64)  # env steps each skill acted, summed over calls
        self.timeline: list = []  # per call since the last reset: the skill each env runs [B]
        self.reset(0)

    def reset(self, batch: int) -> None:
        """Start new episodes: the next step is a decision for every env."""
        self.timeline = []
        self.c = np.zeros(batch, np.int64)
        self.i = np.zeros(batch, np.int64)
        self.k_idx = np.zeros(batch, np.int64)

    def __call__(self, obs):
        """Actions [B, A] for obs [B, O]; the batch size B is fixed by ``reset`` or the first call."""
        obs = np.asarray(obs)
        if self.c.shape[0] != obs.shape[0]:
            self.reset(obs.shape[0])
        decision = self.c <= 1
        if decision.any():
            i_new, k_new = self.scheduler.choose(obs, self.rng)
            self.i = np.where(decision, i_new, self.i)
            self.k_idx = np.where(decision, k_new, self.k_idx)
        self.c = np.where(decision, self.lengths[self.k_idx], self.c - 1)
        every = np.asarray(self.skills(obs))  # [N+1, B, A]
        counts = np.bincount(self.i, minlength=every.shape[0])
        self.timeline.append(self.i.copy())
        self.usage = counts + (self.usage if self.usage.shape == counts.shape else 0)
        return every[self.i, np.arange(obs.shape[0])]


class NumpyExport:
    """An ``export.npz`` + ``export.json`` (``training.export.write_export``) for NumPy."""

    def __init__(self, path: str, arrays: dict, meta: dict):
        self.path, self.meta = path, meta
        try:
            self.obs_size, self.action_size = int(meta["obs_size"]), int(meta["action_size"])
            ns, sc = meta["new_skill"], meta["scheduler"]
            self.new_skill_name = str(ns.get("name", "new_skill"))
            self.skill_names = [str(n) for n in sc["skill_names"]]
            self.skill_lengths = [int(k) for k in sc["skill_lengths"]]
            new_hidden, sched_hidden = ns["hidden"], sc["hidden"]
            min_std = float(ns.get("min_std", MIN_STD))
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"export sidecar of {path} lacks or garbles {e} (not an export of this version?)") from None
        sections = {}
        for name in ("new_skill", "scheduler"):
            prefix = name + "/"
            sections[name] = {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
        try:
            self.new_skill = NumpyGaussianPolicy(sections["new_skill"], new_hidden, self.action_size, min_std,
                                                 obs_size=self.obs_size)
            self.scheduler = NumpySchedulerPolicy(sections["scheduler"], sched_hidden, len(self.skill_names),
                                                  self.skill_lengths, obs_size=self.obs_size)
        except ValueError as e:
            raise ValueError(f"export {path}: {e}") from None

    @property
    def frozen_skill_names(self) -> list[str]:
        """Names of the frozen skills (scheduler indices 0..N-1); index N is the new skill."""
        return self.skill_names[:-1]

    def check_task_sizes(self, obs_size: Optional[int], action_size: Optional[int]) -> None:
        check_task_sizes(self.path, self.obs_size, self.action_size, obs_size, action_size)


def is_export(path: str) -> bool:
    """Whether ``path``'s JSON sidecar says it is an export (False if unreadable)."""
    base = path[:-4] if path.endswith(".npz") else path
    try:
        with open(base + ".json") as f:
            return json.load(f).get("format") == EXPORT_FORMAT
    except Exception:
        return False


def load_export(path: str, obs_size: Optional[int] = None, action_size: Optional[int] = None) -> NumpyExport:
    """Load an export; check its sizes against a task's if given. ValueError (one line) if bad."""
    arrays, meta = read_npz_json(path, what="export")
    if meta.get("format") != EXPORT_FORMAT:
        raise ValueError(f"{path} is not an export (its sidecar has no \"format\": \"{EXPORT_FORMAT}\")")
    if not isinstance(meta.get("version"), int) or meta["version"] > EXPORT_VERSION:
        raise ValueError(f"export {path} has format version {meta.get('version')!r}; this code reads 1 to {EXPORT_VERSION}")
    export = NumpyExport(path, arrays, meta)
    export.check_task_sizes(obs_size, action_size)
    return export
