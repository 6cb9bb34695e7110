"""Configurations: the learners' (paper defaults, SkillS App. B.3, manipulation), the run's
(``TrainConfig``), the recipes (cpu, parallel, paper) and ``resolve`` (device-dependent defaults), and the checks of
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

from parallel_skills import methods

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
    # False: the scheduler never chooses the new skill (the paper's Fig. 6a ablation; the new skill
    # still learns from every transition). networks.SchedulerPolicy gives it a −1e9 logit bias.
    new_skill_choice: bool = True
    # n-step targets for the critic within skill executions (replay.SchedulerNStepTransition,
    # nstep.execution_nstep_fields): Q(s_t, c, i, k) regresses on the next m = min(n, c̄) rewards and
    # the value at s_{t+m} (c̄: the counter of the labelling, the augmented one's included), exact
    # for the option being evaluated (no decision inside an execution). 1: the one-step Eq. 3 (paper).
    n_step: int = 1
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


# NewSkillConfig.baseline -> whether its loss reads the frozen skills' actions at the batch's
# states (the methods whose ``teacher_baseline`` it is pass them: ``methods``).
BASELINE_READS_TEACHER = {"mpo": False, "kl_reg": True, "dagger": True}
BASELINES = tuple(BASELINE_READS_TEACHER)


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
    # α = 1: pure CRR; α < 1: loss = α·CRR + (1 − α)·L_baseline (App. B: every baseline shares
    # this mix and the paper sweeps α ∈ {0, 0.5, 1}).
    mpo_alpha: float = 1.0
    # L_baseline (``BASELINES``; parallel_skills.baseline_losses): "mpo" Gaussian MPO (Abdolmaleki
    # et al. 2018); "kl_reg" MPO whose E-step samples the frozen skills' mixture π₀ as prior and
    # proposal, KL(q ‖ π₀) ≤ mpo_epsilon (the paper sweeps ε ∈ {0.1, 1, 100}); "dagger"
    # dagger_alpha·(−E_π₀ log π) + (1 − dagger_alpha)·MPO (α_D ∈ {0, 0.5, 1}). The last two read the
    # skills' actions at the batch's states (``train.make_trainer`` passes them for
    # ``TrainConfig.method`` kl_reg / dagger, which set this field in ``resolve``).
    baseline: str = "mpo"
    dagger_alpha: float = 1.0
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
        if self.baseline not in BASELINES:
            raise ValueError(f"baseline must be one of {', '.join(BASELINES)}, got {self.baseline!r}")
        if not 0.0 <= self.dagger_alpha <= 1.0:
            raise ValueError(f"dagger_alpha must be in [0, 1], got {self.dagger_alpha}")

    @property
    def reads_teacher(self) -> bool:
        """Whether the policy loss reads the frozen skills' actions (a teacher baseline in the mix)."""
        return self.mpo_alpha < 1.0 and BASELINE_READS_TEACHER[self.baseline]


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Run-level settings. ``None`` fields take device-dependent defaults (``resolve``)."""

    # The learners' recipe (``recipe_values``): "cpu", "parallel" or "paper"; None: "cpu" on a CPU
    # backend, "parallel" on an accelerator (``resolve`` names it).
    recipe: Optional[str] = None
    num_envs: Optional[int] = None  # None: the recipe's (CPU: 32, or 1,024 for "parallel"; accelerator: 4096)
    unroll_length: int = 25  # env steps per env per iteration
    replay_size: Optional[int] = None  # CPU: 300k, accelerator: 1M (paper)
    # ``methods.names()``: "skills" (SkillS). The new skill acting alone: "scratch" (no skills), "finetune"
    # (initialised from one library skill: its parameters and observation statistics, the latter
    # then kept fixed), "kl_reg" / "dagger" (the skills as the prior / teacher of its loss:
    # NewSkillConfig.baseline). "rhpo": a mixture of the frozen skills and the new skill chosen at
    # every step (parallel_skills.rhpo). Paper App. B; the README's "Baselines"; ``parallel_skills.methods``.
    method: str = "skills"
    eval_episodes: int = 16
    eval_every: int = 20  # iterations between evaluations
    # Std of Gaussian noise added to the frozen skills' actions while collecting (not in
    # evaluation). The paper's skills are stochastic Gaussian policies; deterministic (e.g.
    # scripted) skills give the new skill no data off their exact paths to learn recovery
    # from: cloning scripted lift from its noise-free paths fails (docs/learning.md).
    skill_noise_std: float = 0.3
    scheduler: SchedulerConfig = SchedulerConfig()
    new_skill: NewSkillConfig = NewSkillConfig()

    def __post_init__(self):
        method = methods.get(self.method)
        baseline = self.new_skill.baseline
        if BASELINE_READS_TEACHER[baseline] and method.teacher_baseline != baseline:
            teachers = [m.name for m in methods.all_methods() if m.teacher_baseline == baseline]
            raise ValueError(f"new_skill.baseline {baseline!r} reads the skills' actions: it needs "
                             f"method {' or '.join(map(repr, teachers))}, got method {self.method!r}")
        if self.recipe is not None and self.recipe not in RECIPES:
            raise ValueError(f"recipe must be one of {', '.join(RECIPES)} (or null: the device's), got {self.recipe!r}")
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
    size, updates per iteration and sampled rows per collected env step (the scheduler's
    augmented labels are not counted: samples-per-insert counts sampled rows). A method without
    the scheduler's learner (``Method.learns_scheduler``) gives it 0 updates."""
    steps = config.steps_per_iteration
    out = {"env_steps_per_iteration": steps}
    for name in ("scheduler", "new_skill"):
        sub = getattr(config, name)
        n = updates_per_iteration(sub.samples_per_insert, steps, sub.batch_size)
        if name == "scheduler" and not methods.get(config.method).learns_scheduler:
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


# ----------------------------------------------------------------------------- recipes

RECIPES = ("cpu", "parallel", "paper")

# Run sizes left None: (recipe, on a CPU backend?) -> (num_envs, replay_size).
RECIPE_SIZES = {("cpu", True): (32, 300_000), ("parallel", True): (1024, 300_000), ("paper", True): (32, 300_000),
                ("cpu", False): (4096, 1_000_000), ("parallel", False): (4096, 1_000_000),
                ("paper", False): (4096, 1_000_000)}


def recipe_values(recipe: str, num_envs: int, unroll_length: int) -> dict:
    """The learner fields a recipe sets: ``{(learner, field): value}``, learner "scheduler" or
    "new_skill" (and ``RECIPE_UNROLL``: its unroll length). Measured in docs/scaling.md.

    * ``paper``: nothing (App. B.3: batches 128 / 256, samples per insert 100 / 50, one-step CRR
      with exp weights). At 4,096 envs × 25 steps that is 80,000 + 20,000 updates per iteration.
    * ``cpu`` (the default on a CPU backend; 32 envs): the learners are FLOP-bound there, so
      fewer samples per env step than the paper (scheduler 8, new skill 16), a critic-only
      warm-up for the scheduler (Eq. 3's long-horizon values first), and for the new skill CRR's
      indicator weights with 10-step TD targets, which carry the sparse reward back with 4× fewer
      samples than the one-step recipe needed (64).
    * ``parallel`` (the default on an accelerator): one env step per env per iteration and a fixed
      32 updates of batches that grow with the envs: scheduler batch 25·steps/8 × 8 updates
      (25 samples per env step, 4× below the paper's 100), new skill batch = steps × 24 updates
      (24 per env step, the paper's 50 / 2.1), 10-step TD targets; the update-counted schedules
      (warm-up, target periods) are shortened to keep their env-step meaning at 1,024 envs.
    """
    if recipe not in RECIPES:
        raise ValueError(f"unknown recipe {recipe!r}; valid: {', '.join(RECIPES)}")
    if recipe == "paper":
        return {}
    if recipe == "cpu":
        return {("scheduler", "samples_per_insert"): 8.0, ("scheduler", "policy_warmup_updates"): 1500,
                ("new_skill", "samples_per_insert"): 16.0, ("new_skill", "crr_mode"): "indicator",
                ("new_skill", "n_step"): 10}
    steps = int(num_envs) * int(unroll_length)
    return {("scheduler", "batch_size"): max(1, steps * 25 // 8), ("scheduler", "samples_per_insert"): 25.0,
            ("scheduler", "policy_warmup_updates"): 190, ("scheduler", "target_actor_period"): 12,
            ("scheduler", "target_critic_period"): 3,
            ("new_skill", "batch_size"): steps, ("new_skill", "samples_per_insert"): 24.0,
            ("new_skill", "crr_mode"): "indicator", ("new_skill", "n_step"): 10,
            ("new_skill", "target_actor_period"): 2, ("new_skill", "target_critic_period"): 10}


RECIPE_UNROLL = {"parallel": 1}  # unroll_length a recipe sets (when left at the default)


def _show(value) -> str:
    return f"{value:g}" if isinstance(value, (int, float)) else str(value)


def resolve(config: TrainConfig, backend: Optional[str] = None,
            given: Optional[Sequence[str]] = None) -> tuple[TrainConfig, list[str]]:
    """Fill the defaults of the config's recipe (``recipe_values``). Returns the config, with its
    ``recipe`` named, and human-readable notes of what was chosen automatically (to log).

    ``recipe`` None: "cpu" on a CPU backend, "parallel" on an accelerator. ``num_envs`` /
    ``replay_size`` left None take the recipe's sizes (``RECIPE_SIZES``). ``given``: the dotted
    names of the fields the user set (``training.run``: those of its config file and flags, e.g.
    ``"new_skill.n_step"``): every recipe field not among them takes the recipe. ``None``
    (callers that build a config in code, and configs resolved already): a learner config takes
    the recipe only when all its fields are the paper's, ``unroll_length`` only at its default,
    so a resolved config is never changed."""
    if backend is None:
        import jax

        backend = jax.default_backend()
    on_cpu = backend == "cpu"
    recipe = config.recipe or ("cpu" if on_cpu else "parallel")
    notes: list[str] = [] if config.recipe else [f"recipe={recipe}"]
    envs, replay = RECIPE_SIZES[(recipe, on_cpu)]
    cfg = dataclasses.replace(config, recipe=recipe)
    if cfg.num_envs is None:
        cfg = dataclasses.replace(cfg, num_envs=envs)
        notes.append(f"num_envs={envs}")
    if cfg.replay_size is None:
        cfg = dataclasses.replace(cfg, replay_size=replay)
        notes.append(f"replay_size={replay}")
    given = None if given is None else set(given)
    unroll = RECIPE_UNROLL.get(recipe)
    if unroll is not None and (cfg.unroll_length != unroll) and (
            "unroll_length" not in given if given is not None else cfg.unroll_length == TrainConfig.unroll_length):
        cfg = dataclasses.replace(cfg, unroll_length=unroll)
        notes.append(f"unroll_length={unroll} (paper {TrainConfig.unroll_length})")
    values = recipe_values(recipe, cfg.num_envs, cfg.unroll_length)
    for learner, default in (("scheduler", SchedulerConfig()), ("new_skill", NewSkillConfig())):
        sub = getattr(cfg, learner)
        if given is None and sub != default:
            continue
        changes = {f: v for (name, f), v in values.items()
                   if name == learner and (given is None or f"{learner}.{f}" not in given) and getattr(sub, f) != v}
        if changes:
            cfg = dataclasses.replace(cfg, **{learner: dataclasses.replace(sub, **changes)})
            notes.append(f"{learner.replace('_', '-')} " + ", ".join(
                f"{f}={_show(v)} (paper {_show(getattr(default, f))})" for f, v in changes.items()))
    cfg, method_notes = methods.get(cfg.method).resolve(cfg, None if given is None else sorted(given))
    return cfg, notes + method_notes


# ----------------------------------------------------------------------------- JSON input

NESTED = ("scheduler", "new_skill")


def _check_value(where: str, name: str, default, value):
    """Type / range check of one JSON value against the field's default; returns the value."""
    def bad(what):
        return ValueError(f"{where}: {name} must be {what}, got {json.dumps(value)}")

    is_int = isinstance(value, int) and not isinstance(value, bool)
    lo = 1 if name.rsplit(".", 1)[-1] in POSITIVE_FIELDS else 0
    if name == "recipe":
        if value is not None and value not in RECIPES:
            raise bad(f"one of {', '.join(RECIPES)} or null")
        return value
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
