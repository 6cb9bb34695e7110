"""Diagnostic: can the new-skill network imitate a scripted controller? (docs/research/learning.md)

Collects ``--envs`` × ``--steps`` transitions of a scripted controller on a kinematic task,
executed with N(0, ``--noise``) action noise and labelled with the clean controller action
(``--labels clean``, DART-style) or the executed one (``--labels executed``, what SkillS's
replay holds); fits the new-skill Gaussian MLP by negative log-likelihood (``--loss nll``, as
CRR with unit weights) or mean-squared error of the mean; evaluates the clone alone.

    python -m research.bc_diagnostic --noise 0.3 --labels executed --min_std 0.05
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import optax


def main():
    import tasks
    from parallel_skills import NewSkillConfig, learners
    from parallel_skills import normalization as norm
    from parallel_skills.evaluation import make_evaluator
    from parallel_skills.networks import gaussian_log_prob
    from tasks.manipulation import scripted
    from research.scripted_data import collect_noisy_expert

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="lift")
    p.add_argument("--expert", default="lift_green")
    p.add_argument("--envs", type=int, default=512)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--noise", type=float, default=0.3)
    p.add_argument("--labels", default="clean", choices=["clean", "executed"])
    p.add_argument("--loss", default="nll", choices=["nll", "mse"])
    p.add_argument("--min_std", type=float, default=NewSkillConfig.min_std)
    p.add_argument("--avoid_neighbours", action="store_true", help="grasp yaw clear of other cubes")
    p.add_argument("--updates", type=int, default=4000)
    p.add_argument("--eval_episodes", type=int, default=64)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()

    env = tasks.make(args.task)
    prm = dataclasses.replace(scripted.ControllerParams(), avoid_neighbours=args.avoid_neighbours)
    expert = scripted.get(args.expert, prm)
    B, T = args.envs, args.steps
    raw = jax.jit(lambda key: collect_noisy_expert(env, expert, B, T, args.noise, key))(jax.random.PRNGKey(args.seed))
    data = dict(obs=raw["obs"], action=raw["clean_action" if args.labels == "clean" else "action"])
    stats = norm.update(norm.init(env.observation_size), data["obs"])
    policy, _ = learners.new_skill_networks(env.action_size, NewSkillConfig(min_std=args.min_std))
    params = policy.init(jax.random.PRNGKey(args.seed + 1), jnp.zeros((1, env.observation_size)))
    opt = optax.adam(NewSkillConfig.learning_rate)
    opt_state = opt.init(params)

    def loss_fn(params, obs, act):
        mean, std = policy.apply(params, norm.normalize(stats, obs))
        if args.loss == "mse":
            return jnp.mean(jnp.sum((mean - act) ** 2, -1))
        return -jnp.mean(gaussian_log_prob(mean, std, act))

    @jax.jit
    def fit(params, opt_state, key):
        def body(carry, k):
            params, opt_state = carry
            idx = jax.random.randint(k, (NewSkillConfig.batch_size,), 0, B * T)
            loss, g = jax.value_and_grad(loss_fn)(params, data["obs"][idx], data["action"][idx])
            upd, opt_state = opt.update(g, opt_state, params)
            return (optax.apply_updates(params, upd), opt_state), loss

        (params, opt_state), losses = jax.lax.scan(body, (params, opt_state), jax.random.split(key, 1000))
        return params, opt_state, losses[-1]

    print(f"{B * T} transitions; expert {args.expert} with noise {args.noise}, {args.labels} labels, "
          f"{args.loss} loss, min_std {args.min_std}")
    for r in range(max(1, args.updates // 1000)):
        t0 = time.perf_counter()
        params, opt_state, loss = fit(params, opt_state, jax.random.PRNGKey(1000 + r))
        prm_now = params
        ev = make_evaluator(env, lambda o, k: policy.apply(prm_now, norm.normalize(stats, o))[0],
                            args.eval_episodes, 300)(jax.random.PRNGKey(99))
        print(f"{(r + 1) * 1000:6d} updates: loss={float(loss):.2f} clone success={float(ev['success'].mean()):.2f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
