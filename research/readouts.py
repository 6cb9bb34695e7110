"""The new skill of a run's checkpoint read out three ways, on the same episodes' resets:
its mean action (the deterministic policy ``eval/new_skill_success``, ``training.evaluate`` and the
export run), actions sampled from its Gaussian (as it collects), and the best of the mean and 15
samples by its own critic (``crr.critic_weighted_action``: CRR's critic-weighted policy, argmax
form). docs/research/scheduler.md §5 and §8.

    python -m research.readouts RUN_DIR --episodes 384 --json OUT.json

``RUN_DIR``: a ``training.run`` directory with a checkpoint (its latest that restores is read; the
run's config.json fixes the task, physics, skills and networks). Episodes run in batches of
``--batch`` envs (one jitted evaluation each); batch b draws its resets and noise from
``fold_in(PRNGKey(--seed), b)``, the same for every read-out. Prints one line per read-out (success
and return over all episodes, with the binomial standard error); ``--json`` writes them.

``--noise_dims 4`` (repeatable; comma-separated action indices) adds a read-out ``sampled_dims_4``:
the mean action with the Gaussian's noise on those dimensions only (which dimensions need the
noise; manipulation: 0-2 pinch velocity, 3 wrist yaw, 4 fingers).
"""

from __future__ import annotations

import argparse
import json
import math
import os

from training.cli import Parser, UsageError, main_guard

READOUTS = ("mean", "sampled", "critic_weighted")


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="python -m research.readouts", description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="a training.run directory holding a checkpoint")
    p.add_argument("--episodes", type=int, default=384, help="episodes per read-out (a multiple of --batch)")
    p.add_argument("--batch", type=int, default=64, help="envs per jitted evaluation")
    p.add_argument("--seed", type=int, default=0, help="seed of the evaluation episodes")
    p.add_argument("--json", default=None, help="write the results to this file")
    p.add_argument("--noise_dims", action="append", default=[],
                   help="comma-separated action indices: also read out the mean action with noise on these only")
    return p


def parse_dims(text: str, action_size: int) -> tuple[int, ...]:
    """``"0,1,2"`` -> (0, 1, 2); UsageError (one line) unless distinct indices in [0, action_size)."""
    try:
        dims = tuple(int(d) for d in text.split(","))
    except ValueError:
        dims = ()
    if not dims or len(set(dims)) != len(dims) or not all(0 <= d < action_size for d in dims):
        raise UsageError(f"--noise_dims takes distinct comma-separated action indices in 0..{action_size - 1}, "
                         f"got {text!r}")
    return dims


def noise_on_dims_evaluation(env, trainer, num_episodes: int, dims: tuple[int, ...]):
    """A jitted ``evaluate(new_params, normalizer, key)`` of the new skill alone acting with its mean
    action plus its Gaussian's noise on the action dimensions ``dims`` only (clipped to [−1, 1])."""
    import jax
    import jax.numpy as jnp

    from parallel_skills import learners, networks
    from parallel_skills import normalization as obs_norm
    from parallel_skills.evaluation import rollout_episodes

    new_apply = learners.make_new_skill_apply(int(env.action_size), trainer.config.new_skill)
    mask = jnp.zeros((int(env.action_size),)).at[jnp.asarray(dims)].set(1.0)

    def evaluate(new_params, normalizer, key):
        def policy(obs, k):
            mean, std = new_apply(new_params, obs_norm.normalize(normalizer, obs))
            return networks.sample_action(mean, std * mask, k)

        return rollout_episodes(env, policy, key, num_episodes, int(env.episode_length))

    return jax.jit(evaluate)


def read_out(env, trainer, state, episodes: int, batch: int, seed: int, noise_dims=()) -> dict:
    """{read-out: {"success", "success_se", "return", "episodes"}} over ``episodes`` episodes
    (``noise_dims``: tuples of action indices, a ``sampled_dims_<i_j>`` read-out each)."""
    import jax
    import numpy as np

    from parallel_skills.train import make_evaluators

    evals = make_evaluators(env, trainer, batch, int(env.episode_length))
    ns, norm = state.new_skill, state.normalizer
    run = {"mean": lambda k: evals.new_skill(ns.policy_params, norm, k),
           "sampled": lambda k: evals.new_skill_sampled(ns.policy_params, norm, k),
           "critic_weighted": lambda k: evals.new_skill_critic_weighted(ns.policy_params, ns.critic_params, norm, k)}
    for dims in noise_dims:
        ev = noise_on_dims_evaluation(env, trainer, batch, dims)
        run["sampled_dims_" + "_".join(map(str, dims))] = lambda k, ev=ev: ev(ns.policy_params, norm, k)
    out = {}
    for name in run:
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
        from training.run_files import load_checkpointed_run

        loaded = load_checkpointed_run(args.run)
        env, trainer, state, host = loaded.env, loaded.trainer(), loaded.state, loaded.host
        dims = [parse_dims(d, int(env.action_size)) for d in args.noise_dims]
        results = read_out(env, trainer, state, args.episodes, args.batch, args.seed, dims)
        for name, r in results.items():
            print(f"{name:20s} success {r['success']:.3f} ± {r['success_se']:.3f}  return {r['return']:.1f}  "
                  f"({r['episodes']} episodes, checkpoint at {int(host['env_steps'])} env steps)")
        if args.json:
            with open(args.json, "w") as f:
                json.dump({"run": os.path.basename(os.path.normpath(args.run)), "env_steps": int(host["env_steps"]),
                           "seed": args.seed, "readouts": results}, f, indent=1)
        return results

    return main_guard(run)


if __name__ == "__main__":
    main()
