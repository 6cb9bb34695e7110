import numpy as np
import jax
import jax.numpy as jnp

from parallel_skills.counters import advance_counters

K = (2, 3, 5)


def _run(k_choices, new_episode_flags, i_choices=None):
    """Scan advance_counters over time for one env; returns per-step arrays."""
    T = len(new_episode_flags)
    if i_choices is None:
        i_choices = list(range(T))
    c, i, k = jnp.zeros(1, jnp.int32), jnp.zeros(1, jnp.int32), jnp.zeros(1, jnp.int32)
    out = []
    step = jax.jit(advance_counters, static_argnums=6)
    for t in range(T):
        c, i, k, d = step(c, i, k, jnp.array([i_choices[t]]), jnp.array([k_choices[t]]),
                          jnp.array([new_episode_flags[t]]), K)
        out.append((int(c[0]), int(i[0]), int(k[0]), bool(d[0])))
    return out


def test_counter_sequence_with_reset_mid_skill():
    # k choices offered at each step (used only at decisions): index into K=(2,3,5).
    #  t:        0  1  2  3  4  5  6  7  8  9 10
    k_choices = [1, 0, 0, 2, 0, 0, 0, 0, 0, 0, 1]
    new_ep = [True, False, False, False, False, True, False, False, False, False, False]
    out = _run(k_choices, new_ep)
    c = [o[0] for o in out]
    d = [o[3] for o in out]
    i = [o[1] for o in out]
    # t0 decision k=3: c=3,2,1; t3 decision k=5: c=5,4; reset at t5 mid-skill -> decision k=K[0]=2:
    # c=2,1; t7 decision k=2: 2,1; t9 decision k=2 : 2, t10 c=1.
    assert c == [3, 2, 1, 5, 4, 2, 1, 2, 1, 2, 1]
    assert d == [True, False, False, True, False, True, False, True, False, True, False]
    # skill index carries over between decisions.
    assert i == [0, 0, 0, 3, 3, 5, 5, 7, 7, 9, 9]
    k_idx = [o[2] for o in out]
    assert k_idx == [1, 1, 1, 2, 2, 0, 0, 0, 0, 0, 0]


def test_batch_elementwise():
    c_prev = jnp.array([0, 1, 2, 4, 3])
    new_ep = jnp.array([False, False, False, False, True])
    c, i, k, d = advance_counters(c_prev, jnp.full(5, 7), jnp.full(5, 1), jnp.arange(5),
                                  jnp.array([2, 2, 2, 2, 0]), new_ep, K)
    np.testing.assert_array_equal(c, [5, 5, 1, 3, 2])
    np.testing.assert_array_equal(d, [True, True, False, False, True])
    np.testing.assert_array_equal(i, [0, 1, 7, 7, 4])
    np.testing.assert_array_equal(k, [2, 2, 1, 1, 0])
