"""Scheduler counters (paper §4.1, App. A.1 Eq. 5; docs/design.md "Scheduler and counters").

Convention: the counter c_t is the number of steps left for the current skill,
*including* step t. At a decision step c_t = k_t; then c_{t+1} = c_t − 1; when c_t = 1
the next step is a decision. Episode start (and auto-reset) is always a decision.
Before the first step of a run, use c_prev = 0 (which also forces a decision).
"""

from __future__ import annotations

from typing import Sequence, Tuple

import jax.numpy as jnp


def advance_counters(
    c_prev: jnp.ndarray,
    i_prev: jnp.ndarray,
    k_idx_prev: jnp.ndarray,
    i_new: jnp.ndarray,
    k_idx_new: jnp.ndarray,
    new_episode: jnp.ndarray,
    skill_lengths: Sequence[int],
) -> Tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """One step of the scheduler's option process (App. A.1, Eq. 5), elementwise over [B].

    A decision happens at step t iff c_{t-1} ≤ 1 (previous skill expired; 0 at the very
    start) or ``new_episode`` (episode start / auto-reset). Then
    (c_t, i_t, k_t) = (K[k_idx_new], i_new, k_idx_new); otherwise
    (c_t, i_t, k_t) = (c_{t-1} − 1, i_{t-1}, k_{t-1}).

    Args:
      c_prev, i_prev, k_idx_prev: [B] int, the previous step's counter, skill, length index.
      i_new, k_idx_new: [B] int, a fresh scheduler sample z = (i, k_idx) for this step
        (only used where a decision happens).
      new_episode: [B] bool, true on the first step of an episode.
      skill_lengths: the static tuple K (length M).

    Returns:
      (c [B] int32, i [B] int32, k_idx [B] int32, is_decision [B] bool).
    """
    lengths = jnp.asarray(skill_lengths, dtype=jnp.int32)
    c_prev = jnp.asarray(c_prev, jnp.int32)
    is_decision = (c_prev <= 1) | jnp.asarray(new_episode, bool)
    k_idx_new = jnp.asarray(k_idx_new, jnp.int32)
    c = jnp.where(is_decision, lengths[k_idx_new], c_prev - 1)
    i = jnp.where(is_decision, jnp.asarray(i_new, jnp.int32), jnp.asarray(i_prev, jnp.int32))
    k_idx = jnp.where(is_decision, k_idx_new, jnp.asarray(k_idx_prev, jnp.int32))
    return c.astype(jnp.int32), i.astype(jnp.int32), k_idx.astype(jnp.int32), is_decision
