"""Learners ("learning" part of the agent): HCMPO for the scheduler, CRR (± MPO) for the
new skill. Pure functions on ``flax.struct.dataclass`` states, so they run inside a jitted
``lax.scan`` and can be vmapped over seeds. Configs are static (hashable) arguments:

    update = jax.jit(scheduler_learner_update, static_argnames="config")

Which policy / critic is used where
-----------------------------------
Scheduler (HCMPO, paper Eq. 3-4):
  * critic target y: *target* critic Q' and *target* policy π' at s' (exact expectation
    over all (i, k) pairs when c == 1; Q'(s', c−1, i, k) otherwise).
  * E-step: Q = *online* critic Q(s, c=k, i, k) (stop-gradient) on the stored state s;
    prior π_old = *target* policy at s. Only weighted decision rows (weight·is_decision).
  * M-step: cross-entropy of the *online* policy to the E-step weights + KL(π_old ‖ π).
New skill (CRR, Wang et al. 2020):
  * TD target: a'_j ~ *target* policy at s' (J = num_action_samples, clipped), *target*
    critic, mean over j.
  * Advantage: *online* critic (stop-gradient), baseline actions a_j ~ *online* policy at s.
  * Optional MPO mix (mpo_alpha < 1): actions ~ *target* policy at s (π_old), Q from the
    *online* critic (stop-gradient).
Acting uses the *online* policy params (``state.policy_params``) through
``make_scheduler_apply`` / ``make_new_skill_apply`` (or the shape-inferring
``scheduler_logits`` / ``new_skill_distribution``).

Target networks are hard copies every ``target_actor_period`` / ``target_critic_period``
learner steps (``optax.periodic_update``; after update n (1-based), copied when n % period == 0).
"""

from __future__ import annotations

from typing import Callable, Dict, Tuple

import flax
import jax
import jax.numpy as jnp
import optax

from parallel_skills.config import NewSkillConfig, SchedulerConfig
from parallel_skills.crr import crr_advantage, crr_policy_loss, crr_weights, td_target
from parallel_skills.hcmpo import (critic_target, e_step_weights, m_step_loss, masked_mean, positive,
                                   temperature_dual_loss)
from parallel_skills.mpo import gaussian_mpo_loss
from parallel_skills.networks import (GaussianPolicy, QCritic, QEnsemble, SchedulerCritic, SchedulerPolicy,
                                      all_pairs, categorical_entropy, gaussian_log_prob,
                                      joint_log_probs, sample_action)

Params = Dict
Batch = Dict[str, jnp.ndarray]

_MIN_LOG_DUAL = -18.0  # Acme clips log temperature / log alpha from below.


def _optimizer(learning_rate: float, clip: float) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(clip), optax.adam(learning_rate))


def _learner_step(state, grads, config, update_duals: bool):
    """Apply one gradient step to policy, critic (and duals), then the periodic hard target copies.

    Shared by both learners: ``state`` is a Scheduler- or NewSkillLearnerState (same fields),
    ``grads`` = (policy, critic, dual) gradients. Duals are kept ≥ exp-floor via ``_MIN_LOG_DUAL``.
    """
    g_pol, g_crit, g_dual = grads
    opt = _optimizer(config.learning_rate, config.grad_clip_norm)
    upd, policy_opt_state = opt.update(g_pol, state.policy_opt_state, state.policy_params)
    new_policy = optax.apply_updates(state.policy_params, upd)
    upd, critic_opt_state = opt.update(g_crit, state.critic_opt_state, state.critic_params)
    new_critic = optax.apply_updates(state.critic_params, upd)
    if update_duals:
        dual_opt = optax.adam(config.dual_learning_rate)
        upd, dual_opt_state = dual_opt.update(g_dual, state.dual_opt_state, state.dual_params)
        new_dual = jax.tree_util.tree_map(lambda x: jnp.maximum(x, _MIN_LOG_DUAL),
                                          optax.apply_updates(state.dual_params, upd))
    else:
        new_dual, dual_opt_state = state.dual_params, state.dual_opt_state
    steps = state.steps + 1
    return state.replace(
        policy_params=new_policy, critic_params=new_critic,
        target_policy_params=optax.periodic_update(new_policy, state.target_policy_params, steps,
                                                   config.target_actor_period),
        target_critic_params=optax.periodic_update(new_critic, state.target_critic_params, steps,
                                                   config.target_critic_period),
        policy_opt_state=policy_opt_state, critic_opt_state=critic_opt_state,
        dual_params=new_dual, dual_opt_state=dual_opt_state, steps=steps)


def updates_per_iteration(samples_per_insert: float, num_inserted: int, batch_size: int) -> int:
    """Learner updates per collect iteration (DESIGN "Defaults"):
    round(spi · inserted / batch_size), at least 1."""
    return max(1, int(round(samples_per_insert * num_inserted / batch_size)))


# =============================================================================== scheduler

@flax.struct.dataclass
class SchedulerLearnerState:
    policy_params: Params
    critic_params: Params
    target_policy_params: Params
    target_critic_params: Params
    policy_opt_state: optax.OptState
    critic_opt_state: optax.OptState
    dual_params: Dict[str, jnp.ndarray]  # {"log_temperature": [], "log_alpha": []}
    dual_opt_state: optax.OptState
    steps: jnp.ndarray  # int32 scalar: learner updates done.


def scheduler_networks(num_skills_total: int, config: SchedulerConfig) -> Tuple[SchedulerPolicy, SchedulerCritic]:
    """The flax modules (policy, critic) the scheduler learner uses for ``config``."""
    policy = SchedulerPolicy(num_skills=num_skills_total, num_lengths=config.num_lengths,
                             hidden=tuple(config.hidden),
                             initial_max_length_prob=config.initial_max_length_prob)
    critic = SchedulerCritic(num_skills=num_skills_total, num_lengths=config.num_lengths,
                             max_length=config.max_length, hidden=tuple(config.hidden),
                             head_hidden=tuple(config.critic_head_hidden))
    return policy, critic


def make_scheduler_apply(num_skills_total: int, config: SchedulerConfig
                         ) -> Callable[[Params, jnp.ndarray], Tuple[jnp.ndarray, jnp.ndarray]]:
    """``apply(policy_params, obs [..., O]) -> (logits_i [..., N+1], logits_k [..., M])``."""
    policy, _ = scheduler_networks(num_skills_total, config)
    return policy.apply


def _torso_hidden(torso_params: Params) -> Tuple[int, ...]:
    names = sorted((k for k in torso_params if k.startswith("dense_")), key=lambda k: int(k.split("_")[1]))
    return tuple(int(torso_params[k]["kernel"].shape[-1]) for k in names)


def scheduler_logits(params: Params, obs: jnp.ndarray) -> Tuple[jnp.ndarray, jnp.ndarray]:
    """Scheduler policy apply with sizes inferred from ``params`` (the variables dict
    ``{"params": ...}`` of ``state.policy_params``). obs [..., O] -> (logits_i, logits_k)."""
    p = params["params"]
    module = SchedulerPolicy(num_skills=int(p["head_i"]["bias"].shape[0]),
                             num_lengths=int(p["head_k"]["bias"].shape[0]),
                             hidden=_torso_hidden(p["torso"]))
    return module.apply(params, obs)


def scheduler_learner_init(key: jax.Array, obs_size: int, num_skills_total: int,
                           config: SchedulerConfig) -> SchedulerLearnerState:
    """Initial scheduler learner state (targets = copies of the online networks)."""
    policy, critic = scheduler_networks(num_skills_total, config)
    k_pol, k_crit = jax.random.split(key)
    obs = jnp.zeros((1, obs_size), jnp.float32)
    idx = jnp.zeros((1, 1), jnp.int32)
    policy_params = policy.init(k_pol, obs)
    critic_params = critic.init(k_crit, obs, idx + 1, idx, idx)
    dual_params = {"log_temperature": jnp.asarray(config.init_log_temperature, jnp.float32),
                   "log_alpha": jnp.asarray(config.init_log_alpha, jnp.float32)}
    opt = _optimizer(config.learning_rate, config.grad_clip_norm)
    dual_opt = optax.adam(config.dual_learning_rate)
    return SchedulerLearnerState(
        policy_params=policy_params, critic_params=critic_params,
        target_policy_params=policy_params, target_critic_params=critic_params,
        policy_opt_state=opt.init(policy_params), critic_opt_state=opt.init(critic_params),
        dual_params=dual_params, dual_opt_state=dual_opt.init(dual_params),
        steps=jnp.zeros((), jnp.int32))


def scheduler_learner_update(state: SchedulerLearnerState, batch: Batch, key: jax.Array,
                             config: SchedulerConfig) -> Tuple[SchedulerLearnerState, Dict[str, jnp.ndarray]]:
    """One HCMPO update (paper Eq. 3 critic, Eq. 4 policy improvement).

    batch (all [B, ...]): obs [B, O], next_obs [B, O], reward [B], discount [B] (0 terminal,
    1 otherwise incl. truncation), skill [B] int (i), k_idx [B] int, c [B] int,
    is_decision [B] bool, weight [B] float (optional, default 1; rows with weight 0 are
    ignored everywhere). Augmented duplicates are just extra rows (see
    ``augmentation.with_augmentation``).

    Critic: 0.5·(Q(s, c, i, k) − y)² averaged over weighted rows. Policy and duals: only on
    rows with weight·is_decision > 0 (all zero if none). ``key`` is unused (the expectations
    are exact) and kept for interface symmetry.
    """
    del key
    policy_params = state.policy_params
    num_skills = int(policy_params["params"]["head_i"]["bias"].shape[0])
    policy, critic = scheduler_networks(num_skills, config)
    pair_i, pair_k, pair_kv = (jnp.asarray(a) for a in all_pairs(num_skills, config.skill_lengths))
    num_pairs = pair_i.shape[0]

    obs = batch["obs"].astype(jnp.float32)
    next_obs = batch["next_obs"].astype(jnp.float32)
    reward = batch["reward"].astype(jnp.float32)
    discount = batch["discount"].astype(jnp.float32)
    skill = batch["skill"].astype(jnp.int32)
    k_idx = batch["k_idx"].astype(jnp.int32)
    c = batch["c"].astype(jnp.int32)
    b = obs.shape[0]
    weight = batch.get("weight", jnp.ones((b,), jnp.float32)).astype(jnp.float32)
    dmask = weight * batch["is_decision"].astype(jnp.float32)

    def tile(x):
        return jnp.broadcast_to(x[None, :], (b, num_pairs))

    # ---- Policy evaluation target (Eq. 3): target policy + target critic at s'.
    t_li_next, t_lk_next = policy.apply(state.target_policy_params, next_obs)
    probs_next = jnp.exp(joint_log_probs(t_li_next, t_lk_next))  # [B, P]
    q_next = critic.apply(
        state.target_critic_params, next_obs,
        jnp.concatenate([tile(pair_kv), jnp.maximum(c - 1, 1)[:, None]], axis=1),
        jnp.concatenate([tile(pair_i), skill[:, None]], axis=1),
        jnp.concatenate([tile(pair_k), k_idx[:, None]], axis=1))  # [B, P + 1]
    y = critic_target(reward, discount, c, q_next[:, num_pairs], q_next[:, :num_pairs], probs_next,
                      config.discount)

    # ---- π_old = target policy at s.
    t_li, t_lk = policy.apply(state.target_policy_params, obs)
    log_prior = jax.lax.stop_gradient(joint_log_probs(t_li, t_lk))  # [B, P]

    def loss_fn(policy_params, critic_params, dual_params):
        q_all = critic.apply(
            critic_params, obs,
            jnp.concatenate([c[:, None], tile(pair_kv)], axis=1),
            jnp.concatenate([skill[:, None], tile(pair_i)], axis=1),
            jnp.concatenate([k_idx[:, None], tile(pair_k)], axis=1))  # [B, 1 + P]
        q = q_all[:, 0]
        critic_loss = masked_mean(0.5 * jnp.square(q - y), weight)
        q_fresh = jax.lax.stop_gradient(q_all[:, 1:])  # Q(s, c=k, i, k), all pairs
        temperature = positive(dual_params["log_temperature"])
        alpha = positive(dual_params["log_alpha"])
        weights = e_step_weights(q_fresh, log_prior, temperature)
        loss_temperature = temperature_dual_loss(temperature, q_fresh, log_prior, config.epsilon, dmask)
        li, lk = policy.apply(policy_params, obs)
        log_probs = joint_log_probs(li, lk)
        loss_m, kl = m_step_loss(log_probs, weights, log_prior, alpha, config.epsilon_kl, dmask)
        policy_loss = (loss_m + loss_temperature) * (state.steps >= config.policy_warmup_updates)
        aux = dict(critic_loss=critic_loss, q=q, temperature=temperature, alpha=alpha, kl=kl,
                   policy_loss=policy_loss, li=li, lk=lk)
        return critic_loss + policy_loss, aux

    grads, aux = jax.grad(loss_fn, argnums=(0, 1, 2), has_aux=True)(
        state.policy_params, state.critic_params, state.dual_params)

    new_state = _learner_step(state, grads, config, update_duals=True)

    q = aux["q"]
    metrics = dict(
        critic_loss=aux["critic_loss"],
        q_mean=masked_mean(q, weight),
        q_max=jnp.max(jnp.where(weight > 0, q, jnp.min(q))),
        temperature=aux["temperature"],
        alpha=aux["alpha"],
        kl=aux["kl"],
        policy_loss=aux["policy_loss"],
        policy_entropy_i=masked_mean(categorical_entropy(aux["li"]), weight),
        policy_entropy_k=masked_mean(categorical_entropy(aux["lk"]), weight),
        decision_fraction=jnp.sum(dmask) / jnp.maximum(jnp.sum(weight), 1.0),
    )
    return new_state, metrics


# =============================================================================== new skill

@flax.struct.dataclass
class NewSkillLearnerState:
    policy_params: Params
    critic_params: Params
    target_policy_params: Params
    target_critic_params: Params
    policy_opt_state: optax.OptState
    critic_opt_state: optax.OptState
    # {"log_temperature", "log_alpha_mean", "log_alpha_stddev"}: only used when mpo_alpha < 1.
    dual_params: Dict[str, jnp.ndarray]
    dual_opt_state: optax.OptState
    steps: jnp.ndarray


def new_skill_networks(action_size: int, config: NewSkillConfig):
    """The flax modules (policy, critic) the new-skill learner uses for ``config``: the critic is a
    ``QEnsemble`` (q [..., E]), or a plain ``QCritic`` when ``num_critics == 1`` (the parameter
    layout of runs from before the ensemble, so that they still resume). Apply the critic with
    ``critic_values`` to get [..., E] either way."""
    policy = GaussianPolicy(action_size=action_size, hidden=tuple(config.hidden), min_std=config.min_std)
    if int(config.num_critics) == 1:
        return policy, QCritic(hidden=tuple(config.hidden))
    return policy, QEnsemble(hidden=tuple(config.hidden), num_critics=int(config.num_critics))


def critic_values(critic, params: Params, obs: jnp.ndarray, action: jnp.ndarray) -> jnp.ndarray:
    """New-skill critic values q [..., E] (E = 1 for a plain QCritic)."""
    q = critic.apply(params, obs, action)
    return q[..., None] if isinstance(critic, QCritic) else q


def make_new_skill_apply(action_size: int, config: NewSkillConfig
                         ) -> Callable[[Params, jnp.ndarray], Tuple[jnp.ndarray, jnp.ndarray]]:
    """``apply(policy_params, obs [..., O]) -> (mean [..., A], std [..., A])``; act with
    ``networks.sample_action(mean, std, key)`` (clipped) or the mean (deterministic)."""
    policy, _ = new_skill_networks(action_size, config)
    return policy.apply


def new_skill_distribution(params: Params, obs: jnp.ndarray, min_std: float = NewSkillConfig.min_std
                           ) -> Tuple[jnp.ndarray, jnp.ndarray]:
    """New-skill policy apply with sizes inferred from ``params`` (``{"params": ...}``).
    ``min_std`` must match the config used for training (default 0.05).
    obs [..., O] -> (mean [..., A], std [..., A])."""
    p = params["params"]
    module = GaussianPolicy(action_size=int(p["head"]["bias"].shape[0]) // 2,
                            hidden=_torso_hidden(p["torso"]), min_std=min_std)
    return module.apply(params, obs)


def new_skill_learner_init(key: jax.Array, obs_size: int, action_size: int,
                           config: NewSkillConfig) -> NewSkillLearnerState:
    """Initial new-skill learner state (targets = copies of the online networks)."""
    policy, critic = new_skill_networks(action_size, config)
    k_pol, k_crit = jax.random.split(key)
    obs = jnp.zeros((1, obs_size), jnp.float32)
    act = jnp.zeros((1, action_size), jnp.float32)
    policy_params = policy.init(k_pol, obs)
    critic_params = critic.init(k_crit, obs, act)
    dual_params = {"log_temperature": jnp.asarray(config.mpo_init_log_temperature, jnp.float32),
                   "log_alpha_mean": jnp.asarray(config.mpo_init_log_alpha_mean, jnp.float32),
                   "log_alpha_stddev": jnp.asarray(config.mpo_init_log_alpha_stddev, jnp.float32)}
    opt = _optimizer(config.learning_rate, config.grad_clip_norm)
    dual_opt = optax.adam(config.dual_learning_rate)
    return NewSkillLearnerState(
        policy_params=policy_params, critic_params=critic_params,
        target_policy_params=policy_params, target_critic_params=critic_params,
        policy_opt_state=opt.init(policy_params), critic_opt_state=opt.init(critic_params),
        dual_params=dual_params, dual_opt_state=dual_opt.init(dual_params),
        steps=jnp.zeros((), jnp.int32))


def new_skill_learner_update(state: NewSkillLearnerState, batch: Batch, key: jax.Array,
                             config: NewSkillConfig) -> Tuple[NewSkillLearnerState, Dict[str, jnp.ndarray]]:
    """One CRR update (± Gaussian MPO with weight 1 − mpo_alpha).

    batch: obs [B, O], action [B, A], reward [B], discount [B] (0 terminal, 1 otherwise incl.
    truncation), next_obs [B, O], optional weight [B] (default 1).

    Critics (E = num_critics): Σ_e 0.5·(Q_e(s, a) − y)², y = r + γ·d·mean_j min_e Q'_e(s', a'_j),
    a'_j ~ π_target(.|s') (clipped double Q); CRR advantages use min_e Q_e.
    Policy: α·CRR + (1 − α)·MPO (pure CRR when mpo_alpha == 1, decided statically).
    """
    obs = batch["obs"].astype(jnp.float32)
    action = batch["action"].astype(jnp.float32)
    next_obs = batch["next_obs"].astype(jnp.float32)
    reward = batch["reward"].astype(jnp.float32)
    discount = batch["discount"].astype(jnp.float32)
    b, a_size = action.shape
    weight = batch.get("weight", jnp.ones((b,), jnp.float32)).astype(jnp.float32)
    policy, critic = new_skill_networks(a_size, config)
    j = config.num_action_samples
    use_mpo = config.mpo_alpha < 1.0
    k_next, k_crr, k_mpo = jax.random.split(key, 3)

    def tile_obs(x, n):
        return jnp.broadcast_to(x[:, None, :], (b, n, x.shape[-1]))

    # ---- TD target with the target policy and target critic.
    t_mean_next, t_std_next = policy.apply(state.target_policy_params, next_obs)
    a_next = sample_action(jnp.broadcast_to(t_mean_next[:, None], (b, j, a_size)),
                           jnp.broadcast_to(t_std_next[:, None], (b, j, a_size)), k_next)
    # Clipped double Q: the minimum over the target critics.
    q_next = jnp.min(critic_values(critic, state.target_critic_params, tile_obs(next_obs, j), a_next), axis=-1)  # [B, J]
    y = td_target(reward, discount, q_next, config.discount)

    # ---- MPO samples from π_old = target policy at s.
    if use_mpo:
        n_mpo = config.mpo_num_samples
        t_mean, t_std = policy.apply(state.target_policy_params, obs)
        a_mpo = sample_action(jnp.broadcast_to(t_mean[:, None], (b, n_mpo, a_size)),
                              jnp.broadcast_to(t_std[:, None], (b, n_mpo, a_size)), k_mpo)
    else:
        n_mpo = 0

    def loss_fn(policy_params, critic_params, dual_params):
        mean, std = policy.apply(policy_params, obs)
        a_j = jax.lax.stop_gradient(sample_action(
            jnp.broadcast_to(mean[:, None], (b, j, a_size)),
            jnp.broadcast_to(std[:, None], (b, j, a_size)), k_crr))
        actions = [action[:, None], a_j] + ([a_mpo] if use_mpo else [])
        actions = jnp.concatenate(actions, axis=1)  # [B, 1 + J (+ n_mpo), A]
        q_ens = critic_values(critic, critic_params, tile_obs(obs, 1 + j + n_mpo), actions)  # [B, 1 + J (+ n_mpo), E]
        q = q_ens[:, 0]  # [B, E]: every critic regresses on the same target
        critic_loss = masked_mean(jnp.sum(0.5 * jnp.square(q - y[:, None]), axis=-1), weight)
        q_all = jnp.min(q_ens, axis=-1)  # advantages from the clipped (minimum) estimate
        q_sg = jax.lax.stop_gradient(q_all)
        advantage = crr_advantage(q_sg[:, 0], q_sg[:, 1:1 + j])
        w_crr = crr_weights(advantage, config.crr_mode, config.crr_beta, config.crr_clip)
        log_prob = gaussian_log_prob(mean, std, action)
        loss_crr = crr_policy_loss(log_prob, w_crr, weight)
        aux = dict(critic_loss=critic_loss, q=q_all[:, 0], advantage=advantage, w_crr=w_crr, std=std)
        if use_mpo:
            loss_mpo, stats = gaussian_mpo_loss(
                mean, std, t_mean, t_std, a_mpo, q_sg[:, 1 + j:],
                positive(dual_params["log_temperature"]), positive(dual_params["log_alpha_mean"]),
                positive(dual_params["log_alpha_stddev"]), config.mpo_epsilon,
                config.mpo_epsilon_mean, config.mpo_epsilon_stddev, weight)
            policy_loss = config.mpo_alpha * loss_crr + (1.0 - config.mpo_alpha) * loss_mpo
            aux.update(stats)
        else:
            policy_loss = loss_crr
        aux["policy_loss"] = policy_loss
        return critic_loss + policy_loss, aux

    grads, aux = jax.grad(loss_fn, argnums=(0, 1, 2), has_aux=True)(
        state.policy_params, state.critic_params, state.dual_params)

    new_state = _learner_step(state, grads, config, update_duals=use_mpo)

    metrics = dict(
        critic_loss=aux["critic_loss"],
        q_mean=masked_mean(aux["q"], weight),
        crr_weight_mean=masked_mean(aux["w_crr"], weight),
        policy_log_std_mean=jnp.mean(jnp.log(aux["std"])),
        advantage_mean=masked_mean(aux["advantage"], weight),
        policy_loss=aux["policy_loss"],
    )
    if use_mpo:
        for name in ("mpo_kl_mean", "mpo_kl_std", "mpo_temperature"):
            metrics[name] = aux[name]
    return new_state, metrics
