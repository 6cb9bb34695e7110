"""research/op3_schedules.py: the schedule grammar and the per-step skill choice."""

import jax.numpy as jnp
import numpy as np
import pytest

from training.cli import UsageError
from research import op3_schedules as S


def test_parse_schedule():
    assert S.parse_schedule("getup") == ("getup", None)
    assert S.parse_schedule("walk_then_getup:103") == ("walk_then_getup", 103)
    assert S.parse_schedule("random:10") == ("random", 10)
    for bad in ("run", "random", "random:0", "walk:3", "walk_then_getup:x"):
        with pytest.raises(UsageError, match="bad schedule"):
            S.parse_schedule(bad)


def test_choose():
    prev = jnp.array([0, 1, 1], jnp.int32)
    coin = jnp.array([1, 0, 1], jnp.int32)
    stand_run = jnp.array([0.0, 19.0, 20.0])
    c = lambda name, arg, t: np.asarray(S.choose(name, arg, t, stand_run, prev, coin, 20))  # noqa: E731
    np.testing.assert_array_equal(c("getup", None, 5), [0, 0, 0])
    np.testing.assert_array_equal(c("walk", None, 5), [1, 1, 1])
    np.testing.assert_array_equal(c("getup_then_walk", None, 5), [0, 0, 1])  # standing for ≥ 20 steps
    np.testing.assert_array_equal(c("walk_then_getup", 3, 2), [1, 1, 1])
    np.testing.assert_array_equal(c("walk_then_getup", 3, 3), [0, 0, 0])
    np.testing.assert_array_equal(c("random", 10, 20), coin)  # a new coin every K steps
    np.testing.assert_array_equal(c("random", 10, 21), prev)  # else the running choice
