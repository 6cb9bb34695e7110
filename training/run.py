"""Train a new skill with SkillS (or from scratch) on a task: the project's main job.

    python -m training.run                                  # kinematic lift, device-sized defaults
    python -m training.run --task lift --num_envs 4096      # on a GPU
    python -m training.run --resume --out DIR               # continue a killed run exactly
    python -m training.run --resume --out DIR --num_timesteps N   # extend a run to N env steps

Writes into ``--out`` (a new directory; an existing one is only ever written into by
``--resume``): ``config.json`` (the whole run configuration; it fixes the config of a resumed
run), ``metrics.csv`` (one row per evaluation), ``checkpoints/`` (full training state, the latest
2, see ``training.checkpointing``), ``new_skill.npz`` + ``.json`` (the new skill as a loadable
skill: ``python -m training.evaluate --policy DIR/new_skill.npz``), ``best_new_skill.npz`` + ``.json``
(the new skill of the best evaluation so far, rewritten during the run; its sidecar has its env
steps and success), ``export.npz`` + ``.json``
(new skill and scheduler, ``training.export``), TensorBoard event files (``tensorboard --logdir
DIR``; ``training.logging_utils``), ``curves.png`` and ``skill_usage.png`` (``training.plot``) and,
with ``--video``, ``new_skill.mp4`` (or ``.gif`` without ffmpeg; ``training.video``).
Progress: one line per evaluation on stdout, plus a progress bar on stderr when it is a terminal.
The last line printed is ``success=<new skill alone> return=<mean>``.

Settings come from, in increasing precedence: the defaults, ``--config FILE.json`` (any
``TrainConfig`` field, nested ``scheduler`` / ``new_skill`` fields included), command-line flags.
Every ``TrainConfig`` field is a flag too, dotted for the nested ones (``--num_envs 64``,
``--scheduler.n_step 10``, ``--new_skill.samples_per_insert 32``), and so is every ``RunConfig``
field (``--num_timesteps``, ``--seed``, ``--episode_length``, ``--checkpoint_every``): generated
from the dataclasses (``training.config_flags``), which check every value. The flags written out
here are the ones that are no config field. Bad input is reported as one line on stderr with exit
code 2, before anything is written.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import sys
import time

from parallel_skills import methods
from parallel_skills.config import RunConfig, TrainConfig
from training import config_flags, rundir, run_files
from training.cli import Parser, UsageError, check_writable, main_guard, nonnegative_int, positive_int
from training.logging_utils import Progress
from training.rundir import RunRecord

# CPU: the README quickstart must end within 10 minutes on 2 cores (kinematic lift, CPU recipe,
# seed 0: 0.84 at 218k and 256k; other seeds are slower; README, docs/research/scaling.md).
DEFAULT_TIMESTEPS = {"cpu": 256_000, "accelerator": 20_000_000}
# Defaults of the flags that are no config field, applied after parsing (None = "not given":
# --resume rejects given flags that conflict with the run's config.json; so do generated flags).
DEFAULTS = dict(task="lift", physics="kinematic", skills="useful", skill_source="scripted")
BASE_CONFIG = TrainConfig(eval_episodes=32)  # the TrainConfig a run starts from (more evaluation episodes)
RUN_FLAGS = config_flags.flag_names(RunConfig)  # num_timesteps, seed, episode_length, checkpoint_every
TRAIN_FLAGS = config_flags.flag_names(TrainConfig)  # recipe, num_envs, ..., scheduler.*, new_skill.*
DEFAULT_CACHE_DIR = os.path.join(os.path.expanduser("~"), ".cache", "parallel_skills_jax")


def build_parser():
    """The flags that are no config field, written out, then one per ``RunConfig`` and
    ``TrainConfig`` field (``config_flags.add_config_flags``)."""
    import tasks
    from training.skill_library import SET_NAMES, SOURCES

    p = Parser(prog="python -m training.run", description=__doc__.splitlines()[0],
               epilog="The learners' defaults shown are the paper's (App. B.3): the recipe sets its own (docs/research/scaling.md) "
                      "for the fields that no flag and no --config file sets.")
    p.add_argument("--task", default=None, help="task name (see tasks.names()); default lift")
    p.add_argument("--physics", default=None, help=f"one of {', '.join(tasks.PHYSICS)}; default kinematic "
                   f"(mujoco for the OP3 tasks {', '.join(tasks.LOCOMOTION_TASKS)})")
    p.add_argument("--seeds", default=None,
                   help="several seeds trained together in one vmapped iteration, e.g. 0,1,2: each writes its own "
                        "run directory OUT/s<seed> (as --seed would); --resume --out OUT resumes them together")
    p.add_argument("--skills", default=None, help=f"skill set: {', '.join(SET_NAMES)}; default useful")
    p.add_argument("--skill_source", default=None, choices=list(SOURCES),
                   help="where the set's skills come from: scripted controllers, or the shipped neural library "
                        "checkpoints/kinematic/ or (mujoco, mjx, warp) checkpoints/mjx/ (many_useful needs it); default scripted")
    p.add_argument("--skill_dir", default=None,
                   help="directory of your own skills (NAME.npz + NAME.json, as Skill.save writes them): a skill of "
                        "the set found there is loaded from it instead of --skill_source")
    p.add_argument("--finetune_from", default=None,
                   help="--method finetune: the network skill the new skill starts from (library name, or one in "
                        "--skill_dir); default the task's last useful skill, from the library")
    p.add_argument("--config", default=None, help="JSON file overriding TrainConfig fields, e.g. "
                   '{"unroll_length": 25, "scheduler": {"policy_warmup_updates": 1500}, "new_skill": {"crr_mode": "indicator"}}'
                   "; or a run's config.json: its whole resolved TrainConfig (task, skills and length stay flags)")
    p.add_argument("--out", default=None, help="run directory (must not exist unless --resume); "
                   "default runs/<task>-<method>-s<seed>-<time>")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in the existing --out from its latest checkpoint, with its config.json")
    p.add_argument("--video", action="store_true",
                   help="at the end, write DIR/new_skill.mp4 (or .gif without ffmpeg): one episode of the new skill "
                        "alone, rendered headless (MUJOCO_GL=egl, else osmesa)")
    p.add_argument("--coordinator", default=None,
                   help="HOST:PORT of process 0: a multi-process run over several hosts (jax.distributed), with "
                        "--num_processes and --process_id; every process runs the same command with the same --out "
                        "(a shared directory), process 0 alone writes its logs, metrics and exports (README \"One GPU, many GPUs, many hosts\")")
    p.add_argument("--num_processes", type=positive_int, default=None, help="processes of a multi-process run")
    p.add_argument("--process_id", type=nonnegative_int, default=None, help="this process: 0 .. num_processes - 1")
    p.add_argument("--distributed", action="store_true",
                   help="a multi-process run whose coordinator, process count and id JAX reads from the cluster's "
                        "environment (SLURM, Open MPI, ...)")
    p.add_argument("--coordinator_timeout", type=positive_int, default=300,
                   help="seconds to wait for every process to reach the coordinator (default 300)")
    p.add_argument("--no-replay-checkpoint", dest="no_replay_checkpoint", action="store_true",
                   help="leave the replay buffer out of checkpoints (smaller; a resume then starts with an "
                        "empty buffer and is no longer identical to an uninterrupted run)")
    config_flags.add_config_flags(p, RunConfig())
    notes = {"method": "; ".join(f"{m.name}: {m.help}" for m in methods.all_methods()) + "; README \"Configure\"",
             "recipe": "cpu: 32 envs, few samples per env step; parallel: batches that grow with the envs, 32 "
                       "updates per iteration; paper: App. B.3 (docs/research/scaling.md)",
             "eval_every": "(default: 20 evaluations per run)"}
    config_flags.add_config_flags(p, BASE_CONFIG, notes=notes, computed=("eval_every",))
    return p


# ----------------------------------------------------------------------------- config files

def apply_config(cfg, data: dict, where: str):
    """``cfg`` with the TrainConfig fields of ``data`` set (``parallel_skills.config.from_dict``
    checks every name, type and range); a bad value is one error line."""
    from parallel_skills.config import from_dict

    try:
        return from_dict(cfg, data, where)
    except ValueError as e:
        raise UsageError(str(e)) from None


def load_config_file(path: str) -> dict:
    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError:
        raise UsageError(f"config file {path} does not exist") from None
    except IsADirectoryError:
        raise UsageError(f"config file {path} is a directory, not a JSON file") from None
    except (OSError, ValueError) as e:
        raise UsageError(f"cannot read config file {path}: {str(e).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise UsageError(f"config file {path} must hold a JSON object of TrainConfig fields")
    if isinstance(data.get("train_config"), dict) and "task" in data:  # a run's config.json: its whole config
        return rundir.recorded_train_config(data["train_config"])
    return data


def apply_config_file(cfg, path):
    """Override TrainConfig fields (and nested scheduler / new_skill fields) from a JSON file."""
    return apply_config(cfg, load_config_file(path), f"config file {path}")


# ----------------------------------------------------------------------------- preparing a run

def enable_compilation_cache():
    """JAX's persistent compilation cache for CLI runs: ``$JAX_COMPILATION_CACHE_DIR`` if set, else
    ``~/.cache/parallel_skills_jax`` (the tests' default). Left alone if already configured."""
    import jax

    if not jax.config.jax_compilation_cache_dir:
        jax.config.update("jax_compilation_cache_dir", os.environ.get("JAX_COMPILATION_CACHE_DIR") or DEFAULT_CACHE_DIR)


def _command(argv):
    return " ".join(["python -m training.run"] + list(argv))


def _check_writable(out):
    check_writable(out, "the run directory")


def prepare_new(args, argv, num_devices: int = 1, write: bool = True):
    """Validate everything, then create the run directory and its config.json (``write`` False: a
    non-primary process of a multi-process run, which validates alike and writes nothing)."""
    import tasks
    from training import skill_library

    a = {k: (getattr(args, k) if getattr(args, k) is not None else v) for k, v in DEFAULTS.items()}
    if args.physics is None and a["task"] in tasks.LOCOMOTION_TASKS:
        a["physics"] = "mujoco"  # the OP3 tasks' CPU fast path (no kinematic model)
    if a["task"] not in tasks.names():
        raise UsageError(f"unknown task {a['task']!r}; valid tasks: {', '.join(tasks.names())}")
    if a["physics"] not in tasks.PHYSICS:
        raise UsageError(f"unknown physics {a['physics']!r}; valid: {', '.join(tasks.PHYSICS)}")
    if a["skills"] not in skill_library.SET_NAMES:
        raise UsageError(f"unknown skill set {a['skills']!r}; valid: {', '.join(skill_library.SET_NAMES)}")

    from parallel_skills.config import dotted_names, learner_schedule, nested, resolve

    settings = run_settings(args)
    cfg, file_data = BASE_CONFIG, {}
    if args.config:
        file_data = load_config_file(args.config)
        cfg = apply_config(cfg, file_data, f"config file {args.config}")
    flags = config_flags.given(args, TRAIN_FLAGS)
    cfg = apply_config(cfg, nested(flags), "the command line")  # (rules relating fields; each value is parsed)
    method = cfg.method
    spec = methods.get(method)
    if args.finetune_from is not None and not spec.starts_from_skill:
        starting = " / ".join(m.name for m in methods.all_methods() if m.starts_from_skill)
        raise UsageError(f"--finetune_from is for --method {starting}, not {method}")
    if spec.starts_from_skill:
        if args.skill_source == "scripted" and not args.skill_dir:
            raise UsageError(f"--method {method} starts from a network skill: use --skill_source library (the "
                             f"default for {method}) or --skill_dir, not scripted controllers")
        if args.skill_source is None:
            a["skill_source"] = "library"
        names = [args.finetune_from or skill_library.skill_names(a["task"], "useful")[-1]]
    elif not spec.frozen_skills:
        names = []
    else:
        names = skill_library.skill_names(a["task"], a["skills"])

    out = args.out or os.path.join("runs", f"{a['task']}-{method}-s{settings.seed}-{time.strftime('%Y%m%d-%H%M%S')}")
    if write and os.path.exists(out):
        raise UsageError(f"run directory {out} already exists; choose a new --out, or --resume it "
                         "(runs are never overwritten)")
    if write:
        _check_writable(out)

    import jax

    on_cpu = jax.default_backend() == "cpu"
    num_timesteps = settings.num_timesteps or DEFAULT_TIMESTEPS["cpu" if on_cpu else "accelerator"]
    given = dotted_names(file_data) + list(flags)
    try:
        resolved, notes = resolve(cfg, given=given)  # (the recipe fills what the file and flags leave)
    except ValueError as e:  # a field the file or a flag sets conflicts with the method
        raise UsageError(f"config file {args.config}: {e}" if args.config else str(e)) from None
    if "eval_every" in given:
        eval_every = cfg.eval_every
    else:
        eval_every = max(1, round(num_timesteps / (resolved.num_envs * resolved.unroll_length) / 20))
    resolved = dataclasses.replace(resolved, eval_every=eval_every)
    _check_mesh(resolved, num_devices)
    overrides = {} if settings.episode_length is None else {"episode_length": settings.episode_length}
    if settings.start_states != "table":
        overrides["start_states"] = settings.start_states
    env = tasks.make(a["task"], physics=a["physics"], **overrides)  # validates the overrides
    skill_dir = os.path.abspath(args.skill_dir) if args.skill_dir else None
    loaded = skill_library.load_skills(names, a["physics"], a["skill_source"], env.observation_size,
                                       env.action_size, skill_dir=skill_dir)  # exist, fit (ValueError: one line)
    if spec.starts_from_skill:
        from parallel_skills.train import finetune_source

        finetune_source(loaded, resolved)  # a network of the new skill's sizes

    run = RunRecord(
        command=_command(argv), task=a["task"], physics=a["physics"], skill_set=a["skills"],
        skill_source=a["skill_source"], skill_dir=skill_dir, skills=names, seed=settings.seed,
        num_timesteps=num_timesteps, episode_length=int(getattr(env, "episode_length", 0)) or settings.episode_length,
        checkpoint_every=settings.checkpoint_every, start_states=settings.start_states,
        replay_checkpoint=not args.no_replay_checkpoint,
        video=bool(args.video), train_config=dataclasses.asdict(resolved), auto=notes,
        learners=learner_schedule(resolved), host=rundir.host_facts())
    if write:
        rundir.create(out, run)
    return out, run, resolved, env


def run_settings(args) -> RunConfig:
    """The ``RunConfig`` of the given flags (the dataclass's defaults for the rest)."""
    return RunConfig(**config_flags.given(args, RUN_FLAGS))


def _check_mesh(resolved, num_devices: int):
    from parallel_skills.sharding import check_divisible

    try:
        check_divisible(resolved, num_devices)
    except ValueError as e:
        raise UsageError(str(e)) from None


def resume_conflicts(args, run: RunRecord, resolved) -> dict:
    """``{flag: (its value or None, the run's)}`` of the flags a ``--resume`` may only repeat: the
    flags that are no config field, the ``RunConfig`` ones (but ``num_timesteps``, which extends)
    and every ``TrainConfig`` flag (the run's resolved config holds each)."""
    from parallel_skills.config import dotted_value

    starts_from_skill = methods.get(resolved.method).starts_from_skill
    pairs = {"task": (args.task, run.task), "physics": (args.physics, run.physics),
             "skills": (args.skills, run.skill_set), "skill_source": (args.skill_source, run.skill_source),
             "skill_dir": (os.path.abspath(args.skill_dir) if args.skill_dir else None, run.skill_dir),
             "finetune_from": (args.finetune_from, run.skills[0] if starts_from_skill and run.skills else None)}
    pairs.update({name: (value, getattr(run, name))
                  for name, value in config_flags.given(args, RUN_FLAGS).items() if name != "num_timesteps"})
    pairs.update({name: (value, dotted_value(resolved, name))
                  for name, value in config_flags.given(args, TRAIN_FLAGS).items()})
    return pairs


def prepare_resume(args, num_devices: int = 1):
    """Validate a --resume: the run exists, its config.json fixes the config (conflicting flags
    are rejected) and it holds a checkpoint. Writes nothing."""
    import tasks
    from training.checkpointing import Checkpointer

    if args.out is None:
        raise UsageError("--resume needs --out DIR, the run directory to continue")
    out = args.out
    if not os.path.exists(out):
        raise UsageError(f"cannot resume: run directory {out} does not exist")
    if not os.path.isdir(out):
        raise UsageError(f"cannot resume: {out} is not a directory")
    cfg_path = rundir.config_path(out)
    run = rundir.read_record(out, "cannot resume")
    resolved = run.config(f"{cfg_path} train_config")

    for name, (value, stored) in resume_conflicts(args, run, resolved).items():
        if value is not None and value != stored:
            raise UsageError(f"--{name} {config_flags.flag_text(value)} conflicts with {cfg_path} "
                             f"({name}={json.dumps(stored)}); "
                             "--resume continues a run with its own config: drop the flag")
    if args.no_replay_checkpoint and run.replay_checkpoint:
        raise UsageError(f"--no-replay-checkpoint conflicts with {cfg_path} (replay_checkpoint=true); "
                         "--resume continues a run with its own config: drop the flag")
    if args.config:
        from parallel_skills.config import first_difference

        changed = first_difference(resolved, apply_config_file(resolved, args.config))
        if changed:
            raise UsageError(f"--config {args.config} sets {changed[0]}={json.dumps(changed[2], default=str)}, "
                             f"{cfg_path} has {json.dumps(changed[1], default=str)}; --resume continues a run "
                             "with its own config: drop the flag")
    if run.task not in tasks.names() or run.physics not in tasks.PHYSICS:
        raise UsageError(f"cannot resume: {cfg_path} names task {run.task!r} / physics {run.physics!r}, "
                         "which this version does not know")
    from tasks.manipulation import scripted

    unknown = [n for n in run.skills if n not in scripted.names()
               and not (run.skill_dir and os.path.isfile(os.path.join(run.skill_dir, f"{n}.npz")))]
    if unknown and run.skill_source == "scripted":  # (library skills are checked when loaded)
        raise UsageError(f"cannot resume: {cfg_path} names skills {unknown} this version does not have")
    budget, asked = int(run.num_timesteps), run_settings(args).num_timesteps
    if asked is not None and asked < budget:
        raise UsageError(f"--num_timesteps {asked} is below the budget of {out} ({cfg_path}: "
                         f"num_timesteps={budget}); --resume can extend a run, not shorten it")
    target = max(budget, asked or 0)
    exported = rundir.exported_budget(out)
    if exported is not None and exported >= target:
        raise UsageError(f"run {out} is complete (its export.json is at {exported} env steps); nothing to resume; "
                         f"extend it with --resume --num_timesteps N, N > {exported}")
    ckpt = Checkpointer(out)
    if ckpt.latest_step() is None:
        raise UsageError(f"cannot resume: {out} holds no checkpoint (nothing in {ckpt.directory}); "
                         "start the run again with a new --out")
    _check_mesh(resolved, num_devices)
    env = tasks.make(run.task, physics=run.physics, **run.env_overrides())
    return out, dataclasses.replace(run, num_timesteps=target), resolved, env


# ----------------------------------------------------------------------------- running


SEEDS_JSON = "seeds.json"  # OUT/seeds.json of a --seeds group: {"seeds", "runs", "command"}


def _parse_seeds(text: str) -> list:
    try:
        seeds = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise UsageError(f"--seeds must be non-negative integers separated by commas, got {text!r}") from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise UsageError(f"--seeds must be distinct non-negative integers separated by commas, got {text!r}")
    return seeds


def prepare_seeds(args, argv, num_devices: int = 1):
    """A new ``--seeds`` group: validated like one run, then one run directory per seed in OUT and
    OUT/seeds.json. Returns ([out], [run], resolved, env)."""
    import argparse

    seeds = _parse_seeds(args.seeds)
    if args.seed is not None:
        raise UsageError("--seed and --seeds: give one of them")
    out = args.out or os.path.join("runs", f"{args.task or DEFAULTS['task']}-{args.method or BASE_CONFIG.method}-"
                                   f"seeds{'_'.join(map(str, seeds))}-{time.strftime('%Y%m%d-%H%M%S')}")
    if os.path.exists(out):
        raise UsageError(f"run directory {out} already exists; choose a new --out, or --resume it "
                         "(runs are never overwritten)")
    _check_writable(out)
    prepared = [prepare_new(argparse.Namespace(**dict(vars(args), seed=s, out=os.path.join(out, f"s{s}"))), argv,
                            num_devices) for s in seeds]
    with open(os.path.join(out, SEEDS_JSON), "w") as f:
        json.dump({"seeds": seeds, "runs": [f"s{s}" for s in seeds], "command": _command(argv)}, f, indent=2)
    return [p[0] for p in prepared], [p[1] for p in prepared], prepared[0][2], prepared[0][3]


def resume_seeds(args, num_devices: int = 1):
    """``--resume --out OUT`` of a ``--seeds`` group: each run validated as a single resume."""
    import argparse

    if args.seeds is not None:
        raise UsageError("--resume of a --seeds group takes its seeds from seeds.json: drop --seeds")
    try:
        with open(os.path.join(args.out, SEEDS_JSON)) as f:
            names = list(json.load(f)["runs"])
    except (OSError, ValueError, KeyError, TypeError):
        raise UsageError(f"cannot resume: {os.path.join(args.out, SEEDS_JSON)} is unreadable") from None
    prepared = [prepare_resume(argparse.Namespace(**dict(vars(args), out=os.path.join(args.out, n))), num_devices)
                for n in names]
    resolved = prepared[0][2]
    if any(p[2] != resolved for p in prepared) or len({p[1].num_timesteps for p in prepared}) != 1:
        raise UsageError(f"cannot resume {args.out} together: its runs no longer share one config and budget "
                         "(resume them one by one: --resume --out DIR/sSEED)")
    return [p[0] for p in prepared], [p[1] for p in prepared], resolved, prepared[0][3]


def connect(args):
    """``(Distributed, mesh)``: this process joined to the others of a multi-process run
    (``jax.distributed``, before any device is used) and the mesh over every global device (None
    with one device: the single-device program). Bad inputs raise UsageError (one line)."""
    from parallel_skills import sharding

    multi = args.coordinator is not None or args.distributed or args.num_processes is not None \
        or args.process_id is not None
    if multi and args.seeds is not None:
        raise UsageError("--seeds trains in one process: drop --coordinator / --distributed (a multi-process run "
                         "trains one seed)")
    if multi and args.out is None:
        raise UsageError("a multi-process run needs --out DIR, the same directory (on a shared file system) in "
                         "every process")
    try:
        dist = sharding.initialize(args.coordinator, args.num_processes, args.process_id, args.coordinator_timeout,
                                   auto=args.distributed)
    except ValueError as e:
        raise UsageError(str(e)) from None
    import jax

    mesh = sharding.make_mesh() if jax.device_count() > 1 else None
    return dist, mesh


def _barrier(dist, name: str):
    """Every process of a multi-process run waits here for the others (no-op with one)."""
    if dist.num_processes > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(f"parallel_skills: {name}")


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    dist, mesh = main_guard(lambda: connect(args))
    enable_compilation_cache()
    if args.seeds is not None or (args.resume and args.out and os.path.isfile(os.path.join(args.out, SEEDS_JSON))):
        return _main_seeds(args, argv, mesh)
    devices = 1 if mesh is None else mesh.size
    out, run, resolved, env = main_guard(
        lambda: prepare_resume(args, devices) if args.resume else prepare_new(args, argv, devices, write=dist.primary))
    if dist.primary:
        main_guard(lambda: rundir.lock(out))
    try:
        _barrier(dist, "run directory ready")  # (process 0 created it)
        _train([out], [run], resolved, env, resume=args.resume, video=args.video or run.video, mesh=mesh, dist=dist,
               extend_command=_command(argv) if args.resume else None)
    finally:
        if dist.primary:
            rundir.unlock(out)


def _main_seeds(args, argv, mesh=None):
    devices = 1 if mesh is None else mesh.size
    outs, runs, resolved, env = main_guard(lambda: resume_seeds(args, devices) if args.resume
                                           else prepare_seeds(args, argv, devices))
    locked = []
    try:
        for out in outs:
            main_guard(lambda o=out: rundir.lock(o))
            locked.append(out)
        _train(outs, runs, resolved, env, resume=args.resume, video=args.video or runs[0].video, mesh=mesh,
               extend_command=_command(argv) if args.resume else None, grouped=True)
    finally:
        for out in locked:
            rundir.unlock(out)


def _load_skills(run, env):
    from training import skill_library

    return main_guard(lambda: skill_library.load_skills(list(run.skills), run.physics, run.skill_source,
                                                        env.observation_size, env.action_size,
                                                        skill_dir=run.skill_dir))


def _announce(run, resolved, resume: bool, outs, mesh=None, dist=None):
    from parallel_skills.config import describe_schedule, learner_schedule

    if not resume:
        for out in outs:
            print(f"run dir: {out}")
    print(f"task={run.task} physics={run.physics} method={resolved.method} skills={list(run.skills) or '(none)'}")
    if mesh is not None:
        procs = f" in {dist.num_processes} processes" if dist is not None and dist.num_processes > 1 else ""
        print(f"devices: {mesh.size}{procs}, each {resolved.num_envs // mesh.size} envs and 1/{mesh.size} of every "
              "learner batch (parameters and replay replicated)")
    if run.auto and not resume:  # (train() gets the resolved config: it has nothing to choose)
        print("defaults chosen automatically: " + ", ".join(run.auto))
    print(describe_schedule(learner_schedule(resolved)))


def _train(outs, runs, resolved, env, resume: bool, video: bool = False, mesh=None, dist=None, extend_command=None,
           grouped: bool = False):
    """Train the runs ``outs`` / ``runs`` (one, or the seeds of a ``--seeds`` group: same config, one
    seed each, ``grouped``) in one call of ``parallel_skills.train.train_seeds`` (vmapped over the
    group's seeds; one run unbatched, as ``train``); each writes its own run directory
    (``run_files``). ``dist``: this process of a multi-process run (one run), which writes only if
    primary."""
    from parallel_skills.sharding import Distributed
    from parallel_skills.train import train_seeds
    from training.checkpointing import Checkpointer

    dist = dist or Distributed()
    run = runs[0]
    skills = _load_skills(run, env)
    initial_states = host_states = None
    if resume:
        ckpts = [Checkpointer(out, save_replay=r.replay_checkpoint) for out, r in zip(outs, runs)]
        if grouped:
            restored = main_guard(lambda: run_files.restore_group(outs, ckpts, runs, env, skills, resolved, mesh))
        else:
            restored = [main_guard(lambda: run_files.restore_run(
                outs[0], ckpts[0], os.path.join(outs[0], "metrics.csv"), env, skills, resolved, int(run.seed),
                mesh=mesh, primary=dist.primary))]
        if dist.primary:
            for out, r, (_, host) in zip(outs, runs, restored):  # (all restored: only now is anything written)
                run_files.resume_files(out, os.path.join(out, "metrics.csv"), host, r, extend_command)
        initial_states, host_states = [x[0] for x in restored], [x[1] for x in restored]
    if dist.primary:
        _announce(run, resolved, resume, outs, mesh, dist)
    t0 = time.perf_counter()
    bar = Progress(int(run.num_timesteps), int(host_states[0]["env_steps"]) if host_states else 0,
                   **({} if dist.primary else {"out": io.StringIO(), "tty": False}))
    files = [run_files.RunFiles(out, r, resolved, resume, host_states[i] if host_states else None, bar,
                                f"s{r.seed} " if grouped else "", primary=dist.primary, env=env)
             for i, (out, r) in enumerate(zip(outs, runs))]
    try:
        make_policy, params, metrics = train_seeds(
            env, skills, seeds=[int(r.seed) for r in runs], num_timesteps=int(run.num_timesteps), config=resolved,
            progress_fns=[f.progress for f in files], initial_states=initial_states, host_states=host_states,
            checkpoint_fns=[f.checkpoint for f in files], checkpoint_every=run.checkpoint_every,
            checkpoint_min_seconds=run_files.CHECKPOINT_MIN_SECONDS, step_fn=bar.advance, auto_config=False,
            mesh=mesh, seed_axis=grouped, policy_params_fns=[f.policy_params for f in files])
    finally:
        bar.close()
        for f in files:
            f.close()
    if dist.num_processes > 1:  # (each process's replicas: equal when the processes trained together)
        print(f"process {dist.process_id} of {dist.num_processes}: parameters sha256 "
              f"{run_files.params_digest(params[0])}")
    if dist.primary:
        seconds = time.perf_counter() - t0
        for out, r, p, m in zip(outs, runs, params, metrics):
            run_files.write_outputs(out, r, resolved, env, skills, make_policy, p, m, video, seconds)


if __name__ == "__main__":
    main()
