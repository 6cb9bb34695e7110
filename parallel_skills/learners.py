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
    critic, mean over j; or the target policy's mean action alone (``td_target_action`` "mean").
  * Advantage: *online* critic (stop-gradient), baseline actions a_j ~ *online* policy at s.
  * Optional baseline mix (mpo_alpha < 1, paper App. B): actions ~ *target* policy at s
    (π_old; for kl_reg the skills' mixture π₀), Q from the *online* critic (stop-gradient);
    kl_reg / dagger read the frozen skills' actions at s (``SkillMixture``).
Acting uses the *online* policy params (``state.policy_params``) through
``make_scheduler_apply`` / ``make_new_skill_apply``.

Each update reads as targets (NamedTuple, computed from the target networks, no gradient) →
loss (online networks; aux NamedTuple) → one optimiser step → stats (a dict of scalars), as
Acme's MPO learner. Batches are ``replay.Transition`` rows; both learners share one state type,
``LearnerState``.

Target networks are hard copies every ``target_actor_period`` / ``target_critic_period``
learner steps (``optax.periodic_update``; after update n (1-based), copied when n % period == 0).
"""

from __future__ import annotations

from typing import Callable, Dict, NamedTuple, Optional, Tuple, Union

import flax
import jax
import jax.numpy as jnp
import optax

from parallel_skills.augmentation import augment_batch
from parallel_skills.baseline_losses import (dagger_cross_entropy, kl_reg_mpo_loss, mixture_log_prob, prior_e_step,
                                             sample_mixture)
from parallel_skills.config import NewSkillConfig, SchedulerConfig
from parallel_skills.crr import crr_policy_loss, crr_weights, mean_baseline_advantage, td_target
from parallel_skills.hcmpo import (critic_target, e_step_weights, m_step_loss, masked_mean, positive,
                                   temperature_dual_loss)
from parallel_skills.mpo import gaussian_mpo_loss
from parallel_skills.networks import (GaussianPolicy, QCritic, QEnsemble, SchedulerCritic, SchedulerPolicy,
                                      categorical_entropy, gaussian_log_prob, pair_values, read_pairs,
                                      joint_log_probs, sample_action)

from parallel_skills.replay import SchedulerBatch, Transition

Params = Dict

_MIN_LOG_DUAL = -18.0  # Acme clips log temperature / log alpha from below.


def _optimizer(learning_rate: float, clip: float) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(clip), optax.adam(learning_rate))


def learner_step(state, grads, config, update_duals: bool, update_critic: bool = True):
    """Apply one gradient step to policy, critic (and duals), then the periodic hard target copies.

    Shared by both learners (``LearnerState``); ``grads`` = (policy, critic, dual) gradients. Duals are kept ≥ exp-floor via ``_MIN_LOG_DUAL``.
    ``update_critic`` False: the critic, its optimiser state and its target are left as they are
    (the critic gradient is not read; RHPO's categorical lives in a scheduler state whose critic it
    does not use).
    """
    g_pol, g_crit, g_dual = grads
    opt = _optimizer(config.learning_rate, config.grad_clip_norm)
    upd, policy_opt_state = opt.update(g_pol, state.policy_opt_state, state.policy_params)
    new_policy = optax.apply_updates(state.policy_params, upd)
    if update_critic:
        upd, critic_opt_state = opt.update(g_crit, state.critic_opt_state, state.critic_params)
        new_critic = optax.apply_updates(state.critic_params, upd)
    else:
        new_critic, critic_opt_state = state.critic_params, state.critic_opt_state
    if update_duals:
        dual_opt = optax.adam(config.dual_learning_rate)
        upd, dual_opt_state = dual_opt.update(g_dual, state.dual_opt_state, state.dual_params)
        new_dual = jax.tree_util.tree_map(lambda x: jnp.maximum(x, _MIN_LOG_DUAL),
                                          optax.apply_updates(state.dual_params, upd))
    else:
        new_dual, dual_opt_state = state.dual_params, state.dual_opt_state
    steps = state.steps + 1
    # Hard copies every period (the paper).
    target_policy = optax.periodic_update(new_policy, state.target_policy_params, steps, config.target_actor_period)
    target_critic = optax.periodic_update(new_critic, state.target_critic_params, steps, config.target_critic_period)
    if not update_critic:
        target_critic = state.target_critic_params
    ema = state.ema_policy_params
    if ema is not None:  # (only the new skill keeps one: NewSkillConfig.policy_ema)
        ema = optax.incremental_update(new_policy, ema, config.policy_ema)
    return state.replace(
        policy_params=new_policy, critic_params=new_critic,
        target_policy_params=target_policy, target_critic_params=target_critic,
        policy_opt_state=policy_opt_state, critic_opt_state=critic_opt_state,
        dual_params=new_dual, dual_opt_state=dual_opt_state, steps=steps, ema_policy_params=ema)


# The MPO dual variables (log-parameters; positive via ``hcmpo.positive``). Fields in alphabetical
# order: the leaves flatten in the order of the dicts they replace, and a checkpoint names them alike.
@flax.struct.dataclass
class SchedulerDuals:
    """The scheduler's duals: the E-step temperature η and the M-step KL multiplier α (Eq. 4)."""

    log_alpha: jax.Array
    log_temperature: jax.Array

    @classmethod
    def initial(cls, config: SchedulerConfig) -> "SchedulerDuals":
        return cls(log_alpha=jnp.asarray(config.init_log_alpha, jnp.float32),
                   log_temperature=jnp.asarray(config.init_log_temperature, jnp.float32))


@flax.struct.dataclass
class NewSkillDuals:
    """The new skill's Gaussian-MPO duals (used only when mpo_alpha < 1): the temperature and the
    mean's and std's KL multipliers."""

    log_alpha_mean: jax.Array
    log_alpha_stddev: jax.Array
    log_temperature: jax.Array

    @classmethod
    def initial(cls, config: NewSkillConfig) -> "NewSkillDuals":
        return cls(log_alpha_mean=jnp.asarray(config.mpo_init_log_alpha_mean, jnp.float32),
                   log_alpha_stddev=jnp.asarray(config.mpo_init_log_alpha_stddev, jnp.float32),
                   log_temperature=jnp.asarray(config.mpo_init_log_temperature, jnp.float32))


@flax.struct.dataclass
class LearnerState:
    """A learner's networks, their targets, optimiser states and MPO duals (both learners)."""

    policy_params: Params
    critic_params: Params
    target_policy_params: Params
    target_critic_params: Params
    policy_opt_state: optax.OptState
    critic_opt_state: optax.OptState
    dual_params: Union[SchedulerDuals, NewSkillDuals]
    dual_opt_state: optax.OptState
    steps: jnp.ndarray  # int32 scalar: learner updates done.
    # The new skill's moving average of ``policy_params`` (``NewSkillConfig.policy_ema`` > 0);
    # None otherwise (no leaves: the state and its checkpoints are as without the field).
    ema_policy_params: Optional[Params] = None

    @property
    def deployed_policy_params(self) -> Params:
        """The policy a run evaluates, exports and ships: the moving average where one is kept
        (``NewSkillConfig.policy_ema``), else the online policy (which acts while collecting)."""
        return self.policy_params if self.ema_policy_params is None else self.ema_policy_params


def _learner_init(key, policy, critic, policy_inputs, critic_inputs, dual_params, config) -> LearnerState:
    """Initial learner state (targets = copies of the online networks)."""
    k_pol, k_crit = jax.random.split(key)
    policy_params = policy.init(k_pol, *policy_inputs)
    critic_params = critic.init(k_crit, *critic_inputs)
    opt = _optimizer(config.learning_rate, config.grad_clip_norm)
    dual_opt = optax.adam(config.dual_learning_rate)
    return LearnerState(
        policy_params=policy_params, critic_params=critic_params,
        target_policy_params=policy_params, target_critic_params=critic_params,
        policy_opt_state=opt.init(policy_params), critic_opt_state=opt.init(critic_params),
        dual_params=dual_params, dual_opt_state=dual_opt.init(dual_params),
        steps=jnp.zeros((), jnp.int32))


# =============================================================================== scheduler


def scheduler_networks(num_skills_total: int, config: SchedulerConfig) -> Tuple[SchedulerPolicy, SchedulerCritic]:
    """The flax modules (policy, critic) the scheduler learner uses for ``config``."""
    policy = SchedulerPolicy(num_skills=num_skills_total, num_lengths=config.num_lengths,
                             hidden=tuple(config.hidden),
                             initial_max_length_prob=config.initial_max_length_prob,
                             new_skill_choice=config.new_skill_choice)
    critic = SchedulerCritic(num_skills=num_skills_total, num_lengths=config.num_lengths,
                             max_length=config.max_length, hidden=tuple(config.hidden),
                             head_hidden=tuple(config.critic_head_hidden))
    return policy, critic


def make_scheduler_apply(num_skills_total: int, config: SchedulerConfig
                         ) -> Callable[[Params, jnp.ndarray], Tuple[jnp.ndarray, jnp.ndarray]]:
    """``apply(policy_params, obs [..., O]) -> (logits_i [..., N+1], logits_k [..., M])``."""
    policy, _ = scheduler_networks(num_skills_total, config)
    return policy.apply


def scheduler_state_values(policy_params: Params, critic_params: Params, obs: jnp.ndarray, num_skills_total: int,
                           config: SchedulerConfig) -> jnp.ndarray:
    """V(s) = Σ_z π(z|s)·Q(s, c = k_z, z) [B] at decision states ``obs`` [B, O] (normalised): the
    value the scheduler's critic gives a fresh decision under its (online) policy."""
    policy, critic = scheduler_networks(num_skills_total, config)
    lengths = _skill_lengths(config)
    li, lk = policy.apply(policy_params, obs)
    table = critic.apply(critic_params, obs, _tile(lengths, obs.shape[0]))  # [B, M, P]
    return jnp.sum(jnp.exp(joint_log_probs(li, lk)) * pair_values(table, lengths.shape[0]), axis=-1)


def scheduler_learner_init(key: jax.Array, obs_size: int, num_skills_total: int,
                           config: SchedulerConfig) -> LearnerState:
    """Initial scheduler learner state (targets = copies of the online networks)."""
    policy, critic = scheduler_networks(num_skills_total, config)
    obs = jnp.zeros((1, obs_size), jnp.float32)
    idx = jnp.zeros((1, 1), jnp.int32)
    return _learner_init(key, policy, critic, (obs,), (obs, idx + 1, idx, idx), SchedulerDuals.initial(config),
                         config)


class SchedulerTargets(NamedTuple):
    """What the scheduler's loss regresses to, from the target networks (no gradient)."""

    y: jax.Array  # [B, L] critic target of Eq. 3, per labelling
    log_prior: jax.Array  # [B, P] log π_old(z | s) of every pair z = (i, k): the target policy


class SchedulerAux(NamedTuple):
    critic_loss: jax.Array
    q: jax.Array  # [B, L] Q(s, c, i, k) of each labelling
    temperature: jax.Array
    alpha: jax.Array
    kl: jax.Array
    policy_loss: jax.Array
    logits_i: jax.Array
    logits_k: jax.Array


def _skill_lengths(config: SchedulerConfig) -> jax.Array:
    """K [M] int32: the counter values a fresh decision sets (one critic head row each)."""
    return jnp.asarray(config.skill_lengths, jnp.int32)


def _tile(x, b: int):
    return jnp.broadcast_to(x[None, :], (b, x.shape[0]))


class SchedulerLabels(NamedTuple):
    """The labellings of a scheduler batch's states, [B, L] each (L = 2 with augmentation: the
    stored labels, then the duplicate's of App. A.2; L = 1 without). Augmented duplicates share
    their state (obs, next_obs, reward, discount): the networks run once per state and each
    labelling reads its own rows of the critic table."""

    skill: jax.Array  # [B, L] i
    k_idx: jax.Array  # [B, L] index of k in K
    c: jax.Array  # [B, L] counter
    is_decision: jax.Array  # [B, L] bool
    weight: jax.Array  # [B, L] float (0: the duplicate does not apply, or the row is not learnt from)


def scheduler_labels(batch: Transition, config: SchedulerConfig) -> SchedulerLabels:
    """Labels [B, L] of ``batch`` [B]: its own, plus the augmented duplicate's (paper §4.4,
    ``augmentation.augment_batch``) when ``config.augmentation``. Training on them is training on
    ``augmentation.with_augmentation(batch)`` [2B] with the states evaluated once."""
    sets = [batch] + ([augment_batch(batch, config.skill_lengths)] if config.augmentation else [])
    stack = lambda name: jnp.stack([getattr(b, name) for b in sets], axis=1)  # noqa: E731
    return SchedulerLabels(skill=stack("skill"), k_idx=stack("k_idx"), c=stack("c"),
                           is_decision=stack("is_decision"), weight=stack("weight"))


def target_steps(batch: Transition) -> jax.Array:
    """m [B]: the env steps a scheduler batch's targets span (``replay.SchedulerBatch.steps``; 1 for
    a plain ``Transition``: one-step Eq. 3)."""
    if isinstance(batch, SchedulerBatch):
        return batch.steps.astype(jnp.int32)
    return jnp.ones(batch.reward.shape, jnp.int32)


def scheduler_targets(state: LearnerState, batch: Transition, labels: SchedulerLabels, networks, lengths,
                      config: SchedulerConfig) -> SchedulerTargets:
    """Eq. 3's target [B, L] with the target policy and critic at s' (the expectation over
    (i', k') exact), and π_old = the target policy at s. With n-step rows (``replay.SchedulerBatch``,
    reward R = Σ_{j<m} γ^j r_{t+j}, discount γ^(m−1)·d, s' = s_{t+m}) the target is Eq. 3 for the
    option's m steps: R + γ^m·d·V' at s_{t+m}, where the counter there is c − m (fresh decision when
    the execution ended, c − m + 1 == 1)."""
    policy, critic = networks
    b, m = batch.obs.shape[0], lengths.shape[0]
    t_li_next, t_lk_next = policy.apply(state.target_policy_params, batch.next_obs)
    probs_next = jnp.exp(joint_log_probs(t_li_next, t_lk_next))  # [B, P]
    # One head row per distinct counter value: c' = each K (fresh decisions) and c − 1 (continuing,
    # one per labelling).
    # n-step (SchedulerConfig.n_step; replay.SchedulerBatch): s' = s_{t+m}, reached with the counter
    # c − m + 1 at its last step (1: the execution ended, s' is a decision state).
    c_last = labels.c - (target_steps(batch)[:, None] - 1)
    table = critic.apply(state.target_critic_params, batch.next_obs,
                         jnp.concatenate([_tile(lengths, b), jnp.maximum(c_last - 1, 1)], axis=1))
    q_fresh_next = pair_values(table[:, :m], m)  # [B, P]: Q'(s', K, i, k)
    q_cont_next = read_pairs(table[:, m:], labels.skill, labels.k_idx, m)  # [B, L]
    y = critic_target(batch.reward[:, None], batch.discount[:, None], c_last, q_cont_next,
                      q_fresh_next[:, None], probs_next[:, None], config.discount)  # [B, L]
    t_li, t_lk = policy.apply(state.target_policy_params, batch.obs)
    log_prior = jax.lax.stop_gradient(joint_log_probs(t_li, t_lk))  # [B, P]
    return SchedulerTargets(y=y, log_prior=log_prior)


def scheduler_loss(params, steps, batch: Transition, labels: SchedulerLabels, targets: SchedulerTargets,
                   networks, lengths, config: SchedulerConfig) -> Tuple[jax.Array, SchedulerAux]:
    """Critic: 0.5·(Q(s, c, i, k) − y)² over weighted rows of every labelling. Policy (Eq. 4, only
    on weighted decision rows; a state counts once per labelling that makes it one): E-step
    weights q(z|s) ∝ π_old·exp(Q(s, c=k, z)/η) with the temperature dual, M-step cross-entropy
    with the KL(π_old ‖ π) trust region; zero during the policy warm-up.
    ``params`` = (policy, critic, dual)."""
    policy_params, critic_params, dual_params = params
    policy, critic = networks
    b, n_labels = labels.c.shape
    dmask = jnp.sum(labels.weight * labels.is_decision.astype(jnp.float32), axis=1)  # [B]
    table = critic.apply(critic_params, batch.obs,
                         jnp.concatenate([labels.c, _tile(lengths, b)], axis=1))  # [B, L + M, P]
    q = read_pairs(table[:, :n_labels], labels.skill, labels.k_idx, lengths.shape[0])  # [B, L]: Q(s, c, i, k)
    critic_loss = masked_mean(0.5 * jnp.square(q - targets.y), labels.weight)
    q_fresh = jax.lax.stop_gradient(pair_values(table[:, n_labels:], lengths.shape[0]))  # Q(s, c=k, i, k), all pairs
    temperature = positive(dual_params.log_temperature)
    alpha = positive(dual_params.log_alpha)
    weights = e_step_weights(q_fresh, targets.log_prior, temperature)
    loss_temperature = temperature_dual_loss(temperature, q_fresh, targets.log_prior, config.epsilon, dmask)
    li, lk = policy.apply(policy_params, batch.obs)
    log_probs = joint_log_probs(li, lk)
    loss_m, kl = m_step_loss(log_probs, weights, targets.log_prior, alpha, config.epsilon_kl, dmask)
    policy_loss = (loss_m + loss_temperature) * (steps >= config.policy_warmup_updates)
    aux = SchedulerAux(critic_loss=critic_loss, q=q, temperature=temperature, alpha=alpha, kl=kl,
                       policy_loss=policy_loss, logits_i=li, logits_k=lk)
    return critic_loss + policy_loss, aux


def scheduler_stats(aux: SchedulerAux, labels: SchedulerLabels) -> Dict[str, jax.Array]:
    """Scalars to log of one scheduler update (over the rows of every labelling)."""
    weight = labels.weight  # [B, L]
    dmask = weight * labels.is_decision.astype(jnp.float32)
    q = aux.q  # [B, L]
    return dict(
        critic_loss=aux.critic_loss,
        q_mean=masked_mean(q, weight),
        q_max=jnp.max(jnp.where(weight > 0, q, jnp.min(q))),
        temperature=aux.temperature,
        alpha=aux.alpha,
        kl=aux.kl,
        policy_loss=aux.policy_loss,
        policy_entropy_i=masked_mean(categorical_entropy(aux.logits_i)[:, None], weight),
        policy_entropy_k=masked_mean(categorical_entropy(aux.logits_k)[:, None], weight),
        decision_fraction=jnp.sum(dmask) / jnp.maximum(jnp.sum(weight), 1.0),
    )


def scheduler_learner_update(state: LearnerState, batch: Transition, key: jax.Array,
                             config: SchedulerConfig) -> Tuple[LearnerState, Dict[str, jax.Array]]:
    """One HCMPO update (paper Eq. 3 critic, Eq. 4 policy improvement) on ``batch`` [B]
    (``replay.Transition``: obs, next_obs, reward, discount, skill, k_idx, c, is_decision, weight;
    rows with weight 0 are ignored everywhere). With ``config.augmentation`` every row is also
    learnt from with its augmented labels (paper §4.4; ``scheduler_labels``): the same update as
    on ``augmentation.with_augmentation(batch)`` without augmentation, with the networks run once
    per state. ``key`` is unused (the expectations are exact) and kept for interface symmetry."""
    del key
    num_skills = int(state.policy_params["params"]["head_i"]["bias"].shape[0])
    networks = scheduler_networks(num_skills, config)
    lengths = _skill_lengths(config)
    batch = as_float32(batch)
    labels = scheduler_labels(batch, config)
    targets = scheduler_targets(state, batch, labels, networks, lengths, config)
    grads, aux = jax.grad(
        lambda p: scheduler_loss(p, state.steps, batch, labels, targets, networks, lengths, config),
        has_aux=True)((state.policy_params, state.critic_params, state.dual_params))
    return learner_step(state, grads, config, update_duals=True), scheduler_stats(aux, labels)


def as_float32(batch: Transition) -> Transition:
    """Observations, actions, rewards, discounts and weights as float32; labels as int32."""
    f, i = jnp.float32, jnp.int32
    return batch.replace(obs=batch.obs.astype(f), action=batch.action.astype(f), reward=batch.reward.astype(f),
                         discount=batch.discount.astype(f), next_obs=batch.next_obs.astype(f),
                         skill=batch.skill.astype(i), k_idx=batch.k_idx.astype(i), c=batch.c.astype(i),
                         weight=batch.weight.astype(f))


# =============================================================================== new skill

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


def new_skill_learner_init(key: jax.Array, obs_size: int, action_size: int,
                           config: NewSkillConfig) -> LearnerState:
    """Initial new-skill learner state (targets, and the moving average where
    ``config.policy_ema`` > 0, = copies of the online networks)."""
    policy, critic = new_skill_networks(action_size, config)
    obs = jnp.zeros((1, obs_size), jnp.float32)
    act = jnp.zeros((1, action_size), jnp.float32)
    state = _learner_init(key, policy, critic, (obs,), (obs, act), NewSkillDuals.initial(config), config)
    return state.replace(ema_policy_params=state.policy_params) if config.policy_ema > 0 else state


class SkillMixture(NamedTuple):
    """The frozen skills at a batch's states, as the baselines' prior / teacher π₀ =
    (1/N)·Σ_i N(μ_i(s), σ₀²) (``baseline_losses``): means [B, N, A] the skills' actions, std σ₀
    the collection noise std (scalar)."""

    means: jax.Array
    std: jax.Array


class NewSkillTargets(NamedTuple):
    """From the target networks (no gradient)."""

    y: jax.Array  # [B] TD target r + γ·d·mean_j min_e Q'_e(s', a'_j), a'_j ~ π_target(.|s') (or a' = μ_target(s'))
    mpo_mean: jax.Array  # [B, A] π_old = target policy at s (MPO mix only, else [0])
    mpo_std: jax.Array  # [B, A]
    mpo_actions: jax.Array  # [B, n_mpo, A] samples of π_old, or of π₀ for kl_reg (MPO mix only)


class NewSkillAux(NamedTuple):
    critic_loss: jax.Array
    q: jax.Array  # [B] min_e Q_e(s, a) of the stored actions
    advantage: jax.Array  # [B] CRR advantage
    crr_weight: jax.Array  # [B] f(A)
    std: jax.Array  # [B, A] the policy's std at s
    policy_loss: jax.Array
    mpo: Dict[str, jax.Array]  # mpo_kl_mean, mpo_kl_std, mpo_temperature (MPO mix only)


def tile_obs(x, n: int):
    return jnp.broadcast_to(x[:, None, :], (x.shape[0], n, x.shape[-1]))


def sample_n(mean, std, n: int, key):
    """n actions per state from the Gaussian (``networks.sample_action``, clipped).
    mean, std [B, A] -> [B, n, A]."""
    b, a = mean.shape
    return sample_action(jnp.broadcast_to(mean[:, None], (b, n, a)), jnp.broadcast_to(std[:, None], (b, n, a)), key)


def new_skill_targets(state: LearnerState, batch: Transition, networks, key_next, key_mpo,
                      config: NewSkillConfig, teacher: Optional[SkillMixture] = None) -> NewSkillTargets:
    """TD target with the target policy and the target critics (clipped double Q: their minimum);
    with the MPO mix, samples of π_old = the target policy at s (of the skills' mixture π₀ for
    the kl_reg baseline: the prior is the proposal)."""
    policy, critic = networks
    t_mean_next, t_std_next = policy.apply(state.target_policy_params, batch.next_obs)
    if config.td_target_action == "mean":  # Q'(s', μ'(s')): the deterministic read-out's value
        j, a_next = 1, t_mean_next[:, None]
    else:  # the paper's CRR: a'_j ~ π'(.|s')
        j = config.num_action_samples
        a_next = sample_n(t_mean_next, t_std_next, j, key_next)
    q_next = jnp.min(critic_values(critic, state.target_critic_params, tile_obs(batch.next_obs, j), a_next),
                     axis=-1)  # [B, J]
    y = td_target(batch.reward, batch.discount, q_next, config.discount)
    t_mean = t_std = a_mpo = jnp.zeros((0,))
    if config.mpo_alpha < 1.0 and BASELINE_LOSSES[config.baseline].prior_proposes:  # (no π_old: the prior proposes)
        a_mpo = sample_mixture(teacher.means, teacher.std, key_mpo, config.mpo_num_samples)
    elif uses_gaussian_mpo(config):
        t_mean, t_std = policy.apply(state.target_policy_params, batch.obs)
        a_mpo = sample_n(t_mean, t_std, config.mpo_num_samples, key_mpo)
    return NewSkillTargets(y=y, mpo_mean=t_mean, mpo_std=t_std, mpo_actions=a_mpo)


def uses_gaussian_mpo(config: NewSkillConfig) -> bool:
    """Whether the policy loss has a Gaussian MPO term (weight > 0): the mpo baseline, or dagger
    with dagger_alpha < 1, inside a CRR mix with mpo_alpha < 1 (``BaselineLoss.gaussian_mpo``)."""
    return config.mpo_alpha < 1.0 and BASELINE_LOSSES[config.baseline].gaussian_mpo(config)


def new_skill_loss(params, batch: Transition, targets: NewSkillTargets, networks, key_crr,
                   config: NewSkillConfig, teacher: Optional[SkillMixture] = None) -> Tuple[jax.Array, NewSkillAux]:
    """Critics: Σ_e 0.5·(Q_e(s, a) − y)² over weighted rows. Policy: CRR −f(A)·log π(a|s),
    A = min_e Q_e(s, a) − mean_j min_e Q_e(s, a_j), a_j ~ π(.|s); with mpo_alpha < 1,
    α·CRR + (1 − α)·L_baseline (``baseline_policy_loss``).
    ``params`` = (policy, critic, dual)."""
    policy_params, critic_params, dual_params = params
    policy, critic = networks
    j = config.num_action_samples
    use_mpo = config.mpo_alpha < 1.0
    n_mpo = targets.mpo_actions.shape[1] if targets.mpo_actions.ndim == 3 else 0  # (none for pure DAGGER)
    obs, action, weight = batch.obs, batch.action, batch.weight
    mean, std = policy.apply(policy_params, obs)
    a_j = jax.lax.stop_gradient(sample_n(mean, std, j, key_crr))
    q = critic_values(critic, critic_params, obs, action)  # [B, E]: every critic regresses on the same target
    # The sampled actions' values only feed the (stop-gradient) advantage and MPO weights: evaluated
    # with stop-gradient parameters, so that the backward pass runs on the stored actions' rows alone.
    sampled = jnp.concatenate([a_j] + ([targets.mpo_actions] if n_mpo else []), axis=1)  # [B, J (+ n_mpo), A]
    q_sampled = critic_values(critic, jax.lax.stop_gradient(critic_params), tile_obs(obs, j + n_mpo), sampled)
    q_ens = jnp.concatenate([q[:, None], q_sampled], axis=1)  # [B, 1 + J (+ n_mpo), E]
    critic_loss = masked_mean(jnp.sum(0.5 * jnp.square(q - targets.y[:, None]), axis=-1), weight)
    q_all = jnp.min(q_ens, axis=-1)  # advantages from the clipped (minimum) estimate
    q_sg = jax.lax.stop_gradient(q_all)
    advantage = mean_baseline_advantage(q_sg[:, 0], q_sg[:, 1:1 + j])
    w_crr = crr_weights(advantage, config.crr_mode, config.crr_beta, config.crr_clip)
    loss_crr = crr_policy_loss(gaussian_log_prob(mean, std, action), w_crr, weight)
    mpo_stats: Dict[str, jax.Array] = {}
    if use_mpo:
        loss_baseline, mpo_stats = baseline_policy_loss(mean, std, targets, q_sg[:, 1 + j:], dual_params, weight,
                                                        config, teacher)
        policy_loss = config.mpo_alpha * loss_crr + (1.0 - config.mpo_alpha) * loss_baseline
    else:
        policy_loss = loss_crr
    aux = NewSkillAux(critic_loss=critic_loss, q=q_all[:, 0], advantage=advantage, crr_weight=w_crr, std=std,
                      policy_loss=policy_loss, mpo=mpo_stats)
    return critic_loss + policy_loss, aux


def baseline_policy_loss(mean, std, targets: NewSkillTargets, q_mpo, dual_params, weight, config: NewSkillConfig,
                         teacher: Optional[SkillMixture]) -> Tuple[jax.Array, Dict[str, jax.Array]]:
    """L_baseline of the CRR mix (paper App. B), by ``config.baseline`` (``BASELINE_LOSSES``):

    * "mpo": decoupled Gaussian MPO on samples of π_old (``mpo.gaussian_mpo_loss``);
    * "kl_reg": MPO regularised to the skills' mixture π₀: E-step q ∝ π₀·exp(Q/η) on samples of
      π₀ (the prior is the proposal), KL(q ‖ π₀) ≤ mpo_epsilon, M-step weighted maximum
      likelihood (``baseline_losses.prior_e_step`` / ``kl_reg_mpo_loss``);
    * "dagger": dagger_alpha·(−E_{a~π₀} log π(a|s)) (``baseline_losses.dagger_cross_entropy``, on
      the new skill's own states) + (1 − dagger_alpha)·MPO.

    mean, std [B, A] the online policy; q_mpo [B, n_mpo] Q of ``targets.mpo_actions`` (stop-gradient);
    weight [B]. Returns (loss, stats)."""
    return BASELINE_LOSSES[config.baseline].loss(mean, std, targets, q_mpo, dual_params, weight, config, teacher)


def mpo_baseline_loss(mean, std, targets: NewSkillTargets, q_mpo, dual_params, weight, config: NewSkillConfig,
                      teacher=None) -> Tuple[jax.Array, Dict[str, jax.Array]]:
    """The Gaussian MPO term (zero, no stats, when ``uses_gaussian_mpo`` is False: pure DAGGER)."""
    del teacher
    if not uses_gaussian_mpo(config):  # pure DAGGER (dagger_alpha = 1): no MPO term, no samples
        return jnp.zeros(()), {}
    return gaussian_mpo_loss(
        mean, std, targets.mpo_mean, targets.mpo_std, targets.mpo_actions, q_mpo,
        positive(dual_params.log_temperature), positive(dual_params.log_alpha_mean),
        positive(dual_params.log_alpha_stddev), config.mpo_epsilon, config.mpo_epsilon_mean,
        config.mpo_epsilon_stddev, weight)


def kl_reg_baseline_loss(mean, std, targets: NewSkillTargets, q_mpo, dual_params, weight, config: NewSkillConfig,
                         teacher: SkillMixture) -> Tuple[jax.Array, Dict[str, jax.Array]]:
    """MPO regularised to the skills' mixture π₀ (samples of π₀ in ``targets.mpo_actions``)."""
    temperature = positive(dual_params.log_temperature)
    log_prior = mixture_log_prob(teacher.means, teacher.std, targets.mpo_actions)  # [B, n_mpo]
    weights, loss_temperature = prior_e_step(q_mpo, log_prior, log_prior, temperature, config.mpo_epsilon, weight)
    loss, stats = kl_reg_mpo_loss(mean, std, targets.mpo_actions, weights, weight)
    return loss + loss_temperature, dict(stats, mpo_temperature=temperature)


def dagger_baseline_loss(mean, std, targets: NewSkillTargets, q_mpo, dual_params, weight, config: NewSkillConfig,
                         teacher: SkillMixture) -> Tuple[jax.Array, Dict[str, jax.Array]]:
    """dagger_alpha·(cross-entropy to π₀) + (1 − dagger_alpha)·Gaussian MPO."""
    loss_mpo, stats = mpo_baseline_loss(mean, std, targets, q_mpo, dual_params, weight, config)
    cross_entropy = dagger_cross_entropy(mean, std, teacher.means, teacher.std, weight)
    loss = config.dagger_alpha * cross_entropy + (1.0 - config.dagger_alpha) * loss_mpo
    return loss, dict(stats, dagger_cross_entropy=cross_entropy)


class BaselineLoss(NamedTuple):
    """How one ``NewSkillConfig.baseline`` enters the new skill's loss."""

    prior_proposes: bool  # its MPO samples are the skills' mixture π₀'s (else π_old's)
    gaussian_mpo: Callable[[NewSkillConfig], bool]  # it has a Gaussian MPO term of weight > 0
    loss: Callable  # (mean, std, targets, q_mpo, dual_params, weight, config, teacher) -> (loss, stats)


# (Whether a baseline reads the teacher is config.BASELINE_READS_TEACHER: configs check it.)
BASELINE_LOSSES = {
    "mpo": BaselineLoss(prior_proposes=False, gaussian_mpo=lambda c: True, loss=mpo_baseline_loss),
    "kl_reg": BaselineLoss(prior_proposes=True, gaussian_mpo=lambda c: False, loss=kl_reg_baseline_loss),
    "dagger": BaselineLoss(prior_proposes=False, gaussian_mpo=lambda c: c.dagger_alpha < 1.0,
                           loss=dagger_baseline_loss),
}


def new_skill_stats(aux: NewSkillAux, batch: Transition) -> Dict[str, jax.Array]:
    """Scalars to log of one new-skill update."""
    weight = batch.weight
    stats = dict(
        critic_loss=aux.critic_loss,
        q_mean=masked_mean(aux.q, weight),
        crr_weight_mean=masked_mean(aux.crr_weight, weight),
        policy_log_std_mean=jnp.mean(jnp.log(aux.std)),
        advantage_mean=masked_mean(aux.advantage, weight),
        policy_loss=aux.policy_loss,
    )
    for name in ("mpo_kl_mean", "mpo_kl_std", "mpo_temperature", "kl_reg_ess", "dagger_cross_entropy"):
        if name in aux.mpo:
            stats[name] = aux.mpo[name]
    return stats


def new_skill_learner_update(state: LearnerState, batch: Transition, key: jax.Array, config: NewSkillConfig,
                             teacher: Optional[SkillMixture] = None) -> Tuple[LearnerState, Dict[str, jax.Array]]:
    """One CRR update (± L_baseline with weight 1 − mpo_alpha) on ``batch`` [B]
    (``replay.Transition``: obs, action, reward, discount, next_obs, weight; rows with weight 0
    are ignored). Critics (E = num_critics) regress on one target; clipped double Q for E > 1.
    ``teacher``: the skills at the batch's states, needed by the kl_reg and dagger baselines."""
    if config.reads_teacher and teacher is None:
        raise ValueError(f"new_skill.baseline {config.baseline!r} needs the skills' actions (teacher)")
    batch = as_float32(batch)
    networks = new_skill_networks(batch.action.shape[-1], config)
    k_next, k_crr, k_mpo = jax.random.split(key, 3)
    targets = new_skill_targets(state, batch, networks, k_next, k_mpo, config, teacher)
    grads, aux = jax.grad(lambda p: new_skill_loss(p, batch, targets, networks, k_crr, config, teacher),
                          has_aux=True)((state.policy_params, state.critic_params, state.dual_params))
    new_state = learner_step(state, grads, config, update_duals=config.mpo_alpha < 1.0)
    return new_state, new_skill_stats(aux, batch)
