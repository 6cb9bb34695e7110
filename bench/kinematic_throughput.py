"""Kinematic blocks throughput: env steps/s of `jit(vmap(step))` inside `lax.scan`, and its ratio
to a bare pure-JAX point-mass step at the same batch, measured in the same run.

    python bench/kinematic_throughput.py --task stack --num_envs 4096 --steps 200
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

import tasks


def point_mass_step(pos_vel, action):
    """The bare reference: a 3-D point mass, velocity control, 20 Hz."""
    pos, vel = pos_vel
    vel = jnp.clip(action[:3], -1.0, 1.0) * 0.05
    pos = jnp.clip(pos + vel * 0.05, -0.1, 0.3)
    return (pos, vel)


def measure(step_fn, state, num_envs, steps, action_size, repeats=3):
    """Best-of-``repeats`` env steps/s of ``jit(vmap(step_fn))`` scanned over ``steps`` steps.
    Actions are drawn once beforehand (uniform in [-1, 1]) so that random-number generation is
    not counted as environment time."""
    actions = jax.random.uniform(jax.random.PRNGKey(0), (steps, num_envs, action_size), minval=-1.0, maxval=1.0)

    def run(state, actions):
        def body(s, a):
            return jax.vmap(step_fn)(s, a), None

        return jax.lax.scan(body, state, actions)[0]

    run = jax.jit(run, donate_argnums=0)
    t0 = time.perf_counter()
    state = jax.block_until_ready(run(state, actions))
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for r in range(repeats):
        t0 = time.perf_counter()
        state = jax.block_until_ready(run(state, actions))
        best = min(best, time.perf_counter() - t0)
    return num_envs * steps / best, compile_s


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="stack")
    p.add_argument("--num_envs", type=int, default=4096)
    p.add_argument("--steps", type=int, default=200)
    args = p.parse_args()

    env = tasks.make(args.task, physics="kinematic")
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), args.num_envs))
    env_sps, env_compile = measure(env.step, state, args.num_envs, args.steps, env.action_size)

    pm_state = (jnp.zeros((args.num_envs, 3)), jnp.zeros((args.num_envs, 3)))
    pm_sps, _ = measure(point_mass_step, pm_state, args.num_envs, args.steps, env.action_size)

    print(f"devices: {jax.devices()}  num_envs={args.num_envs} steps/iter={args.steps}")
    print(f"kinematic {args.task}: {env_sps:,.0f} env steps/s (compile {env_compile:.1f} s)")
    print(f"point-mass reference: {pm_sps:,.0f} env steps/s")
    print(f"ratio kinematic/point-mass: {env_sps / pm_sps:.3f}")


if __name__ == "__main__":
    main()
