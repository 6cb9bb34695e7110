"""Scheduler data augmentation (paper §4.4, App. A.2 Eq. 7; docs/design.md "Augmentation").

A skill execution of length k* that is a multiple of k_min = min(K) is also labelled as
if the scheduler had chosen the same skill with k_min repeatedly. Only the labels
(k, c, is_decision) change, so every stored step can carry both labellings and the
learner trains on both (the duplicate gets sample weight 0 where it does not apply).

Labels are per step, so executions cut short by the episode end (or by an auto-reset)
are handled automatically: each surviving step is relabelled from its own counter.

Choice made here: when k* == k_min the duplicate would be *identical* to the original,
so ``applies`` is False there (the data is not counted twice). Only k* > k_min with
k* mod k_min == 0 produces a duplicate.
"""

from __future__ import annotations

from typing import Sequence, Tuple

import jax
import jax.numpy as jnp


def augment_labels(
    k_value: jnp.ndarray, c: jnp.ndarray, k_min: int
) -> Tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """Duplicate labels of App. A.2 Eq. 7, elementwise over any shape [...].

    For a step of an execution of length k with counter c (c ∈ {k, ..., 1}):
      if k mod k_min == 0 and k > k_min:
        k̄ = k_min,  c̄ = ((c − 1) mod k_min) + 1,  is_decision̄ = (c̄ == k_min)
      else: labels unchanged (k̄ = k, c̄ = c, is_decision̄ = (c == k)), applies = False.

    NOTE: the paper prints c̄ = c − ⌊c/k_min − 1⌋·k_min for c > k_min; that formula is wrong
    (e.g. c = 51, k_min = 10 gives 11, outside 1..k_min). We implement the intended
    mapping ((c − 1) mod k_min) + 1, which counts k_min, ..., 1 repeatedly.

    Args:
      k_value: [...] int, the executed skill length k (a value in K, not an index).
      c: [...] int, the counter (steps left including this one), 1 ≤ c ≤ k.
      k_min: static int, the smallest length in K.

    Returns:
      (k_aug [...] int32, c_aug [...] int32, is_decision_aug [...] bool, applies [...] bool).
    """
    k_value = jnp.asarray(k_value, jnp.int32)
    c = jnp.asarray(c, jnp.int32)
    applies = (k_value % k_min == 0) & (k_value > k_min)
    c_dup = (c - 1) % k_min + 1
    k_aug = jnp.where(applies, k_min, k_value).astype(jnp.int32)
    c_aug = jnp.where(applies, c_dup, c).astype(jnp.int32)
    is_decision_aug = c_aug == k_aug
    return k_aug, c_aug, is_decision_aug, applies


def augment_labels_indexed(
    k_idx: jnp.ndarray, c: jnp.ndarray, skill_lengths: Sequence[int]
) -> Tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """Same as ``augment_labels`` but on length *indices* into K (what replay stores).

    Args:
      k_idx: [...] int, index of the executed length in ``skill_lengths``.
      c: [...] int counter.
      skill_lengths: static tuple K.

    Returns:
      (k_idx_aug [...] int32 (index of k_min in K where applies, else k_idx),
       c_aug [...] int32, is_decision_aug [...] bool, applies [...] bool).
    """
    lengths = jnp.asarray(skill_lengths, jnp.int32)
    k_min = int(min(skill_lengths))
    k_min_idx = int(list(skill_lengths).index(k_min))
    k_idx = jnp.asarray(k_idx, jnp.int32)
    _, c_aug, is_decision_aug, applies = augment_labels(lengths[k_idx], c, k_min)
    k_idx_aug = jnp.where(applies, k_min_idx, k_idx).astype(jnp.int32)
    return k_idx_aug, c_aug, is_decision_aug, applies


def augment_batch(batch, skill_lengths: Sequence[int]):
    """The duplicate of a scheduler batch (a ``replay.Transition`` [B]).

    Relabels ``k_idx``, ``c``, ``is_decision`` and multiplies ``weight`` by ``applies``; other
    fields are shared. Rows where augmentation does not apply keep their original labels
    (including the original ``is_decision``) with weight 0.
    """
    k_idx_aug, c_aug, is_decision_aug, applies = augment_labels_indexed(batch.k_idx, batch.c, skill_lengths)
    return batch.replace(k_idx=k_idx_aug, c=c_aug,
                         is_decision=jnp.where(applies, is_decision_aug, batch.is_decision),
                         weight=batch.weight * applies.astype(batch.weight.dtype))


def with_augmentation(batch, skill_lengths: Sequence[int]):
    """Original batch [B] concatenated with its duplicate -> batch [2B] (originals first)."""
    aug = augment_batch(batch, skill_lengths)
    return jax.tree.map(lambda a, b: jnp.concatenate([a, b], axis=0), batch, aug)
