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

    def _buffer(self, batch_size: int):
        return fbx.make_item_buffer(self.capacity, 1, batch_size, add_batches=True)

    def init(self):
        """An empty buffer whose rows are ``Transition`` (``NStepTransition`` when n_step > 1)."""
        tr = Transition.zeros(self.obs_size, self.action_size)
        if self.n_step > 1:
            z = jnp.zeros((), jnp.float32)
            tr = NStepTransition(**tr.fields(), nstep_reward=z, nstep_discount=z, nstep_next_obs=jnp.zeros((self.obs_size,)),
                                 nstep_weight=z)
        return self._buffer(self.scheduler_batch_size).init(tr)

    def init_pending(self) -> Optional[PendingStep]:
        """n − 1 placeholder steps per env [n − 1, B]: weight 0 (never learnt from), done (no return
        reaches past them). None for 1-step runs."""
        if self.n_step == 1:
            return None
        tr = Transition.zeros(self.obs_size, self.action_size, (self.n_step - 1, self.num_envs))
        return PendingStep(**tr.fields(), done=jnp.ones((self.n_step - 1, self.num_envs), bool))

    def size(self, state) -> jax.Array:
        """Rows stored (int32 scalar)."""
        return jnp.where(state.is_full, self.capacity, state.current_index)

    def insert(self, state, pending: Optional[PendingStep], traj: Transition, done: jax.Array):
        """Insert an unroll ``traj`` [T, B] (``done`` [T, B]: episode ends). n_step > 1: the T steps
        whose n-step returns are now known are inserted (n − 1 steps late) and the last n − 1 are
        kept as the new ``pending``. Returns (state, pending)."""
        t = traj.reward.shape[0]
        if self.n_step > 1:
            step = PendingStep(**traj.fields(), done=done)
            window = jax.tree.map(lambda p, x: jnp.concatenate([p, x], axis=0), pending, step)
            pending = jax.tree.map(lambda x: x[t:], window)
            head = jax.tree.map(lambda x: x[:t], window).one_step()
            fields = nstep.nstep_fields(window, self.n_step, self.discount)
            rows = NStepTransition(**head.fields(), **fields)
        else:
            rows = traj
        flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), rows)  # [T, B, ...] -> [T·B, ...]
        return self._buffer(self.scheduler_batch_size).add(state, flat), pending

    def sample_scheduler(self, state, normalizer, key) -> Transition:
        """A scheduler batch [batch] with normalised observations and no actions ([batch, 0]: the
        scheduler reads none). Its learner adds the augmented labels (``learners.scheduler_labels``)."""
        rows = self._buffer(self.scheduler_batch_size).sample(state, key).experience
        return _normalized(rows.one_step().replace(action=rows.action[:, :0]), normalizer)

    def sample_new_skill(self, state, normalizer, key, raw_obs: bool = False):
        """A new-skill batch [batch] with normalised observations; with n_step > 1 its reward,
        discount, next_obs and weight are the n-step ones. ``raw_obs``: returns (batch, (obs,
        next_obs)), the batch's observations before normalisation [batch, O] each, for what reads
        raw observations (the frozen skills)."""
        rows = self._buffer(self.new_skill_batch_size).sample(state, key).experience
        if self.n_step > 1:
            raw = (rows.obs, rows.nstep_next_obs)
            rows = rows.replace(nstep_next_obs=obs_norm.normalize(normalizer, rows.nstep_next_obs))
            batch = _normalized(rows.as_nstep_target(), normalizer, next_obs=False)
        else:
            raw = (rows.obs, rows.next_obs)
            batch = _normalized(rows, normalizer)
        return (batch, raw) if raw_obs else batch


def _normalized(batch: Transition, normalizer, next_obs: bool = True) -> Transition:
    obs = obs_norm.normalize(normalizer, batch.obs)
    if not next_obs:
        return batch.replace(obs=obs)
    return batch.replace(obs=obs, next_obs=obs_norm.normalize(normalizer, batch.next_obs))
