"""Running observation normalisation (Welford / Chan parallel update), as Brax and Acme do.

Every network (scheduler, critics, new skill) sees ``normalize(stats, obs)``; the statistics are
updated from each iteration's collected observations and exported with the policies.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

STD_FLOOR = 1e-3
CLIP = 10.0


@struct.dataclass
class RunningStats:
    """count []; mean [O]; m2 [O] (sum of squared deviations)."""

    count: jax.Array
    mean: jax.Array
    m2: jax.Array


def init(size: int) -> RunningStats:
    return RunningStats(jnp.zeros(()), jnp.zeros((size,)), jnp.zeros((size,)))


def update(stats: RunningStats, batch: jax.Array, weight: jax.Array | None = None) -> RunningStats:
    """Merge a batch [N, O] (rows with weight 0 ignored) into the statistics."""
    w = jnp.ones(batch.shape[:1]) if weight is None else weight.astype(jnp.float32)
    n = jnp.sum(w)
    b_mean = jnp.sum(batch * w[:, None], 0) / jnp.maximum(n, 1.0)
    b_m2 = jnp.sum(jnp.square(batch - b_mean) * w[:, None], 0)
    total = stats.count + n
    delta = b_mean - stats.mean
    mean = stats.mean + delta * n / jnp.maximum(total, 1.0)
    m2 = stats.m2 + b_m2 + jnp.square(delta) * stats.count * n / jnp.maximum(total, 1.0)
    return RunningStats(total, mean, m2)


def std(stats: RunningStats) -> jax.Array:
    return jnp.maximum(jnp.sqrt(stats.m2 / jnp.maximum(stats.count, 1.0)), STD_FLOOR)


def normalize(stats: RunningStats, obs: jax.Array) -> jax.Array:
    """(obs - mean) / std, clipped to ±10. obs [..., O]."""
    return jnp.clip((obs - stats.mean) / std(stats), -CLIP, CLIP)
