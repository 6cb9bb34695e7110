"""Datasets of a scripted controller executed with Gaussian action noise (for the experiments)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def collect_noisy_expert(env, controller, num_envs: int, steps: int, noise: float, key: jax.Array) -> dict:
    """Run ``controller(obs, key) -> action`` on ``num_envs`` envs for ``steps`` steps, executing
    clip(action + N(0, noise²), −1, 1). Returns flat arrays [num_envs·steps, ...]: ``obs``,
    ``clean_action`` (the controller's), ``action`` (executed), ``reward``, ``discount`` (ones),
    ``next_obs``. Pure; wrap in ``jax.jit`` with static sizes."""
    ctl = jax.vmap(controller)
    k0, k1 = jax.random.split(key)
    s = jax.vmap(env.reset)(jax.random.split(k0, num_envs))

    def body(s, k):
        a0 = ctl(s.obs, None)
        a = jnp.clip(a0 + noise * jax.random.normal(k, a0.shape), -1, 1)
        n = jax.vmap(env.step)(s, a)
        return n, dict(obs=s.obs, clean_action=a0, action=a, reward=n.reward, discount=jnp.ones(num_envs),
                       next_obs=n.obs)

    _, d = jax.lax.scan(body, s, jax.random.split(k1, steps))
    return jax.tree.map(lambda x: x.reshape((num_envs * steps,) + x.shape[2:]), d)
