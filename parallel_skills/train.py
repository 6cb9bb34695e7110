"""SkillS training: one jitted iteration = collect (``acting``) → insert (``replay``) → learner
updates (``learners``, each a ``lax.scan``), and the host loop around it (docs/design.md "Data flow").

Brax-style entry point::

    make_policy, params, metrics = parallel_skills.train(
        env, skills, num_timesteps=..., num_envs=..., episode_length=..., seed=0, config=TrainConfig())

``init(key)`` and ``iteration(state)`` are pure functions of their inputs (``make_trainer``), so a
whole run is a pure function of the seed: ``jax.vmap`` over seeds works, and nothing assumes a
single device (the env batch axis is a plain leading axis that can be sharded).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from typing import Any, Callable, NamedTuple, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from parallel_skills import crr, learners, methods, networks, sharding
from parallel_skills import normalization as obs_norm
from parallel_skills.acting import Actor, ActorState, StepStats
from parallel_skills.config import RunConfig, TrainConfig, resolve, updates_per_iteration
from parallel_skills.evaluation import rollout_episodes
from parallel_skills.replay import PendingStep, Replay, Transition
from parallel_skills.rhpo import rhpo_learner_update
from parallel_skills.skills import GaussianSkillParams, Skill, SkillSet

log = logging.getLogger("parallel_skills")


@struct.dataclass
class TrainingState:
    """Everything a run carries from one iteration to the next (checkpointed whole)."""

    scheduler: learners.LearnerState
    new_skill: learners.LearnerState
    replay: Any  # flashbax buffer state of replay.Transition rows
    actor: ActorState
    normalizer: obs_norm.RunningStats
    key: jax.Array
    env_steps: jax.Array
    iteration: jax.Array
    # new_skill.n_step > 1: the last n − 1 collected steps of every env, inserted with the next
    # unroll once their n-step returns are known (``Replay.insert``). None for 1-step runs (their
    # checkpoints keep their structure).
    pending: Optional[PendingStep] = None


@struct.dataclass
class TrainedParams:
    """What ``train`` returns of a run's networks: the new skill's (its deployed policy: the moving
    average where ``NewSkillConfig.policy_ema`` keeps one) and the scheduler's policy variables
    (flax) and the observation statistics both normalise with."""

    new_skill: Any
    scheduler: Any
    normalizer: obs_norm.RunningStats

    @classmethod
    def of(cls, state: "TrainingState") -> "TrainedParams":
        return cls(new_skill=state.new_skill.deployed_policy_params, scheduler=state.scheduler.policy_params,
                   normalizer=state.normalizer)

    def new_skill_params(self) -> GaussianSkillParams:
        """The new skill as a Gaussian-MLP skill's parameters (``Skill.gaussian_mlp``)."""
        return GaussianSkillParams.from_normalizer(self.new_skill, self.normalizer)


@dataclasses.dataclass(frozen=True)
class Trainer:
    """Pure functions of a configured run (see ``make_trainer``)."""

    init: Callable[[jax.Array], TrainingState]
    iteration: Callable[[TrainingState], tuple]  # iteration(state) -> (state, metrics)
    collect_insert: Callable  # collect_insert(state, key) -> (state, Transition [T, B], StepStats [T, B])
    learn: Callable  # learn(state, key) -> (scheduler state, new-skill state, metrics, metrics)
    actor: Actor  # the acting functions (reset, step, collect) of the run's B envs
    replay: Replay
    config: TrainConfig
    skills: tuple
    num_skills_total: int
    scheduler_updates: int
    new_skill_updates: int
    steps_per_iteration: int


def make_actor(environment, skills: Sequence[Skill], config: TrainConfig, num_envs: int,
               collecting: bool = False) -> Actor:
    """The acting functions of ``num_envs`` envs (``skills``: the frozen ones; none from scratch).
    The scheduler chooses when the method says so (``Method.scheduler_acts``: SkillS's scheduler,
    RHPO's categorical, a scheduler with K = {1}); otherwise the new skill always acts.
    ``collecting``: the training envs, of which ``config.greedy_env_fraction`` act greedily (the
    evaluations' actors act as each evaluation says)."""
    n_total = len(skills) + 1  # frozen skills + the new skill (index N)
    return Actor(env=environment, skill_set=SkillSet(skills),
                 scheduler_apply=learners.make_scheduler_apply(n_total, config.scheduler),
                 new_skill_apply=learners.make_new_skill_apply(int(environment.action_size), config.new_skill),
                 skill_lengths=tuple(config.scheduler.skill_lengths), num_envs=int(num_envs),
                 skill_noise_std=config.skill_noise_std, scheduler_acts=methods.get(config.method).scheduler_acts,
                 greedy_envs=greedy_env_count(config.greedy_env_fraction, num_envs) if collecting else 0,
                 new_skill_collects_mean=config.new_skill_collects == "mean")


def greedy_env_count(fraction: float, num_envs: int) -> int:
    """The envs of a batch of ``num_envs`` that collect greedily: round(fraction · num_envs)."""
    return int(round(float(fraction) * int(num_envs)))


def make_replay(environment, config: TrainConfig, num_skills: int) -> Replay:
    """The run's replay; ``num_skills``: the frozen skills N (the new skill's index in
    ``Transition.skill``, which ``NewSkillConfig.n_step_returns`` "own" reads)."""
    sc, nc = config.scheduler, config.new_skill
    capacity = max(int(config.replay_size), config.steps_per_iteration, sc.batch_size, nc.batch_size)
    # (The scheduler's n-step rows only where its learner runs: SkillS.)
    sched_n = int(sc.n_step) if methods.get(config.method).learns_scheduler else 1
    return Replay(capacity=capacity, num_envs=int(config.num_envs), obs_size=int(environment.observation_size),
                  action_size=int(environment.action_size), scheduler_batch_size=sc.batch_size,
                  new_skill_batch_size=nc.batch_size, n_step=int(nc.n_step), discount=nc.discount,
                  scheduler_n_step=sched_n, scheduler_discount=sc.discount,
                  skill_lengths=tuple(sc.skill_lengths), augmentation=bool(sc.augmentation),
                  own_returns_index=int(num_skills) if nc.n_step_returns == "own" else None)


def run_learner(update, sample, config, state, key, num_updates: int, ready):
    """``num_updates`` updates of one learner in a ``lax.scan`` when ``ready`` (else none, zero
    metrics): each samples its batch with ``sample(key)``. Returns (state, the last update's metrics)."""
    def body(s, k):
        k1, k2 = jax.random.split(k)
        return update(s, sample(k1), k2, config)

    def run(s):
        s, m = jax.lax.scan(body, s, jax.random.split(key, num_updates))
        return s, jax.tree.map(lambda x: x[-1], m)

    zero = jax.tree.map(jnp.zeros_like, jax.eval_shape(run, state)[1])
    return jax.lax.cond(ready, run, lambda s: (s, zero), state)


def iteration_metrics(traj: Transition, stats: StepStats, num_skills_total: int, num_lengths: int) -> dict:
    """Training-episode and acting statistics of one unroll (traj, stats: [T, B])."""
    done = stats.done.astype(jnp.float32)
    n_done = jnp.sum(done)
    dec = traj.is_decision.astype(jnp.float32)
    return {
        "reward_mean": jnp.mean(traj.reward),
        "episodes": n_done,
        "episode_return": jnp.sum(stats.ep_return * done) / jnp.maximum(n_done, 1.0),
        "episode_success": jnp.sum(stats.ep_success * done) / jnp.maximum(n_done, 1.0),
        "new_skill_selection_rate": jnp.mean(stats.new_skill_active),
        "nonfinite_transitions": jnp.sum(stats.nonfinite),
        "skill_histogram": jnp.sum(jax.nn.one_hot(traj.skill, num_skills_total) * dec[..., None], axis=(0, 1)),
        "length_histogram": jnp.sum(jax.nn.one_hot(traj.k_idx, num_lengths) * dec[..., None], axis=(0, 1)),
        # Steps each skill acted (for usage plots: average consecutive execution per skill).
        "skill_steps": jnp.sum(jax.nn.one_hot(traj.skill, num_skills_total), axis=(0, 1)),
        # Maximal consecutive runs of each skill that ended (skill_steps / skill_runs = the
        # average consecutive execution, paper Fig. 4c).
        "skill_runs": jnp.sum(stats.skill_runs, axis=(0, 1)),
        # Entropies of the scheduler's π(i | s) and π(k | s), summed over the decisions taken
        # (``EpisodeAccumulator.summary``: their means per decision, decision_entropy_i / _k).
        "entropy_i_sum": jnp.sum(stats.entropy_i * dec),
        "entropy_k_sum": jnp.sum(stats.entropy_k * dec),
    }


def make_trainer(environment, skills: Sequence[Skill], config: TrainConfig, mesh=None) -> Trainer:
    """Build the pure ``init`` / ``iteration`` functions for ``environment`` and frozen ``skills``.

    ``mesh`` (``sharding.make_mesh``, more than one device): the iteration constrains the actor
    state to be split along its env axis and every learner batch along its rows (the parameters
    stay replicated); with ``sharding.state_shardings`` as the jit's in / out shardings it runs data
    parallel over the mesh's devices and computes what it computes on one device."""
    if config.num_envs is None or config.replay_size is None:
        raise ValueError("make_trainer needs a resolved config (see parallel_skills.config.resolve)")
    method = methods.get(config.method)
    initial_skill = finetune_source(skills, config) if method.starts_from_skill else None
    skills = list(skills) if method.frozen_skills else []
    n_total = len(skills) + 1  # frozen skills + the new skill (index N)
    sc, nc = config.scheduler, config.new_skill
    obs_size, action_size = int(environment.observation_size), int(environment.action_size)
    learn_scheduler = method.learns_scheduler
    steps_per_iter = config.steps_per_iteration
    n_sched = updates_per_iteration(sc.samples_per_insert, steps_per_iter, sc.batch_size)
    n_new = updates_per_iteration(nc.samples_per_insert, steps_per_iter, nc.batch_size)
    actor = make_actor(environment, skills, config, config.num_envs, collecting=True)
    replay = make_replay(environment, config, len(skills))

    # A teacher baseline (kl_reg / dagger): the new skill's loss reads the frozen skills' actions at
    # its batch's states; the mixture learner (rhpo) at its states and next states (the components).
    rhpo = method.mixture_learner
    with_teacher = nc.reads_teacher
    if rhpo and not skills:
        raise ValueError(f"method {method.name} needs at least one frozen skill (its mixture's components)")
    if mesh is not None and mesh.size > 1:
        sharding.check_divisible(config, mesh.size)
        envs = lambda tree: sharding.constrain(tree, mesh, config.num_envs)  # noqa: E731
        rows = lambda sample, n: (lambda k: sharding.constrain(sample(k), mesh, n))  # noqa: E731
    else:
        envs = lambda tree: tree  # noqa: E731
        rows = lambda sample, n: sample  # noqa: E731

    def init(key) -> TrainingState:
        k_s, k_n, k_e, k_run = jax.random.split(key, 4)
        new_skill = learners.new_skill_learner_init(k_n, obs_size, action_size, nc)
        normalizer = obs_norm.init(obs_size)
        if initial_skill is not None:
            new_skill, normalizer = start_from_skill(new_skill, initial_skill)
        return TrainingState(
            scheduler=learners.scheduler_learner_init(k_s, obs_size, n_total, sc), new_skill=new_skill,
            replay=replay.init(), actor=actor.reset(k_e), normalizer=normalizer, key=k_run,
            env_steps=jnp.zeros((), jnp.int32), iteration=jnp.zeros((), jnp.int32), pending=replay.init_pending())

    def collect_insert(ts: TrainingState, key):
        """Acting half of an iteration: T steps of the B envs, inserted into the replay."""
        actor_state, traj, stats = actor.collect(envs(ts.actor), ts.scheduler.policy_params,
                                                 ts.new_skill.policy_params, ts.normalizer, key, config.unroll_length)
        actor_state = envs(actor_state)
        replay_state, pending = replay.insert(ts.replay, ts.pending, traj, stats.done)
        flat = lambda x: x.reshape((-1,) + x.shape[2:])  # noqa: E731  [T, B, ...] -> [T·B, ...]
        normalizer = ts.normalizer
        if initial_skill is None:  # (fine-tuning keeps the skill's own statistics)
            normalizer = obs_norm.update(normalizer, flat(traj.obs), flat(traj.weight))  # this unroll's steps
        return ts.replace(replay=replay_state, actor=actor_state, normalizer=normalizer, pending=pending), traj, stats

    def sample_new_skill(ts: TrainingState, key):
        """A new-skill batch, and with a teacher the skills' actions at its states (raw observations)."""
        if not with_teacher:
            return replay.sample_new_skill(ts.replay, ts.normalizer, key), None
        k_rows, k_skills = jax.random.split(key)
        batch, (raw_obs, _) = replay.sample_new_skill(ts.replay, ts.normalizer, k_rows, raw_obs=True)
        return batch, skill_mixture(raw_obs, k_skills)

    def new_skill_update(state, batch_teacher, key, cfg):
        batch, teacher = batch_teacher
        return learners.new_skill_learner_update(state, batch, key, cfg, teacher)

    def skill_mixture(raw_obs, key):
        means = jnp.swapaxes(actor.skill_set.frozen_actions(raw_obs, key), 0, 1)  # [B, N, A]
        return learners.SkillMixture(means=means, std=jnp.asarray(config.skill_noise_std, jnp.float32))

    def sample_rhpo(ts: TrainingState, key):
        k_rows, k_obs, k_next = jax.random.split(key, 3)
        batch, (raw_obs, raw_next) = replay.sample_new_skill(ts.replay, ts.normalizer, k_rows, raw_obs=True)
        return batch, skill_mixture(raw_obs, k_obs), skill_mixture(raw_next, k_next)

    def rhpo_update(states, batch_skills, key, cfg):
        batch, skills_now, skills_next = batch_skills
        cat_state, comp_state, stats = rhpo_learner_update(*states, batch, skills_now, skills_next, key, sc, cfg)
        return (cat_state, comp_state), stats

    def learn(ts: TrainingState, key):
        """Learning half: both learners' updates on batches sampled from the replay."""
        k_s, k_n = jax.random.split(key)
        size = replay.size(ts.replay)
        if rhpo:  # one update trains the categorical (the scheduler's policy) and the component
            (sched_state, new_state), new_m = run_learner(
                rhpo_update, rows(lambda k: sample_rhpo(ts, k), nc.batch_size), nc, (ts.scheduler, ts.new_skill),
                k_n, n_new, size >= nc.min_replay_size)
            return sched_state, new_state, {}, new_m
        sched_state, sched_m = run_learner(
            learners.scheduler_learner_update,
            rows(lambda k: replay.sample_scheduler(ts.replay, ts.normalizer, k), sc.batch_size), sc, ts.scheduler,
            k_s, n_sched, learn_scheduler & (size >= sc.min_replay_size))
        new_state, new_m = run_learner(new_skill_update, rows(lambda k: sample_new_skill(ts, k), nc.batch_size), nc,
                                       ts.new_skill, k_n, n_new, size >= nc.min_replay_size)
        return sched_state, new_state, sched_m, new_m

    def iteration(ts: TrainingState):
        key, k_collect, k_learn = jax.random.split(ts.key, 3)
        ts, traj, stats = collect_insert(ts, k_collect)
        sched_state, new_state, sched_m, new_m = learn(ts, k_learn)
        metrics = iteration_metrics(traj, stats, n_total, sc.num_lengths)
        metrics.update({f"scheduler/{k}": v for k, v in sched_m.items()})
        metrics.update({f"new_skill/{k}": v for k, v in new_m.items()})
        ts = ts.replace(scheduler=sched_state, new_skill=new_state, key=key,
                        env_steps=ts.env_steps + steps_per_iter, iteration=ts.iteration + 1)
        return ts, metrics

    return Trainer(init=init, iteration=iteration, collect_insert=collect_insert, learn=learn, actor=actor,
                   replay=replay, config=config, skills=tuple(skills), num_skills_total=n_total,
                   scheduler_updates=n_sched if learn_scheduler else 0, new_skill_updates=n_new,
                   steps_per_iteration=steps_per_iter)


def finetune_source(skills: Sequence[Skill], config: TrainConfig) -> Skill:
    """The one skill ``method="finetune"`` starts the new skill from: a Gaussian-MLP skill (as
    ``Skill.load`` gives) with the new skill's network sizes. ValueError (one line) otherwise."""
    skills = list(skills)
    if len(skills) != 1:
        raise ValueError(f"method finetune starts from exactly one skill, got {len(skills)}")
    s = skills[0]
    hidden = s.metadata.get("hidden")
    if not isinstance(s.params, GaussianSkillParams) or hidden is None:
        raise ValueError(f"method finetune needs a network skill (e.g. from the library), {s.name!r} has no "
                         "network parameters (scripted skills are code)")
    if tuple(int(h) for h in hidden) != tuple(config.new_skill.hidden):
        raise ValueError(f"skill {s.name!r} has hidden sizes {tuple(hidden)}, the new skill "
                         f"{tuple(config.new_skill.hidden)}: set new_skill.hidden to fine-tune it")
    return s


def start_from_skill(new_skill: learners.LearnerState, skill: Skill):
    """The new skill's learner state with ``skill``'s policy as online and target policy, and the
    skill's observation statistics as the normaliser (the critic starts fresh). Returns
    (learner state, normaliser)."""
    policy = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), skill.params.policy)
    mean = jnp.asarray(skill.params.obs_mean, jnp.float32)
    std = jnp.asarray(skill.params.obs_std, jnp.float32)
    # count 1 and m2 = std²: normalize() reproduces (obs − mean) / std exactly (std ≥ STD_FLOOR).
    normalizer = obs_norm.RunningStats(count=jnp.ones(()), mean=mean, m2=jnp.square(std))
    ema = None if new_skill.ema_policy_params is None else policy
    return new_skill.replace(policy_params=policy, target_policy_params=policy, ema_policy_params=ema), normalizer


def make_policy_factory(action_size: int, config: TrainConfig, num_skills_total: int):
    """``make_policy(params, which="new_skill" | "scheduler", deterministic=True)``.

    ``which="new_skill"``: ``policy(obs [O], key) -> action [A]`` (Gaussian mean, or a sample).
    ``which="scheduler"``: ``policy(obs [O], key) -> z [2] = (skill index i, length k)``, the
    scheduler's own action (argmax, or a sample); executing z needs the skills and a counter,
    see ``evaluate_scheduler``.
    """
    new_apply = learners.make_new_skill_apply(action_size, config.new_skill)
    sched_apply = learners.make_scheduler_apply(num_skills_total, config.scheduler)
    lengths = jnp.asarray(config.scheduler.skill_lengths, jnp.int32)

    def make_policy(params: TrainedParams, which: str = "new_skill", deterministic: bool = True):
        stats = params.normalizer
        if which == "new_skill":
            p = params.new_skill

            def policy(obs, key):
                mean, std = new_apply(p, obs_norm.normalize(stats, obs))
                return mean if deterministic else networks.sample_action(mean, std, key)

            return policy
        if which == "scheduler":
            p = params.scheduler

            def policy(obs, key):
                li, lk = sched_apply(p, obs_norm.normalize(stats, obs))
                if deterministic:
                    i, k = jnp.argmax(li), jnp.argmax(lk)
                else:
                    k1, k2 = jax.random.split(key)
                    i, k = jax.random.categorical(k1, li), jax.random.categorical(k2, lk)
                return jnp.stack([i, lengths[k]])

            return policy
        raise ValueError(f"which must be 'new_skill' or 'scheduler', got {which!r}")

    return make_policy


class Evaluators(NamedTuple):
    """The jitted whole-episode evaluations of ``make_evaluators``; each returns a dict of
    per-episode arrays [num_episodes] (``return``, ``success``, ...)."""

    new_skill: Callable  # (new_params, normalizer, key): the new skill alone, mean actions
    new_skill_sampled: Callable  # (new_params, normalizer, key): the same, actions sampled from π_N
    new_skill_critic_weighted: Callable  # (new_params, critic_params, normalizer, key): the best of
    # crr.CRITIC_WEIGHTED_CANDIDATES actions by its critic (``crr.critic_weighted_action``)
    scheduler: Callable  # (sched_params, new_params, normalizer, key): greedy decisions
    scheduler_new_skill_sampled: Callable  # the same, the new skill's actions sampled from π_N
    scheduler_sampled: Callable  # (sched_params, critic_params, new_params, normalizer, key)


def make_evaluators(env, trainer: Trainer, num_episodes: int, episode_length: int, mesh=None) -> Evaluators:
    """Jitted whole-episode evaluations of the new skill alone and of the scheduler alone
    (paper App. C.3): ``new_skill(new_params, normalizer, key)`` acts with the new skill's mean
    action (the deterministic policy ``training.evaluate`` and the export run);
    ``new_skill_sampled`` with actions sampled from its Gaussian, as it acts when the scheduler
    picks it during collection; ``new_skill_critic_weighted(new_params, critic_params, normalizer,
    key)`` with the action its own critic values highest of the mean and samples from its Gaussian
    (``crr.critic_weighted_action``); ``scheduler(sched_params, new_params, normalizer, key)`` acts
    greedily (argmax z) with its counters, through the run's acting step (``Actor.step``) on
    ``num_episodes`` envs, the frozen skills without collection noise and the new skill's mean action;
    ``scheduler_new_skill_sampled`` (same arguments) the same greedy decisions with the new skill's
    actions sampled, as when the scheduler's critic learnt its values; ``scheduler_sampled(sched_params,
    critic_params, new_params, normalizer, key)`` runs it as it collects (sampled, with the collection noise) and adds
    ``discounted_return`` and its critic's ``value_at_reset`` per episode. Each returns a dict of
    per-episode ``return`` / ``success`` [num_episodes]."""
    new_apply = learners.make_new_skill_apply(int(env.action_size), trainer.config.new_skill)
    actor = make_actor(env, trainer.skills, trainer.config, num_episodes)

    def new_skill_evaluation(act):  # act: networks.deterministic_action or networks.sample_action
        def evaluate(new_params, normalizer, key):
            def policy(obs, k):
                mean, std = new_apply(new_params, obs_norm.normalize(normalizer, obs))
                return act(mean, std, k)

            return rollout_episodes(env, policy, key, num_episodes, episode_length)

        return evaluate

    _, new_critic = learners.new_skill_networks(int(env.action_size), trainer.config.new_skill)

    def eval_new_skill_critic_weighted(new_params, critic_params, normalizer, key):
        def policy(obs, k):
            x = obs_norm.normalize(normalizer, obs)
            mean, std = new_apply(new_params, x)
            score = lambda a: jnp.min(learners.critic_values(  # noqa: E731 - actions [M, A] -> [M]
                new_critic, critic_params, jnp.broadcast_to(x, a.shape[:-1] + x.shape), a), axis=-1)
            return crr.critic_weighted_action(mean, std, score, k, crr.CRITIC_WEIGHTED_CANDIDATES)

        return rollout_episodes(env, policy, key, num_episodes, episode_length)

    def scheduler_evaluation(new_skill_sampled: bool):
        def evaluate(sched_params, new_params, normalizer, key):
            k0, k1 = jax.random.split(key)

            def body(carry, k):
                state, ret, succ = carry
                state, tr, st = actor.step(state, sched_params, new_params, normalizer, k, greedy=True,
                                           new_skill_sampled=new_skill_sampled)
                return (state, ret + tr.reward, jnp.maximum(succ, st.ep_success)), None

            z = jnp.zeros(num_episodes)
            (_, ret, succ), _ = jax.lax.scan(body, (actor.reset(k0), z, z), jax.random.split(k1, episode_length))
            return {"return": ret, "success": succ}

        return evaluate

    def eval_scheduler_sampled(sched_params, critic_params, new_params, normalizer, key):
        """The scheduler as it collects (sampled decisions, collection noise, the new skill as
        ``TrainConfig.new_skill_collects`` says): per episode return, success, the discounted return Σ_t γ^t r_t of the
        first episode and the scheduler critic's value V(s_0) at its reset state."""
        k0, k1 = jax.random.split(key)
        gamma = trainer.config.scheduler.discount
        start = actor.reset(k0)
        value = learners.scheduler_state_values(sched_params, critic_params,
                                                obs_norm.normalize(normalizer, start.env_state.obs),
                                                trainer.num_skills_total, trainer.config.scheduler)

        def body(carry, k):
            state, ret, succ, disc_ret, scale = carry
            state, tr, st = actor.step(state, sched_params, new_params, normalizer, k, greedy=False)
            return (state, ret + tr.reward, jnp.maximum(succ, st.ep_success), disc_ret + scale * tr.reward,
                    jnp.where(st.done, 0.0, scale * gamma)), None

        z = jnp.zeros(num_episodes)
        (_, ret, succ, disc_ret, _), _ = jax.lax.scan(body, (start, z, z, z, jnp.ones(num_episodes)),
                                                      jax.random.split(k1, episode_length))
        return {"return": ret, "success": succ, "discounted_return": disc_ret, "value_at_reset": value}

    mean_action = lambda mean, std, k: networks.deterministic_action(mean, std)  # noqa: E731
    return Evaluators(new_skill=jax.jit(new_skill_evaluation(mean_action)),
                      new_skill_sampled=jax.jit(new_skill_evaluation(networks.sample_action)),
                      new_skill_critic_weighted=jax.jit(eval_new_skill_critic_weighted),
                      scheduler=jax.jit(scheduler_evaluation(False)),
                      scheduler_new_skill_sampled=jax.jit(scheduler_evaluation(True)),
                      scheduler_sampled=jax.jit(eval_scheduler_sampled))


def _checked_config(environment, skills, config: TrainConfig, num_timesteps, num_envs, checkpoint_every,
                    auto_config: bool) -> TrainConfig:
    """``config`` with ``num_envs`` set and (``auto_config``) the device's defaults filled; ValueError
    for bad arguments (one line; the values are checked by ``RunConfig`` and ``TrainConfig``)."""
    RunConfig(num_timesteps=num_timesteps, checkpoint_every=checkpoint_every)
    if num_envs is not None:
        config = dataclasses.replace(config, num_envs=num_envs)
    if auto_config:
        config, notes = resolve(config)
        if notes:
            log.warning("defaults chosen automatically: %s", ", ".join(notes))
    elif config.num_envs is None or config.replay_size is None:
        raise ValueError("auto_config=False needs a resolved config (num_envs and replay_size set): see resolve()")
    for s in skills:
        s_obs = s.metadata.get("obs_size")
        if s_obs is not None and int(s_obs) != int(environment.observation_size):
            raise ValueError(f"skill {s.name!r} expects observations of size {s_obs}, the env gives "
                             f"{environment.observation_size}")
    return config


def _checkpoint_due(it: int, steps_per_iteration: int, checkpoint_every, evaluated: bool, last: bool) -> bool:
    """After iteration ``it`` (0-based): the last one, or env steps crossed a multiple of
    ``checkpoint_every`` (None: at every evaluation)."""
    if last or checkpoint_every is None:
        return last or evaluated
    every = int(checkpoint_every)
    return (it + 1) * steps_per_iteration // every > it * steps_per_iteration // every


def train(
    environment,
    skills: Sequence[Skill],
    *,
    num_timesteps: int,
    num_envs: Optional[int] = None,
    episode_length: Optional[int] = None,
    seed: int = 0,
    config: TrainConfig = TrainConfig(),
    progress_fn: Optional[Callable[[int, dict], None]] = None,
    eval_env=None,
    initial_state: Optional[TrainingState] = None,
    host_state: Optional[dict] = None,
    checkpoint_fn: Optional[Callable[[TrainingState, dict], None]] = None,
    checkpoint_every: Optional[int] = None,
    checkpoint_min_seconds: float = 0.0,
    step_fn: Optional[Callable[[int], None]] = None,
    auto_config: bool = True,
    mesh=None,
    policy_params_fn: Optional[Callable[[int, "TrainedParams", dict], None]] = None,
):
    """Train SkillS on ``environment`` (Brax env API) with frozen ``skills``.

    Returns ``(make_policy, params, metrics)``: ``params`` a ``TrainedParams`` (the new skill's
    and the scheduler's policy parameters and the observation statistics), ``metrics`` the last evaluation and training metrics (Python floats / lists).
    ``progress_fn(env_steps, metrics)`` is called after every evaluation (Brax style);
    ``step_fn(env_steps)`` after every iteration (a progress bar's count; a host int, no device sync);
    ``policy_params_fn(env_steps, params, metrics)`` after every evaluation with the evaluated
    ``TrainedParams`` (Brax's ``policy_params_fn``; e.g. to keep the best evaluated new skill).
    ``auto_config``: fill the device's defaults with ``resolve(config)``; False: train with ``config``
    exactly (``training.run`` resolves it once, from what the user set, and records it).

    Checkpoints and exact resumption (``training.checkpointing``): ``checkpoint_fn(state,
    host_state)`` is called after the iteration in which ``env_steps`` crosses a multiple of
    ``checkpoint_every`` (``None``: after every evaluation at least ``checkpoint_min_seconds`` of
    wall time after the previous checkpoint or the start) and after the last iteration, with the
    whole ``TrainingState`` and the host-side loop state (a JSON-able dict: iteration, env_steps,
    the last evaluation's metrics, the training statistics accumulated since it, elapsed wall
    time). It must finish with ``state`` before returning (the next iteration donates its
    buffers). ``train(..., initial_state=state, host_state=host_state)`` with the same arguments
    otherwise continues that run exactly: the evaluation keys derive from (seed, iteration).

    ``mesh`` (``parallel_skills.sharding.make_mesh()``; several devices, possibly several
    processes): the run is data parallel over its devices (envs and learner batches split,
    parameters and replay replicated; ``sharding``'s docstring) and computes what the one-device
    run computes, up to float summation order. ``num_envs`` and both learner batch sizes must
    divide by the device count. Every process calls ``train`` alike; the callbacks run in each.
    """
    make_policy, params, metrics = train_seeds(
        environment, skills, seeds=[seed], num_timesteps=num_timesteps, num_envs=num_envs,
        episode_length=episode_length, config=config, eval_env=eval_env, progress_fns=[progress_fn],
        initial_states=None if initial_state is None else [initial_state], host_states=[host_state],
        checkpoint_fns=[checkpoint_fn], checkpoint_every=checkpoint_every,
        checkpoint_min_seconds=checkpoint_min_seconds, step_fn=step_fn, auto_config=auto_config, mesh=mesh,
        seed_axis=False, policy_params_fns=[policy_params_fn])
    return make_policy, params[0], metrics[0]


def train_seeds(
    environment,
    skills: Sequence[Skill],
    *,
    seeds: Sequence[int],
    num_timesteps: int,
    num_envs: Optional[int] = None,
    episode_length: Optional[int] = None,
    config: TrainConfig = TrainConfig(),
    eval_env=None,
    progress_fns: Optional[Sequence[Optional[Callable[[int, dict], None]]]] = None,
    initial_states: Optional[Sequence[TrainingState]] = None,
    host_states: Optional[Sequence[Optional[dict]]] = None,
    checkpoint_fns: Optional[Sequence[Optional[Callable[[TrainingState, dict], None]]]] = None,
    checkpoint_every: Optional[int] = None,
    checkpoint_min_seconds: float = 0.0,
    step_fn: Optional[Callable[[int], None]] = None,
    auto_config: bool = True,
    mesh=None,
    seed_axis: bool = True,
    policy_params_fns: Optional[Sequence[Optional[Callable[[int, "TrainedParams", dict], None]]]] = None,
):
    """``train`` for several seeds at once: one compiled iteration ``vmap``-ed over the seed axis
    (S = len(seeds) runs in lockstep: on an accelerator S times the envs for about the cost of one
    run). Everything per seed is what ``train(..., seed=seeds[i])`` takes and gives: the i-th
    progress function, checkpoint function (called with the i-th seed's state, unbatched), initial
    state and host state, and the i-th element of the returned lists. Evaluations run per seed with
    ``train``'s keys, so seed s evaluates the same episodes as a single run of s; the learning
    itself matches a single run up to float reordering in the batched matrix products
    (tests/test_train.py states the tolerance).

    ``seed_axis`` False: one seed, its state unbatched (no vmap): what ``train`` runs, through this
    same code path.

    Returns ``(make_policy, [params per seed], [metrics per seed])``.
    """
    seeds = [int(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct integers, got {seeds}")
    n = len(seeds)
    per_seed = lambda xs: list(xs) if xs is not None else [None] * n  # noqa: E731
    progress_fns, host_states, checkpoint_fns = per_seed(progress_fns), per_seed(host_states), per_seed(checkpoint_fns)
    policy_params_fns = per_seed(policy_params_fns)
    if any(len(x) != n for x in (progress_fns, host_states, checkpoint_fns, policy_params_fns)):
        raise ValueError(f"progress_fns, host_states, checkpoint_fns and policy_params_fns need one entry per "
                         f"seed ({n})")
    if not seed_axis and n != 1:
        raise ValueError(f"seed_axis=False trains one seed, got {n}")
    config = _checked_config(environment, skills, config, num_timesteps, num_envs, checkpoint_every, auto_config)
    episode_length = int(episode_length or getattr(environment, "episode_length", 1000))
    mesh = mesh if mesh is not None and mesh.size > 1 else None
    trainer = make_trainer(environment, skills, config, mesh)
    init, iteration, place = compile_trainer(trainer, mesh, seed_axis=seed_axis)
    if initial_states is None:
        keys = [jax.random.PRNGKey(s) for s in seeds]
        state = init(jnp.stack(keys) if seed_axis else keys[0])
    else:
        if len(initial_states) != n:
            raise ValueError(f"initial_states needs one state per seed ({n}), got {len(initial_states)}")
        if seed_axis and len({int(s.iteration) for s in initial_states}) != 1:
            raise ValueError("initial_states must all be at the same iteration (checkpoints of one vmapped run)")
        state = place(jax.tree.map(lambda *xs: jnp.stack(xs), *initial_states) if seed_axis else initial_states[0])
    evaluates = [make_evaluation(eval_env or environment, trainer, episode_length, s, mesh) for s in seeds]
    state, metrics = _host_loop(trainer, iteration, state, n if seed_axis else None, evaluates, num_timesteps,
                                host_states, progress_fns, checkpoint_fns, checkpoint_every, checkpoint_min_seconds,
                                step_fn, policy_params_fns)
    params = [TrainedParams.of(_seed_slice(state, i if seed_axis else None)) for i in range(n)]
    make_policy = make_policy_factory(int(environment.action_size), config, trainer.num_skills_total)
    return make_policy, params, metrics


def compile_trainer(trainer: Trainer, mesh, seed_axis: bool):
    """``(init(key), iteration(state), place(state))`` jitted for one device (``mesh`` None) or data
    parallel over ``mesh`` (``sharding.state_shardings`` in and out; ``place`` puts a restored state
    on the mesh). ``seed_axis``: ``train_seeds``' functions, vmapped over a leading seed axis."""
    init_fn, iter_fn = trainer.init, trainer.iteration
    if seed_axis:
        init_fn, iter_fn = jax.vmap(init_fn), jax.vmap(iter_fn)
    if mesh is None:
        return jax.jit(init_fn), jax.jit(iter_fn, donate_argnums=0), lambda state: state
    rep = sharding.replicated(mesh)
    key = jax.random.PRNGKey(0)
    abstract = jax.eval_shape(init_fn, jnp.stack([key]) if seed_axis else key)
    state_sh = sharding.state_shardings(abstract, mesh, trainer.config.num_envs, seed_axis=seed_axis)
    init_jit = jax.jit(init_fn, out_shardings=state_sh)
    iteration = jax.jit(iter_fn, donate_argnums=0, in_shardings=(state_sh,), out_shardings=(state_sh, rep))
    return (lambda keys: init_jit(sharding.put(keys, rep)), iteration,
            lambda state: sharding.put(state, state_sh))


def _seed_slice(tree, i: Optional[int]):
    """Seed i of a tree batched over seeds (the tree itself when ``i`` is None: one unbatched run)."""
    return tree if i is None else jax.tree.map(lambda x: x[i], tree)


def _host_loop(trainer: Trainer, iteration, state, num_seeds: Optional[int], evaluates, num_timesteps,
               host_states, progress_fns, checkpoint_fns, checkpoint_every, checkpoint_min_seconds, step_fn,
               policy_params_fns=None):
    """The host side of ``train`` / ``train_seeds``: iterations, per-seed training statistics,
    evaluations, progress and checkpoint calls. ``num_seeds`` None: ``state`` is one run; else it is
    batched over that many seeds and every per-seed list has one entry each. Returns (state,
    [last metrics per seed])."""
    config = trainer.config
    seeds = [None] if num_seeds is None else list(range(num_seeds))
    rewarded_fraction = jax.jit(trainer.replay.rewarded_fraction if num_seeds is None
                                else jax.vmap(trainer.replay.rewarded_fraction))
    start = int(jax.device_get(state.iteration).reshape(-1)[0])
    spi = trainer.steps_per_iteration
    num_iterations = max(1, math.ceil(int(num_timesteps) / spi))
    log.info("training: %d iterations x %d env steps, %d scheduler + %d new-skill updates per iteration%s",
             num_iterations, spi, trainer.scheduler_updates, trainer.new_skill_updates,
             "" if num_seeds is None else f", {num_seeds} seeds")
    host_states = [h or {} for h in host_states]
    metrics = [dict(h.get("metrics") or {}) for h in host_states]
    accs = [EpisodeAccumulator.from_dict(h.get("accumulator")) for h in host_states]
    # (The wall clock of a vmapped run is shared: its seeds started together.)
    t0 = time.perf_counter() - float(host_states[0].get("wall_time", 0.0))
    last_checkpoint = time.perf_counter()
    for it in range(start, num_iterations):
        state, train_m = iteration(state)
        summed = EpisodeAccumulator.fetch(train_m)  # one device-to-host copy for all seeds
        for j, i in enumerate(seeds):
            accs[j].add(_seed_slice(summed, i))
        if step_fn is not None:
            step_fn((it + 1) * spi)
        last = it == num_iterations - 1
        evaluated = (it + 1) % config.eval_every == 0 or last
        if evaluated:
            # (Evaluations read the policies and the statistics: the replay is not sliced for them.)
            # (O(buffer): read at evaluations only, not in the iteration.)
            rewarded = jax.device_get(rewarded_fraction(state.replay)).reshape(-1)
            light = state if num_seeds is None else state.replace(replay=None, actor=None, pending=None)
            for j, i in enumerate(seeds):
                one = _seed_slice(light, i)
                metrics[j] = dict(accs[j].summary(_seed_slice(train_m, i)), **evaluates[j](one, it + 1),
                                  replay_rewarded_fraction=float(rewarded[j]))
                accs[j] = EpisodeAccumulator()
                metrics[j].update(env_steps=int(one.env_steps), wall_time=time.perf_counter() - t0, iteration=it + 1)
                if progress_fns[j] is not None:
                    progress_fns[j](int(one.env_steps), metrics[j])
                if policy_params_fns and policy_params_fns[j] is not None:
                    policy_params_fns[j](int(one.env_steps), TrainedParams.of(one), metrics[j])
        # (Only at evaluations: the agreement across processes is a collective.)
        spaced = evaluated and sharding.agreed(time.perf_counter() - last_checkpoint >= checkpoint_min_seconds)
        if _checkpoint_due(it, spi, checkpoint_every, spaced, last) and any(checkpoint_fns):
            last_checkpoint = time.perf_counter()
            for j, i in enumerate(seeds):
                if checkpoint_fns[j] is not None:
                    checkpoint_fns[j](_seed_slice(state, i),
                                      {"iteration": it + 1, "env_steps": (it + 1) * spi, "metrics": metrics[j],
                                       "accumulator": accs[j].to_dict(), "wall_time": time.perf_counter() - t0})
    return state, metrics


def make_evaluation(env, trainer: Trainer, episode_length: int, seed: int,
                    mesh=None) -> Callable[[TrainingState, int], dict]:
    """``evaluate(state, iteration) -> {"eval/new_skill_success", ...}`` (host floats): the new skill
    alone and (SkillS) the scheduler alone over ``config.eval_episodes`` episodes. The keys derive
    from (seed, iteration), not from the loop's history: a resumed run draws the same evaluation
    episodes as an uninterrupted one. ``mesh``: the evaluations run replicated on its devices (every
    process of a multi-process run evaluates the same episodes)."""
    evals = make_evaluators(env, trainer, trainer.config.eval_episodes, episode_length, mesh)
    base_key = jax.random.PRNGKey(seed + 10_000)
    method = methods.get(trainer.config.method)
    diagnostics = bool(trainer.config.eval_diagnostics)
    place = (lambda k: k) if mesh is None else (lambda k: sharding.put(k, sharding.replicated(mesh)))  # noqa: E731
    # (device_get first: a multi-process run's arrays are global, this process reads its replica.)
    mean = lambda x: float(jnp.mean(jax.device_get(x)))  # noqa: E731

    def readout_key(iteration: int, i: int):
        """Read-out i's own key at an evaluation: each draws the same with or without the others."""
        return place(jax.random.fold_in(jax.random.fold_in(base_key, iteration), i))

    def evaluate(state: TrainingState, iteration: int) -> dict:
        k1, k2 = map(place, jax.random.split(jax.random.fold_in(base_key, iteration)))
        deployed = state.new_skill.deployed_policy_params  # the moving average where one is kept
        ev = evals.new_skill(deployed, state.normalizer, k1)
        out = {"eval/new_skill_success": mean(ev["success"]), "eval/new_skill_return": mean(ev["return"])}
        if state.new_skill.ema_policy_params is not None:  # the online policy, on the same episodes (k1)
            ev = evals.new_skill(state.new_skill.policy_params, state.normalizer, k1)
            out["eval/new_skill_online_success"] = mean(ev["success"])
            out["eval/new_skill_online_return"] = mean(ev["return"])
        ev = evals.new_skill_sampled(state.new_skill.policy_params, state.normalizer, readout_key(iteration, 2))
        out["eval/new_skill_sampled_success"] = mean(ev["success"])
        out["eval/new_skill_sampled_return"] = mean(ev["return"])
        if method.scheduler_acts:  # the scheduler acting (rhpo: the whole mixture)
            ev = evals.scheduler(state.scheduler.policy_params, deployed, state.normalizer, k2)
            out["eval/scheduler_success"] = mean(ev["success"])
            out["eval/scheduler_return"] = mean(ev["return"])
        if diagnostics:
            out.update(diagnostic_readouts(state, iteration))
        return out

    def diagnostic_readouts(state: TrainingState, iteration: int) -> dict:
        """``TrainConfig.eval_diagnostics``: the read-outs that explain a run rather than measure it."""
        out = {}
        ev = evals.new_skill_critic_weighted(state.new_skill.policy_params, state.new_skill.critic_params,
                                             state.normalizer, readout_key(iteration, 3))
        out["eval/new_skill_critic_weighted_success"] = mean(ev["success"])
        out["eval/new_skill_critic_weighted_return"] = mean(ev["return"])
        if method.scheduler_acts:
            # The same greedy decisions with the new skill's sampled actions: the scheduler's choices
            # apart from the new skill's mean-action read-out (docs/skills.md).
            ev = evals.scheduler_new_skill_sampled(state.scheduler.policy_params, state.new_skill.policy_params,
                                                   state.normalizer, readout_key(iteration, 4))
            out["eval/scheduler_new_skill_sampled_success"] = mean(ev["success"])
            out["eval/scheduler_new_skill_sampled_return"] = mean(ev["return"])
        if method.learns_scheduler:  # the scheduler as it collects; its critic at the reset states
            ev = evals.scheduler_sampled(state.scheduler.policy_params, state.scheduler.critic_params,
                                         state.new_skill.policy_params, state.normalizer, readout_key(iteration, 1))
            out["eval/scheduler_sampled_success"] = mean(ev["success"])
            out["eval/scheduler_sampled_return"] = mean(ev["return"])
            out["eval/scheduler_discounted_return"] = mean(ev["discounted_return"])
            out["eval/scheduler_value_at_reset"] = mean(ev["value_at_reset"])
        return out

    return evaluate


class EpisodeAccumulator:
    """Training-episode statistics summed over the iterations between two reports."""

    SUMMED = ("episodes", "nonfinite_transitions", "skill_histogram", "length_histogram", "skill_steps",
              "skill_runs", "entropy_i_sum", "entropy_k_sum")
    # Sums reported as means per decision (``summary``), not as sums.
    PER_DECISION = {"entropy_i_sum": "decision_entropy_i", "entropy_k_sum": "decision_entropy_k"}
    WEIGHTED = ("episode_return", "episode_success")  # means over the episodes that ended

    def __init__(self):
        self.sums: dict = {}
        self.weighted = {k: 0.0 for k in self.WEIGHTED}

    @classmethod
    def fetch(cls, m) -> dict:
        """The metrics ``add`` reads, on the host (numpy)."""
        return jax.device_get({k: m[k] for k in cls.SUMMED + cls.WEIGHTED})

    def add(self, m):
        m = self.fetch(m)
        for k in self.SUMMED:
            self.sums[k] = self.sums.get(k, 0.0) + np.asarray(m[k], np.float64)
        for k in self.weighted:
            self.weighted[k] += float(m[k]) * float(m["episodes"])

    def to_dict(self) -> dict:
        """JSON-able state (for checkpoints); ``from_dict`` restores it exactly."""
        return {"sums": {k: _to_py(v) for k, v in self.sums.items()}, "weighted": dict(self.weighted)}

    @classmethod
    def from_dict(cls, d: Optional[dict]) -> "EpisodeAccumulator":
        acc = cls()
        if d:
            acc.sums = {k: np.asarray(v, np.float64) for k, v in d["sums"].items()}
            acc.weighted = {k: float(v) for k, v in d["weighted"].items()}
        return acc

    def summary(self, last_metrics):
        out = {k: _to_py(v) for k, v in last_metrics.items()}
        out.update({k: _to_py(v) for k, v in self.sums.items()})
        n = float(self.sums.get("episodes", 0.0))
        for k, v in self.weighted.items():  # NaN when no training episode ended in the interval
            out[k] = v / n if n > 0 else float("nan")
        # The scheduler's decisions in the interval: entropies per decision, shares per skill / length.
        hist = {k: np.asarray(self.sums[k], np.float64) for k in ("skill_histogram", "length_histogram")
                if k in self.sums}
        decisions = float(np.sum(hist["skill_histogram"])) if "skill_histogram" in hist else 0.0
        for k, name in self.PER_DECISION.items():
            out.pop(k, None)
            if k in self.sums:
                out[name] = float(self.sums[k]) / decisions if decisions > 0 else float("nan")
        for k, name in (("skill_histogram", "skill_share"), ("length_histogram", "length_share")):
            if k in hist:
                total = float(np.sum(hist[k]))
                out[name] = _to_py(hist[k] / total) if total > 0 else [float("nan")] * int(hist[k].size)
        return out


def _to_py(v):
    a = np.asarray(v)
    return a.tolist() if a.ndim else float(a)
