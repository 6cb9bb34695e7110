"""Whole-episode evaluation of a policy on a batch of environments, in one jitted ``lax.scan``.

The new skill is evaluated alone for whole episodes (paper App. C.3, Fig. "evaluation").
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp


def rollout_episodes(env, policy: Callable, key: jax.Array, num_episodes: int, episode_length: int | None = None):
    """Run ``num_episodes`` episodes in parallel (one per env) for ``episode_length`` steps.

    policy: pure ``policy(obs [O], key) -> action [A]`` for one observation.
    Returns a dict of per-episode arrays [num_episodes]: ``return`` (sum of rewards), ``success``
    (1 if the task's success test held at any step), ``final_success`` (at the last step).
    Not jitted here: wrap the call in ``jax.jit`` with static ``env``/``policy``/sizes, or use
    ``make_evaluator``.
    """
    length = int(episode_length or env.episode_length)
    k_reset, k_act = jax.random.split(key)
    state = jax.vmap(env.reset)(jax.random.split(k_reset, num_episodes))
    batched_policy = jax.vmap(policy)

    def body(carry, step_key):
        state, ret, success = carry
        action = batched_policy(state.obs, jax.random.split(step_key, num_episodes))
        state = jax.vmap(env.step)(state, action)
        ret = ret + state.reward
        success = jnp.maximum(success, state.metrics.get("success", jnp.zeros_like(state.reward)))
        return (state, ret, success), None

    zeros = jnp.zeros(num_episodes)
    (state, ret, success), _ = jax.lax.scan(body, (state, zeros, zeros), jax.random.split(k_act, length))
    return {"return": ret, "success": success,
            "final_success": state.metrics.get("success", jnp.zeros_like(state.reward))}


def make_evaluator(env, policy: Callable, num_episodes: int, episode_length: int | None = None):
    """A jitted ``evaluate(key) -> dict`` of per-episode results (see ``rollout_episodes``)."""
    return jax.jit(lambda key: rollout_episodes(env, policy, key, num_episodes, episode_length))
