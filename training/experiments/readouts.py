"""The new skill of a run's checkpoint read out three ways, on the same episodes' resets:
its mean action (the deterministic policy ``eval/new_skill_success``, ``training.evaluate`` and the
export run), actions sampled from its Gaussian (as it collects), and the best of the mean and 15
samples by its own critic (``crr.critic_weighted_action``: CRR's critic-weighted policy, argmax
form). docs/scheduler.md §5 and §8.

    python -m training.experiments.readouts RUN_DIR --episodes 384 --json OUT.json

``RUN_DIR``: a ``training.run`` directory with a checkpoint (its latest that restores is read; the
run's config.json fixes the task, physics, skills and networks). Episodes run in batches of
``--batch`` envs (one jitted evaluation each); batch b draws its resets and noise from
``fold_in(PRNGKey(--seed), b)``, the same for every read-out. Prints one line per read-out (success
and return over all episodes, with the binomial standard error); ``--json`` writes them.
"""

from __future__ import annotations

import argparse
import json
import math
import os

from training.cli import Parser, UsageError, main_guard

READOUTS = ("mean", "sampled", "critic_weighted")


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="python -m training.experiments.readouts", description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="a training.run directory holding a checkpoint")
    p.add_argument("--episodes", type=int, default=384, help="episodes per read-out (a multiple of --batch)")
    p.add_argument("--batch", type=int, default=64, help="envs per jitted evaluation")
    p.add_argument("--seed", type=int, default=0, help="seed of the evaluation episodes")
    p.add_argument("--json", default=None, help="write the results to this file")
    return p


def load_run_state(run_dir: str):
    """``(env, trainer, state, host)`` of the latest restorable checkpoint of ``run_dir`` (read only).
    UsageError (one line) when the directory is not a run with a checkpoint."""
    import tasks
    from parallel_skills.train import make_trainer
    from training import rundir, skill_library
    from training.checkpointing import CheckpointError, Checkpointer, abstract_training_state

    record = rundir.read_record(run_dir, "cannot read the run")
    resolved = record.config(f"{rundir.config_path(run_dir)} train_config")
    env = tasks.make(record.task, physics=record.physics, **record.env_overrides())
    skills = skill_library.load_skills(list(record.skills), record.physics, record.skill_source,
                                       env.observation_size, env.action_size, skill_dir=record.skill_dir)
    abstract, fresh_replay = abstract_training_state(env, skills, resolved, int(record.seed))
    try:
        state, host = Checkpointer(run_dir).restore_latest(abstract, fresh_replay)
    except CheckpointError as e:
        raise UsageError(f"{run_dir}: {e}") from None
    return env, make_trainer(env, skills, resolved), state, host


def read_out(env, trainer, state, episodes: int, batch: int, seed: int) -> dict:
    """{read-out: {"success", "success_se", "return", "episodes"}} over ``episodes`` episodes."""
    import jax
    import numpy as np

    from parallel_skills.train import make_evaluators

    evals = make_evaluators(env, trainer, batch, int(env.episode_length))
    ns, norm = state.new_skill, state.normalizer
    run = {"mean": lambda k: evals.new_skill(ns.policy_params, norm, k),
           "sampled": lambda k: evals.new_skill_sampled(ns.policy_params, norm, k),
           "critic_weighted": lambda k: evals.new_skill_critic_weighted(ns.policy_params, ns.critic_params, norm, k)}
    out = {}
    for name in READOUTS:
        success, ret = [], []
        for b in range(episodes // batch):
            ev = jax.device_get(run[name](jax.random.fold_in(jax.random.PRNGKey(seed), b)))
            success.append(np.asarray(ev["success"])), ret.append(np.asarray(ev["return"]))
        s, r = np.concatenate(success), np.concatenate(ret)
        p = float(np.mean(s))
        out[name] = {"success": p, "success_se": math.sqrt(p * (1 - p) / len(s)), "return": float(np.mean(r)),
                     "episodes": int(len(s))}
    return out


def main(argv=None):
    args = build_parser().parse_args(argv)

    def run():
        if args.batch < 1 or args.episodes < args.batch or args.episodes % args.batch:
            raise UsageError(f"--episodes must be a positive multiple of --batch ({args.batch}), got {args.episodes}")
        if not os.path.isdir(args.run):
            raise UsageError(f"run directory {args.run} does not exist")
        env, trainer, state, host = load_run_state(args.run)
        results = read_out(env, trainer, state, args.episodes, args.batch, args.seed)
        for name, r in results.items():
            print(f"{name:16s} success {r['success']:.3f} ± {r['success_se']:.3f}  return {r['return']:.1f}  "
                  f"({r['episodes']} episodes, checkpoint at {int(host['env_steps'])} env steps)")
        if args.json:
            with open(args.json, "w") as f:
                json.dump({"run": os.path.basename(os.path.normpath(args.run)), "env_steps": int(host["env_steps"]),
                           "seed": args.seed, "readouts": results}, f, indent=1)
        return results

    return main_guard(run)


if __name__ == "__main__":
    main()
