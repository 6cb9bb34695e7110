"""Acting: the per-env actor state and one env step of the batch — decide where counters expired,
act (frozen skills + the new skill), step the env, auto-reset — and ``collect``, a ``lax.scan`` of
such steps (docs/design.md "Data flow", "Scheduler and counters").

Frozen skills see raw observations; the scheduler and the new skill normalised ones.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax
import jax.numpy as jnp
from flax import struct

from parallel_skills import networks
from parallel_skills import normalization as obs_norm
from parallel_skills.counters import advance_counters
from parallel_skills.replay import Transition
from parallel_skills.skills import SkillSet


@struct.dataclass
class ActorState:
    """Per-env acting state. env_state: batched brax State; c/i/k_idx [B] the running skill's
    counter, index and length index; first [B] whether the next step must be a decision (an
    episode starts, or the physics restarted the env: ``info["nan_reset"]``);
    ep_return / ep_success [B] of the running episode."""

    env_state: Any
    c: jax.Array
    i: jax.Array
    k_idx: jax.Array
    first: jax.Array
    ep_return: jax.Array
    ep_success: jax.Array


@struct.dataclass
class StepStats:
    """What an acting step reports besides its ``Transition`` (each [B]; skill_runs [B, N+1])."""

    done: jax.Array  # the episode ended at this step (termination, truncation, non-finite)
    ep_return: jax.Array  # the episode's return so far, this step included
    ep_success: jax.Array  # whether its success test held at some step so far
    nonfinite: jax.Array  # 1.0 where the env returned a non-finite observation or reward
    new_skill_active: jax.Array  # 1.0 where the new skill acted
    skill_runs: jax.Array  # runs of consecutive execution that ended here, per skill
    entropy_i: jax.Array  # entropy of the scheduler's π(i | s) at this step's state (read at decisions)
    entropy_k: jax.Array  # entropy of its π(k | s)


def skill_run_ends(i_prev, first_prev, i, is_decision, done, num_skills: int):
    """Maximal consecutive runs of one skill that end at an acting step, as counts per skill
    [..., num_skills] (for usage plots: average consecutive execution = skill steps / runs).

    A run goes on across decisions that choose the same skill again. It ends at an episode end
    (``done``: the run of ``i``, the skill that acted at this step) or when a decision switches
    skill (the run of ``i_prev`` ended at the previous step; counted at this step).
    ``first_prev``: this step starts an episode, so no run of ``i_prev`` goes on into it.
    """
    switched = is_decision & ~first_prev & (i != i_prev)
    return (jax.nn.one_hot(i, num_skills) * done[..., None].astype(jnp.float32)
            + jax.nn.one_hot(i_prev, num_skills) * switched[..., None].astype(jnp.float32))


def _finite(x):
    return jnp.all(jnp.isfinite(x.reshape(x.shape[0], -1)), axis=-1)


@dataclasses.dataclass(frozen=True)
class Actor:
    """The acting functions of B envs of ``env`` with frozen ``skill_set`` + the new skill (index
    N = ``skill_set.num_skills``). ``scheduler_apply(params, obs) -> (logits_i, logits_k)``,
    ``new_skill_apply(params, obs) -> (mean, std)``. ``scheduler_acts`` False: the new skill
    always acts (training from scratch). ``greedy_envs``: the first that many envs act greedily even
    when collecting (argmax decisions, the new skill's mean, no collection noise; Ape-X-style
    exploration levels per actor, ``TrainConfig.greedy_env_fraction``); 0: all explore (the paper).
    ``new_skill_collects_mean``: the new skill acts with its mean action when not greedy too
    (``TrainConfig.new_skill_collects``); False: sampled from its Gaussian (the paper)."""

    env: Any
    skill_set: SkillSet
    scheduler_apply: Callable
    new_skill_apply: Callable
    skill_lengths: tuple
    num_envs: int
    skill_noise_std: float
    scheduler_acts: bool = True
    greedy_envs: int = 0
    new_skill_collects_mean: bool = False

    @property
    def new_index(self) -> int:
        return self.skill_set.num_frozen

    @property
    def num_skills_total(self) -> int:
        return self.new_index + 1

    def reset(self, key) -> ActorState:
        """Fresh episodes in all B envs; every env decides at its first step."""
        env_state = jax.vmap(self.env.reset)(jax.random.split(key, self.num_envs))
        zi = jnp.zeros((self.num_envs,), jnp.int32)
        b = self.num_envs
        return ActorState(env_state, zi, zi, zi, jnp.ones((b,), bool), jnp.zeros((b,)), jnp.zeros((b,)))

    def greedy_mask(self):
        """[B] bool: the envs that act greedily while collecting (the first ``greedy_envs``)."""
        return jnp.arange(self.num_envs) < self.greedy_envs

    def decide(self, actor: ActorState, logits_i, logits_k, k_i, k_k, greedy: bool):
        """Sample z = (i, k) for every env (argmax where greedy), used where its counter expired
        (or an episode starts): the counters of paper App. A.1. Returns (c, i, k_idx, is_decision), each [B]."""
        if greedy:
            i_new, k_new = jnp.argmax(logits_i, -1), jnp.argmax(logits_k, -1)
        else:
            i_new = jax.random.categorical(k_i, logits_i)
            k_new = jax.random.categorical(k_k, logits_k)
            if self.greedy_envs:
                mask = self.greedy_mask()
                i_new = jnp.where(mask, jnp.argmax(logits_i, -1), i_new)
                k_new = jnp.where(mask, jnp.argmax(logits_k, -1), k_new)
        if not self.scheduler_acts:  # from scratch: the new skill always acts
            i_new = jnp.full_like(i_new, self.new_index)
        return advance_counters(actor.c, actor.i, actor.k_idx, i_new.astype(jnp.int32), k_new.astype(jnp.int32),
                                actor.first, self.skill_lengths)

    def actions(self, obs, nobs, new_params, i, k_a, k_s, greedy: bool, new_skill_sampled: bool | None = None):
        """Each env's action [B, A] from its running skill i [B]; collection noise (not greedy) on
        the frozen skills' actions, those whose ``Skill.collection_noise`` is set. The new skill's
        action is sampled from its Gaussian unless greedy or ``new_skill_collects_mean`` (then its
        mean); ``new_skill_sampled`` overrides that choice (the greedy scheduler with the new skill
        sampled). The ``greedy_envs`` act as greedy in any case."""
        mean, std = self.new_skill_apply(new_params, nobs)
        sampled = (not greedy and not self.new_skill_collects_mean) if new_skill_sampled is None \
            else bool(new_skill_sampled)
        new_action = networks.sample_action(mean, std, k_a) if sampled else networks.deterministic_action(mean)
        explores = ~self.greedy_mask() if (self.greedy_envs and not greedy) else None  # [B]
        if explores is not None and sampled:
            new_action = jnp.where(explores[:, None], new_action, networks.deterministic_action(mean))
        action = self.skill_set.actions(new_action, obs, i, k_s)
        if self.skill_noise_std > 0 and not greedy:
            noise = self.skill_noise_std * jax.random.normal(jax.random.fold_in(k_s, 1), action.shape)
            noisy = jnp.asarray(self.skill_set.collection_noise)[i]  # [B]; False for the new skill
            if explores is not None:
                noisy = noisy & explores
            action = jnp.where(noisy[:, None], jnp.clip(action + noise, -1.0, 1.0), action)
        return action

    def step(self, actor: ActorState, scheduler_params, new_params, normalizer, key, greedy: bool = False,
             new_skill_sampled: bool | None = None):
        """One env step of the batch: decide, act, step, auto-reset. ``greedy``: argmax decisions,
        no collection noise, the new skill's mean action (``new_skill_sampled`` True: its samples).
        Returns (actor, Transition [B], StepStats [B])."""
        k_i, k_k, k_a, k_s, k_r = jax.random.split(key, 5)
        obs = actor.env_state.obs
        nobs = obs_norm.normalize(normalizer, obs)
        logits_i, logits_k = self.scheduler_apply(scheduler_params, nobs)
        c, i, k_idx, is_decision = self.decide(actor, logits_i, logits_k, k_i, k_k, greedy)
        action = self.actions(obs, nobs, new_params, i, k_a, k_s, greedy, new_skill_sampled)
        nxt = jax.vmap(self.env.step)(actor.env_state, action)
        finite = _finite(nxt.obs) & jnp.isfinite(nxt.reward)
        done = (nxt.done > 0) | ~finite
        # A physics backend that restarted a blown-up env in place (info["nan_reset"]): the step
        # leads from a broken state to a fresh one. Never learnt from; the scheduler decides anew.
        nan_reset = nxt.info.get("nan_reset", jnp.zeros_like(nxt.reward)) > 0
        # Envs without a time limit of their own: wrap them (e.g. brax's EpisodeWrapper).
        truncation = nxt.info.get("truncation", jnp.zeros_like(nxt.done)) > 0
        reward = jnp.where(finite, nxt.reward, 0.0)
        transition = Transition(
            obs=obs, action=action, reward=reward,
            # Time-limit truncation bootstraps from the true last observation; termination does not.
            discount=jnp.where((nxt.done > 0) & ~truncation, 0.0, 1.0).astype(jnp.float32),
            next_obs=jnp.where(finite[:, None], nxt.obs, 0.0), skill=i, k_idx=k_idx, c=c,
            is_decision=is_decision, weight=(finite & ~nan_reset).astype(jnp.float32))
        ep_return = actor.ep_return + reward
        ep_success = jnp.maximum(actor.ep_success, nxt.metrics.get("success", jnp.zeros_like(nxt.reward)))
        stats = StepStats(
            done=done, ep_return=ep_return, ep_success=ep_success, nonfinite=(~finite).astype(jnp.float32),
            new_skill_active=(i == self.new_index).astype(jnp.float32),
            skill_runs=skill_run_ends(actor.i, actor.first, i, is_decision, done, self.num_skills_total),
            entropy_i=networks.categorical_entropy(logits_i), entropy_k=networks.categorical_entropy(logits_k))
        env_state = self.auto_reset(nxt, done, k_r)
        actor = ActorState(env_state=env_state, c=c, i=i, k_idx=k_idx, first=done | nan_reset,
                           ep_return=jnp.where(done, 0.0, ep_return), ep_success=jnp.where(done, 0.0, ep_success))
        return actor, transition, stats

    def auto_reset(self, env_state, done, key):
        """``env_state`` with fresh episodes where ``done`` [B] (reset only when some env is done)."""
        def do_reset(_):
            fresh = jax.vmap(self.env.reset)(jax.random.split(key, self.num_envs))
            return jax.tree.map(
                lambda f, n: jnp.where(done.reshape(done.shape + (1,) * (n.ndim - 1)), f, n), fresh, env_state)

        return jax.lax.cond(jnp.any(done), do_reset, lambda _: env_state, None)

    def collect(self, actor: ActorState, scheduler_params, new_params, normalizer, key, unroll_length: int):
        """``unroll_length`` = T steps of the B envs (``lax.scan``).
        Returns (actor, Transition [T, B], StepStats [T, B])."""
        def body(a, k):
            a, tr, st = self.step(a, scheduler_params, new_params, normalizer, k)
            return a, (tr, st)

        actor, (traj, stats) = jax.lax.scan(body, actor, jax.random.split(key, unroll_length))
        return actor, traj, stats
