"""Diagnostic: the new-skill learner (CRR) on a fixed dataset of noisy scripted-expert episodes.

Isolates the new skill's learning from the scheduler: collects ``--envs × --steps`` transitions of a
scripted controller with Gaussian action noise on a kinematic task, then runs CRR updates on them and
evaluates the new skill alone every ``--chunk`` updates.

    python -m research.offline_crr --task lift --expert lift_green --crr_mode exp --chunks 8
"""

from __future__ import annotations

import argparse
import time

import jax


def main():
    import tasks
    from parallel_skills import NewSkillConfig, learners
    from parallel_skills import normalization as norm
    from parallel_skills.evaluation import make_evaluator
    from parallel_skills.replay import Transition
    from tasks.manipulation import scripted
    from research.scripted_data import collect_noisy_expert

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="lift")
    p.add_argument("--expert", default="lift_green")
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--noise", type=float, default=0.1)
    p.add_argument("--crr_mode", default="exp", choices=["exp", "indicator"])
    p.add_argument("--chunk", type=int, default=500)
    p.add_argument("--chunks", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()

    env = tasks.make(args.task)
    B, T = args.envs, args.steps
    collect = jax.jit(lambda key: collect_noisy_expert(env, scripted.get(args.expert), B, T, args.noise, key))
    data = collect(jax.random.PRNGKey(args.seed))
    del data["clean_action"]
    stats = norm.update(norm.init(env.observation_size), data["obs"])
    cfg = NewSkillConfig(crr_mode=args.crr_mode)
    state = learners.new_skill_learner_init(jax.random.PRNGKey(args.seed + 1), env.observation_size,
                                            env.action_size, cfg)
    apply = learners.make_new_skill_apply(env.action_size, cfg)
    size = B * T
    print(f"{size} transitions, rewarded fraction {float((data['reward'] > 0).mean()):.3f}")

    @jax.jit
    def train(state, key):
        def body(st, k):
            k1, k2 = jax.random.split(k)
            idx = jax.random.randint(k1, (cfg.batch_size,), 0, size)
            b = jax.tree.map(lambda x: x[idx], data)
            batch = Transition.batch(obs=norm.normalize(stats, b["obs"]), action=b["action"], reward=b["reward"],
                                     discount=b["discount"], next_obs=norm.normalize(stats, b["next_obs"]))
            return learners.new_skill_learner_update(st, batch, k2, cfg)

        return jax.lax.scan(body, state, jax.random.split(key, args.chunk))

    for r in range(args.chunks):
        t0 = time.perf_counter()
        state, m = train(state, jax.random.PRNGKey(1000 + r))
        params = state.policy_params
        ev = make_evaluator(env, lambda o, k: apply(params, norm.normalize(stats, o))[0], 32)(jax.random.PRNGKey(99))
        print(f"{(r + 1) * args.chunk:6d} updates ({time.perf_counter() - t0:4.0f} s): new skill alone "
              f"success={float(ev['success'].mean()):.2f} crr_weight={float(m['crr_weight_mean'][-1]):.2f} "
              f"q={float(m['q_mean'][-1]):.1f} log_std={float(m['policy_log_std_mean'][-1]):.2f}", flush=True)


if __name__ == "__main__":
    main()
