"""Configurations: the learners' (paper defaults, SkillS App. B.3, manipulation), the run's
(``TrainConfig``), the CPU recipe and ``resolve`` (device-dependent defaults), and the checks of
every value (``__post_init__`` of each class; ``from_dict`` for JSON input: types and ranges).

All configs are frozen, hashable ``dataclasses.dataclass`` objects: pass them as
static arguments to ``jax.jit`` (or close over them); every field is a Python scalar,
string or tuple, never an array.

Target-network periods are deliberately different for the two learners (App. B.3):
scheduler actor 100 / critic 25, new skill actor 25 / critic 100.
"""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Optional, Sequence, Tuple

# Integer fields that must be >= 1 (every other integer field must be >= 0), in any config class.
POSITIVE_FIELDS = frozenset({
    "num_envs", "replay_size", "unroll_length", "eval_episodes", "eval_every", "batch_size",
    "target_actor_period", "target_critic_period", "num_action_samples", "mpo_num_samples",
    "num_critics", "n_step"})


def check_ranges(config) -> None:
    """The range rule of every config class: integer fields ≥ 1 (``POSITIVE_FIELDS``) or ≥ 0, float
    fields finite, ``target_tau`` in [0, 1]. ValueError naming the field."""
    tau = getattr(config, "target_tau", 0.0)
    if not 0.0 <= tau <= 1.0:
        raise ValueError(f"target_tau must be in [0, 1] (0: periodic hard copies), got {tau}")
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if isinstance(value, bool) or value is None:
            continue
        if isinstance(value, int):
            lo = 1 if f.name in POSITIVE_FIELDS else 0
            if value < lo:
                raise ValueError(f"{f.name} must be {'a positive' if lo else 'a non-negative'} integer, got {value}")
        elif isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{f.name} must be a finite number, got {value}")


@dataclasses.dataclass(frozen=True)
class SchedulerConfig:
    """HCMPO scheduler learner (paper §4.3, Eq. 3-4; App. A, B.3)."""

    # Action space z = (i, k): K = {10, 20, ..., 100} (App. B.3).
    skill_lengths: Tuple[int, ...] = (10, 20, 30, 40, 50, 60, 70, 80, 90, 100)
    # Initial P(k = max K); the other M-1 lengths share the rest uniformly, i.e.
    # (1 - 0.95) / 9 ≈ 0.00556 each (the paper prints 0.005, which does not sum to 1).
    initial_max_length_prob: float = 0.95
    batch_size: int = 128
    learning_rate: float = 1e-4
    min_replay_size: int = 400
    samples_per_insert: float = 100.0
    target_actor_period: int = 100
    target_critic_period: int = 25
    # 0: target networks are hard copies every target_*_period updates (the paper). τ in (0, 1]:
    # Polyak averaging after every update, θ' ← τ·θ + (1 − τ)·θ' (FastTD3: 0.1); the periods are
    # then unused.
    target_tau: float = 0.0
    epsilon: float = 0.1  # E-step KL bound (temperature dual).
    epsilon_kl: float = 5e-3  # M-step categorical KL(π_old ‖ π) trust region.
    discount: float = 0.99
    hidden: Tuple[int, ...] = (128, 256, 128)  # policy and critic torsos.
    critic_head_hidden: Tuple[int, ...] = (128,)  # per-(c, i, k) critic head.
    # Dual variables are positive via softplus(log_param) + 1e-8 (as Acme).
    init_log_temperature: float = 1.0
    init_log_alpha: float = 1.0
    dual_learning_rate: float = 1e-2
    grad_clip_norm: float = 40.0
    augmentation: bool = True
    # Learner updates during which only the critic learns (policy and duals frozen): lets the
    # long-horizon values of Eq. 3 propagate before policy improvement starts (0 = paper).
    policy_warmup_updates: int = 0

    def __post_init__(self):
        check_ranges(self)
        lengths = tuple(self.skill_lengths)
        if not lengths or any(int(k) < 1 for k in lengths) or list(lengths) != sorted(set(lengths)):
            raise ValueError(f"skill_lengths must be positive, unique and ascending, got {lengths}")
        if not 0.0 < self.initial_max_length_prob < 1.0 and len(lengths) > 1:
            raise ValueError("initial_max_length_prob must be in (0, 1)")

    @property
    def num_lengths(self) -> int:
        return len(self.skill_lengths)

    @property
    def max_length(self) -> int:
        return max(self.skill_lengths)


@dataclasses.dataclass(frozen=True)
class NewSkillConfig:
    """CRR new-skill learner (paper §4.2, App. B, B.3; Wang et al. 2020)."""

    hidden: Tuple[int, ...] = (128, 256, 128)  # policy and critic torsos.
    batch_size: int = 256
    learning_rate: float = 3e-4
    min_replay_size: int = 200
    samples_per_insert: float = 50.0
    target_actor_period: int = 25
    target_critic_period: int = 100
    target_tau: float = 0.0  # as SchedulerConfig.target_tau
    discount: float = 0.99
    crr_mode: str = "exp"  # "exp": min(exp(A/β), clip); "indicator": 1[A > 0].
    crr_beta: float = 1.0
    crr_clip: float = 20.0
    num_action_samples: int = 4  # J: samples for the CRR baseline and the TD target.
    # > 1: clipped double Q (Fujimoto et al. 2018): independent critics, the TD target and the CRR
    # advantage use their minimum. With one critic (CRR as in the paper) the new skill's Q drifted
    # above any achievable return on sparse stack (114 > r_max/(1-γ) = 100 at rewarded replay
    # states; 2.5-8x the measured return at hover states); two critics keep it below the bound, but
    # did not make stack learn within 200k steps (docs/learning.md), so the default stays 1.
    num_critics: int = 1
    # n-step TD targets for the critic (parallel_skills.nstep; the paper's learner trains on
    # trajectories of length 10, App. B.3). 1: one-step TD over single transitions (the layout and
    # numerics of runs from before this field). Uncorrected returns of the behaviour's next n steps.
    n_step: int = 1
    # α = 1: pure CRR; α < 1: loss = α·CRR + (1 − α)·MPO (App. B "baselines").
    mpo_alpha: float = 1.0
    mpo_num_samples: int = 20  # sampled actions for the Gaussian MPO E-step.
    mpo_epsilon: float = 0.1
    mpo_epsilon_mean: float = 5e-3
    mpo_epsilon_stddev: float = 1e-5
    mpo_init_log_temperature: float = 1.0
    mpo_init_log_alpha_mean: float = 1.0
    mpo_init_log_alpha_stddev: float = 10.0
    dual_learning_rate: float = 1e-2
    # Lower bound of the policy's std (actions in [-1, 1]). With a state-dependent std and a
    # near-zero floor, the weighted log-likelihood lets the std collapse on easy states and
    # all but ignore the mean's error on hard ones (the gradient on the mean scales with 1/std²):
    # cloning the scripted lift with min_std 1e-3 gave success 0.00, with 0.05 0.97
    # (docs/learning.md). 0.05 keeps every state's error in the loss.
    min_std: float = 0.05
    grad_clip_norm: float = 40.0

    def __post_init__(self):
        check_ranges(self)
        if self.crr_mode not in ("exp", "indicator"):
            raise ValueError(f"crr_mode must be 'exp' or 'indicator', got {self.crr_mode!r}")
        if int(self.num_critics) < 1:
            raise ValueError(f"num_critics must be a positive integer, got {self.num_critics}")
        if int(self.n_step) < 1:
            raise ValueError(f"n_step must be a positive integer, got {self.n_step}")
        if not 0.0 <= self.mpo_alpha <= 1.0:
            raise ValueError(f"mpo_alpha must be in [0, 1], got {self.mpo_alpha}")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Run-level settings. ``None`` fields take device-dependent defaults (``resolve``)."""

    num_envs: Optional[int] = None  # CPU: 32, accelerator: 4096
    unroll_length: int = 25  # env steps per env per iteration
    replay_size: Optional[int] = None  # CPU: 300k, accelerator: 1M (paper)
    method: str = "skills"  # "skills" (SkillS) or "scratch" (the new skill acting alone)
    eval_episodes: int = 16
    eval_every: int = 20  # iterations between evaluations
    # Std of Gaussian noise added to the frozen skills' actions while collecting (not in
    # evaluation). The paper's skills are stochastic Gaussian policies; deterministic (e.g.
    # scripted) skills give the new skill no data off their exact paths to learn recovery
    # from: cloning scripted lift from its noise-free paths fails (docs/learning.md).
    skill_noise_std: float = 0.3
    scheduler: SchedulerConfig = SchedulerConfig()
    new_skill: NewSkillConfig = NewSkillConfig()

    METHODS = ("skills", "scratch")

    def __post_init__(self):
        if self.method not in self.METHODS:
            raise ValueError(f"method must be 'skills' or 'scratch', got {self.method!r}")
        check_ranges(self)

    @property
    def steps_per_iteration(self) -> int:
        """Env steps collected per iteration (num_envs · unroll_length; needs a resolved config)."""
        return int(self.num_envs) * int(self.unroll_length)


def updates_per_iteration(samples_per_insert: float, num_inserted: int, batch_size: int) -> int:
    """Learner updates per collect iteration (docs/design.md "Defaults"):
    round(spi · inserted / batch_size), at least 1."""
    return max(1, int(round(samples_per_insert * num_inserted / batch_size)))


def learner_schedule(config: TrainConfig) -> dict:
    """What a resolved config makes the learners do per iteration: for each learner its batch
    size, updates per iteration and sampled rows per collected env step (the scheduler's batch is
    augmented to twice its rows: counted once, as samples-per-insert counts it). From scratch the
    scheduler does not learn (0 updates)."""
    steps = config.steps_per_iteration
    out = {"env_steps_per_iteration": steps}
    for name in ("scheduler", "new_skill"):
        sub = getattr(config, name)
        n = updates_per_iteration(sub.samples_per_insert, steps, sub.batch_size)
        if name == "scheduler" and config.method != "skills":
            n = 0
        out[name] = {"batch_size": sub.batch_size, "updates_per_iteration": n,
                     "samples_per_env_step": round(n * sub.batch_size / steps, 3)}
    return out


def describe_schedule(schedule: dict) -> str:
    """One line for the log: ``learner_schedule`` in words."""
    parts = [f"{name.replace('_', '-')} batch {s['batch_size']} x {s['updates_per_iteration']} updates "
             f"({s['samples_per_env_step']:g} samples per env step)"
             for name, s in ((n, schedule[n]) for n in ("scheduler", "new_skill"))]
    return (f"learners per iteration of {schedule['env_steps_per_iteration']:,} env steps: " + "; ".join(parts))


# ----------------------------------------------------------------------------- device defaults

# The CPU recipe (docs/learning.md: with it, kinematic lift from the useful skills reaches 0.91 at
# 240k env steps and 0.99 at 400k for seed 0; seeds 1, 2 are at 0.13 / 0.41 after 200k). Learners
# dominate on a CPU (≈1 update per env step at the paper's ratios), so the scheduler takes fewer
# samples per insert and learns its critic alone for its first updates (Eq. 3's long-horizon values
# first); the new skill keeps a high replay ratio (at 16 it did not learn lift in 300k steps) with
# CRR's indicator weights.
CPU_DEFAULTS = dict(num_envs=32, replay_size=300_000, scheduler_spi=8.0, scheduler_policy_warmup_updates=1500,
                    new_skill_spi=64.0, new_skill_crr_mode="indicator")


# The CPU recipe's learner fields: (learner, field) -> (CPU value, the paper's value).
CPU_RECIPE = {
    ("scheduler", "samples_per_insert"): (CPU_DEFAULTS["scheduler_spi"], SchedulerConfig.samples_per_insert),
    ("scheduler", "policy_warmup_updates"): (CPU_DEFAULTS["scheduler_policy_warmup_updates"],
                                             SchedulerConfig.policy_warmup_updates),
    ("new_skill", "samples_per_insert"): (CPU_DEFAULTS["new_skill_spi"], NewSkillConfig.samples_per_insert),
    ("new_skill", "crr_mode"): (CPU_DEFAULTS["new_skill_crr_mode"], NewSkillConfig.crr_mode),
}


def _show(value) -> str:
    return f"{value:g}" if isinstance(value, (int, float)) else str(value)


def resolve(config: TrainConfig, backend: Optional[str] = None,
            given: Optional[Sequence[str]] = None) -> tuple[TrainConfig, list[str]]:
    """Fill device-dependent defaults. Returns the config and human-readable notes of what was
    chosen automatically (to log).

    On a CPU, ``num_envs`` / ``replay_size`` left None get the CPU sizes, and the learners the CPU
    recipe (``CPU_RECIPE``). ``given``: the dotted names of the fields the user set (``training.run``:
    those of its config file, e.g. ``"new_skill.n_step"``): every recipe field not among them takes
    the recipe. ``None`` (callers that build a config in code, and configs resolved already): a
    learner config takes the recipe only when all its fields are the paper's, so a resolved config
    is never changed."""
    if backend is None:
        import jax

        backend = jax.default_backend()
    if backend != "cpu":
        return dataclasses.replace(config, num_envs=4096 if config.num_envs is None else config.num_envs,
                                   replay_size=1_000_000 if config.replay_size is None else config.replay_size), []
    notes: list[str] = []
    cfg = config
    if cfg.num_envs is None:
        cfg = dataclasses.replace(cfg, num_envs=CPU_DEFAULTS["num_envs"])
        notes.append(f"num_envs={cfg.num_envs}")
    if cfg.replay_size is None:
        cfg = dataclasses.replace(cfg, replay_size=CPU_DEFAULTS["replay_size"])
        notes.append(f"replay_size={cfg.replay_size}")
    given = None if given is None else set(given)
    for learner, default in (("scheduler", SchedulerConfig()), ("new_skill", NewSkillConfig())):
        sub = getattr(cfg, learner)
        if given is None and sub != default:
            continue
        changes = {f: cpu for (name, f), (cpu, _) in CPU_RECIPE.items()
                   if name == learner and (given is None or f"{learner}.{f}" not in given)}
        if changes:
            cfg = dataclasses.replace(cfg, **{learner: dataclasses.replace(sub, **changes)})
            notes.append(f"{learner.replace('_', '-')} " + ", ".join(
                f"{f}={_show(v)} (paper {_show(CPU_RECIPE[(learner, f)][1])})" for f, v in changes.items()))
    return cfg, notes


# ----------------------------------------------------------------------------- JSON input

NESTED = ("scheduler", "new_skill")


def _check_value(where: str, name: str, default, value):
    """Type / range check of one JSON value against the field's default; returns the value."""
    def bad(what):
        return ValueError(f"{where}: {name} must be {what}, got {json.dumps(value)}")

    is_int = isinstance(value, int) and not isinstance(value, bool)
    lo = 1 if name.rsplit(".", 1)[-1] in POSITIVE_FIELDS else 0
    if default is None:  # device-dependent size (num_envs, replay_size)
        if value is None:
            return None
        if not is_int or value < lo:
            raise bad("a positive integer or null")
        return value
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if isinstance(default, int):
        if not is_int or value < lo:
            raise bad("a positive integer" if lo else "a non-negative integer")
        return value
    if isinstance(default, float):
        if not (is_int or isinstance(value, float)) or not math.isfinite(value):
            raise bad("a finite number")
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise bad("a string")
        return value
    if isinstance(default, tuple):
        if (not isinstance(value, (list, tuple)) or not value
                or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in value)):
            raise bad("a non-empty list of positive integers")
        return tuple(value)
    return value


def from_dict(cfg: TrainConfig, data: dict, where: str) -> TrainConfig:
    """``cfg`` with the TrainConfig fields of the JSON object ``data`` (nested scheduler / new_skill
    objects) set; every name, type and range checked. ``where`` names the source in the one-line
    ValueError."""
    if not isinstance(data, dict):
        raise ValueError(f"{where} must hold a JSON object of TrainConfig fields")
    top = {f.name for f in dataclasses.fields(cfg)}
    updates = {}
    for key, value in data.items():
        if key not in top:
            raise ValueError(f"unknown config field {key!r} in {where}; valid: {', '.join(sorted(top))}")
        if key in NESTED:
            sub = getattr(cfg, key)
            if not isinstance(value, dict):
                raise ValueError(f"{where}: {key} must be a JSON object of {type(sub).__name__} fields")
            valid = {f.name for f in dataclasses.fields(sub)}
            bad = sorted(set(value) - valid)
            if bad:
                raise ValueError(f"unknown {key} config field(s) {bad} in {where}; valid: {', '.join(sorted(valid))}")
            checked = {k: _check_value(where, f"{key}.{k}", getattr(sub, k), v) for k, v in value.items()}
            try:
                value = dataclasses.replace(sub, **checked)
            except (ValueError, TypeError) as e:
                raise ValueError(f"{where}: invalid {key} config: {e}") from None
        else:
            value = _check_value(where, key, getattr(cfg, key), value)
        updates[key] = value
    try:
        return dataclasses.replace(cfg, **updates)
    except (ValueError, TypeError) as e:
        raise ValueError(f"{where}: invalid config: {e}") from None


def dotted_names(data: dict, prefix: str = "") -> list[str]:
    """``{"a": 1, "new_skill": {"n_step": 3}}`` -> ``["a", "new_skill.n_step"]``."""
    out = []
    for k, v in data.items():
        out += dotted_names(v, f"{prefix}{k}.") if isinstance(v, dict) else [f"{prefix}{k}"]
    return out


def first_difference(a, b, prefix=""):
    """``(dotted field, a's value, b's value)`` of the first field two configs differ in, or None."""
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if dataclasses.is_dataclass(x):
            d = first_difference(x, y, f"{prefix}{f.name}.")
            if d:
                return d
        elif x != y:
            return f"{prefix}{f.name}", x, y
    return None
