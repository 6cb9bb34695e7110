"""Hierarchical Categorical MPO losses (paper §4.3 Eq. 3-4; docs/design.md "HCMPO").

Joint scheduler actions z = (i, k) are enumerated exactly (P = (N+1)·M pairs, order of
``networks.all_pairs``), so all expectations are sums, not samples.

Positivity of the duals (as Acme): η = softplus(log_η) + 1e-8, α = softplus(log_α) + 1e-8
(``positive``). All functions take the *positive* η / α values.

Masks: ``mask [B]`` are float weights (0/1); every mean is Σ mask·x / max(Σ mask, 1) and the
dual terms are multiplied by 1[Σ mask > 0], so a batch with no decision rows gives exactly 0
loss and 0 gradients (never NaN).
"""

from __future__ import annotations

from typing import Tuple

import jax
import jax.numpy as jnp

_MPO_FLOAT_EPSILON = 1e-8


def positive(log_param: jnp.ndarray) -> jnp.ndarray:
    """Dual variable from its unconstrained parameter: softplus(x) + 1e-8 (Acme)."""
    return jax.nn.softplus(log_param) + _MPO_FLOAT_EPSILON


def masked_mean(x: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    """Σ mask·x / max(Σ mask, 1) over all axes. x, mask: [B] -> scalar."""
    mask = mask.astype(x.dtype)
    return jnp.sum(mask * x) / jnp.maximum(jnp.sum(mask), 1.0)


def critic_target(
    reward: jnp.ndarray,
    discount: jnp.ndarray,
    c: jnp.ndarray,
    q_next_continue: jnp.ndarray,
    q_next_fresh: jnp.ndarray,
    probs_next: jnp.ndarray,
    gamma: float,
) -> jnp.ndarray:
    """HCMPO policy-evaluation target (paper Eq. 3, with App. A.1 Eq. 5).

        y = r + γ·d·( Σ_p π(z_p|s')·Q'(s', c=k_p, i_p, k_p)   if c == 1
                    ( Q'(s', c − 1, i, k)                       otherwise

    (c is the counter of the *stored* step; c == 1 means s' is a decision state. The
    learner passes the target policy's probabilities as ``probs_next``.)

    Args:
      reward, discount: [B] (discount 0 at termination, 1 otherwise incl. time-limit truncation).
      c: [B] int counter of step t.
      q_next_continue: [B] Q'(s', c − 1, i, k).
      q_next_fresh: [B, P] Q'(s', c=k_p, i_p, k_p).
      probs_next: [B, P] π_S(i_p, k_p | s'), rows sum to 1.
      gamma: discount factor.

    Returns:
      y [B], with stop-gradient applied.
    """
    v_fresh = jnp.sum(probs_next * q_next_fresh, axis=-1)
    v_next = jnp.where(c == 1, v_fresh, q_next_continue)
    return jax.lax.stop_gradient(reward + gamma * discount * v_next)


def e_step_weights(q: jnp.ndarray, log_prior: jnp.ndarray, temperature: jnp.ndarray) -> jnp.ndarray:
    """Non-parametric E-step policy (paper Eq. 4; categorical MPO):

        q(z|s) = π_old(z|s)·exp(Q(s, c=k, z)/η) / Σ_z' π_old(z'|s)·exp(Q(s, c=k', z')/η).

    Args:
      q: [B, P] Q values of all pairs ("fresh decision", c = k).
      log_prior: [B, P] log π_old(z|s).
      temperature: scalar η > 0.

    Returns:
      weights [B, P] (stop-gradient), rows sum to 1.
    """
    logits = jax.lax.stop_gradient(q) / jax.lax.stop_gradient(temperature) + jax.lax.stop_gradient(log_prior)
    return jax.lax.stop_gradient(jax.nn.softmax(logits, axis=-1))


def temperature_dual_loss(
    temperature: jnp.ndarray,
    q: jnp.ndarray,
    log_prior: jnp.ndarray,
    epsilon: float,
    mask: jnp.ndarray,
) -> jnp.ndarray:
    """E-step temperature dual (categorical MPO):

        g(η) = η·ε + η·mean_{s: mask} log Σ_z π_old(z|s)·exp(Q(s, z)/η)

    computed with logsumexp. Gradients flow only into η.

    Args:
      temperature: scalar η > 0 (differentiable).
      q: [B, P]; log_prior: [B, P]; epsilon: KL bound ε; mask: [B] weights (decision rows).

    Returns:
      scalar (0 when Σ mask == 0).
    """
    q = jax.lax.stop_gradient(q)
    log_prior = jax.lax.stop_gradient(log_prior)
    lse = jax.scipy.special.logsumexp(q / temperature + log_prior, axis=-1)  # [B]
    has_rows = (jnp.sum(mask) > 0).astype(q.dtype)
    return has_rows * temperature * (epsilon + masked_mean(lse, mask))


def categorical_kl(log_p: jnp.ndarray, log_q: jnp.ndarray) -> jnp.ndarray:
    """KL(p ‖ q) = Σ_z p(z)(log p(z) − log q(z)). [B, P] x2 -> [B]."""
    return jnp.sum(jnp.exp(log_p) * (log_p - log_q), axis=-1)


def m_step_loss(
    log_probs_online: jnp.ndarray,
    weights: jnp.ndarray,
    log_prior: jnp.ndarray,
    alpha: jnp.ndarray,
    epsilon_kl: float,
    mask: jnp.ndarray,
) -> Tuple[jnp.ndarray, jnp.ndarray]:
    """M-step: weighted maximum likelihood with a KL trust region (paper Eq. 4; Acme
    ``CategoricalMPO``):

        L = mean_s[ −Σ_z q(z|s)·log π(z|s) ] + sg(α)·KL̄ + α·(ε_kl − sg(KL̄)),
        KL̄ = mean_s KL(π_old(.|s) ‖ π(.|s)),

    means over masked (decision) rows only. The policy sees the cross-entropy and sg(α)·KL̄;
    α sees only its dual term.

    Args:
      log_probs_online: [B, P] log π(z|s) (online policy; differentiable).
      weights: [B, P] E-step weights q(z|s).
      log_prior: [B, P] log π_old(z|s) (target policy).
      alpha: scalar α > 0 (differentiable).
      epsilon_kl: KL bound.
      mask: [B] weights.

    Returns:
      (loss scalar, KL̄ scalar). Both 0 when Σ mask == 0.
    """
    cross_entropy = -jnp.sum(jax.lax.stop_gradient(weights) * log_probs_online, axis=-1)  # [B]
    kl = categorical_kl(jax.lax.stop_gradient(log_prior), log_probs_online)  # [B]
    mean_ce = masked_mean(cross_entropy, mask)
    mean_kl = masked_mean(kl, mask)
    has_rows = (jnp.sum(mask) > 0).astype(log_probs_online.dtype)
    loss_kl = jax.lax.stop_gradient(alpha) * mean_kl
    loss_alpha = has_rows * alpha * (epsilon_kl - jax.lax.stop_gradient(mean_kl))
    return mean_ce + loss_kl + loss_alpha, mean_kl
