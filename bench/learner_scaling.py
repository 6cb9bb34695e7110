"""Learner cost against batch size: one update of each learner (HCMPO scheduler, CRR new skill) at
batch 256 … 32,768 on this machine, with its time, samples/s and achieved GFLOP/s, next to a large
matrix product's GFLOP/s measured in the same run (how close the learners come to the machine's
limit). FLOPs are XLA's own count of the compiled update (``cost_analysis``).

    python bench/learner_scaling.py                           # kinematic lift sizes, useful skills
    python bench/learner_scaling.py --batches 256,4096 --task stack --skills useful+distractors

The scheduler's batch is augmented (paper §4.4): an update of batch b learns from 2·b labelled rows
of b states (the networks run once per state); "samples/s" counts the b sampled rows, as
samples-per-insert does.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

import tasks
from parallel_skills import learners
from parallel_skills.config import NewSkillConfig, SchedulerConfig
from parallel_skills.replay import Transition
from training import skill_library


def compiled_flops(compiled) -> float:
    """XLA's FLOP count of a compiled function (``cost_analysis``; a loop's body is counted once)."""
    cost = compiled.cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return float(cost.get("flops", float("nan")))


def measure(fn, args, min_time: float):
    """(seconds per call, FLOPs per call) of ``fn`` jitted: compiled once, then repeated for at least
    ``min_time`` seconds (3 calls at least); the best of three such rounds."""
    compiled = jax.jit(fn).lower(*args).compile()
    jax.block_until_ready(compiled(*args))
    best = float("inf")
    for _ in range(3):
        n, t0 = 0, time.perf_counter()
        while n < 3 or time.perf_counter() - t0 < min_time:
            jax.block_until_ready(compiled(*args))
            n += 1
        best = min(best, (time.perf_counter() - t0) / n)
    return best, compiled_flops(compiled)


def random_batch(key, b: int, obs_size: int, action_size: int, num_skills: int, lengths) -> Transition:
    ks = jax.random.split(key, 7)
    k_idx = jax.random.randint(ks[0], (b,), 0, len(lengths))
    c = jnp.minimum(jax.random.randint(ks[1], (b,), 1, max(lengths) + 1), jnp.asarray(lengths)[k_idx])
    return Transition.batch(
        obs=jax.random.normal(ks[2], (b, obs_size)), next_obs=jax.random.normal(ks[3], (b, obs_size)),
        action=jnp.clip(jax.random.normal(ks[4], (b, action_size)), -1, 1),
        reward=(jax.random.uniform(ks[5], (b,)) < 0.1).astype(jnp.float32), discount=jnp.ones(b),
        skill=jax.random.randint(ks[6], (b,), 0, num_skills), k_idx=k_idx.astype(jnp.int32), c=c.astype(jnp.int32),
        is_decision=c == jnp.asarray(lengths)[k_idx])


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="lift")
    p.add_argument("--skills", default="useful", help="skill set (its size sets the scheduler's action space)")
    p.add_argument("--batches", default="256,1024,4096,16384,32768")
    p.add_argument("--matmul", type=int, default=2048, help="size n of the reference n x n matrix product")
    p.add_argument("--min_time", type=float, default=0.5, help="seconds of repeated calls per measurement")
    args = p.parse_args()
    env = tasks.make(args.task)
    obs_size, action_size = int(env.observation_size), int(env.action_size)
    num_skills = len(skill_library.skill_names(args.task, args.skills)) + 1
    sc, nc = SchedulerConfig(), NewSkillConfig()
    key = jax.random.PRNGKey(0)

    n = args.matmul
    a = jax.random.normal(key, (n, n))
    t_mm, f_mm = measure(lambda x, y: x @ y, (a, a), args.min_time)
    peak = f_mm / t_mm / 1e9
    print(f"backend {jax.default_backend()}, {jax.device_count()} device(s); task {args.task}: obs {obs_size}, "
          f"action {action_size}, {num_skills} scheduler choices x {sc.num_lengths} lengths")
    print(f"reference: {n}x{n} float32 matmul {t_mm * 1e3:.2f} ms = {peak:.1f} GFLOP/s")
    print(f"{'learner':<10} {'batch':>7} {'ms/update':>10} {'samples/s':>11} {'GFLOP/update':>13} "
          f"{'GFLOP/s':>8} {'of matmul':>9}")

    sched_state = learners.scheduler_learner_init(key, obs_size, num_skills, sc)
    new_state = learners.new_skill_learner_init(key, obs_size, action_size, nc)
    for b in (int(x) for x in args.batches.split(",")):
        batch = random_batch(jax.random.fold_in(key, b), b, obs_size, action_size, num_skills, sc.skill_lengths)
        cases = (
            ("scheduler", lambda s, bt, k: learners.scheduler_learner_update(s, bt, k, sc), sched_state),
            ("new_skill", lambda s, bt, k: learners.new_skill_learner_update(s, bt, k, nc), new_state),
        )
        for name, fn, state in cases:
            t, flops = measure(fn, (state, batch, key), args.min_time)
            gflops = flops / t / 1e9
            print(f"{name:<10} {b:>7} {t * 1e3:>10.2f} {b / t:>11,.0f} {flops / 1e9:>13.3f} {gflops:>8.1f} "
                  f"{gflops / peak:>9.2f}", flush=True)


if __name__ == "__main__":
    main()
