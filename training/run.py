"""Train a new skill with SkillS (or from scratch) on a task: the project's main job.

    python -m training.run                                  # kinematic lift, device-sized defaults
    python -m training.run --task lift --num_envs 4096      # on a GPU

Writes into ``--out`` (a new directory; an existing one is never written into):
``config.json``, ``metrics.csv`` (one row per evaluation), ``new_skill.npz`` + ``.json`` (the
new skill as a loadable skill: ``python -m training.evaluate --policy DIR/new_skill.npz``).
The last line printed is ``success=<new skill alone> return=<mean>``.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import sys
import time

from training.cli import Parser, UsageError, main_guard, nonnegative_int, positive_int

DEFAULT_TIMESTEPS = {"cpu": 400_000, "accelerator": 20_000_000}


def build_parser():
    import tasks
    from tasks.manipulation.skill_sets import SET_NAMES

    p = Parser(prog="python -m training.run", description=__doc__.splitlines()[0])
    p.add_argument("--task", default="lift", help="task name (see tasks.names())")
    p.add_argument("--physics", default="kinematic", help=f"one of {', '.join(tasks.PHYSICS)}")
    p.add_argument("--num_envs", type=positive_int, default=None, help="default: 32 on CPU, 4096 on GPU")
    p.add_argument("--num_timesteps", type=positive_int, default=None, help="env steps (default: 400k on CPU)")
    p.add_argument("--episode_length", type=positive_int, default=None)
    p.add_argument("--seed", type=nonnegative_int, default=0)
    p.add_argument("--skills", default="useful", help=f"skill set: {', '.join(SET_NAMES)}")
    p.add_argument("--method", default="skills", choices=["skills", "scratch"])
    p.add_argument("--eval_every", type=positive_int, default=None, help="iterations between evaluations")
    p.add_argument("--eval_episodes", type=positive_int, default=32)
    p.add_argument("--config", default=None, help="JSON file overriding TrainConfig fields, e.g. "
                   '{"unroll_length": 25, "scheduler": {"policy_warmup_updates": 1500}, "new_skill": {"crr_mode": "indicator"}}')
    p.add_argument("--out", default=None, help="run directory (must not exist); default runs/<task>-<method>-s<seed>-<time>")
    return p


def apply_config_file(cfg, path):
    """Override TrainConfig fields (and nested scheduler / new_skill fields) from a JSON file."""
    from parallel_skills import NewSkillConfig, SchedulerConfig

    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError:
        raise UsageError(f"config file {path} does not exist") from None
    except (OSError, ValueError) as e:
        raise UsageError(f"cannot read config file {path}: {e}") from None
    if not isinstance(data, dict):
        raise UsageError(f"config file {path} must hold a JSON object of TrainConfig fields")
    nested = {"scheduler": SchedulerConfig, "new_skill": NewSkillConfig}
    top = {f.name for f in dataclasses.fields(cfg)}
    updates = {}
    for key, value in data.items():
        if key not in top:
            raise UsageError(f"unknown config field {key!r} in {path}; valid: {', '.join(sorted(top))}")
        if key in nested:
            sub = getattr(cfg, key)
            valid = {f.name for f in dataclasses.fields(sub)}
            bad = sorted(set(value) - valid) if isinstance(value, dict) else ["(not an object)"]
            if bad:
                raise UsageError(f"unknown {key} config field(s) {bad} in {path}; valid: {', '.join(sorted(valid))}")
            value = dataclasses.replace(sub, **{k: tuple(v) if isinstance(v, list) else v for k, v in value.items()})
        updates[key] = value
    return dataclasses.replace(cfg, **updates)


def main(argv=None):
    args = build_parser().parse_args(argv)
    main_guard(lambda: _run(args))


def _run(args):
    import tasks
    from tasks.manipulation import scripted, skill_sets

    if args.task not in tasks.names():
        raise UsageError(f"unknown task {args.task!r}; valid tasks: {', '.join(tasks.names())}")
    if args.physics not in tasks.PHYSICS:
        raise UsageError(f"unknown physics {args.physics!r}; valid: {', '.join(tasks.PHYSICS)}")
    names = [] if args.method == "scratch" else skill_sets.skill_names(args.task, args.skills)
    out = args.out or os.path.join("runs", f"{args.task}-{args.method}-s{args.seed}-{time.strftime('%Y%m%d-%H%M%S')}")
    if os.path.exists(out):
        raise UsageError(f"run directory {out} already exists; choose a new --out (runs are never overwritten)")
    parent = os.path.dirname(os.path.abspath(out))
    if os.path.exists(parent) and not os.access(parent, os.W_OK):
        raise UsageError(f"cannot write the run directory {out}: {parent} is not writable")

    import jax

    from parallel_skills import Skill, TrainConfig, train
    from parallel_skills.normalization import std as norm_std
    from parallel_skills.train import resolve

    overrides = {} if args.episode_length is None else {"episode_length": args.episode_length}
    env = tasks.make(args.task, physics=args.physics, **overrides)
    skills = [Skill.from_fn(n, scripted.get(n), source="scripted") for n in names]
    on_cpu = jax.default_backend() == "cpu"
    num_timesteps = args.num_timesteps or DEFAULT_TIMESTEPS["cpu" if on_cpu else "accelerator"]
    cfg = TrainConfig(num_envs=args.num_envs, method=args.method, eval_episodes=args.eval_episodes)
    if args.config:
        cfg = apply_config_file(cfg, args.config)
    resolved, notes = resolve(cfg)
    steps_per_iter = resolved.num_envs * resolved.unroll_length
    eval_every = args.eval_every or max(1, round(num_timesteps / steps_per_iter / 20))
    cfg = dataclasses.replace(cfg, eval_every=eval_every)

    try:
        os.makedirs(out)
    except OSError as e:
        raise UsageError(f"cannot create the run directory {out}: {e.strerror}") from None
    with open(os.path.join(out, "config.json"), "w") as f:
        json.dump({"command": " ".join(["python -m training.run"] + sys.argv[1:]), "task": args.task,
                   "physics": args.physics, "skills": names, "seed": args.seed, "num_timesteps": num_timesteps,
                   "train_config": dataclasses.asdict(resolved), "auto": notes}, f, indent=2, default=str)
    print(f"run dir: {out}")
    print(f"task={args.task} physics={args.physics} method={args.method} skills={names or '(none)'}")
    # (train() logs the device-dependent defaults it chose.)

    csv_path = os.path.join(out, "metrics.csv")
    fields = ["env_steps", "wall_time", "eval/new_skill_success", "eval/new_skill_return", "eval/scheduler_success",
              "eval/scheduler_return", "episode_success", "episode_return", "new_skill_selection_rate",
              "scheduler/critic_loss", "new_skill/critic_loss", "scheduler/policy_entropy_i", "skill_histogram",
              "length_histogram", "skill_steps"]
    t0 = time.perf_counter()

    with open(csv_path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()

        def progress(steps, m):
            writer.writerow({k: json.dumps(m[k]) if isinstance(m.get(k), list) else m.get(k, "") for k in fields})
            f.flush()
            rate = steps / max(time.perf_counter() - t0, 1e-9)
            sched = f" scheduler={m['eval/scheduler_success']:.2f}" if "eval/scheduler_success" in m else ""
            print(f"[{steps:>10,d} steps {rate:8,.0f}/s] new_skill success={m['eval/new_skill_success']:.2f}"
                  f" return={m['eval/new_skill_return']:.1f}{sched} train_success={m['episode_success']:.2f}"
                  f" new_skill_rate={m['new_skill_selection_rate']:.2f}", flush=True)

        make_policy, params, metrics = train(env, skills, num_timesteps=num_timesteps, seed=args.seed, config=cfg,
                                             progress_fn=progress)

    stats = params["normalizer"]
    skill = Skill.gaussian_mlp(
        f"{args.task}_new_skill", {"policy": params["new_skill"], "obs_mean": stats.mean, "obs_std": norm_std(stats)},
        env.action_size, resolved.new_skill.hidden)
    skill.save(os.path.join(out, "new_skill.npz"), obs_size=int(env.observation_size), task=args.task,
               physics=args.physics, seed=args.seed, command=" ".join(["python -m training.run"] + sys.argv[1:]),
               success=metrics["eval/new_skill_success"], trained_with=names, env_steps=metrics["env_steps"])
    print(f"new skill saved: {os.path.join(out, 'new_skill.npz')}  ({metrics['env_steps']:,} env steps, "
          f"{time.perf_counter() - t0:.0f} s)")
    print(f"success={metrics['eval/new_skill_success']:.4f} return={metrics['eval/new_skill_return']:.3f}")


if __name__ == "__main__":
    main()
