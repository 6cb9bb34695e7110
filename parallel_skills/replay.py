"""Replay: the transition type, insert (with the n-step window) and one sampler per learner
(docs/design.md "Data flow", "Augmentation").

One flashbax item buffer holds every low-level transition, whichever skill acted; both learners
sample it, each with its own batch size (two flashbax views of the same buffer state). Inserting
is O(rows inserted), never O(buffer). Samples are normalised with the observation statistics at
sampling time; the scheduler's learner adds the augmented labels (paper §4.4).
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import flashbax as fbx
import jax
import jax.numpy as jnp
from flax import struct

from parallel_skills import normalization as obs_norm
from parallel_skills import nstep
from parallel_skills.augmentation import augment_labels_indexed


@struct.dataclass
class Transition:
    """One low-level step (s, a, r, s') with the scheduler's labels; every field has leading batch
    axes [...] (e.g. [T, B] from the collector, [N] in a learner batch).

    obs [..., O], action [..., A], reward [...], discount [...] (0 at termination, 1 otherwise
    — a time-limit truncation bootstraps from next_obs, the true last observation), next_obs
    [..., O], skill [...] int32 (i: the skill that acted; N = the new skill), k_idx [...] int32
    (index of its length k in K), c [...] int32 (the counter: steps left including this one),
    is_decision [...] bool (the scheduler chose z = (i, k) at this step), weight [...] float32
    (0: never learnt from, e.g. a non-finite step or an augmented duplicate that does not apply).
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    discount: jax.Array
    next_obs: jax.Array
    skill: jax.Array
    k_idx: jax.Array
    c: jax.Array
    is_decision: jax.Array
    weight: jax.Array

    @classmethod
    def zeros(cls, obs_size: int, action_size: int, shape: tuple = ()) -> "Transition":
        f, i = jnp.float32, jnp.int32
        return cls(obs=jnp.zeros(shape + (obs_size,), f), action=jnp.zeros(shape + (action_size,), f),
                   reward=jnp.zeros(shape, f), discount=jnp.zeros(shape, f),
                   next_obs=jnp.zeros(shape + (obs_size,), f), skill=jnp.zeros(shape, i),
                   k_idx=jnp.zeros(shape, i), c=jnp.zeros(shape, i), is_decision=jnp.zeros(shape, bool),
                   weight=jnp.zeros(shape, f))

    @classmethod
    def batch(cls, *, obs, reward, discount, next_obs, action=None, skill=None, k_idx=None, c=None,
              is_decision=None, weight=None) -> "Transition":
        """A learner batch [B] from arrays. Fields a learner does not read may be left out: the new
        skill's learner reads no labels (skill, k_idx, c, is_decision: 0), the scheduler's no
        action ([B, 0]); weight defaults to 1."""
        b = jnp.shape(reward)[0]
        zi = jnp.zeros((b,), jnp.int32)
        return cls(obs=obs, action=jnp.zeros((b, 0), jnp.float32) if action is None else action, reward=reward,
                   discount=discount, next_obs=next_obs, skill=zi if skill is None else skill,
                   k_idx=zi if k_idx is None else k_idx, c=zi if c is None else c,
                   is_decision=jnp.zeros((b,), bool) if is_decision is None else is_decision,
                   weight=jnp.ones((b,), jnp.float32) if weight is None else weight)

    def fields(self) -> dict:
        """The ``Transition`` fields of this row (a subclass's extra fields left out), by name."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(Transition)}

    def one_step(self) -> "Transition":
        """The plain ``Transition`` (drops the subclasses' extra fields)."""
        return Transition(**self.fields())


@struct.dataclass
class NStepTransition(Transition):
    """A ``Transition`` with its n-step return (``nstep.nstep_fields``): what replay stores when
    ``new_skill.n_step > 1``. nstep_reward / nstep_discount / nstep_weight [...],
    nstep_next_obs [..., O]."""

    nstep_reward: jax.Array
    nstep_discount: jax.Array
    nstep_next_obs: jax.Array
    nstep_weight: jax.Array

    def as_nstep_target(self) -> Transition:
        """The 1-step view a learner's target r + γ·d·Q'(s') reads as the n-step one
        R + γ^m·d·Q'(s_{t+m})."""
        return self.one_step().replace(reward=self.nstep_reward, discount=self.nstep_discount,
                                       next_obs=self.nstep_next_obs, weight=self.nstep_weight)


@struct.dataclass
class SchedulerNStepTransition(NStepTransition):
    """An ``NStepTransition`` with the scheduler's n-step return as well (``SchedulerConfig.n_step``
    > 1; ``nstep.execution_nstep_fields``: returns that stop where a skill execution ends):
    sched_reward / sched_discount / sched_weight [...], sched_next_obs [..., O], sched_steps [...]
    int32 (m, the steps the return spans)."""

    sched_reward: jax.Array
    sched_discount: jax.Array
    sched_next_obs: jax.Array
    sched_weight: jax.Array
    sched_steps: jax.Array


@struct.dataclass
class SchedulerBatch(Transition):
    """A scheduler learner batch [B]: reward / discount / next_obs / weight are those of the target
    R + γ^m·d·V'(s_{t+m}) (for m = 1 the one-step ones), ``steps`` [B] int32 is m."""

    steps: jax.Array


@struct.dataclass
class PendingStep(Transition):
    """A collected step waiting for its n-step return (``done`` [...] bool: the episode ended at
    this step)."""

    done: jax.Array


@dataclasses.dataclass(frozen=True)
class Replay:
    """Pure insert / sample functions of one run's buffer (state: a flashbax buffer state)."""

    capacity: int
    num_envs: int
    obs_size: int
    action_size: int
    scheduler_batch_size: int
    new_skill_batch_size: int
    n_step: int = 1
    discount: float = 0.99
    # The scheduler's n-step returns (SchedulerConfig.n_step; 1: one-step Eq. 3), its discount, K
    # and whether its learner augments (the returns stop where the duplicate's executions end too).
    scheduler_n_step: int = 1
    scheduler_discount: float = 0.99
    skill_lengths: tuple = (10,)
    augmentation: bool = True
    # NewSkillConfig.n_step_returns "own": the new skill's n-step returns stop before another
    # skill's step (nstep.own_nstep_fields); None: the behaviour's next n steps. The value is the
    # new skill's index N in ``Transition.skill``.
    own_returns_index: Optional[int] = None

    @property
    def window(self) -> int:
        """Steps an insert needs to see past a step: the longer of the two n-step returns."""
        return max(int(self.n_step), int(self.scheduler_n_step))

    def _buffer(self, batch_size: int):
        return fbx.make_item_buffer(self.capacity, 1, batch_size, add_batches=True)

    def init(self):
        """An empty buffer whose rows are ``Transition`` (``NStepTransition`` when n_step > 1,
        ``SchedulerNStepTransition`` when scheduler_n_step > 1)."""
        tr = Transition.zeros(self.obs_size, self.action_size)
        z, obs = jnp.zeros((), jnp.float32), jnp.zeros((self.obs_size,))
        if self.n_step > 1 or self.scheduler_n_step > 1:
            tr = NStepTransition(**tr.fields(), nstep_reward=z, nstep_discount=z, nstep_next_obs=obs, nstep_weight=z)
        if self.scheduler_n_step > 1:
            tr = SchedulerNStepTransition(**tr.fields(), **_nstep_row_fields(tr), sched_reward=z, sched_discount=z,
                                          sched_next_obs=obs, sched_weight=z, sched_steps=jnp.zeros((), jnp.int32))
        return self._buffer(self.scheduler_batch_size).init(tr)

    def init_pending(self) -> Optional[PendingStep]:
        """n − 1 placeholder steps per env [n − 1, B]: weight 0 (never learnt from), done (no return
        reaches past them), n = ``window``. None for 1-step runs."""
        if self.window == 1:
            return None
        tr = Transition.zeros(self.obs_size, self.action_size, (self.window - 1, self.num_envs))
        return PendingStep(**tr.fields(), done=jnp.ones((self.window - 1, self.num_envs), bool))

    def size(self, state) -> jax.Array:
        """Rows stored (int32 scalar)."""
        return jnp.where(state.is_full, self.capacity, state.current_index)

    def insert(self, state, pending: Optional[PendingStep], traj: Transition, done: jax.Array):
        """Insert an unroll ``traj`` [T, B] (``done`` [T, B]: episode ends). n_step > 1: the T steps
        whose n-step returns are now known are inserted (n − 1 steps late) and the last n − 1 are
        kept as the new ``pending``. Returns (state, pending)."""
        t = traj.reward.shape[0]
        if self.window > 1:
            step = PendingStep(**traj.fields(), done=done)
            window = jax.tree.map(lambda p, x: jnp.concatenate([p, x], axis=0), pending, step)
            pending = jax.tree.map(lambda x: x[t:], window)
            head = jax.tree.map(lambda x: x[:t], window).one_step()
            first = lambda n: jax.tree.map(lambda x: x[:t + n - 1], window)  # noqa: E731  (t complete n-step returns)
            if self.own_returns_index is None:
                fields = nstep.nstep_fields(first(self.n_step), self.n_step, self.discount)
            else:
                fields = nstep.own_nstep_fields(first(self.n_step), self.n_step, self.discount,
                                                self.own_returns_index)
            rows = NStepTransition(**head.fields(), **_nstep_row_fields(fields))
            if self.scheduler_n_step > 1:
                sched = first(self.scheduler_n_step)
                sched = nstep.execution_nstep_fields(sched, self.scheduler_n_step, self.scheduler_discount,
                                                     self.execution_ends(sched))
                rows = SchedulerNStepTransition(**rows.fields(), **_nstep_row_fields(rows),
                                                **{f"sched_{k[len('nstep_'):]}": v for k, v in sched.items()})
        else:
            rows = traj
        flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), rows)  # [T, B, ...] -> [T·B, ...]
        return self._buffer(self.scheduler_batch_size).add(state, flat), pending

    def rewarded_fraction(self, state) -> jax.Array:
        """The fraction of stored rows with a positive reward (float32 scalar; 0 when empty)."""
        reward = state.experience.reward.reshape(-1)
        stored = jnp.arange(reward.shape[0]) < self.size(state)
        return jnp.sum(stored & (reward > 0)) / jnp.maximum(self.size(state), 1).astype(jnp.float32)

    def execution_ends(self, steps) -> jax.Array:
        """[...] bool: the skill execution of each step (``Transition`` labels k_idx, c) ends at it,
        in the scheduler's labelling and, with the augmentation, in its duplicate's (c̄ = 1)."""
        c = steps.c
        if self.augmentation:
            _, c, _, _ = augment_labels_indexed(steps.k_idx, steps.c, self.skill_lengths)
        return c == 1

    def sample_scheduler(self, state, normalizer, key) -> SchedulerBatch:
        """A scheduler batch [batch] with normalised observations and no actions ([batch, 0]: the
        scheduler reads none); with scheduler_n_step > 1 its reward, discount, next_obs and weight
        are the n-step ones (``SchedulerBatch.steps`` = m). Its learner adds the augmented labels
        (``learners.scheduler_labels``)."""
        rows = self._buffer(self.scheduler_batch_size).sample(state, key).experience
        one = rows.one_step().replace(action=rows.action[:, :0])
        if self.scheduler_n_step > 1:
            one = one.replace(reward=rows.sched_reward, discount=rows.sched_discount, next_obs=rows.sched_next_obs,
                              weight=rows.sched_weight)
            steps = rows.sched_steps
        else:
            steps = jnp.ones(rows.reward.shape, jnp.int32)
        return _normalized(SchedulerBatch(**one.fields(), steps=steps), normalizer)

    def sample_new_skill(self, state, normalizer, key, raw_obs: bool = False):
        """A new-skill batch [batch] with normalised observations; with n_step > 1 its reward,
        discount, next_obs and weight are the n-step ones. ``raw_obs``: returns (batch, (obs,
        next_obs)), the batch's observations before normalisation [batch, O] each, for what reads
        raw observations (the frozen skills)."""
        rows = self._buffer(self.new_skill_batch_size).sample(state, key).experience
        if self.n_step > 1 or self.scheduler_n_step > 1:  # (n_step 1: the n-step fields are the 1-step ones)
            raw = (rows.obs, rows.nstep_next_obs)
            rows = rows.replace(nstep_next_obs=obs_norm.normalize(normalizer, rows.nstep_next_obs))
            batch = _normalized(rows.as_nstep_target(), normalizer, next_obs=False)
        else:
            raw = (rows.obs, rows.next_obs)
            batch = _normalized(rows, normalizer)
        return (batch, raw) if raw_obs else batch


def _nstep_row_fields(fields) -> dict:
    """The ``NStepTransition`` fields of a dict of ``nstep.nstep_fields`` or of a row."""
    get = fields.get if isinstance(fields, dict) else lambda k: getattr(fields, k)  # noqa: E731
    return {k: get(k) for k in ("nstep_reward", "nstep_discount", "nstep_next_obs", "nstep_weight")}


def _normalized(batch: Transition, normalizer, next_obs: bool = True) -> Transition:
    obs = obs_norm.normalize(normalizer, batch.obs)
    if not next_obs:
        return batch.replace(obs=obs)
    return batch.replace(obs=obs, next_obs=obs_norm.normalize(normalizer, batch.next_obs))
