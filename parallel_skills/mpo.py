"""Decoupled Gaussian MPO policy loss (Abdolmaleki et al. 2018; Acme's ``MPO`` loss), used
for the new skill only when ``NewSkillConfig.mpo_alpha < 1`` (paper App. B: loss =
α·CRR + (1 − α)·MPO).

Conventions: sampled actions a_j ~ π_old(.|s) with π_old the *target* policy, arrays
[B, J, A] / [B, J]; duals are positive values (``hcmpo.positive``); ``mask [B]`` weights.
The KL constraints are on the sum over action dimensions (one α for the mean, one for the
std; Acme's ``per_dim_constraining=False``).
"""

from __future__ import annotations

import math
from typing import Dict, Tuple

import jax
import jax.numpy as jnp

from parallel_skills.hcmpo import e_step_weights, masked_mean, temperature_dual_loss
from parallel_skills.networks import gaussian_log_prob


def sample_e_step(q: jnp.ndarray, temperature: jnp.ndarray, epsilon: float,
                  mask: jnp.ndarray) -> Tuple[jnp.ndarray, jnp.ndarray]:
    """Sample-based E-step (MPO Eq. 7-8): for a_j ~ π_old, q(a_j|s) ∝ exp(Q(s, a_j)/η), and the
    dual g(η) = η·ε + η·mean_s log (1/J)·Σ_j exp(Q(s, a_j)/η).

    q [B, J]; temperature scalar; mask [B] -> (weights [B, J] stop-grad, dual loss scalar)."""
    j = q.shape[-1]
    log_prior = jnp.full(q.shape, -math.log(j), q.dtype)
    weights = e_step_weights(q, log_prior, temperature)
    return weights, temperature_dual_loss(temperature, q, log_prior, epsilon, mask)


def gaussian_kl_mean(target_mean, target_std, online_mean) -> jnp.ndarray:
    """KL(N(μ_t, σ_t) ‖ N(μ_o, σ_t)) = Σ_d (μ_t − μ_o)²/(2σ_t²). [B, A] -> [B]."""
    return jnp.sum(0.5 * jnp.square((target_mean - online_mean) / target_std), axis=-1)


def gaussian_kl_std(target_std, online_std) -> jnp.ndarray:
    """KL(N(μ, σ_t) ‖ N(μ, σ_o)) = Σ_d log(σ_o/σ_t) + σ_t²/(2σ_o²) − 1/2. [B, A] -> [B]."""
    r = jnp.square(target_std / online_std)
    return jnp.sum(0.5 * (r - 1.0 - jnp.log(r)), axis=-1)


def gaussian_mpo_loss(
    online_mean: jnp.ndarray, online_std: jnp.ndarray,
    target_mean: jnp.ndarray, target_std: jnp.ndarray,
    actions: jnp.ndarray, q: jnp.ndarray,
    temperature: jnp.ndarray, alpha_mean: jnp.ndarray, alpha_std: jnp.ndarray,
    epsilon: float, epsilon_mean: float, epsilon_std: float,
    mask: jnp.ndarray,
) -> Tuple[jnp.ndarray, Dict[str, jnp.ndarray]]:
    """Decoupled MPO loss (Abdolmaleki et al. 2018, Eq. 7-10; Acme ``MPO``):

      E-step:  w_bj = softmax_j(Q(s_b, a_bj)/η), dual g(η).
      M-step:  L_μ = −mean_b Σ_j w_bj log N(a_bj; μ_o, σ_t),  L_σ = −mean_b Σ_j w_bj log N(a_bj; μ_t, σ_o),
               + sg(α_μ)·KL̄_μ + α_μ(ε_μ − sg KL̄_μ) + sg(α_σ)·KL̄_σ + α_σ(ε_σ − sg KL̄_σ).

    Args:
      online_mean/std: [B, A] (differentiable); target_mean/std: [B, A] (π_old).
      actions: [B, J, A] samples of π_old; q: [B, J] Q(s, a_j).
      temperature, alpha_mean, alpha_std: positive scalars (differentiable).
      mask: [B] row weights.

    Returns:
      (loss scalar incl. all dual terms, stats dict of scalars).
    """
    target_mean = jax.lax.stop_gradient(target_mean)
    target_std = jax.lax.stop_gradient(target_std)
    actions = jax.lax.stop_gradient(actions)
    weights, loss_temperature = sample_e_step(q, temperature, epsilon, mask)
    lp_fixed_std = gaussian_log_prob(online_mean[:, None], target_std[:, None], actions)  # [B, J]
    lp_fixed_mean = gaussian_log_prob(target_mean[:, None], online_std[:, None], actions)
    loss_mean = masked_mean(-jnp.sum(weights * lp_fixed_std, axis=-1), mask)
    loss_std = masked_mean(-jnp.sum(weights * lp_fixed_mean, axis=-1), mask)
    kl_mean = masked_mean(gaussian_kl_mean(target_mean, target_std, online_mean), mask)
    kl_std = masked_mean(gaussian_kl_std(target_std, online_std), mask)
    has_rows = (jnp.sum(mask) > 0).astype(q.dtype)
    sg = jax.lax.stop_gradient
    loss_kl = sg(alpha_mean) * kl_mean + sg(alpha_std) * kl_std
    loss_alpha = has_rows * (alpha_mean * (epsilon_mean - sg(kl_mean))
                             + alpha_std * (epsilon_std - sg(kl_std)))
    loss = loss_mean + loss_std + loss_kl + loss_alpha + loss_temperature
    stats = dict(mpo_loss_mean=loss_mean, mpo_loss_std=loss_std, mpo_kl_mean=kl_mean,
                 mpo_kl_std=kl_std, mpo_temperature=temperature)
    return loss, stats
