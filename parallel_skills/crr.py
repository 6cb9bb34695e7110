"""Critic Regularized Regression for the new skill (Wang et al. 2020; paper §4.2;
docs/design.md "New skill").

Policy loss −E[f(A)·log π(a|s)] with A(s, a) = Q(s, a) − mean_j Q(s, a_j), a_j ~ π(.|s),
f = min(exp(A/β), clip) ("exp") or 1[A > 0] ("indicator").
The critic Q(s, a) is learnt by TD with the new skill as target policy. ``critic_weighted_action``:
the new skill read out through its critic at evaluation (CRR's critic-weighted policy, argmax form).
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from parallel_skills import networks


def mean_baseline_advantage(q_taken: jnp.ndarray, q_sampled: jnp.ndarray) -> jnp.ndarray:
    """A(s, a) = Q(s, a) − V̂(s), V̂(s) = (1/J)·Σ_j Q(s, a_j), a_j ~ π(.|s) (CRR, Wang et al. 2020,
    Eq. 3, its mean estimator). q_taken [B], q_sampled [B, J] -> [B] (stop-gradient)."""
    return jax.lax.stop_gradient(q_taken - jnp.mean(q_sampled, axis=-1))


def crr_weights(advantage: jnp.ndarray, mode: str = "exp", beta: float = 1.0,
                clip: float = 20.0) -> jnp.ndarray:
    """CRR filter f(A) (Wang et al. 2020): "exp": min(exp(A/β), clip); "indicator": 1[A > 0].

    ``mode`` is static. [B] -> [B] float (stop-gradient)."""
    if mode == "exp":
        # exp(min(A/β, log clip)) == min(exp(A/β), clip) without overflow.
        w = jnp.exp(jnp.minimum(advantage / beta, jnp.log(clip)))
    elif mode == "indicator":
        w = (advantage > 0).astype(advantage.dtype)
    else:
        raise ValueError(f"unknown CRR mode {mode!r}")
    return jax.lax.stop_gradient(w)


def crr_policy_loss(log_prob_taken: jnp.ndarray, weights: jnp.ndarray,
                    mask: jnp.ndarray = None) -> jnp.ndarray:
    """L_π = −mean_b f(A_b)·log π(a_b|s_b) (CRR). [B], [B] (, mask [B]) -> scalar.

    With ``mask`` the mean is over masked rows: Σ m·f·log π / max(Σ m, 1)."""
    x = jax.lax.stop_gradient(weights) * log_prob_taken
    if mask is None:
        return -jnp.mean(x)
    mask = mask.astype(x.dtype)
    return -jnp.sum(mask * x) / jnp.maximum(jnp.sum(mask), 1.0)


def td_target(reward: jnp.ndarray, discount: jnp.ndarray, q_next: jnp.ndarray,
              gamma: float) -> jnp.ndarray:
    """y = r + γ·d·(1/J)·Σ_j Q'(s', a'_j), a'_j ~ π_target(.|s') (expected SARSA with the new
    skill as target policy). reward, discount [B]; q_next [B, J] (J ≥ 1) -> y [B]
    (stop-gradient). discount is 0 at termination, 1 otherwise (truncation bootstraps)."""
    return jax.lax.stop_gradient(reward + gamma * discount * jnp.mean(q_next, axis=-1))


CRITIC_WEIGHTED_CANDIDATES = 16  # the mean and 15 samples (``critic_weighted_action``)


def critic_weighted_action(mean: jnp.ndarray, std: jnp.ndarray, score: Callable, key: jax.Array,
                           num_candidates: int) -> jnp.ndarray:
    """The new skill read out through its critic: of the mean action and ``num_candidates − 1``
    actions sampled from its Gaussian (``networks.sample_action``, clipped), the one ``score``
    (min over the critics of Q(s, a)) values highest; the argmax form of CRR's critic-weighted
    policy (Wang et al. 2020, §3.3: sample from π, pick by Q). (mean [A], std [A]) -> action [A];
    ``score``: actions [M, A] -> [M]."""
    m, a = int(num_candidates), mean.shape[-1]
    sampled = networks.sample_action(jnp.broadcast_to(mean, (m - 1, a)), jnp.broadcast_to(std, (m - 1, a)), key)
    candidates = jnp.concatenate([mean[None], sampled], axis=0)  # [M, A]
    return candidates[jnp.argmax(score(candidates))]
