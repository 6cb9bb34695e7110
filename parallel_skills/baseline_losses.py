"""Policy losses of the skill-reuse baselines (paper App. B): DAGGER, KL-regularisation to the
skill mixture ("KL-reg. to Mixture") and RHPO with frozen skills.

Each baseline trains a policy for the new task against a critic Q(s, a) (a diagonal Gaussian
π(a|s) = N(μ(s), σ(s)²); for RHPO a mixture with one trainable Gaussian component) and the
learner mixes its policy loss with CRR: L = α·L_CRR + (1 − α)·L_baseline (App. B).

Skill-mixture prior. The frozen skills are deterministic maps s ↦ μ_i(s) ∈ [−1, 1]^A (mostly
scripted, so without a density). The prior / teacher of the baselines is the uniform mixture of
Gaussians around the skills' actions with the collection noise std σ₀ (``skill_noise_std``):

    π₀(a|s) = (1/N)·Σ_i N(a; μ_i(s), σ₀²·I)        (App. B, "KL-Regularisation", π_i = N(μ_i, σ₀²)).

The collected actions are clipped to [−1, 1], but the clipping is ignored here: π₀ is the
density of the unclipped mixture and ``sample_mixture`` does not clip.

Conventions as in ``mpo`` / ``hcmpo``: a batch of B states, J sampled actions per state
([B, J, A] / [B, J]); duals are positive values (``hcmpo.positive``); ``mask [B]`` are float row
weights, means are Σ m·x / max(Σ m, 1) and dual terms are multiplied by 1[Σ m > 0].
"""

from __future__ import annotations

import math
from typing import Dict, Tuple

import jax
import jax.numpy as jnp

from parallel_skills.hcmpo import categorical_kl as _kl_from_log_probs
from parallel_skills.hcmpo import e_step_weights, masked_mean, temperature_dual_loss
from parallel_skills.mpo import gaussian_kl_mean, gaussian_kl_std, sample_e_step
from parallel_skills.networks import gaussian_log_prob


# --------------------------------------------------------------------------- Gaussian mixtures

def _component_log_probs(means: jnp.ndarray, stds: jnp.ndarray, action: jnp.ndarray) -> jnp.ndarray:
    """log N(a; μ_c, σ_c²) of every component c.

    means [B, C, A]; stds broadcastable to means; action [B, A] or [B, J, A] -> [B, C] or [B, J, C].
    """
    stds = jnp.broadcast_to(stds, means.shape)
    if action.ndim == means.ndim:  # [B, J, A]: every sample against every component.
        means, stds = means[:, None], stds[:, None]
    elif action.ndim != means.ndim - 1:
        raise ValueError(f"action must be [B, A] or [B, J, A], got shape {action.shape}")
    return gaussian_log_prob(means, stds, action[..., None, :])


def _sample_components(means: jnp.ndarray, stds: jnp.ndarray, component: jnp.ndarray,
                       key: jax.Array) -> jnp.ndarray:
    """a = μ_c + σ_c·ε, ε ~ N(0, I), for component indices c [B, J]. means, stds [B, C, A] -> [B, J, A]."""
    mean = jnp.take_along_axis(means, component[..., None], axis=1)
    std = jnp.take_along_axis(stds, component[..., None], axis=1)
    return mean + std * jax.random.normal(key, mean.shape, mean.dtype)


def mixture_log_prob(means: jnp.ndarray, std, action: jnp.ndarray) -> jnp.ndarray:
    """log π₀(a|s) = logsumexp_i log N(a; μ_i(s), σ₀²·I) − log N (the skill-mixture prior).

    Density of the unclipped mixture (action clipping ignored).

    Args:
      means: [B, N, A] the skills' actions μ_i(s).
      std: scalar σ₀ (the collection noise std).
      action: [B, A] or [B, J, A].

    Returns:
      [B] or [B, J].
    """
    log_probs = _component_log_probs(means, std, action)
    return jax.scipy.special.logsumexp(log_probs, axis=-1) - math.log(means.shape[-2])


def sample_mixture(means: jnp.ndarray, std, key: jax.Array, num_samples: int) -> jnp.ndarray:
    """Samples of π₀: a skill i uniformly at random, then a = μ_i(s) + σ₀·ε, ε ~ N(0, I).

    Not clipped to [−1, 1] (consistent with ``mixture_log_prob``).

    Args:
      means: [B, N, A]; std: scalar σ₀; key: PRNG key; num_samples: J (static).

    Returns:
      [B, J, A].
    """
    k_component, k_noise = jax.random.split(key)
    batch, num_skills = means.shape[:2]
    component = jax.random.randint(k_component, (batch, num_samples), 0, num_skills)
    return _sample_components(means, jnp.broadcast_to(std, means.shape), component, k_noise)


# --------------------------------------------------------------------------- DAGGER

def dagger_cross_entropy(mean: jnp.ndarray, std: jnp.ndarray, teacher_means: jnp.ndarray, teacher_std,
                         mask: jnp.ndarray) -> jnp.ndarray:
    """DAGGER loss (Ross et al. 2011; paper App. B "DAGGER"): cross-entropy from the teacher π₀
    to the student π on the student's states s_b,

        L = mean_{b: mask} −E_{a~π₀(.|s_b)} log N(a; μ_b, σ_b²)
          = mean_{b: mask} (1/N)·Σ_i Σ_d [½·log(2π σ_d²) + ((μ_{i,d} − μ_d)² + σ₀²)/(2σ_d²)],

    in closed form (E_{a~N(μ_i, σ₀²)} (a − μ)² = (μ_i − μ)² + σ₀²), so no samples are needed.
    Differentiable in (mean, std); the teacher is stop-gradient.

    Args:
      mean, std: [B, A] the student π(.|s).
      teacher_means: [B, N, A] the skills' actions μ_i(s); teacher_std: scalar σ₀.
      mask: [B] row weights.

    Returns:
      scalar (0 when Σ mask == 0).
    """
    teacher_means = jax.lax.stop_gradient(teacher_means)
    teacher_var = jnp.square(jax.lax.stop_gradient(teacher_std))
    sq_dist = jnp.mean(jnp.square(teacher_means - mean[:, None]), axis=1)  # [B, A], mean over skills
    var = jnp.square(std)
    cross_entropy = jnp.sum(0.5 * jnp.log(2.0 * math.pi * var) + (sq_dist + teacher_var) / (2.0 * var),
                            axis=-1)
    return masked_mean(cross_entropy, mask)


# --------------------------------------------------------------------------- KL-reg to the mixture

def prior_e_step(q: jnp.ndarray, log_prior: jnp.ndarray, log_proposal: jnp.ndarray, temperature: jnp.ndarray,
                 epsilon: float, mask: jnp.ndarray) -> Tuple[jnp.ndarray, jnp.ndarray]:
    """E-step of MPO regularised to the prior π₀ (paper App. B "KL-Regularisation"):

        q(a|s) ∝ π₀(a|s)·exp(Q(s, a)/η),   mean_s KL(q(.|s) ‖ π₀(.|s)) ≤ ε,

    on J actions a_j ~ ρ(.|s) of a proposal ρ (π₀ itself, or e.g. the mixture ½π₀ + ½π_old, whose
    log-density the caller computes), with self-normalised importance weights standing in for π₀
    over the samples:

        log w̃_j = log_softmax_j(log π₀(a_j|s) − log ρ(a_j|s)),
        q_j     = softmax_j(log w̃_j + Q(s, a_j)/η),
        g(η)    = η·ε + η·mean_{s: mask} log Σ_j w̃_j·exp(Q(s, a_j)/η).

    This is the categorical E-step over the J samples with log w̃ as the prior
    (``hcmpo.e_step_weights`` / ``hcmpo.temperature_dual_loss``); with ρ = π₀, w̃_j = 1/J and it
    is ``mpo.sample_e_step``.

    Args:
      q: [B, J] Q(s, a_j).
      log_prior: [B, J] log π₀(a_j|s) (``mixture_log_prob``).
      log_proposal: [B, J] log ρ(a_j|s).
      temperature: scalar η > 0 (differentiable, through the dual only).
      epsilon: KL bound ε.
      mask: [B] row weights.

    Returns:
      (weights [B, J] stop-gradient, rows sum to 1; temperature dual loss scalar, 0 when Σ mask == 0).
    """
    log_weights = jax.nn.log_softmax(jax.lax.stop_gradient(log_prior - log_proposal), axis=-1)
    weights = e_step_weights(q, log_weights, temperature)
    return weights, temperature_dual_loss(temperature, q, log_weights, epsilon, mask)


def kl_reg_mpo_loss(online_mean: jnp.ndarray, online_std: jnp.ndarray, actions: jnp.ndarray,
                    weights: jnp.ndarray, mask: jnp.ndarray) -> Tuple[jnp.ndarray, Dict[str, jnp.ndarray]]:
    """M-step of KL-reg to the mixture: weighted maximum likelihood of π to the E-step's q,

        L = −mean_{b: mask} Σ_j q_bj·log N(a_bj; μ(s_b), σ(s_b)²).

    No trust region to π_old: the prior regularises instead, through the E-step bound
    KL(q ‖ π₀) ≤ ε. The temperature dual is returned by ``prior_e_step``, not included here.

    Args:
      online_mean, online_std: [B, A] (differentiable).
      actions: [B, J, A] the E-step's samples; weights: [B, J] the E-step's q (``prior_e_step``).
      mask: [B] row weights.

    Returns:
      (loss scalar, stats: ``kl_reg_loss`` and ``kl_reg_ess``, the weights' effective sample
      size 1/Σ_j q_bj² averaged over rows, in samples).
    """
    weights = jax.lax.stop_gradient(weights)
    log_probs = gaussian_log_prob(online_mean[:, None], online_std[:, None], jax.lax.stop_gradient(actions))
    loss = masked_mean(-jnp.sum(weights * log_probs, axis=-1), mask)
    ess = masked_mean(1.0 / jnp.sum(jnp.square(weights), axis=-1), mask)
    return loss, dict(kl_reg_loss=loss, kl_reg_ess=ess)


# --------------------------------------------------------------------------- RHPO

def rhpo_log_prob(logits: jnp.ndarray, means: jnp.ndarray, stds: jnp.ndarray,
                  action: jnp.ndarray) -> jnp.ndarray:
    """log π(a|s) = logsumexp_c [log softmax(logits)_c + log N(a; μ_c, σ_c²)] (RHPO mixture).

    Args:
      logits: [B, C]; means, stds: [B, C, A]; action: [B, A] or [B, J, A].

    Returns:
      [B] or [B, J].
    """
    log_mix = jax.nn.log_softmax(logits, axis=-1)
    if action.ndim == means.ndim:
        log_mix = log_mix[:, None]
    return jax.scipy.special.logsumexp(log_mix + _component_log_probs(means, stds, action), axis=-1)


def sample_rhpo(logits: jnp.ndarray, means: jnp.ndarray, stds: jnp.ndarray, key: jax.Array,
                num_samples: int) -> jnp.ndarray:
    """Samples of the RHPO mixture: c ~ softmax(logits), then a = μ_c + σ_c·ε (not clipped).

    Args:
      logits: [B, C]; means, stds: [B, C, A]; key: PRNG key; num_samples: J (static).

    Returns:
      [B, J, A].
    """
    k_component, k_noise = jax.random.split(key)
    shape = (logits.shape[0], num_samples)
    component = jax.random.categorical(k_component, logits[:, None, :], axis=-1, shape=shape)
    return _sample_components(means, stds, component, k_noise)


def rhpo_components(frozen_means: jnp.ndarray, frozen_std, mean: jnp.ndarray,
                    std: jnp.ndarray) -> Tuple[jnp.ndarray, jnp.ndarray]:
    """Components of the RHPO policy with frozen skills: N(μ_i(s), σ₀²) for the N skills
    (indices 0..N−1) and the trainable N(μ(s), σ(s)²) last (index N).

    frozen_means [B, N, A], frozen_std scalar σ₀, mean / std [B, A] -> (means, stds) [B, N+1, A].
    """
    frozen_stds = jnp.broadcast_to(jnp.asarray(frozen_std, std.dtype), frozen_means.shape)
    means = jnp.concatenate([frozen_means, mean[:, None]], axis=1)
    stds = jnp.concatenate([frozen_stds, std[:, None]], axis=1)
    return means, stds


def categorical_kl(logits_old: jnp.ndarray, logits: jnp.ndarray) -> jnp.ndarray:
    """KL(π_old ‖ π) = Σ_c π_old(c)·(log π_old(c) − log π(c)) of softmax distributions. [B, C] x2 -> [B]."""
    return _kl_from_log_probs(jax.nn.log_softmax(logits_old, axis=-1), jax.nn.log_softmax(logits, axis=-1))


def _trust_region_loss(alpha: jnp.ndarray, kl: jnp.ndarray, epsilon: float,
                       has_rows: jnp.ndarray) -> jnp.ndarray:
    """sg(α)·KL̄ + 1[rows]·α·(ε − sg(KL̄)) (Acme MPO): the policy sees the penalty, α its dual."""
    sg = jax.lax.stop_gradient
    return sg(alpha) * kl + has_rows * alpha * (epsilon - sg(kl))


def rhpo_mpo_loss(
    online_logits: jnp.ndarray, online_mean: jnp.ndarray, online_std: jnp.ndarray,
    target_logits: jnp.ndarray, target_mean: jnp.ndarray, target_std: jnp.ndarray,
    frozen_means: jnp.ndarray, frozen_std,
    actions: jnp.ndarray, q: jnp.ndarray,
    temperature: jnp.ndarray, alpha_cat: jnp.ndarray, alpha_mean: jnp.ndarray, alpha_std: jnp.ndarray,
    epsilon: float, epsilon_cat: float, epsilon_mean: float, epsilon_std: float,
    mask: jnp.ndarray,
) -> Tuple[jnp.ndarray, Dict[str, jnp.ndarray]]:
    """RHPO loss with frozen skills (Wulfmeier et al. 2020; paper App. B "Fine-tuning and RHPO",
    freeze variant). The policy is the mixture (``rhpo_components``)

        π(a|s) = Σ_{c=0}^{N} softmax(logits(s))_c·N(a; μ_c(s), σ_c(s)²),

    components 0..N−1 the frozen skills N(μ_i(s), σ₀²), component N the trainable N(μ(s), σ(s)²);
    the categorical picks a component at every step. Subscripts o / t: online / target (π_old).

      E-step: w_bj = softmax_j(Q(s_b, a_bj)/η), a_bj ~ π_old (``mpo.sample_e_step``), dual g(η).
      M-step: weighted maximum likelihood of the mixture, decoupled as Acme's Gaussian MPO: each
      parameter group is fitted with the other groups at their target values,
        L_cat = −mean_b Σ_j w_bj·log π(a_bj; logits_o, μ_t, σ_t),
        L_μ   = −mean_b Σ_j w_bj·log π(a_bj; logits_t, μ_o, σ_t),
        L_σ   = −mean_b Σ_j w_bj·log π(a_bj; logits_t, μ_t, σ_o),
      with one trust region per group (RHPO bounds the categorical and the components separately;
      frozen components have no parameters, so only the trainable one is constrained, unweighted
      by its probability):
        KL̄_cat = mean_b KL(π_t(c|s) ‖ π_o(c|s)),
        KL̄_μ   = mean_b KL(N(μ_t, σ_t) ‖ N(μ_o, σ_t)),  KL̄_σ = mean_b KL(N(μ_t, σ_t) ‖ N(μ_t, σ_o)),
      each added as sg(α)·KL̄ + α·(ε − sg(KL̄)) (as ``mpo.gaussian_mpo_loss``).

      L = L_cat + L_μ + L_σ + Σ_{cat, μ, σ} [sg(α)·KL̄ + α·(ε − sg(KL̄))] + g(η).

    Means are over masked rows. Gradients reach the online logits / mean / std and the duals only;
    the target policy, the frozen skills and the actions are stop-gradient.

    Args:
      online_logits: [B, N+1]; online_mean, online_std: [B, A] (differentiable).
      target_logits: [B, N+1]; target_mean, target_std: [B, A] (π_old).
      frozen_means: [B, N, A] the skills' actions; frozen_std: scalar σ₀.
      actions: [B, J, A] samples of π_old (``sample_rhpo``); q: [B, J] Q(s, a_j).
      temperature, alpha_cat, alpha_mean, alpha_std: positive scalars (differentiable).
      epsilon: E-step KL bound; epsilon_cat, epsilon_mean, epsilon_std: M-step KL bounds.
      mask: [B] row weights.

    Returns:
      (loss scalar incl. all dual terms, stats dict of scalars).
    """
    sg = jax.lax.stop_gradient
    target_logits, target_mean, target_std = sg(target_logits), sg(target_mean), sg(target_std)
    frozen_means, actions = sg(frozen_means), sg(actions)
    weights, loss_temperature = sample_e_step(q, temperature, epsilon, mask)

    def fit(logits, mean, std):  # −mean_b Σ_j w_bj·log π(a_bj|s_b)
        means, stds = rhpo_components(frozen_means, frozen_std, mean, std)
        return masked_mean(-jnp.sum(weights * rhpo_log_prob(logits, means, stds, actions), axis=-1), mask)

    loss_cat = fit(online_logits, target_mean, target_std)
    loss_mean = fit(target_logits, online_mean, target_std)
    loss_std = fit(target_logits, target_mean, online_std)
    kl_cat = masked_mean(categorical_kl(target_logits, online_logits), mask)
    kl_mean = masked_mean(gaussian_kl_mean(target_mean, target_std, online_mean), mask)
    kl_std = masked_mean(gaussian_kl_std(target_std, online_std), mask)
    has_rows = (jnp.sum(mask) > 0).astype(q.dtype)
    loss_trust = (_trust_region_loss(alpha_cat, kl_cat, epsilon_cat, has_rows)
                  + _trust_region_loss(alpha_mean, kl_mean, epsilon_mean, has_rows)
                  + _trust_region_loss(alpha_std, kl_std, epsilon_std, has_rows))
    loss = loss_cat + loss_mean + loss_std + loss_trust + loss_temperature
    new_component_prob = masked_mean(jax.nn.softmax(online_logits, axis=-1)[:, -1], mask)
    stats = dict(rhpo_loss_cat=loss_cat, rhpo_loss_mean=loss_mean, rhpo_loss_std=loss_std,
                 rhpo_kl_cat=kl_cat, rhpo_kl_mean=kl_mean, rhpo_kl_std=kl_std,
                 rhpo_temperature=temperature, rhpo_new_component_prob=new_component_prob)
    return loss, stats
