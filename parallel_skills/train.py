"""SkillS training: one jitted iteration = collect (lax.scan) → insert → learner updates (lax.scan).

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
from typing import Any, Callable, Optional, Sequence

import flashbax as fbx
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from parallel_skills import learners, networks
from parallel_skills import normalization as obs_norm
from parallel_skills import nstep
from parallel_skills.augmentation import with_augmentation
from parallel_skills.config import NewSkillConfig, SchedulerConfig
from parallel_skills.counters import advance_counters
from parallel_skills.evaluation import rollout_episodes
from parallel_skills.skills import Skill, SkillSet

log = logging.getLogger("parallel_skills")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Run-level settings. ``None`` fields take device-dependent defaults (``resolve``)."""

    num_envs: Optional[int] = None  # CPU: 32, accelerator: 4096
    unroll_length: int = 25  # env steps per env per iteration
    replay_size: Optional[int] = None  # CPU: 300k, accelerator: 1M (paper)
    method: str = "skills"  # "skills" (SkillS) or "scratch" (the new skill acting alone)
    eval_episodes: int = 16
    eval_every: int = 20  # iterations between evaluations
    # Std of Gaussian noise added to the frozen skills' actions while collecting (not in
    # evaluation). The paper's skills are stochastic Gaussian policies; deterministic (e.g.
    # scripted) skills give the new skill no data off their exact paths to learn recovery
    # from: cloning scripted lift from its noise-free paths fails (docs/learning.md).
    skill_noise_std: float = 0.3
    scheduler: SchedulerConfig = SchedulerConfig()
    new_skill: NewSkillConfig = NewSkillConfig()

    def __post_init__(self):
        if self.method not in ("skills", "scratch"):
            raise ValueError(f"method must be 'skills' or 'scratch', got {self.method!r}")
        for name in ("unroll_length", "eval_episodes", "eval_every"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)}")


# The CPU recipe (docs/learning.md: with it, kinematic lift from the useful skills reaches 0.91 at
# 240k env steps and 0.99 at 400k for seed 0; seeds 1, 2 are at 0.13 / 0.41 after 200k). Learners dominate on a CPU (STACK.md: ≈1 update per env step at the
# paper's ratios), so the scheduler takes fewer samples per insert and learns its critic alone for
# its first updates (Eq. 3's long-horizon values first); the new skill keeps a high replay ratio
# (at 16 it did not learn lift in 300k steps) with CRR's indicator weights.
CPU_DEFAULTS = dict(num_envs=32, replay_size=300_000, scheduler_spi=8.0, scheduler_policy_warmup_updates=1500,
                    new_skill_spi=64.0, new_skill_crr_mode="indicator")


# The CPU recipe's learner fields: (learner, field) -> (CPU value, the paper's value).
CPU_RECIPE = {
    ("scheduler", "samples_per_insert"): (CPU_DEFAULTS["scheduler_spi"], SchedulerConfig.samples_per_insert),
    ("scheduler", "policy_warmup_updates"): (CPU_DEFAULTS["scheduler_policy_warmup_updates"],
                                             SchedulerConfig.policy_warmup_updates),
    ("new_skill", "samples_per_insert"): (CPU_DEFAULTS["new_skill_spi"], NewSkillConfig.samples_per_insert),
    ("new_skill", "crr_mode"): (CPU_DEFAULTS["new_skill_crr_mode"], NewSkillConfig.crr_mode),
}


def _show(value) -> str:
    return f"{value:g}" if isinstance(value, (int, float)) else str(value)


def resolve(config: TrainConfig, backend: Optional[str] = None,
            given: Optional[Sequence[str]] = None) -> tuple[TrainConfig, list[str]]:
    """Fill device-dependent defaults. Returns the config and human-readable notes of what was
    chosen automatically (to log).

    On a CPU, ``num_envs`` / ``replay_size`` left None get the CPU sizes, and the learners the CPU
    recipe (``CPU_RECIPE``). ``given``: the dotted names of the fields the user set (``training.run``:
    those of its config file, e.g. ``"new_skill.n_step"``): every recipe field not among them takes
    the recipe. ``None`` (callers that build a config in code, and configs resolved already): a
    learner config takes the recipe only when all its fields are the paper's, so a resolved config
    is never changed."""
    backend = backend or jax.default_backend()
    notes: list[str] = []
    cfg = config
    if backend == "cpu":
        if cfg.num_envs is None:
            cfg = dataclasses.replace(cfg, num_envs=CPU_DEFAULTS["num_envs"])
            notes.append(f"num_envs={cfg.num_envs}")
        if cfg.replay_size is None:
            cfg = dataclasses.replace(cfg, replay_size=CPU_DEFAULTS["replay_size"])
            notes.append(f"replay_size={cfg.replay_size}")
        given = None if given is None else set(given)
        for learner, default in (("scheduler", SchedulerConfig()), ("new_skill", NewSkillConfig())):
            sub = getattr(cfg, learner)
            if given is None and sub != default:
                continue
            changes = {f: cpu for (name, f), (cpu, _) in CPU_RECIPE.items()
                       if name == learner and (given is None or f"{learner}.{f}" not in given)}
            if changes:
                cfg = dataclasses.replace(cfg, **{learner: dataclasses.replace(sub, **changes)})
                notes.append(f"{learner.replace('_', '-')} " + ", ".join(
                    f"{f}={_show(v)} (paper {_show(CPU_RECIPE[(learner, f)][1])})" for f, v in changes.items()))
    else:
        if cfg.num_envs is None:
            cfg = dataclasses.replace(cfg, num_envs=4096)
        if cfg.replay_size is None:
            cfg = dataclasses.replace(cfg, replay_size=1_000_000)
    return cfg, notes


@struct.dataclass
class ActorState:
    """Per-env acting state. env_state: batched brax State; c/i/k_idx [B] the running skill's
    counter, index and length index; first [B] whether the next step starts an episode."""

    env_state: Any
    c: jax.Array
    i: jax.Array
    k_idx: jax.Array
    first: jax.Array
    ep_return: jax.Array
    ep_success: jax.Array


@struct.dataclass
class TrainingState:
    scheduler: learners.SchedulerLearnerState
    new_skill: learners.NewSkillLearnerState
    replay: Any
    actor: ActorState
    normalizer: obs_norm.RunningStats
    key: jax.Array
    env_steps: jax.Array
    iteration: jax.Array
    # new_skill.n_step > 1: the last n − 1 collected steps of every env ([n − 1, B, ...] replay
    # fields + done), inserted with the next unroll once their n-step returns are known
    # (parallel_skills.nstep). None for 1-step runs (their checkpoints keep their structure).
    pending: Any = None


def _finite(x):
    return jnp.all(jnp.isfinite(x.reshape(x.shape[0], -1)), axis=-1)


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


@dataclasses.dataclass(frozen=True)
class Trainer:
    """Pure functions of a configured run (see ``make_trainer``)."""

    init: Callable[[jax.Array], TrainingState]
    iteration: Callable[[TrainingState], tuple]
    act: Callable  # act(actor, sched_params, new_params, key, greedy) -> (actor, transition, stats)
    reset_actor: Callable[[jax.Array], ActorState]
    collect_insert: Callable  # collect_insert(state, key) -> (state, trajectory, stats)
    learn: Callable  # learn(state, key) -> (scheduler state, new-skill state, metrics, metrics)
    config: TrainConfig
    skills: tuple
    num_skills_total: int
    scheduler_updates: int
    new_skill_updates: int
    steps_per_iteration: int


def make_trainer(environment, skills: Sequence[Skill], config: TrainConfig) -> Trainer:
    """Build the pure ``init`` / ``iteration`` functions for ``environment`` and frozen ``skills``."""
    if config.num_envs is None or config.replay_size is None:
        raise ValueError("make_trainer needs a resolved config (see parallel_skills.train.resolve)")
    env = environment
    skills = [] if config.method == "scratch" else list(skills)
    skill_set = SkillSet(skills)
    n_total = len(skills) + 1  # frozen skills + the new skill (index N)
    new_index = len(skills)
    B, T = int(config.num_envs), int(config.unroll_length)
    sc, nc = config.scheduler, config.new_skill
    obs_size, action_size = int(env.observation_size), int(env.action_size)
    sched_apply = learners.make_scheduler_apply(n_total, sc)
    new_apply = learners.make_new_skill_apply(action_size, nc)
    learn_scheduler = config.method == "skills"
    n_step = int(nc.n_step)

    steps_per_iter = B * T
    n_sched = learners.updates_per_iteration(sc.samples_per_insert, steps_per_iter, sc.batch_size)
    n_new = learners.updates_per_iteration(nc.samples_per_insert, steps_per_iter, nc.batch_size)
    capacity = max(int(config.replay_size), steps_per_iter, sc.batch_size, nc.batch_size)
    sched_buffer = fbx.make_item_buffer(capacity, 1, sc.batch_size, add_batches=True)
    new_buffer = fbx.make_item_buffer(capacity, 1, nc.batch_size, add_batches=True)

    def empty_transition():
        f = jnp.float32
        return dict(
            obs=jnp.zeros((obs_size,), f), action=jnp.zeros((action_size,), f), reward=jnp.zeros((), f),
            discount=jnp.zeros((), f), next_obs=jnp.zeros((obs_size,), f), skill=jnp.zeros((), jnp.int32),
            k_idx=jnp.zeros((), jnp.int32), c=jnp.zeros((), jnp.int32), is_decision=jnp.zeros((), bool),
            weight=jnp.zeros((), f),
        ) | (dict(nstep_reward=jnp.zeros((), f), nstep_discount=jnp.zeros((), f),
                  nstep_next_obs=jnp.zeros((obs_size,), f), nstep_weight=jnp.zeros((), f)) if n_step > 1 else {})

    def empty_pending():
        """n − 1 placeholder steps per env: weight 0 (never learnt from), done (no return reaches
        past them)."""
        tr = {k: v for k, v in empty_transition().items() if not k.startswith("nstep_")}
        tr["done"] = jnp.ones((), bool)
        return jax.tree.map(lambda x: jnp.broadcast_to(x, (n_step - 1, B) + x.shape), tr)

    def reset_actor(key) -> ActorState:
        env_state = jax.vmap(env.reset)(jax.random.split(key, B))
        zi = jnp.zeros((B,), jnp.int32)
        return ActorState(env_state, zi, zi, zi, jnp.ones((B,), bool), jnp.zeros((B,)), jnp.zeros((B,)))

    def init(key) -> TrainingState:
        k_s, k_n, k_e, k_run = jax.random.split(key, 4)
        return TrainingState(
            scheduler=learners.scheduler_learner_init(k_s, obs_size, n_total, sc),
            new_skill=learners.new_skill_learner_init(k_n, obs_size, action_size, nc),
            replay=sched_buffer.init(empty_transition()),
            actor=reset_actor(k_e),
            normalizer=obs_norm.init(obs_size),
            key=k_run,
            env_steps=jnp.zeros((), jnp.int32),
            iteration=jnp.zeros((), jnp.int32),
            pending=empty_pending() if n_step > 1 else None,
        )

    def act(actor: ActorState, sched_params, new_params, normalizer, key, greedy: bool = False):
        """One env step for the batch: decide where counters expired, act, step, auto-reset.
        Frozen skills see raw observations; the scheduler and the new skill normalised ones."""
        k_i, k_k, k_a, k_s, k_r = jax.random.split(key, 5)
        obs = actor.env_state.obs
        nobs = obs_norm.normalize(normalizer, obs)
        logits_i, logits_k = sched_apply(sched_params, nobs)
        if greedy:
            i_new, k_new = jnp.argmax(logits_i, -1), jnp.argmax(logits_k, -1)
        else:
            i_new = jax.random.categorical(k_i, logits_i)
            k_new = jax.random.categorical(k_k, logits_k)
        if not learn_scheduler:  # from scratch: the new skill always acts
            i_new = jnp.full_like(i_new, new_index)
        c, i, k_idx, is_decision = advance_counters(
            actor.c, actor.i, actor.k_idx, i_new.astype(jnp.int32), k_new.astype(jnp.int32), actor.first, sc.skill_lengths)
        mean, std = new_apply(new_params, nobs)
        new_action = networks.deterministic_action(mean) if greedy else networks.sample_action(mean, std, k_a)
        action = skill_set.actions(new_action, obs, i, k_s)
        if config.skill_noise_std > 0 and not greedy:
            noise = config.skill_noise_std * jax.random.normal(jax.random.fold_in(k_s, 1), action.shape)
            action = jnp.where((i != new_index)[:, None], jnp.clip(action + noise, -1.0, 1.0), action)
        nxt = jax.vmap(env.step)(actor.env_state, action)
        finite = _finite(nxt.obs) & jnp.isfinite(nxt.reward)
        done = (nxt.done > 0) | ~finite
        # Envs without a time limit of their own: wrap them (e.g. brax's EpisodeWrapper).
        truncation = nxt.info.get("truncation", jnp.zeros_like(nxt.done)) > 0
        reward = jnp.where(finite, nxt.reward, 0.0)
        transition = dict(
            obs=obs, action=action, reward=reward,
            # Time-limit truncation bootstraps from the true last observation; termination does not.
            discount=jnp.where((nxt.done > 0) & ~truncation, 0.0, 1.0).astype(jnp.float32),
            next_obs=jnp.where(finite[:, None], nxt.obs, 0.0), skill=i, k_idx=k_idx, c=c,
            is_decision=is_decision, weight=finite.astype(jnp.float32),
        )
        ep_return = actor.ep_return + reward
        ep_success = jnp.maximum(actor.ep_success, nxt.metrics.get("success", jnp.zeros_like(nxt.reward)))
        stats = dict(
            done=done, ep_return=ep_return, ep_success=ep_success, nonfinite=(~finite).astype(jnp.float32),
            new_skill_active=(i == new_index).astype(jnp.float32),
            skill_runs=skill_run_ends(actor.i, actor.first, i, is_decision, done, n_total),
        )

        def do_reset(_):
            fresh = jax.vmap(env.reset)(jax.random.split(k_r, B))
            return jax.tree.map(
                lambda f, n: jnp.where(done.reshape(done.shape + (1,) * (n.ndim - 1)), f, n), fresh, nxt)

        env_state = jax.lax.cond(jnp.any(done), do_reset, lambda _: nxt, None)
        actor = ActorState(
            env_state=env_state, c=c, i=i, k_idx=k_idx, first=done,
            ep_return=jnp.where(done, 0.0, ep_return), ep_success=jnp.where(done, 0.0, ep_success),
        )
        return actor, transition, stats

    def collect(ts: TrainingState, key):
        sched_params = ts.scheduler.policy_params
        new_params = ts.new_skill.policy_params

        def body(actor, k):
            actor, tr, st = act(actor, sched_params, new_params, ts.normalizer, k)
            return actor, (tr, st)

        actor, (traj, stats) = jax.lax.scan(body, ts.actor, jax.random.split(key, T))
        return actor, traj, stats

    def normalized(b, normalizer):
        b = dict(b)
        b["obs"] = obs_norm.normalize(normalizer, b["obs"])
        b["next_obs"] = obs_norm.normalize(normalizer, b["next_obs"])
        if n_step > 1:
            b["nstep_next_obs"] = obs_norm.normalize(normalizer, b["nstep_next_obs"])
        return b

    def sample_scheduler_batch(replay, normalizer, key):
        b = normalized(sched_buffer.sample(replay, key).experience, normalizer)
        batch = {k: b[k] for k in ("obs", "next_obs", "reward", "discount", "skill", "k_idx", "c", "is_decision", "weight")}
        return with_augmentation(batch, sc.skill_lengths) if sc.augmentation else batch

    def learn(ts: TrainingState, key):
        k_s, k_n = jax.random.split(key)

        def sched_body(state, k):
            k1, k2 = jax.random.split(k)
            state, m = learners.scheduler_learner_update(state, sample_scheduler_batch(ts.replay, ts.normalizer, k1), k2, sc)
            return state, m

        def new_body(state, k):
            k1, k2 = jax.random.split(k)
            b = normalized(new_buffer.sample(ts.replay, k1).experience, ts.normalizer)
            if n_step > 1:  # the learner's 1-step target r + γ·d·Q' becomes the n-step one
                batch = {"obs": b["obs"], "action": b["action"], "reward": b["nstep_reward"],
                         "discount": b["nstep_discount"], "next_obs": b["nstep_next_obs"], "weight": b["nstep_weight"]}
            else:
                batch = {k_: b[k_] for k_ in ("obs", "action", "reward", "discount", "next_obs", "weight")}
            return learners.new_skill_learner_update(state, batch, k2, nc)

        size = jnp.where(ts.replay.is_full, capacity, ts.replay.current_index)
        sched_ready = learn_scheduler & (size >= sc.min_replay_size)
        new_ready = size >= nc.min_replay_size

        def run_sched(state):
            state, m = jax.lax.scan(sched_body, state, jax.random.split(k_s, n_sched))
            return state, jax.tree.map(lambda x: x[-1], m)

        def run_new(state):
            state, m = jax.lax.scan(new_body, state, jax.random.split(k_n, n_new))
            return state, jax.tree.map(lambda x: x[-1], m)

        sched_zero = jax.tree.map(jnp.zeros_like, jax.eval_shape(run_sched, ts.scheduler)[1])
        new_zero = jax.tree.map(jnp.zeros_like, jax.eval_shape(run_new, ts.new_skill)[1])
        sched_state, sched_m = jax.lax.cond(sched_ready, run_sched, lambda s: (s, sched_zero), ts.scheduler)
        new_state, new_m = jax.lax.cond(new_ready, run_new, lambda s: (s, new_zero), ts.new_skill)
        return sched_state, new_state, sched_m, new_m

    def collect_insert(ts: TrainingState, key):
        """Acting half of an iteration: T steps of the B envs, inserted into the replay."""
        actor, traj, stats = collect(ts, key)
        pending = ts.pending
        if n_step > 1:  # insert the T steps that now have their n-step returns (n − 1 steps late)
            window = jax.tree.map(lambda p, x: jnp.concatenate([p, x], axis=0), pending,
                                  dict(traj, done=stats["done"]))
            pending = jax.tree.map(lambda x: x[T:], window)
            ready = {k: v[:T] for k, v in window.items() if k != "done"}
            ready.update(nstep.nstep_fields(window, n_step, nc.discount))
        else:
            ready = traj
        def flat(x):  # [T, B, ...] -> [T·B, ...]
            return x.reshape((T * B,) + x.shape[2:])

        replay = sched_buffer.add(ts.replay, jax.tree.map(flat, ready))
        normalizer = obs_norm.update(ts.normalizer, flat(traj["obs"]), flat(traj["weight"]))  # this unroll's steps
        return ts.replace(replay=replay, actor=actor, normalizer=normalizer, pending=pending), traj, stats

    def iteration(ts: TrainingState):
        key, k_collect, k_learn = jax.random.split(ts.key, 3)
        ts, traj, stats = collect_insert(ts, k_collect)
        sched_state, new_state, sched_m, new_m = learn(ts, k_learn)

        done = stats["done"].astype(jnp.float32)
        n_done = jnp.sum(done)
        dec = traj["is_decision"].astype(jnp.float32)
        metrics = {
            "reward_mean": jnp.mean(traj["reward"]),
            "episodes": n_done,
            "episode_return": jnp.sum(stats["ep_return"] * done) / jnp.maximum(n_done, 1.0),
            "episode_success": jnp.sum(stats["ep_success"] * done) / jnp.maximum(n_done, 1.0),
            "new_skill_selection_rate": jnp.mean(stats["new_skill_active"]),
            "nonfinite_transitions": jnp.sum(stats["nonfinite"]),
            "skill_histogram": jnp.sum(jax.nn.one_hot(traj["skill"], n_total) * dec[..., None], axis=(0, 1)),
            "length_histogram": jnp.sum(jax.nn.one_hot(traj["k_idx"], sc.num_lengths) * dec[..., None], axis=(0, 1)),
            # Steps each skill acted (for usage plots: average consecutive execution per skill).
            "skill_steps": jnp.sum(jax.nn.one_hot(traj["skill"], n_total), axis=(0, 1)),
            # Maximal consecutive runs of each skill that ended (skill_steps / skill_runs = the
            # average consecutive execution, paper Fig. 4c).
            "skill_runs": jnp.sum(stats["skill_runs"], axis=(0, 1)),
        }
        metrics.update({f"scheduler/{k}": v for k, v in sched_m.items()})
        metrics.update({f"new_skill/{k}": v for k, v in new_m.items()})
        ts = ts.replace(scheduler=sched_state, new_skill=new_state, key=key,
                        env_steps=ts.env_steps + steps_per_iter, iteration=ts.iteration + 1)
        return ts, metrics

    return Trainer(init=init, iteration=iteration, act=act, reset_actor=reset_actor,
                   collect_insert=collect_insert, learn=learn, config=config,
                   skills=tuple(skills), num_skills_total=n_total,
                   scheduler_updates=n_sched if learn_scheduler else 0, new_skill_updates=n_new,
                   steps_per_iteration=steps_per_iter)


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

    def make_policy(params, which: str = "new_skill", deterministic: bool = True):
        stats = params["normalizer"]
        if which == "new_skill":
            p = params["new_skill"]

            def policy(obs, key):
                mean, std = new_apply(p, obs_norm.normalize(stats, obs))
                return mean if deterministic else networks.sample_action(mean, std, key)

            return policy
        if which == "scheduler":
            p = params["scheduler"]

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


def make_evaluators(env, trainer: Trainer, num_episodes: int, episode_length: int):
    """Jitted whole-episode evaluations of the new skill alone and of the scheduler alone
    (paper App. C.3): ``eval_new(new_params, key)``, ``eval_scheduler(sched_params, new_params, key)``
    -> dict of per-episode ``return`` / ``success``. The scheduler acts greedily (argmax z) with
    its counters, through the trainer's own acting step."""
    new_apply = learners.make_new_skill_apply(int(env.action_size), trainer.config.new_skill)

    def eval_new(new_params, normalizer, key):
        policy = lambda obs, k: new_apply(new_params, obs_norm.normalize(normalizer, obs))[0]  # noqa: E731
        return rollout_episodes(env, policy, key, num_episodes, episode_length)

    cfg = dataclasses.replace(trainer.config, num_envs=num_episodes, replay_size=num_episodes)
    acting = make_trainer(env, trainer.skills, cfg)

    def eval_scheduler(sched_params, new_params, normalizer, key):
        k0, k1 = jax.random.split(key)
        actor = acting.reset_actor(k0)

        def body(carry, k):
            actor, ret, succ = carry
            actor, tr, st = acting.act(actor, sched_params, new_params, normalizer, k, greedy=True)
            return (actor, ret + tr["reward"], jnp.maximum(succ, st["ep_success"])), None

        z = jnp.zeros(num_episodes)
        (_, ret, succ), _ = jax.lax.scan(body, (actor, z, z), jax.random.split(k1, episode_length))
        return {"return": ret, "success": succ}

    return jax.jit(eval_new), jax.jit(eval_scheduler)


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
    step_fn: Optional[Callable[[int], None]] = None,
    auto_config: bool = True,
):
    """Train SkillS on ``environment`` (Brax env API) with frozen ``skills``.

    Returns ``(make_policy, params, metrics)``: ``params`` = {"new_skill", "scheduler"} policy
    parameters, ``metrics`` the last evaluation and training metrics (Python floats / lists).
    ``progress_fn(env_steps, metrics)`` is called after every evaluation (Brax style);
    ``step_fn(env_steps)`` after every iteration (a progress bar's count; a host int, no device sync).
    ``auto_config``: fill the device's defaults with ``resolve(config)``; False: train with ``config``
    exactly (``training.run`` resolves it once, from what the user set, and records it).

    Checkpoints and exact resumption (``training.checkpointing``): ``checkpoint_fn(state,
    host_state)`` is called after the iteration in which ``env_steps`` crosses a multiple of
    ``checkpoint_every`` (``None``: after every evaluation) and after the last iteration, with the
    whole ``TrainingState`` and the host-side loop state (a JSON-able dict: iteration, env_steps,
    the last evaluation's metrics, the training statistics accumulated since it, elapsed wall
    time). It must finish with ``state`` before returning (the next iteration donates its
    buffers). ``train(..., initial_state=state, host_state=host_state)`` with the same arguments
    otherwise continues that run exactly: the evaluation keys derive from (seed, iteration).
    """
    if int(num_timesteps) < 1:
        raise ValueError(f"num_timesteps must be a positive integer, got {num_timesteps}")
    if num_envs is not None:
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs}")
        config = dataclasses.replace(config, num_envs=int(num_envs))
    if auto_config:
        config, notes = resolve(config)
        if notes:
            log.warning("CPU backend: smaller defaults chosen automatically: %s", ", ".join(notes))
    elif config.num_envs is None or config.replay_size is None:
        raise ValueError("auto_config=False needs a resolved config (num_envs and replay_size set): see resolve()")
    episode_length = int(episode_length or getattr(environment, "episode_length", 1000))
    for s in skills:
        s_obs = s.metadata.get("obs_size")
        if s_obs is not None and int(s_obs) != int(environment.observation_size):
            raise ValueError(f"skill {s.name!r} expects observations of size {s_obs}, the env gives {environment.observation_size}")
    trainer = make_trainer(environment, skills, config)
    eval_env = eval_env or environment
    eval_new, eval_sched = make_evaluators(eval_env, trainer, config.eval_episodes, episode_length)
    iteration = jax.jit(trainer.iteration, donate_argnums=0)
    if initial_state is None:
        state = jax.jit(trainer.init)(jax.random.PRNGKey(seed))
    else:
        state = initial_state
    start = int(state.iteration)
    num_iterations = max(1, math.ceil(int(num_timesteps) / trainer.steps_per_iteration))
    if checkpoint_every is not None and int(checkpoint_every) < 1:
        raise ValueError(f"checkpoint_every must be a positive integer (env steps), got {checkpoint_every}")
    log.info("training: %d iterations x %d env steps, %d scheduler + %d new-skill updates per iteration",
             num_iterations, trainer.steps_per_iteration, trainer.scheduler_updates, trainer.new_skill_updates)
    host_state = host_state or {}
    metrics: dict = dict(host_state.get("metrics") or {})
    t0 = time.perf_counter() - float(host_state.get("wall_time", 0.0))
    eval_base_key = jax.random.PRNGKey(seed + 10_000)
    acc = _Accumulator.from_dict(host_state.get("accumulator"))
    spi = trainer.steps_per_iteration
    for it in range(start, num_iterations):
        state, train_m = iteration(state)
        acc.add(train_m)
        if step_fn is not None:
            step_fn((it + 1) * spi)
        last = it == num_iterations - 1
        evaluate = (it + 1) % config.eval_every == 0 or last
        if evaluate:
            # Derived from (seed, iteration), not from the loop's history: a resumed run draws
            # the same evaluation episodes as an uninterrupted one.
            k1, k2 = jax.random.split(jax.random.fold_in(eval_base_key, it + 1))
            ev_new = eval_new(state.new_skill.policy_params, state.normalizer, k1)
            metrics = acc.summary(train_m)
            acc = _Accumulator()
            metrics["eval/new_skill_success"] = float(jnp.mean(ev_new["success"]))
            metrics["eval/new_skill_return"] = float(jnp.mean(ev_new["return"]))
            if config.method == "skills":
                ev_s = eval_sched(state.scheduler.policy_params, state.new_skill.policy_params, state.normalizer, k2)
                metrics["eval/scheduler_success"] = float(jnp.mean(ev_s["success"]))
                metrics["eval/scheduler_return"] = float(jnp.mean(ev_s["return"]))
            metrics["env_steps"] = int(state.env_steps)
            metrics["wall_time"] = time.perf_counter() - t0
            metrics["iteration"] = it + 1
            if progress_fn is not None:
                progress_fn(int(state.env_steps), metrics)
        if checkpoint_fn is not None and (
                last or (evaluate if checkpoint_every is None else
                         (it + 1) * spi // int(checkpoint_every) > it * spi // int(checkpoint_every))):
            checkpoint_fn(state, {"iteration": it + 1, "env_steps": (it + 1) * spi, "metrics": metrics,
                                  "accumulator": acc.to_dict(), "wall_time": time.perf_counter() - t0})
    params = {"new_skill": state.new_skill.policy_params, "scheduler": state.scheduler.policy_params,
              "normalizer": state.normalizer}
    make_policy = make_policy_factory(int(environment.action_size), config, trainer.num_skills_total)
    return make_policy, params, metrics


class _Accumulator:
    """Training-episode statistics summed over the iterations between two reports."""

    SUMMED = ("episodes", "nonfinite_transitions", "skill_histogram", "length_histogram", "skill_steps",
              "skill_runs")

    def __init__(self):
        self.sums: dict = {}
        self.weighted = {"episode_return": 0.0, "episode_success": 0.0}

    def add(self, m):
        m = jax.device_get({k: m[k] for k in self.SUMMED + tuple(self.weighted)})
        for k in self.SUMMED:
            self.sums[k] = self.sums.get(k, 0.0) + np.asarray(m[k], np.float64)
        for k in self.weighted:
            self.weighted[k] += float(m[k]) * float(m["episodes"])

    def to_dict(self) -> dict:
        """JSON-able state (for checkpoints); ``from_dict`` restores it exactly."""
        return {"sums": {k: _to_py(v) for k, v in self.sums.items()}, "weighted": dict(self.weighted)}

    @classmethod
    def from_dict(cls, d: Optional[dict]) -> "_Accumulator":
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
        return out


def _to_py(v):
    a = np.asarray(v)
    return a.tolist() if a.ndim else float(a)
