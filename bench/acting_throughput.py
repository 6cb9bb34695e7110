"""Acting-step throughput: scheduler + skills + counters + replay insert, over the bare env step
at the same num_envs (both `jit(vmap)` inside `lax.scan`, measured in one run); and learner
updates per second.

    python bench/acting_throughput.py --task stack --num_envs 4096 --steps 50
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax

import tasks
from parallel_skills import Skill, TrainConfig
from parallel_skills.config import resolve
from parallel_skills.train import make_trainer
from tasks.manipulation import scripted
from training import skill_library


def timed(fn, *args, repeats=3):
    out = jax.block_until_ready(fn(*args))  # compile + warm up
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best, out


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="stack")
    p.add_argument("--physics", default="kinematic")
    p.add_argument("--num_envs", type=int, default=4096)
    p.add_argument("--steps", type=int, default=50, help="unroll length per measured call")
    p.add_argument("--skills", default="useful")
    args = p.parse_args()

    env = tasks.make(args.task, physics=args.physics)
    names = skill_library.skill_names(args.task, args.skills)
    skills = [Skill.from_fn(n, scripted.get(n)) for n in names]
    cfg, _ = resolve(TrainConfig(num_envs=args.num_envs, unroll_length=args.steps, replay_size=200_000))
    trainer = make_trainer(env, skills, cfg)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    B, T = args.num_envs, args.steps

    def bare(env_state, key):
        def body(s, k):
            a = jax.random.uniform(k, (B, env.action_size), minval=-1.0, maxval=1.0)
            return jax.vmap(env.step)(s, a), None

        return jax.lax.scan(body, env_state, jax.random.split(key, T))[0]

    t_bare, _ = timed(jax.jit(bare), state.actor.env_state, jax.random.PRNGKey(1))
    acting = jax.jit(lambda s, k: trainer.collect_insert(s, k)[0])
    t_act, state = timed(acting, state, jax.random.PRNGKey(2))

    bare_sps, act_sps = B * T / t_bare, B * T / t_act
    print(f"{args.physics} {args.task}, num_envs={B}, {len(skills)} frozen skills ({', '.join(names)}), device {jax.devices()[0]}")
    print(f"bare env step:            {bare_sps:12,.0f} env steps/s")
    print(f"acting step (+ insert):   {act_sps:12,.0f} env steps/s")
    print(f"ratio acting / bare:      {act_sps / bare_sps:.3f}")

    # Learner updates per second at the configured batch sizes (replay now holds data).
    sc, nc = cfg.scheduler, cfg.new_skill
    one = dataclasses.replace(cfg, scheduler=dataclasses.replace(sc, samples_per_insert=sc.batch_size / (B * T)),
                              new_skill=dataclasses.replace(nc, samples_per_insert=nc.batch_size / (B * T)))
    n_updates = 20
    t_learn = make_trainer(env, skills, dataclasses.replace(
        one, scheduler=dataclasses.replace(one.scheduler, samples_per_insert=n_updates * sc.batch_size / (B * T)),
        new_skill=dataclasses.replace(one.new_skill, samples_per_insert=n_updates * nc.batch_size / (B * T))))
    learn = jax.jit(lambda s, k: t_learn.learn(s, k)[:2])
    secs, _ = timed(learn, state, jax.random.PRNGKey(3))
    print(f"learner: {t_learn.scheduler_updates} scheduler (batch {sc.batch_size}, augmented x2) + "
          f"{t_learn.new_skill_updates} new-skill (batch {nc.batch_size}) updates in {secs * 1e3:.0f} ms "
          f"-> {(t_learn.scheduler_updates + t_learn.new_skill_updates) / secs:,.0f} updates/s")


if __name__ == "__main__":
    main()
