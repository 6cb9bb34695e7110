"""Hand-written sequences of a manipulation task's frozen skills, and a uniform random scheduler:
what a scheduler could earn with a skill set before any learning (docs/research/schedules.md).

    python -m training.experiments.schedules --task triple_stack \\
        stack_yellow_on_blue:150,stack_green_on_yellow stack_yellow_on_blue:100,stack_green_on_yellow random
    python -m training.experiments.schedules --task lift reach_green:until+20,lift_arm_closed --noise 0.3
    python -m training.experiments.schedules --task stack --skill_source library random:10-100 --episodes 256
    python -m training.experiments.schedules --task triple_stack --new_skill RUN_DIR new \
        --probes stack_yellow_on_blue,lift_green,triple_stack

Each positional argument is one schedule, run on ``--episodes`` envs of ``--task`` (any manipulation
task, ``tasks.make(task, physics=--physics)``) per seed of ``--seeds``, for ``--steps`` env steps
(default: the env's episode length). A schedule is either a sequence of comma-separated steps

* ``NAME:K``: skill NAME for K env steps (K a positive integer), then the next step;
* ``NAME:until``: skill NAME until its own success test holds on the current observation (the
  dense skill task of the same name in ``tasks/manipulation/task_defs.py``: reach, hover, open
  fingers, lift arm open / closed; or the sparse task: lift X, stack X on Y, pyramid, triple stack),
  then the next step, at that same env step (a test that already holds hands over at once: the
  step runs no env step and counts as not reached). A skill without a task of its own is refused.
  The test is not capped: a step whose test never holds runs to the episode end;
* ``NAME:until+K``: the same, and then K more env steps of NAME (the tests are looser than what
  the next skill may need: reach's holds 5.5 cm from the cube, docs/research/schedules.md);
* ``NAME``: the last step, bare: skill NAME until the episode ends (only the last step is bare,
  and the last step is always bare);

or ``random`` / ``random:KMIN-KMAX``: the uniform random scheduler of the trainer's counters
(``parallel_skills.counters``): at the episode start and whenever the running skill's counter
expires, a skill uniformly from ``--skills`` (the task's ``useful`` or ``useful+distractors`` set of
``training.skill_library.TABLE``) and a hold length uniformly from {KMIN, KMIN + 10, ..., KMAX}
(KMAX - KMIN a multiple of 10; default 10-100, the trainer's K = {10, ..., 100}); the task needs a
skill table (lift, stack, pyramid, triple_stack and the chain's stages).

Skills come from ``--skill_source``: ``scripted`` (``tasks.manipulation.scripted``) or ``library``
(the shipped neural skills, ``training.skill_library.load_skills``), a ``NAME.npz`` in ``--skill_dir``
replacing skill NAME; they see raw observations and
act with ``SkillSet.actions``, plus ``--noise`` (the trainer's ``skill_noise_std``: Gaussian noise on
the frozen skills' actions, clipped to [-1, 1], as ``parallel_skills.acting.Actor.actions`` adds
it; default 0). Episode success: the task's success test (``state.metrics["success"]``) held at
some step of the episode, as in ``parallel_skills.evaluation``. Every step of an episode batch runs
in one jitted ``lax.scan`` over the vmapped envs.

``--new_skill PATH`` adds a trained new skill (a ``training.run`` directory's ``new_skill.npz``, or
that directory; no collection noise; its mean actions, or with ``--new_skill_actions sampled`` actions
sampled from its Gaussian as the trainer collects) as the step name ``new``: ``new`` alone is the new
skill's own evaluation, ``stack_yellow_on_blue:150,new`` asks whether it finishes what a frozen skill
began. ``--probes NAME,...`` also reports, per schedule, the fraction of episodes in which each named
success test (a skill's own task, as for ``:until``, or a sparse task) held at some step: where a
schedule gets to when it does not succeed (e.g. ``--probes stack_yellow_on_blue,lift_green``).

Printed: one line per schedule and seed (success, mean return; for a sequence the mean env step at
which each of its steps started and, in brackets, the fraction of episodes that reached it), then a
summary line per schedule (mean over seeds).
``--start_states mixed`` (kinematic) draws the resets from ``tasks.make``'s wider distribution (one cube on or
beside another in two thirds of them), e.g. to see a skill in the states an earlier one leaves.
``--json PATH`` writes all of it. Bad input is one ``error:`` line, exit code 2.
"""

from __future__ import annotations

import dataclasses
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from training.cli import Parser, UsageError, check_writable, main_guard, positive_int, write_json_atomic
from training.rundir import new_skill_min_std

SOURCES = ("scripted", "library")
NEW_SKILL = "new"  # the step name of --new_skill
SKILL_SETS = ("useful", "useful+distractors")
K_GRID = 10  # spacing of the random scheduler's hold lengths
DEFAULT_K = (10, 100)
FORMS = ("NAME:K,...,NAME (hold each skill K env steps; the bare last one until the episode ends), "
         "NAME:until or NAME:until+K as a step (until the skill's own success test holds, then K more "
         "steps), random, random:KMIN-KMAX")


@dataclasses.dataclass(frozen=True)
class Step:
    """One step of a sequence: ``hold`` K (int), ``"until"`` (then ``extra`` more steps) or None
    (the last step, to the episode end)."""

    skill: str
    hold: object = None
    extra: int = 0


@dataclasses.dataclass(frozen=True)
class Schedule:
    """A parsed schedule: ``steps`` (a sequence) or ``lengths`` (the random scheduler's K)."""

    text: str
    steps: tuple = ()
    lengths: tuple = ()

    @property
    def is_random(self) -> bool:
        return bool(self.lengths)


def _bad(text: str, why: str) -> UsageError:
    return UsageError(f"bad schedule {text!r}: {why}; valid forms: {FORMS}")


def parse_schedule(text: str) -> Schedule:
    """The schedule ``text`` (module docstring) -> ``Schedule``; UsageError naming the valid forms.
    Skill names are checked later: ``check_schedule`` (success tests), ``load_skills`` (the source)."""
    if text == "random" or text.startswith("random:"):
        if text == "random":
            return Schedule(text, lengths=tuple(range(DEFAULT_K[0], DEFAULT_K[1] + 1, K_GRID)))
        arg = text[len("random:"):]
        lo, sep, hi = arg.partition("-")
        if not (sep and lo.isdigit() and hi.isdigit()):
            raise _bad(text, "the random scheduler's lengths are KMIN-KMAX (e.g. random:10-100)")
        lo, hi = int(lo), int(hi)
        if lo < 1 or hi < lo or (hi - lo) % K_GRID:
            raise _bad(text, f"need 1 ≤ KMIN ≤ KMAX with KMAX - KMIN a multiple of {K_GRID}")
        return Schedule(text, lengths=tuple(range(lo, hi + 1, K_GRID)))
    parts = text.split(",")
    steps = []
    for n, part in enumerate(parts):
        name, colon, hold = part.partition(":")
        last = n == len(parts) - 1
        if not name or not all(ch.isalnum() or ch in "_." for ch in name):
            raise _bad(text, f"step {n + 1} {part!r} does not start with a skill name")
        if name == "random":
            raise _bad(text, "random is a schedule of its own, not a step of a sequence")
        if last:
            if colon:
                raise _bad(text, f"the last step runs until the episode ends: write it bare ({name!r}, "
                                 f"not {part!r})")
            steps.append(Step(name))
        elif not colon:
            raise _bad(text, f"step {n + 1} {part!r} needs a hold ({name}:K or {name}:until); only the "
                             f"last step is bare")
        elif hold == "until":
            steps.append(Step(name, "until"))
        elif hold.startswith("until+") and hold[6:].isdigit():
            steps.append(Step(name, "until", int(hold[6:])))
        elif hold.isdigit() and int(hold) > 0:
            steps.append(Step(name, int(hold)))
        else:
            raise _bad(text, f"step {n + 1} {part!r}: the hold is a positive integer K, 'until' or 'until+K'")
    return Schedule(text, steps=tuple(steps))


def success_test(skill: str):
    """The success test of skill ``skill``'s own task (``task_defs``; a library seed ``NAME.sN`` has
    NAME's): ``fn(Inputs) -> 0/1``. UsageError if the skill has no task of its own."""
    from tasks.manipulation import task_defs
    from training.skill_library import split_seed

    base, _ = split_seed(skill)
    if base not in task_defs.TASKS:
        raise UsageError(f"skill {skill!r} has no success test of its own (no task {base!r} in "
                         f"tasks/manipulation/task_defs.py): hold it for K steps ({skill}:K)")
    return task_defs.get(base).success


def inputs_from_obs(obs):
    """``task_defs.Inputs`` read off a batch of observations [B, OBS_SIZE] (the layout every
    manipulation backend shares: pinch position, aperture, grasp sensor, cube positions)."""
    from tasks.manipulation import layout as L
    from tasks.manipulation import task_defs

    cubes = jnp.stack([obs[:, L.cube_pos(n)] for n in L.CUBE_NAMES], axis=1)  # [B, 3, 3]
    return task_defs.Inputs(obs[:, L.PINCH_POS], obs[:, L.FINGER], obs[:, L.GRASP], cubes)


def schedule_skills(schedule: Schedule, task: str, skill_set: str) -> list[str]:
    """The skill names a schedule runs, each once, in order of first use."""
    if schedule.is_random:
        from tasks.manipulation import task_defs
        from training.skill_library import TABLE, skill_names

        if task not in TABLE:
            with_table = sorted(t for t in TABLE if t in task_defs.TASKS)
            raise UsageError(f"schedule {schedule.text!r}: task {task!r} has no skill table for the random "
                             f"scheduler; manipulation tasks with one: {', '.join(with_table)}")
        return skill_names(task, skill_set)
    return list(dict.fromkeys(s.skill for s in schedule.steps))


def check_schedule(schedule: Schedule) -> None:
    """Every ``:until`` step's skill has a success test (UsageError otherwise)."""
    for s in schedule.steps:
        if s.hold == "until":
            success_test(s.skill)


def make_rollout(env, skills, schedule: Schedule, num_envs: int, steps: int, noise: float, probes: tuple = ()):
    """jit ``fn(key) -> dict`` of per-episode arrays: ``success`` [B] (the task's success test held at
    some step), ``return`` [B], for a sequence of P steps ``reached`` [P, B] (whether each step
    started) and ``start`` [P, B] (the env step it started at, -1 if never), and with ``probes`` (Q
    names with success tests, ``success_test``) ``probes`` [Q, B]: each test held at some step.
    ``skills``: the ``Skill`` objects of ``schedule_skills`` (same order)."""
    probe_tests = [success_test(name) for name in probes]
    from parallel_skills.acting import Actor
    from parallel_skills.counters import advance_counters
    from parallel_skills.skills import SkillSet

    skill_set = SkillSet(skills)
    index = {s.name: n for n, s in enumerate(skill_set.skills)}
    a_size = env.action_size

    def no_new_skill(params, obs):  # the new skill never acts here (index N is never chosen)
        return jnp.zeros((obs.shape[0], a_size)), jnp.ones((obs.shape[0], a_size))

    lengths = schedule.lengths or (1,)
    actor = Actor(env=env, skill_set=skill_set, scheduler_apply=None, new_skill_apply=no_new_skill,
                  skill_lengths=tuple(lengths), num_envs=num_envs, skill_noise_std=float(noise))
    b = num_envs
    if not schedule.is_random:
        n_steps = len(schedule.steps)
        step_skill = jnp.asarray([index[s.skill] for s in schedule.steps], jnp.int32)
        # Hold per step: K, or a huge K for 'until' (ended by its test) and for the last step.
        big = np.iinfo(np.int32).max
        hold = jnp.asarray([s.hold if isinstance(s.hold, int) else big for s in schedule.steps], jnp.int32)
        until = [(p, success_test(s.skill)) for p, s in enumerate(schedule.steps) if s.hold == "until"]
        extra = jnp.asarray([s.extra for s in schedule.steps], jnp.int32)

    def choose(carry, obs, t, key):
        """(skill index [B], new carry entries) at env step t."""
        if schedule.is_random:
            k_i, k_k = jax.random.split(key)
            i_new = jax.random.randint(k_i, (b,), 0, skill_set.num_frozen)
            k_new = jax.random.randint(k_k, (b,), 0, len(lengths))
            c, i, k_idx, _ = advance_counters(carry["c"], carry["i"], carry["k_idx"], i_new, k_new,
                                              jnp.full((b,), t == 0), lengths)
            return i, dict(c=c, i=i, k_idx=k_idx)
        # held: steps the current step has run; since: steps since its 'until' test first held (-1: not yet).
        p, held, since = carry["p"], carry["held"], carry["since"]
        if until:
            inp = inputs_from_obs(obs)
            passed = jnp.zeros((n_steps, b), bool)
            for q, test in until:
                passed = passed.at[q].set(test(inp) > 0.5)
        for _ in range(n_steps):  # an 'until' step whose test already holds hands over at once
            expired = held >= hold[p]
            if until:
                now = jnp.take_along_axis(passed, p[None], axis=0)[0]
                since = jnp.where((since < 0) & now, 0, since)
                expired = expired | (since >= extra[p])
            advance = (p < n_steps - 1) & expired
            p = jnp.where(advance, p + 1, p)
            held = jnp.where(advance, 0, held)
            since = jnp.where(advance, -1, since)
        now_at = jax.nn.one_hot(p, n_steps, dtype=bool).T  # [P, B]
        start = jnp.where(now_at & ~carry["reached"], t, carry["start"])
        return step_skill[p], dict(p=p, held=held + 1, since=jnp.where(since >= 0, since + 1, since),
                                   reached=carry["reached"] | now_at, start=start)

    @jax.jit
    def rollout(key):
        k_reset, k_run = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(k_reset, b))
        zi = jnp.zeros((b,), jnp.int32)
        if schedule.is_random:
            sched0 = dict(c=zi, i=zi, k_idx=zi)
        else:
            sched0 = dict(p=zi, held=zi, since=zi - 1, reached=jnp.zeros((n_steps, b), bool),
                          start=jnp.full((n_steps, b), -1, jnp.int32))
        zero = jnp.zeros((b,))

        def body(carry, xs):
            t, k = xs
            state = carry["state"]
            k_c, k_a, k_s = jax.random.split(k, 3)
            i, sched = choose(carry["sched"], state.obs, t, k_c)
            action = actor.actions(state.obs, state.obs, None, i, k_a, k_s, greedy=False)
            state = jax.vmap(env.step)(state, action)
            success = jnp.maximum(carry["success"], state.metrics.get("success", zero))
            held = carry["probes"]
            if probe_tests:
                inp = inputs_from_obs(state.obs)
                held = held | jnp.stack([test(inp) > 0.5 for test in probe_tests])
            return dict(state=state, sched=sched, ret=carry["ret"] + state.reward, success=success,
                        probes=held), None

        carry0 = dict(state=state, sched=sched0, ret=zero, success=zero,
                      probes=jnp.zeros((len(probe_tests), b), bool))
        carry, _ = jax.lax.scan(body, carry0, (jnp.arange(steps), jax.random.split(k_run, steps)))
        out = {"success": carry["success"], "return": carry["ret"], "probes": carry["probes"].astype(jnp.float32)}
        if not schedule.is_random:
            out["reached"] = carry["sched"]["reached"].astype(jnp.float32)
            out["start"] = carry["sched"]["start"]
        return out

    return rollout


NEW_SKILL_ACTIONS = ("mean", "sampled")  # --new_skill_actions


def load_new_skill(path, env, actions: str = "mean", std_scale: float = 1.0):
    """``--new_skill`` (a ``training.run`` directory or a ``new_skill.npz``) as a ``Skill`` named
    ``NEW_SKILL`` without collection noise, acting with its mean action (``actions="mean"``, its
    evaluation) or with actions sampled from its Gaussian (``"sampled"``: clip(mean + std·ε, −1, 1),
    as the trainer collects with it; the std floor is the run's ``new_skill.min_std`` from the
    ``config.json`` beside the file, else ``NewSkillConfig.min_std``; ``std_scale`` multiplies the
    std, e.g. 0.1 for a tenth of the policy's noise). UsageError (one line) when
    not given or not a new skill of this task's sizes."""
    from parallel_skills.skills import Skill

    if not path:
        raise UsageError(f"a schedule runs {NEW_SKILL!r} but --new_skill is not given (a training.run "
                         f"directory or its new_skill.npz)")
    if actions not in NEW_SKILL_ACTIONS:
        raise UsageError(f"--new_skill_actions must be one of {', '.join(NEW_SKILL_ACTIONS)}, got {actions!r}")
    file = os.path.join(path, "new_skill.npz") if os.path.isdir(path) else path
    try:
        skill = Skill.load(file, obs_size=env.observation_size, action_size=env.action_size)
    except ValueError as e:
        raise UsageError(f"--new_skill: {str(e).splitlines()[0]}") from None
    skill = dataclasses.replace(skill, name=NEW_SKILL, collection_noise=False)
    if actions == "sampled":
        from parallel_skills.skills import gaussian_mlp_apply

        min_std = new_skill_min_std(os.path.dirname(os.path.abspath(file)))
        # Its own arch: SkillSet stacks skills of equal arch under one apply, and a library skill of
        # the same network (acting with its mean) must not take this one's sampling away.
        skill = dataclasses.replace(skill, apply=gaussian_mlp_apply(skill.metadata["action_size"], skill.metadata["hidden"],
                                                                    sampled=True, min_std=min_std,
                                                                    std_scale=std_scale),
                                    arch=f"{skill.arch} sampled(min_std={min_std}, std_scale={std_scale})")
    return skill


def parse_seeds(text: str) -> list[int]:
    try:
        seeds = [int(s) for s in text.split(",")]
    except ValueError:
        raise UsageError(f"--seeds takes comma-separated non-negative integers (e.g. 0,1,2), got {text!r}") from None
    if not seeds or any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise UsageError(f"--seeds takes distinct comma-separated non-negative integers (e.g. 0,1,2), got {text!r}")
    return seeds


def make_env(task: str, physics: str, steps: int | None, episodes: int, start_states: str = "table"):
    """``tasks.make(task, physics)`` with ``episode_length`` = ``steps`` if given and the reset
    distribution ``start_states`` (``--start_states``: ``table``, or ``mixed``, kinematic: one cube on or
    beside another in two thirds of the resets)."""
    import tasks
    from tasks.manipulation import task_defs

    if task not in task_defs.TASKS:
        raise UsageError(f"unknown manipulation task {task!r}; valid: {', '.join(task_defs.names())}")
    if physics not in tasks.PHYSICS:
        raise UsageError(f"unknown physics {physics!r}; valid: {', '.join(tasks.PHYSICS)}")
    overrides = {} if steps is None else {"episode_length": steps}
    if start_states != "table":
        overrides["start_states"] = start_states
    if physics == "mjx":
        from tasks.manipulation.mjx_env import pin_to_one_core

        pin_to_one_core()  # MJX-jax can deadlock on 2 unpinned CPU cores
    if physics in ("mjx", "warp"):
        overrides["max_envs"] = episodes  # MJX-Warp sizes its contact buffer for the batch
    if physics == "mujoco":
        overrides["num_threads"] = 1
    return tasks.make(task, physics=physics, **overrides)


def main(argv=None):
    p = Parser(description=__doc__.split("\n\n")[0])
    p.add_argument("schedules", nargs="+", help=FORMS)
    p.add_argument("--task", default="lift", help="a manipulation task (lift, stack, pyramid, triple_stack, ...)")
    p.add_argument("--physics", default="kinematic", help="kinematic, mjx, warp or mujoco")
    p.add_argument("--skill_source", default="scripted", choices=SOURCES)
    p.add_argument("--skill_dir", default=None,
                   help="a directory of your own skills: NAME.npz there replaces skill NAME (as training.run's)")
    p.add_argument("--skills", default="useful", choices=SKILL_SETS, help="the random scheduler's skill set")
    p.add_argument("--episodes", type=positive_int, default=64, help="episodes (envs) per seed")
    p.add_argument("--seeds", default="0,1,2", help="comma-separated seeds; each its own episodes")
    p.add_argument("--noise", type=float, default=0.0, help="std of the Gaussian noise on the skills' actions")
    p.add_argument("--steps", type=positive_int, default=None, help="episode length (default: the env's)")
    p.add_argument("--start_states", default="table",
                   help="the env's reset distribution: table (the paper's) or mixed (kinematic; also one cube on "
                        "or beside another) or TOP_on_BOTTOM (kinematic; half with that cube on the other) or after:NAME:K "
                        "(kinematic; half where library skill NAME leaves the table resets after K steps)")
    p.add_argument("--new_skill", default=None,
                   help="a trained new skill (a training.run directory or its new_skill.npz), step name 'new'")
    p.add_argument("--new_skill_actions", default="mean", choices=NEW_SKILL_ACTIONS,
                   help="the new skill's actions: mean (its evaluation) or sampled (as the trainer collects)")
    p.add_argument("--new_skill_std_scale", type=float, default=1.0,
                   help="with --new_skill_actions sampled: the Gaussian's std times this (1: as collected)")
    p.add_argument("--probes", default="", help="comma-separated success tests to report per schedule "
                   "(skills' own tasks or sparse tasks, as for NAME:until)")
    p.add_argument("--json", default=None, help="write the figures to this file")
    args = p.parse_args(argv)
    probes = tuple(n for n in args.probes.split(",") if n)
    for name in probes:
        success_test(name)
    schedules = [parse_schedule(s) for s in args.schedules]
    seeds = parse_seeds(args.seeds)
    if not (np.isfinite(args.noise) and args.noise >= 0):
        raise UsageError(f"--noise must be a finite number ≥ 0, got {args.noise}")
    if not (np.isfinite(args.new_skill_std_scale) and args.new_skill_std_scale >= 0):
        raise UsageError(f"--new_skill_std_scale must be a finite number ≥ 0, got {args.new_skill_std_scale}")
    if args.new_skill_std_scale != 1.0 and args.new_skill_actions != "sampled":
        raise UsageError("--new_skill_std_scale scales the sampled actions' std: give --new_skill_actions sampled")
    twice = [t for n, t in enumerate(args.schedules) if t in args.schedules[:n]]
    if twice:
        raise UsageError(f"schedule {twice[0]!r} is given twice")
    if args.json:
        check_writable(args.json, "--json file")
    for s in schedules:
        check_schedule(s)
    names = {s.text: schedule_skills(s, args.task, args.skills) for s in schedules}
    env = make_env(args.task, args.physics, args.steps, args.episodes, args.start_states)
    steps = int(env.episode_length)
    from training.skill_library import load_skills

    loaded = {}  # ValueError (one line) for an unknown skill or one missing from the library
    if any(NEW_SKILL in names[s.text] for s in schedules):
        loaded[NEW_SKILL] = load_new_skill(args.new_skill, env, args.new_skill_actions, args.new_skill_std_scale)
    for s in schedules:
        for n in names[s.text]:
            if n not in loaded:
                loaded[n] = load_skills([n], args.physics, args.skill_source, obs_size=env.observation_size,
                                        action_size=env.action_size, skill_dir=args.skill_dir)[0]
    if args.new_skill and NEW_SKILL not in loaded:
        raise UsageError(f"--new_skill is given but no schedule runs it (its step name is {NEW_SKILL!r})")
    print(f"task {args.task}  physics {args.physics}  skills {args.skill_source}  noise {args.noise:g}  "
          f"{args.episodes} episodes x seeds {','.join(map(str, seeds))}  {steps} steps"
          + ("" if args.start_states == "table" else f"  start states {args.start_states}"), flush=True)
    results = {}
    for s in schedules:
        t0 = time.time()
        rollout = make_rollout(env, [loaded[n] for n in names[s.text]], s, args.episodes, steps, args.noise,
                               probes)
        per_seed = []
        for seed in seeds:
            t1 = time.time()
            out = jax.device_get(rollout(jax.random.PRNGKey(seed)))
            rec = {"seed": seed, "success": float(np.mean(out["success"])), "return": float(np.mean(out["return"])),
                   "wall_time_s": round(time.time() - t1, 2)}
            reached = ""
            if "reached" in out:
                rec["reached"] = [float(x) for x in np.mean(out["reached"], axis=1)]
                rec["start_step"] = [float(np.mean(st[st >= 0])) if np.any(st >= 0) else None for st in out["start"]]
                reached = "  steps start at t " + " ".join(
                    "never" if t is None else f"{t:.0f} ({r:.2f})" for t, r in zip(rec["start_step"], rec["reached"]))
            if probes:
                rec["probes"] = {n: float(x) for n, x in zip(probes, np.mean(out["probes"], axis=1))}
                reached += "  probes " + " ".join(f"{n} {x:.2f}" for n, x in rec["probes"].items())
            per_seed.append(rec)
            print(f"{s.text}  seed {seed}: success {rec['success']:.3f}  return {rec['return']:.1f}{reached}  "
                  f"({rec['wall_time_s']} s)", flush=True)
        succ = [r["success"] for r in per_seed]
        summary = {"success_mean": float(np.mean(succ)), "return_mean": float(np.mean([r["return"] for r in per_seed])),
                   "skills": names[s.text], "per_seed": per_seed, "wall_time_s": round(time.time() - t0, 1)}
        if probes:
            summary["probes_mean"] = {n: float(np.mean([r["probes"][n] for r in per_seed])) for n in probes}
        results[s.text] = summary
        print(f"{s.text}  mean: success {summary['success_mean']:.3f} ({' '.join(f'{x:.3f}' for x in succ)})  "
              f"return {summary['return_mean']:.1f}  [{summary['wall_time_s']} s]", flush=True)
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        write_json_atomic(args.json, dict(task=args.task, physics=args.physics, skill_source=args.skill_source,
                                          skills=args.skills, skill_dir=args.skill_dir, episodes=args.episodes, seeds=seeds, noise=args.noise,
                                          steps=steps, start_states=args.start_states, new_skill=args.new_skill,
                                          new_skill_actions=args.new_skill_actions if args.new_skill else None,
                                          new_skill_std_scale=args.new_skill_std_scale if args.new_skill else None,
                                          results=results), indent=1)


if __name__ == "__main__":
    main_guard(main)
