"""RHPO with frozen skills (Wulfmeier et al. 2020; paper App. B "Fine-tuning and RHPO", freeze
variant): the ``rhpo`` baseline's learner.

The policy is a mixture chosen afresh at every step,

    π(a|s) = Σ_{c=0}^{N} π(c|s)·π_c(a|s),   π_c = N(μ_c(s), σ₀²) for the N frozen skills (c < N),
                                           π_N = N(μ(s), σ(s)²) the one trainable component,

with σ₀ the collection noise std. It maps onto the trainer's two learner states: the categorical
π(c|s) is the scheduler's policy network with one skill length (K = {1}: a decision at every
step, so the trainer's acting is RHPO's acting), and the trainable component with the critic
Q(s, a) is the new skill's learner state. HCMPO does not run; this update trains both:

* critic: TD target with J samples of the *target* mixture at s' (as the new skill's);
* policy: α·CRR + (1 − α)·RHPO-MPO (App. B's mix), CRR's log-likelihood and baseline actions
  those of the *online* mixture, the MPO part ``baseline_losses.rhpo_mpo_loss`` on samples of
  the *target* mixture at s. The categorical's KL bound is ``SchedulerConfig.epsilon_kl``, its
  multiplier the scheduler state's ``log_alpha``; temperature and the component's multipliers
  are the new skill's duals.
"""

from __future__ import annotations

from typing import Dict, NamedTuple, Tuple

import jax
import jax.numpy as jnp

from parallel_skills.baseline_losses import rhpo_components, rhpo_log_prob, rhpo_mpo_loss, sample_rhpo
from parallel_skills.config import NewSkillConfig, SchedulerConfig
from parallel_skills.crr import crr_policy_loss, crr_weights, mean_baseline_advantage, td_target
from parallel_skills.hcmpo import masked_mean, positive
from parallel_skills.learners import (LearnerState, SkillMixture, as_float32, tile_obs, critic_values,
                                      learner_step, new_skill_networks, scheduler_networks)
from parallel_skills.replay import Transition


class RHPOTargets(NamedTuple):
    """From the target networks (no gradient)."""

    y: jax.Array  # [B] TD target with samples of the target mixture at s'
    logits: jax.Array  # [B, N+1] π_old(c|s)
    mean: jax.Array  # [B, A] π_old's trainable component at s
    std: jax.Array  # [B, A]
    actions: jax.Array  # [B, n_mpo, A] samples of π_old at s (these four: MPO mix only, else [0])


def _mixture(categorical, component, cat_params, comp_params, obs, skills: SkillMixture):
    """(logits [B, N+1], means [B, N+1, A], stds [B, N+1, A], trainable mean, std [B, A]) at obs."""
    logits, _ = categorical.apply(cat_params, obs)
    mean, std = component.apply(comp_params, obs)
    means, stds = rhpo_components(skills.means, skills.std, mean, std)
    return logits, means, stds, mean, std


def _sample(logits, means, stds, key, n: int):
    return jnp.clip(sample_rhpo(logits, means, stds, key, n), -1.0, 1.0)  # acting clips too


def rhpo_targets(categorical_state: LearnerState, state: LearnerState, batch: Transition, skills: SkillMixture,
                 next_skills: SkillMixture, networks, key_next, key_mpo, config: NewSkillConfig) -> RHPOTargets:
    categorical, component, critic = networks
    j = config.num_action_samples
    nxt = _mixture(categorical, component, categorical_state.target_policy_params, state.target_policy_params,
                   batch.next_obs, next_skills)
    a_next = _sample(*nxt[:3], key_next, j)
    q_next = jnp.min(critic_values(critic, state.target_critic_params, tile_obs(batch.next_obs, j), a_next), -1)
    y = td_target(batch.reward, batch.discount, q_next, config.discount)
    if config.mpo_alpha >= 1.0:  # pure CRR: no π_old term
        empty = jnp.zeros((0,))
        return RHPOTargets(y=y, logits=empty, mean=empty, std=empty, actions=empty)
    logits, means, stds, mean, std = _mixture(categorical, component, categorical_state.target_policy_params,
                                              state.target_policy_params, batch.obs, skills)
    actions = _sample(logits, means, stds, key_mpo, config.mpo_num_samples)
    return RHPOTargets(y=y, logits=logits, mean=mean, std=std, actions=actions)


def rhpo_loss(params, batch: Transition, skills: SkillMixture, targets: RHPOTargets, networks, key_crr,
              sched_config: SchedulerConfig, config: NewSkillConfig) -> Tuple[jax.Array, Dict[str, jax.Array]]:
    """Critic 0.5·(Q(s, a) − y)² + α·CRR(mixture) + (1 − α)·RHPO-MPO. ``params`` = (categorical
    policy, component policy, critic, component duals, categorical duals)."""
    cat_params, comp_params, critic_params, duals, cat_duals = params
    categorical, component, critic = networks
    j, weight = config.num_action_samples, batch.weight
    logits, means, stds, mean, std = _mixture(categorical, component, cat_params, comp_params, batch.obs, skills)
    q = critic_values(critic, critic_params, batch.obs, batch.action)  # [B, E]
    critic_loss = masked_mean(jnp.sum(0.5 * jnp.square(q - targets.y[:, None]), axis=-1), weight)
    sg = jax.lax.stop_gradient
    a_j = sg(_sample(logits, means, stds, key_crr, j))
    frozen_critic = sg(critic_params)
    q_j = jnp.min(critic_values(critic, frozen_critic, tile_obs(batch.obs, j), a_j), -1)  # [B, J]
    advantage = mean_baseline_advantage(sg(jnp.min(q, -1)), q_j)
    w_crr = crr_weights(advantage, config.crr_mode, config.crr_beta, config.crr_clip)
    loss_crr = crr_policy_loss(rhpo_log_prob(logits, means, stds, batch.action), w_crr, weight)
    stats = {"critic_loss": critic_loss, "q_mean": masked_mean(jnp.min(q, -1), weight),
             "crr_weight_mean": masked_mean(w_crr, weight), "policy_log_std_mean": jnp.mean(jnp.log(std)),
             "advantage_mean": masked_mean(advantage, weight),
             "rhpo_new_component_prob": masked_mean(jax.nn.softmax(logits, -1)[:, -1], weight)}
    policy_loss = loss_crr
    if config.mpo_alpha < 1.0:
        q_mpo = jnp.min(critic_values(critic, frozen_critic, tile_obs(batch.obs, config.mpo_num_samples),
                                      targets.actions), -1)
        loss_mpo, mpo_stats = rhpo_mpo_loss(
            logits, mean, std, targets.logits, targets.mean, targets.std, skills.means, skills.std, targets.actions,
            q_mpo, positive(duals.log_temperature), positive(cat_duals.log_alpha),
            positive(duals.log_alpha_mean), positive(duals.log_alpha_stddev), config.mpo_epsilon,
            sched_config.epsilon_kl, config.mpo_epsilon_mean, config.mpo_epsilon_stddev, weight)
        policy_loss = config.mpo_alpha * loss_crr + (1.0 - config.mpo_alpha) * loss_mpo
        stats.update({k: v for k, v in mpo_stats.items() if k != "rhpo_new_component_prob"})
    stats["policy_loss"] = policy_loss
    return critic_loss + policy_loss, stats


def rhpo_learner_update(categorical_state: LearnerState, state: LearnerState, batch: Transition,
                        skills: SkillMixture, next_skills: SkillMixture, key: jax.Array,
                        sched_config: SchedulerConfig, config: NewSkillConfig
                        ) -> Tuple[LearnerState, LearnerState, Dict[str, jax.Array]]:
    """One RHPO update on ``batch`` [B] (rows with weight 0 ignored): ``skills`` /
    ``next_skills`` the frozen skills' actions at obs / next_obs ([B, N, A]). Returns the
    categorical's and the component's learner states and the stats."""
    batch = as_float32(batch)
    num_components = skills.means.shape[1] + 1
    categorical, _ = scheduler_networks(num_components, sched_config)
    component, critic = new_skill_networks(batch.action.shape[-1], config)
    networks = (categorical, component, critic)
    k_next, k_crr, k_mpo = jax.random.split(key, 3)
    targets = rhpo_targets(categorical_state, state, batch, skills, next_skills, networks, k_next, k_mpo, config)
    params = (categorical_state.policy_params, state.policy_params, state.critic_params, state.dual_params,
              categorical_state.dual_params)
    grads, stats = jax.grad(lambda p: rhpo_loss(p, batch, skills, targets, networks, k_crr, sched_config, config),
                            has_aux=True)(params)
    g_cat, g_comp, g_critic, g_duals, g_cat_duals = grads
    update_duals = config.mpo_alpha < 1.0
    state = learner_step(state, (g_comp, g_critic, g_duals), config, update_duals)
    # (The scheduler state's critic is not RHPO's: left as it is.)
    categorical_state = learner_step(categorical_state, (g_cat, None, g_cat_duals), sched_config, update_duals,
                                     update_critic=False)
    return categorical_state, state, stats
