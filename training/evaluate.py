"""Evaluate a policy for whole episodes.

    python -m training.evaluate --task lift --physics kinematic --policy scripted:lift_green --episodes 64
    python -m training.evaluate --task lift --physics kinematic --policy library:lift_green
    python -m training.evaluate --task lift --physics mujoco --policy runs/<run>/export.npz
    python -m training.evaluate --task lift --physics kinematic --policy runs/<run>/export.npz:scheduler

``--policy``:

* ``scripted:NAME``: a scripted controller (see ``tasks.manipulation.scripted``);
* ``library:NAME``: the shipped skill NAME of the physics' library (``checkpoints/<library>/NAME.npz``,
  found in the installed package);
* ``PATH.npz``: a Gaussian-MLP skill with its JSON sidecar (``Skill.save``, e.g. ``new_skill.npz``);
* ``DIR/export.npz`` (or ``DIR/export.npz:new_skill``): an export's new skill alone
  (``training.export``);
* ``DIR`` (a ``training.run`` directory; ``DIR:scheduler``): its ``export.npz``, as below;
* ``DIR/export.npz:scheduler``: the export's scheduler sequencing the skills recorded in it (each
  from where the run took it: scripted controller, shipped library or ``--skill_dir`` file, checked
  against the file's recorded SHA-256; and the new skill) with its counters: it picks (i, k)
  greedily, runs skill i for K[k] steps, then decides again.

With ``--physics mujoco`` the ``.npz`` policies run on the classic-MuJoCo twin
(``tasks.manipulation.physics_np``) with a NumPy forward pass and import no JAX, except
``:scheduler`` with scripted skills, which imports JAX for them (they are JAX functions). The last line
printed is ``success=<fraction> return=<mean>``.

``--actions`` (Gaussian-MLP policies: a skill ``.npz`` or an export's new skill): ``mean`` (default,
the deterministic read-out that ``eval/new_skill_success`` reports) or ``sampled``: clip(mean + std·ε,
−1, 1) with the policy's own std and std floor, as the trainer collects with it and as
``eval/new_skill_sampled_success`` reports (docs/research/scheduler.md §5: the learnt new skill *is* the
Gaussian; its mean can succeed much less often). With ``:scheduler`` it applies to the new skill
only: the choices stay greedy and the frozen skills noise-free, so the difference to ``mean`` is
what the scheduler's runs of the new skill owe to its Gaussian.

``--decisions`` / ``--skill_noise`` (``:scheduler`` only): ``sampled`` draws each choice (i, k) from
the scheduler's two categorical heads instead of taking their argmax, and ``--skill_noise STD`` adds
clip(a + STD·ε, −1, 1) to the frozen skills' actions, as the trainer's collection noise
(``--skill_noise_std``, 0.3) does. ``--decisions sampled --actions sampled --skill_noise 0.3`` is the
scheduler as it collects (``eval/scheduler_sampled_success``); the defaults are the greedy scheduler
(``eval/scheduler_success``), so each read-out of docs/research/skills.md can be measured apart, with as many
episodes as wanted.
"""

from __future__ import annotations

import os

import numpy as np

from training.cli import Parser, UsageError, main_guard, nonnegative_int, positive_int

EXPORT_SUFFIXES = ("new_skill", "scheduler")
ACTIONS = ("mean", "sampled")  # --actions
DECISIONS = ("greedy", "sampled")  # --decisions


def parse_policy(spec: str, physics: str = "kinematic") -> tuple[str, str, str | None]:
    """``--policy`` -> (kind, name or path, suffix): kind "scripted", "skill" or "export".
    ``library:NAME`` is the shipped skill NAME of ``physics``'s library (wherever the package is installed)."""
    if spec.startswith("scripted:"):
        return "scripted", spec.split(":", 1)[1], None
    run_dir, sep, suffix = spec.rpartition(":")
    if not (sep and suffix in EXPORT_SUFFIXES and os.path.isdir(run_dir)):
        run_dir, suffix = spec, None
    if os.path.isdir(run_dir):  # a training.run directory: its export (the finished run)
        from training.rundir import read_record

        read_record(run_dir, f"--policy {spec}")
        export = os.path.join(run_dir, "export.npz")
        if not os.path.isfile(export):
            raise UsageError(f"run {run_dir} has no export.npz: it has not finished; resume it with "
                             f"python -m training.run --resume --out {run_dir}")
        spec = export + (f":{suffix}" if suffix else "")
    if spec.startswith("library:"):
        from training.skill_library import library_dir, library_path

        path = library_path(physics, spec.split(":", 1)[1])
        if not os.path.isfile(path):
            shipped = sorted(f[:-4] for f in os.listdir(os.path.dirname(path)) if f.endswith(".npz"))
            raise UsageError(f"no skill {spec.split(':', 1)[1]!r} in the {library_dir(physics)} library; "
                             f"shipped: {', '.join(shipped)}")
        return "skill", path, None
    path, sep, suffix = spec.rpartition(".npz:")
    if sep:
        path += ".npz"
        if suffix not in EXPORT_SUFFIXES:
            raise UsageError(f"unknown --policy suffix ':{suffix}'; valid after an export: "
                             f"{', '.join(':' + s for s in EXPORT_SUFFIXES)} (e.g. DIR/export.npz:scheduler)")
    else:
        path, suffix = spec, None
    if not path.endswith(".npz"):
        raise UsageError(f"--policy must be 'scripted:NAME', a skill 'PATH.npz' or an export "
                         f"'DIR/export.npz[:scheduler]', got {spec!r}")
    if not os.path.exists(path):
        raise UsageError(f"policy file {path} does not exist")
    from parallel_skills.numpy_policy import is_export

    if suffix is None and not is_export(path):
        return "skill", path, None
    return "export", path, suffix or "new_skill"


# --- batches of episodes stepped from the host (NumPy policies, the scheduler's counters) -------
class TwinBatch:
    """``num`` episodes of the classic-MuJoCo twin (``physics_np``: the ``MujocoTwin`` step, batched
    through one ``Stepper``). NumPy only."""

    def __init__(self, task: str, num: int, seed: int):
        from tasks.manipulation import physics_np as P

        self.P, self.task, self.num = P, P.task_defs.get(task), num
        self.stepper = P.Stepper(num_threads=min(2, num))
        self.rng = np.random.default_rng(seed)

    def reset(self):
        self.states = self.P.init_states(self.rng.integers(2**32, size=self.num))
        return self.P.observe_states(self.states)

    def step(self, actions):
        self.states, _ = self.stepper.step(self.states, actions, reset_seeds=self.rng.integers(2**32, size=self.num))
        reward, success = self.P.reward_success(self.task, self.states)
        return self.P.observe_states(self.states), reward, success

    def close(self):
        self.stepper.close()


class JaxEnvBatch:
    """``num`` episodes of a Brax-API env, reset and stepped by jitted vmapped calls."""

    def __init__(self, env, num: int, seed: int):
        import jax

        self.jax, self.num = jax, num
        self._reset, self._step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
        self.key = jax.random.PRNGKey(seed)

    def reset(self):
        k_reset, _ = self.jax.random.split(self.key)  # the reset states of ``rollout_episodes`` for this key
        self.state = self._reset(self.jax.random.split(k_reset, self.num))
        start = self.state.info.get("start") if isinstance(self.state.info, dict) else None
        self.start_kind = None if start is None else np.asarray(start)  # [B], envs with several kinds of start
        return np.asarray(self.state.obs)

    def step(self, actions):
        self.state = self._step(self.state, self.jax.numpy.asarray(actions, self.jax.numpy.float32))
        s = self.state
        return np.asarray(s.obs), np.asarray(s.reward), np.asarray(s.metrics.get("success", np.zeros(self.num)))

    def close(self):
        pass


def run_episodes(envs, act, length: int) -> dict:
    """Whole episodes from the host: ``act(obs [B, O]) -> actions [B, A]``. Per-episode ``return``
    and ``success`` (1 if the task's success test held at some step), as ``rollout_episodes``."""
    obs = envs.reset()
    ret = np.zeros(envs.num)
    success = np.zeros(envs.num)
    for _ in range(length):
        obs, reward, succ = envs.step(act(obs))
        ret += reward
        success = np.maximum(success, succ)
    envs.close()
    return {"return": ret, "success": success}


def scripted_controller(name: str):
    """The scripted controller ``name`` as ``fn(obs [O], key) -> action [A]``: an arm controller of
    ``tasks.manipulation.scripted`` or an OP3 controller (``op3_getup``, ``op3_walk``;
    ``training.skill_library``)."""
    from training.skill_library import load_skills

    try:
        skill = load_skills([name], "kinematic", "scripted")[0]
    except ValueError as e:
        raise UsageError(str(e)) from None
    return lambda obs, key: skill.apply(skill.params, obs, key)


def scripted_skills(names, seed: int):
    """The frozen skills of an export as (``fn(obs [B, O]) -> actions [N, B, A]`` (jitted JAX),
    each skill's ``Skill.collection_noise`` [N])."""
    import jax

    from parallel_skills.skills import SkillSet
    from training.skill_library import load_skills

    try:
        skills = load_skills(list(names), "kinematic", "scripted")
    except ValueError as e:
        raise UsageError(f"the export's skills {list(names)} are not all scripted controllers ({e}); ':scheduler' "
                         f"runs scripted skills and the new skill") from None
    skill_set = SkillSet(skills)
    frozen = jax.jit(skill_set.frozen_actions)
    key, step = jax.random.PRNGKey(seed), [0]

    def actions(obs):
        step[0] += 1
        return np.asarray(frozen(jax.numpy.asarray(obs, jax.numpy.float32), jax.random.fold_in(key, step[0])))

    return actions, skill_set.collection_noise[:-1]  # (the last entry is the new skill's)


def neural_skill(entry: dict, export_path: str):
    """A frozen neural skill of an export's ``skill_sources`` entry (library or skill_dir) as a NumPy
    policy ``obs [B, O] -> mean actions [B, A]``, checked against the SHA-256 recorded at training."""
    from parallel_skills.numpy_policy import NumpyGaussianPolicy
    from training.skill_library import library_path
    from training.export import file_sha256

    if entry["source"] == "library":  # entry["library"] is a library_dir name, which maps to itself
        path = library_path(entry["library"], entry["name"])
    else:
        path = entry["path"]
    if not os.path.isfile(path):
        raise UsageError(f"{export_path}: its skill {entry['name']!r} ({entry['source']}) was {path}, which does not "
                         f"exist (':scheduler' runs the skills the run was trained with)")
    if file_sha256(path) != entry.get("sha256"):
        raise UsageError(f"{export_path}: its skill file {path} changed since the run (SHA-256 differs); "
                         f"':scheduler' needs the skills the run was trained with")
    return NumpyGaussianPolicy.load(path)


def frozen_skills(export, seed: int):
    """The export's N frozen skills as (``fn(obs [B, O]) -> actions [N, B, A]`` (NumPy), whether each
    takes the trainer's collection noise [N] (``Skill.collection_noise``; neural skills do)), each from
    where the run took it (``metadata["skill_sources"]``; exports without it: scripted controllers).
    Only scripted skills need JAX. (None, None) when there are no frozen skills."""
    names = export.frozen_skill_names
    if not names:
        return None, None
    sources = export.meta.get("metadata", {}).get("skill_sources") or [{"name": n, "source": "scripted"}
                                                                       for n in names]
    if [e["name"] for e in sources] != names:
        raise UsageError(f"{export.path}: metadata skill_sources names {[e['name'] for e in sources]}, the scheduler "
                         f"{names}")
    scripted_idx = [j for j, e in enumerate(sources) if e["source"] == "scripted"]
    neural = {j: neural_skill(e, export.path) for j, e in enumerate(sources) if e["source"] != "scripted"}
    scripted, scripted_noise = scripted_skills([names[j] for j in scripted_idx], seed) if scripted_idx else (None, [])
    takes_noise = np.ones(len(names), bool)
    takes_noise[scripted_idx] = scripted_noise

    def actions(obs):
        out = [None] * len(names)
        if scripted is not None:
            for j, a in zip(scripted_idx, scripted(obs)):
                out[j] = a
        for j, policy in neural.items():
            out[j] = policy(obs)
        return np.stack(out).astype(np.float32)

    return actions, takes_noise


def with_collection_noise(actions, std: float, rng: np.random.Generator, noisy_skills: np.ndarray):
    """``actions`` (``fn(obs) -> [N, B, A]``) with clip(a + std·ε, −1, 1), ε ~ N(0, I) added to the
    skills where ``noisy_skills`` [N] is True, as the trainer's collection noise on the frozen skills
    (``Actor.actions``)."""
    mask = np.asarray(noisy_skills, bool)[:, None, None]

    def noisy(obs):
        a = actions(obs)
        noised = np.clip(a + std * rng.standard_normal(a.shape), -1.0, 1.0)
        return np.where(mask, noised, a).astype(np.float32)

    return noisy


def scheduler_policy(export, seed: int, new_skill_actions: str = "mean", decisions: str = "greedy",
                     skill_noise: float = 0.0):
    """The export's scheduler running its skills (counters): a batched NumPy ``act(obs) -> actions``
    with a ``usage`` attribute (steps per skill). ``new_skill_actions`` (``ACTIONS``): the new skill's
    mean action, or actions sampled from its Gaussian; ``decisions`` (``DECISIONS``): argmax choices
    or choices sampled from the scheduler; ``skill_noise``: the std of the Gaussian collection noise
    on the frozen skills' actions (clipped to [−1, 1]; 0: none)."""
    from parallel_skills.numpy_policy import ScheduledPolicy

    frozen, takes_noise = frozen_skills(export, seed)
    if frozen is not None and skill_noise > 0:
        frozen = with_collection_noise(frozen, skill_noise, np.random.default_rng([seed, 2]), takes_noise)
    rng = np.random.default_rng([seed, 1])

    def new_skill(obs):
        return export.new_skill.sample(obs, rng) if new_skill_actions == "sampled" else export.new_skill(obs)

    def every_skill(obs):
        new = new_skill(obs)[None]
        return new if frozen is None else np.concatenate([frozen(obs), new], axis=0)

    return ScheduledPolicy(export.scheduler, every_skill, export.skill_lengths,
                           rng=np.random.default_rng([seed, 3]) if decisions == "sampled" else None)


def jax_new_skill(export):
    """An export's new skill as a JAX ``Skill`` (mean action)."""
    import jax.numpy as jnp

    from parallel_skills.skills import Skill, unflatten_params

    params = unflatten_params({k: jnp.asarray(v, jnp.float32) for k, v in export.new_skill.a.items()})
    return Skill.gaussian_mlp(export.new_skill_name, params, export.action_size, export.new_skill.hidden)


def main(argv=None):
    import tasks

    p = Parser(prog="python -m training.evaluate", description=__doc__.splitlines()[0])
    p.add_argument("--task", default="lift", help="task name (see tasks.names())")
    p.add_argument("--physics", default="kinematic", help=f"one of {', '.join(tasks.PHYSICS)}")
    p.add_argument("--policy", required=True,
                   help="scripted:NAME, library:NAME (a shipped skill), a skill PATH.npz, a run directory DIR "
                        "(its export; DIR:scheduler), DIR/export.npz (the new skill alone) or "
                        "DIR/export.npz:scheduler (the scheduler running the export's skills). With --physics "
                        "mujoco the .npz policies import no JAX (NumPy + classic MuJoCo), except :scheduler, "
                        "whose scripted skills are JAX functions")
    p.add_argument("--episodes", type=positive_int, default=64)
    p.add_argument("--episode_length", type=positive_int, default=None)
    p.add_argument("--start_states", default="table",
                   help="the env's reset distribution: table (the paper's) or mixed (also one cube on or beside "
                        "another; kinematic physics) or TOP_on_BOTTOM (kinematic; half with that cube on the other) or after:NAME:K (kinematic; half where library skill NAME leaves the table resets after K steps)")
    p.add_argument("--seed", type=nonnegative_int, default=0)
    p.add_argument("--actions", default="mean",
                   help=f"one of {', '.join(ACTIONS)}: a Gaussian-MLP policy's mean action or actions sampled from "
                        "its Gaussian (as collected); with :scheduler, the new skill's (choices stay greedy, the "
                        "frozen skills noise-free)")
    p.add_argument("--decisions", default="greedy",
                   help=f"with :scheduler, one of {', '.join(DECISIONS)}: the argmax of the scheduler's heads or "
                        "choices sampled from them (as collected)")
    p.add_argument("--skill_noise", type=float, default=0.0,
                   help="with :scheduler: std of the Gaussian noise on the frozen skills' actions (the trainer "
                        "collects with 0.3); default 0")
    p.add_argument("--usage_plot", default=None,
                   help="with a ':scheduler' policy: write this image of the skill it runs at each step of the "
                        "episode (share of episodes per skill over episode time)")
    args = p.parse_args(argv)

    def run():
        if args.usage_plot and not args.policy.endswith(":scheduler"):
            raise UsageError(f"--usage_plot needs a ':scheduler' policy (DIR:scheduler), not {args.policy!r}")
        result = evaluate_policy(args.task, args.physics, args.policy, episodes=args.episodes, seed=args.seed,
                                 episode_length=args.episode_length, actions=args.actions,
                                 start_states=args.start_states, decisions=args.decisions,
                                 skill_noise=args.skill_noise)
        if args.usage_plot:
            from training.plot import plot_usage_over_episode

            timeline = result.pop("timeline")
            plot_usage_over_episode(timeline, result.pop("skill_names"), args.usage_plot, result.pop("step_seconds"),
                                    title=f"{args.task}: skill the scheduler runs", groups=result.pop("groups"),
                                    group_names=result.pop("group_names"))
            result["lines"].append(f"usage plot: {args.usage_plot}")
        lines = result.pop("lines")
        for k in ("timeline", "skill_names", "step_seconds", "groups", "group_names"):
            result.pop(k, None)
        success = float(np.mean(result["success"]))
        ret = float(np.mean(result["return"]))
        print(f"task={args.task} physics={args.physics} policy={args.policy} episodes={args.episodes}"
              + (f" actions={args.actions}" if args.actions != "mean" else "")
              + (f" decisions={args.decisions}" if args.decisions != "greedy" else "")
              + (f" skill_noise={args.skill_noise:g}" if args.skill_noise else ""))
        for line in lines:
            print(line)
        print(f"success={success:.4f} return={ret:.3f}")

    main_guard(run)


def evaluate_policy(task: str, physics: str, policy: str, episodes: int = 64, seed: int = 0,
                    episode_length: int | None = None, actions: str = "mean", start_states: str = "table",
                    decisions: str = "greedy", skill_noise: float = 0.0) -> dict:
    """What ``python -m training.evaluate`` computes, as a function: per-episode ``success`` and
    ``return`` arrays of ``policy`` (a ``--policy`` spec) on ``task`` / ``physics``, plus ``lines``
    (the extra report lines); ``actions``, ``start_states``, ``decisions``, ``skill_noise`` as their
    flags. UsageError / ValueError on bad input."""
    import argparse

    import tasks

    if task not in tasks.names():
        raise UsageError(f"unknown task {task!r}; valid tasks: {', '.join(tasks.names())}")
    if physics not in tasks.PHYSICS:
        raise UsageError(f"unknown physics {physics!r}; valid: {', '.join(tasks.PHYSICS)}")
    if actions not in ACTIONS:
        raise UsageError(f"--actions must be one of {', '.join(ACTIONS)}, got {actions!r}")
    if decisions not in DECISIONS:
        raise UsageError(f"--decisions must be one of {', '.join(DECISIONS)}, got {decisions!r}")
    if not (np.isfinite(skill_noise) and skill_noise >= 0):
        raise UsageError(f"--skill_noise must be a finite std >= 0, got {skill_noise!r}")
    args = argparse.Namespace(task=task, physics=physics, policy=policy, episodes=int(episodes), seed=int(seed),
                              episode_length=episode_length, actions=actions, start_states=start_states,
                              decisions=decisions, skill_noise=float(skill_noise))
    kind, target, suffix = parse_policy(policy, physics)
    if suffix != "scheduler" and (decisions != "greedy" or skill_noise):
        raise UsageError(f"--decisions and --skill_noise apply to a scheduler (DIR:scheduler or "
                         f"DIR/export.npz:scheduler), not {policy!r}")
    if actions == "sampled" and kind == "scripted":
        raise UsageError(f"--actions sampled needs a Gaussian-MLP policy (a skill .npz, an export's new skill, or "
                         f"its scheduler's new skill), not {policy!r}")
    if kind == "scripted":
        scripted_controller(target)  # exists (UsageError naming the valid ones)
    export = None
    if kind == "export":
        from parallel_skills.numpy_policy import load_export

        export = load_export(target)
    if physics == "mujoco" and kind != "scripted" and task not in tasks.LOCOMOTION_TASKS:
        if start_states != "table":
            raise UsageError(f"--start_states {start_states!r}: the MuJoCo twin resets with 'table' only "
                             "(the JAX kinematic env has the others)")
        result, lines = _evaluate_on_twin(args, kind, target, export, suffix)
    else:
        result, lines = _evaluate_on_jax_env(args, kind, target, export, suffix)
    return dict(result, lines=lines)


def _usage_line(export, policy) -> list[str]:
    frac = policy.usage / max(policy.usage.sum(), 1)
    return ["skill usage (fraction of steps): " + " ".join(f"{n}={f:.3f}" for n, f in zip(export.skill_names, frac))]


def _with_timeline(result: dict, export, policy, step_seconds, groups=None, group_names=None) -> dict:
    """``result`` plus the scheduler's skill per episode step (``timeline`` [T, B]) and the episodes'
    start kinds (``groups`` [B] or None), for --usage_plot."""
    return dict(result, timeline=np.stack(policy.timeline), skill_names=list(export.skill_names),
                step_seconds=step_seconds, groups=groups, group_names=group_names)


def _evaluate_on_twin(args, kind, path, export, suffix):
    """The classic-MuJoCo twin with NumPy policies: no JAX (``:scheduler``'s scripted skills aside)."""
    from parallel_skills.numpy_policy import NumpyGaussianPolicy, ScheduledPolicy
    from tasks.manipulation import layout as L

    length = args.episode_length or L.DEFAULT_EPISODE_LENGTH
    if kind == "skill":
        policy = NumpyGaussianPolicy.load(path, obs_size=L.OBS_SIZE, action_size=L.ACTION_SIZE)
    else:
        export.check_task_sizes(L.OBS_SIZE, L.ACTION_SIZE)
        policy = export.new_skill if suffix != "scheduler" else scheduler_policy(export, args.seed, args.actions,
                                                                                  args.decisions, args.skill_noise)
    if args.actions == "sampled" and suffix != "scheduler":
        gaussian, rng = policy, np.random.default_rng([args.seed, 1])
        policy = lambda obs: gaussian.sample(obs, rng)  # noqa: E731
    result = run_episodes(TwinBatch(args.task, args.episodes, args.seed), policy, length)
    if isinstance(policy, ScheduledPolicy):
        return _with_timeline(result, export, policy, L.CONTROL_DT), _usage_line(export, policy)
    return result, []


def _evaluate_on_jax_env(args, kind, target, export, suffix):
    import jax

    import tasks

    overrides = {} if args.episode_length is None else {"episode_length": args.episode_length}
    if args.start_states != "table":
        overrides["start_states"] = args.start_states
    if args.physics == "mjx":
        from tasks.manipulation.mjx_env import pin_to_one_core

        pin_to_one_core()  # MJX-jax can deadlock on 2 unpinned CPU cores (STACK.md)
    if args.physics in ("mjx", "warp"):
        overrides["max_envs"] = args.episodes  # MJX-Warp sizes its contact buffer for the batch
    env = tasks.make(args.task, physics=args.physics, **overrides)
    if export is not None:
        export.check_task_sizes(env.observation_size, env.action_size)
        if suffix == "scheduler":
            policy = scheduler_policy(export, args.seed, args.actions, args.decisions, args.skill_noise)
            envs = JaxEnvBatch(env, args.episodes, args.seed)
            result = run_episodes(envs, policy, int(env.episode_length))
            return (_with_timeline(result, export, policy, getattr(env, "dt", None), envs.start_kind,
                                   getattr(env, "START_NAMES", None)), _usage_line(export, policy))
        skill = jax_new_skill(export)
        min_std = export.new_skill.min_std
    elif kind == "skill":
        from parallel_skills.skills import Skill

        skill = Skill.load(target, obs_size=env.observation_size, action_size=env.action_size)
        min_std = skill.metadata.get("min_std")
        if min_std is None:  # a run's new_skill.npz: the std floor is in the run's config.json
            from training.rundir import new_skill_min_std

            min_std = new_skill_min_std(os.path.dirname(os.path.abspath(target)))
    if kind == "scripted":
        policy = scripted_controller(target)
    else:
        apply = skill.apply
        if args.actions == "sampled":
            from parallel_skills.skills import gaussian_mlp_apply

            apply = gaussian_mlp_apply(skill.metadata["action_size"], skill.metadata["hidden"], sampled=True,
                                       min_std=min_std)
        policy = lambda obs, key: apply(skill.params, obs, key)  # noqa: E731

    from parallel_skills.evaluation import make_evaluator

    result = make_evaluator(env, policy, args.episodes)(jax.random.PRNGKey(args.seed))
    return jax.device_get(result), []


if __name__ == "__main__":
    main()
