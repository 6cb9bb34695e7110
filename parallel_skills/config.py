"""Configurations: the learners' (paper defaults, SkillS App. B.3, manipulation), the run's
(``TrainConfig``; ``RunConfig``: length, seed, checkpoints), the recipes (cpu, parallel, paper) and
``resolve`` (device-dependent defaults), and the checks of every value.

Every value is checked here alone, by the classes: each ``__post_init__`` runs ``check_fields``
(types and ranges, from the fields' types) and then its class's own rules. A value that one field
does not allow is a ``FieldError`` (field, what is allowed, value), which the inputs turn into
their one-line messages: ``from_dict`` for JSON (config files, a run's config.json) and
``training.config_flags`` for the command line, whose flags are generated from these fields.

All configs are frozen, hashable ``dataclasses.dataclass`` objects: pass them as
static arguments to ``jax.jit`` (or close over them); every field is a Python scalar,
string or tuple, never an array.

Target-network periods are deliberately different for the two learners (App. B.3):
scheduler actor 100 / critic 25, new skill actor 25 / critic 100.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import numbers
import typing
from typing import Optional, Sequence, Tuple

from parallel_skills import methods

# Integer fields that must be >= 1 (every other integer field must be >= 0), in any config class.
POSITIVE_FIELDS = frozenset({
    "num_envs", "replay_size", "unroll_length", "eval_episodes", "eval_every", "batch_size",
    "target_actor_period", "target_critic_period", "num_action_samples", "mpo_num_samples",
    "num_critics", "n_step", "num_timesteps", "episode_length", "checkpoint_every"})
# Float fields that must lie in [0, 1] (every other float field must be finite), in any config class.
UNIT_INTERVAL_FIELDS = frozenset({"mpo_alpha", "dagger_alpha", "greedy_env_fraction", "policy_ema"})


class FieldError(ValueError):
    """A value that one field does not allow whatever the other fields hold: ``name`` (dotted
    from the outermost config where it is re-raised, ``within``), ``allowed`` (a noun phrase:
    "a positive integer"), ``value``; a ``nullable`` field also takes None (JSON null).
    A rule that relates several fields raises a plain ValueError instead."""

    def __init__(self, name: str, allowed: str, value, nullable: bool = False):
        super().__init__(name, allowed, value, nullable)
        self.name, self.allowed, self.value, self.nullable = name, allowed, value, nullable

    def __str__(self) -> str:
        allowed = self.allowed + (" or null" if self.nullable else "")
        shown = repr(self.value) if isinstance(self.value, str) else json.dumps(self.value, default=str)
        return f"{self.name} must be {allowed}, got {shown}"

    def within(self, prefix: str) -> "FieldError":
        """The same error, its field named from an enclosing config (``prefix`` "scheduler.")."""
        return FieldError(prefix + self.name, self.allowed, self.value, self.nullable)


@functools.lru_cache(maxsize=None)
def field_types(cls) -> dict:
    """``{field name: (type, nullable)}`` of a config class: ``Optional[int]`` -> ``(int, True)``,
    ``Tuple[int, ...]`` -> ``(tuple, False)``, a nested config -> ``(its class, False)``."""
    out = {}
    for name, hint in typing.get_type_hints(cls).items():
        args = typing.get_args(hint)
        nullable = typing.get_origin(hint) is typing.Union and type(None) in args
        if nullable:
            hint = next(a for a in args if a is not type(None))
        out[name] = (typing.get_origin(hint) or hint, nullable)
    return {f.name: out[f.name] for f in dataclasses.fields(cls)}


def allowed_values(name: str, kind) -> str:
    """What the type / range rule lets field ``name`` of type ``kind`` hold, as a noun phrase."""
    if kind is bool:
        return "true or false"
    if kind is int:
        return "a positive integer" if name in POSITIVE_FIELDS else "a non-negative integer"
    if kind is float:
        return "a number in [0, 1]" if name in UNIT_INTERVAL_FIELDS else "a finite number"
    if kind is tuple:
        return "a non-empty list of positive integers"
    if kind is str:
        return "a string"
    return f"a {kind.__name__}"


def fits(name: str, kind, value) -> bool:
    """Whether ``value`` has field ``name``'s type ``kind`` and lies in its range (``allowed_values``)."""
    def integer(v, lo):
        return isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= lo

    if kind is bool:
        return isinstance(value, bool)
    if kind is int:
        return integer(value, 1 if name in POSITIVE_FIELDS else 0)
    if kind is float:
        if not isinstance(value, numbers.Real) or isinstance(value, bool) or not math.isfinite(value):
            return False
        return 0.0 <= value <= 1.0 if name in UNIT_INTERVAL_FIELDS else True
    if kind is tuple:
        return isinstance(value, (tuple, list)) and len(value) > 0 and all(integer(v, 1) for v in value)
    return isinstance(value, kind)


def check_fields(config) -> None:
    """The type and range rule of every config class, from its fields' types: integers ≥ 1
    (``POSITIVE_FIELDS``) or ≥ 0, floats finite (in [0, 1]: ``UNIT_INTERVAL_FIELDS``), tuples
    non-empty of positive integers, booleans and strings as typed; None only where the type is
    Optional. FieldError naming the first field that breaks it. Each class's ``__post_init__``
    calls it, then checks its own rules."""
    for name, (kind, nullable) in field_types(type(config)).items():
        value = getattr(config, name)
        if value is None and nullable:
            continue
        if not fits(name, kind, value):
            raise FieldError(name, allowed_values(name, kind), value, nullable)


def check_choice(name: str, value, choices: Sequence[str], allowed: str, nullable: bool = False) -> None:
    """FieldError unless ``value`` is one of ``choices`` (or None, ``nullable``); ``allowed`` says them."""
    if not (value in choices or (nullable and value is None)):
        raise FieldError(name, allowed, value, nullable)


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
        check_fields(self)
        lengths = tuple(self.skill_lengths)
        if list(lengths) != sorted(set(lengths)):
            raise FieldError("skill_lengths", "positive, unique and ascending integers", lengths)
        if not 0.0 < self.initial_max_length_prob < 1.0 and len(lengths) > 1:
            raise ValueError(f"initial_max_length_prob must be in (0, 1) with more than one skill length, "
                             f"got {self.initial_max_length_prob}")

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
N_STEP_RETURNS = ("behaviour", "own")  # NewSkillConfig.n_step_returns


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
    discount: float = 0.99
    crr_mode: str = "exp"  # "exp": min(exp(A/β), clip); "indicator": 1[A > 0].
    crr_beta: float = 1.0
    crr_clip: float = 20.0
    num_action_samples: int = 4  # J: samples for the CRR baseline and the TD target.
    # The action at s' in the critic's TD target: "sampled" (the paper's CRR: the mean of Q' over J
    # actions of the target policy, so Q values the Gaussian as it acts) or "mean" (beyond the paper:
    # Q'(s', μ'(s')), so Q values the deterministic read-out, the policy the new skill is evaluated
    # and deployed as). With "sampled", a state where the mean dwells (holding a cube over its
    # target) is valued as the sampled policy that leaves it on its noise, so dwelling costs only
    # discount and CRR's weights cannot single out the one leaving step (docs/research/skills.md).
    td_target_action: str = "sampled"
    # > 1: clipped double Q (Fujimoto et al. 2018): independent critics, the TD target and the CRR
    # advantage use their minimum. With one critic (CRR as in the paper) the new skill's Q drifted
    # above any achievable return on sparse stack (114 > r_max/(1-γ) = 100 at rewarded replay
    # states; 2.5-8x the measured return at hover states); two critics keep it below the bound, but
    # did not make stack learn within 200k steps (docs/research/learning.md), so the default stays 1. The
    # ``parallel`` recipe takes 2 (docs/research/scaling.md: lift at 1,024 envs holds on every seed with them).
    num_critics: int = 1
    # τ > 0 (beyond the paper): keep an exponential moving average of the policy's parameters,
    # ema ← ema + τ·(θ − ema) after every update (Polyak averaging of the iterates), and deploy it:
    # it is the new skill that evaluations report (``eval/new_skill_*``; the online policy beside it
    # as ``eval/new_skill_online_*``, the same episodes), that the greedy scheduler runs, and that
    # new_skill.npz / export.npz hold (``LearnerState.deployed_policy_params``). Training (acting,
    # targets, losses) reads only the online policy, so a run trains the same with or without it.
    # 0: none kept.
    policy_ema: float = 0.0
    # n-step TD targets for the critic (parallel_skills.nstep; the paper's learner trains on
    # trajectories of length 10, App. B.3). 1: one-step TD over single transitions (the layout and
    # numerics of runs from before this field). Uncorrected returns of the behaviour's next n steps.
    n_step: int = 1
    # Whose steps the n-step returns follow (n_step > 1): "behaviour" (Acme's uncorrected n-step:
    # the next n steps, whichever skill the scheduler ran) or "own" (beyond the paper;
    # nstep.own_nstep_fields): a return stops before the first later step another skill took and
    # bootstraps there, so Q(s, a) values what the new skill itself does after a. With
    # "behaviour", holding a cube over its target is credited with the release that the
    # scheduler's next skill makes within n steps, so the new skill's critic does not rank
    # releasing above holding (docs/research/skills.md).
    n_step_returns: str = "behaviour"
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
    # (docs/research/learning.md). 0.05 keeps every state's error in the loss.
    min_std: float = 0.05
    grad_clip_norm: float = 40.0

    def __post_init__(self):
        check_fields(self)
        check_choice("crr_mode", self.crr_mode, ("exp", "indicator"), "'exp' or 'indicator'")
        check_choice("td_target_action", self.td_target_action, ("sampled", "mean"), "'sampled' or 'mean'")
        check_choice("n_step_returns", self.n_step_returns, N_STEP_RETURNS, "'behaviour' or 'own'")
        check_choice("baseline", self.baseline, BASELINES, f"one of {', '.join(BASELINES)}")

    @property
    def reads_teacher(self) -> bool:
        """Whether the policy loss reads the frozen skills' actions (a teacher baseline in the mix)."""
        return self.mpo_alpha < 1.0 and BASELINE_READS_TEACHER[self.baseline]


NEW_SKILL_COLLECTS = ("sampled", "mean")  # TrainConfig.new_skill_collects


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
    # every step (parallel_skills.rhpo). Paper App. B; README "Configure"; ``parallel_skills.methods``.
    method: str = "skills"
    eval_episodes: int = 16
    eval_every: int = 20  # iterations between evaluations
    # What an evaluation reads out: False, the new skill alone (mean actions: what is deployed and
    # exported; and its sampled actions) and the greedy scheduler; True, also the diagnostics: the
    # new skill through its own critic (critic-weighted), the greedy scheduler with the new skill's
    # actions sampled, and the scheduler as it collects with its critic's value at the resets.
    eval_diagnostics: bool = False
    # Std of Gaussian noise added to the frozen skills' actions while collecting (not in
    # evaluation). The paper's skills are stochastic Gaussian policies; deterministic (e.g.
    # scripted) skills give the new skill no data off their exact paths to learn recovery
    # from: cloning scripted lift from its noise-free paths fails (docs/research/learning.md).
    skill_noise_std: float = 0.3
    # Fraction of the training envs (the first round(f · num_envs)) that collect as the greedy
    # evaluation acts: argmax decisions, the new skill's mean action, no collection noise (beyond
    # the paper; Ape-X's per-actor exploration levels). Their data show the learners the states the
    # deterministic read-outs reach. 0: every env explores (the paper).
    greedy_env_fraction: float = 0.0
    # How the new skill acts when the scheduler picks it while collecting: "sampled" from its
    # Gaussian (the paper) or its "mean" action, as every read-out of it acts (beyond the paper):
    # the scheduler's critic then values choosing the new skill by what its mean does, and the
    # exploration comes from the scheduler's choices and the frozen skills' collection noise.
    new_skill_collects: str = "sampled"
    scheduler: SchedulerConfig = SchedulerConfig()
    new_skill: NewSkillConfig = NewSkillConfig()

    def __post_init__(self):
        check_fields(self)
        check_choice("recipe", self.recipe, RECIPES, f"one of {', '.join(RECIPES)}", nullable=True)
        check_choice("method", self.method, methods.names(), f"one of {', '.join(methods.names())}")
        check_choice("new_skill_collects", self.new_skill_collects, NEW_SKILL_COLLECTS, "'sampled' or 'mean'")
        if self.new_skill_collects == "mean" and not methods.get(self.method).scheduler_acts:
            raise ValueError(f"new_skill_collects 'mean' needs a method whose scheduler acts (else nothing "
                             f"explores), got method {self.method!r}")
        baseline = self.new_skill.baseline
        if BASELINE_READS_TEACHER[baseline] and methods.get(self.method).teacher_baseline != baseline:
            teachers = [m.name for m in methods.all_methods() if m.teacher_baseline == baseline]
            raise ValueError(f"new_skill.baseline {baseline!r} reads the skills' actions: it needs "
                             f"method {' or '.join(map(repr, teachers))}, got method {self.method!r}")

    @property
    def steps_per_iteration(self) -> int:
        """Env steps collected per iteration (num_envs · unroll_length; needs a resolved config)."""
        return int(self.num_envs) * int(self.unroll_length)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """A run's length, seed and checkpoints: the arguments of ``train`` besides its ``TrainConfig``
    (checked here; ``training.run`` has a flag of each name and records them in config.json)."""

    # Env steps to train for; None: training.run's default (256k on a CPU, 20M on an accelerator).
    num_timesteps: Optional[int] = None
    seed: int = 0
    episode_length: Optional[int] = None  # env steps per episode; None: the task's
    # The env's reset distribution (tasks.make(..., start_states=)): "table" (the paper's resets) or
    # "mixed" (also one cube on or beside another; kinematic physics) or "TOP_on_BOTTOM" (half the
    # resets with that cube resting on the other, e.g. "yellow_on_blue"; kinematic) or "after:NAME:K"
    # (half where library skill NAME leaves the table resets after K steps; kinematic).
    start_states: str = "table"
    # Env steps between checkpoints; None: at evaluations, at most once a minute, and at the end
    # (training.run keeps the latest 2).
    checkpoint_every: Optional[int] = None

    def __post_init__(self):
        check_fields(self)


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
    "new_skill" (and ``RECIPE_UNROLL``: its unroll length). Measured in docs/research/scaling.md.

    * ``paper``: nothing (App. B.3: batches 128 / 256, samples per insert 100 / 50, one-step CRR
      with exp weights). At 4,096 envs × 25 steps that is 80,000 + 20,000 updates per iteration.
    * ``cpu`` (the default on a CPU backend; 32 envs): the learners are FLOP-bound there, so
      fewer samples per env step than the paper (scheduler 8, new skill 16), a critic-only
      warm-up for the scheduler (Eq. 3's long-horizon values first), and for the new skill 10-step
      TD targets, which carry the sparse reward back with 4× fewer samples than the one-step
      recipe needed (64), with the paper's CRR exp weights (until 2026-12-04 the indicator's, whose
      mean action held the cube over the target on stack and never let go: docs/research/scheduler.md §8);
      and for the scheduler 10-step targets within skill executions (``SchedulerConfig.n_step``;
      one-step Eq. 3 until 2026-12-04), with which it learns triple stack within 3M env steps
      (docs/research/scheduler.md §1, §9).
    * ``parallel`` (the default on an accelerator): one env step per env per iteration and a fixed
      32 updates of batches that grow with the envs: scheduler batch 25·steps/8 × 8 updates
      (25 samples per env step, 4× below the paper's 100), new skill batch = steps × 24 updates
      (24 per env step, the paper's 50 / 2.1), 10-step TD targets, two new-skill critics (clipped
      double Q; since 2026-12-06: every seed of kinematic lift at 1,024 envs reaches 0.8 and holds
      ≥ 0.59 after it, where one critic's did not, docs/research/scaling.md); the update-counted schedules
      (warm-up, target periods) are shortened to keep their env-step meaning at 1,024 envs.
    """
    if recipe not in RECIPES:
        raise ValueError(f"unknown recipe {recipe!r}; valid: {', '.join(RECIPES)}")
    if recipe == "paper":
        return {}
    if recipe == "cpu":
        return {("scheduler", "samples_per_insert"): 8.0, ("scheduler", "policy_warmup_updates"): 1500,
                ("scheduler", "n_step"): 10, ("new_skill", "samples_per_insert"): 16.0, ("new_skill", "n_step"): 10}
    steps = int(num_envs) * int(unroll_length)
    return {("scheduler", "batch_size"): max(1, steps * 25 // 8), ("scheduler", "samples_per_insert"): 25.0,
            ("scheduler", "policy_warmup_updates"): 190, ("scheduler", "target_actor_period"): 12,
            ("scheduler", "target_critic_period"): 3,
            ("new_skill", "batch_size"): steps, ("new_skill", "samples_per_insert"): 24.0,
            ("new_skill", "crr_mode"): "indicator", ("new_skill", "n_step"): 10, ("new_skill", "num_critics"): 2,
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

def from_json_value(kind, value):
    """A JSON value as field type ``kind`` holds it: a list as a tuple, an integer as a float for a
    float field; anything else as it is (the config's ``__post_init__`` judges it)."""
    if kind is tuple and isinstance(value, list):
        return tuple(value)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def replaced(cfg, data: dict, where: str, prefix: str = ""):
    """``cfg`` (any config class) with the fields of the JSON object ``data`` set, nested configs'
    from nested objects. Every name and object is checked here, every value by the config classes
    (``__post_init__``); either failure is a one-line ValueError naming ``where`` (a field dotted
    from ``prefix``, "scheduler.")."""
    kinds = field_types(type(cfg))
    updates = {}
    for key, value in data.items():
        if key not in kinds:
            valid = ", ".join(sorted(kinds))
            raise ValueError(f"unknown config field {key!r} in {where}; valid: {valid}" if not prefix else
                             f"unknown {prefix[:-1]} config field(s) {sorted(set(data) - set(kinds))} in {where}; "
                             f"valid: {valid}")
        kind = kinds[key][0]
        if dataclasses.is_dataclass(kind):
            if not isinstance(value, dict):
                raise ValueError(f"{where}: {key} must be a JSON object of {kind.__name__} fields")
            updates[key] = replaced(getattr(cfg, key), value, where, f"{prefix}{key}.")
        else:
            updates[key] = from_json_value(kind, value)
    try:
        return dataclasses.replace(cfg, **updates)
    except FieldError as e:
        raise ValueError(f"{where}: {e.within(prefix)}") from None
    except (ValueError, TypeError) as e:  # a rule relating several fields
        raise ValueError(f"{where}: {e}") from None


def from_dict(cfg: TrainConfig, data: dict, where: str) -> TrainConfig:
    """``cfg`` with the TrainConfig fields of the JSON object ``data`` (nested scheduler / new_skill
    objects) set (``replaced``: names checked here, values by the config classes). ``where`` names
    the source in the one-line ValueError."""
    if not isinstance(data, dict):
        raise ValueError(f"{where} must hold a JSON object of TrainConfig fields")
    return replaced(cfg, data, where)


def nested(values: dict) -> dict:
    """``{"a": 1, "new_skill.n_step": 3}`` -> ``{"a": 1, "new_skill": {"n_step": 3}}`` (``dotted_names``' inverse)."""
    out: dict = {}
    for name, value in values.items():
        *path, leaf = name.split(".")
        node = out
        for part in path:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


def dotted_value(cfg, name: str):
    """The value of the dotted field ``name`` of ``cfg`` (``"scheduler.n_step"``)."""
    for part in name.split("."):
        cfg = getattr(cfg, part)
    return cfg


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
