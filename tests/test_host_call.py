"""tasks.host_call: pure_callback semantics (broadcast_all under vmap, jit, eager) with the host
function receiving NumPy arrays, so it never waits on an asynchronous device_put (the mujoco
backends' deadlock when pinned to one core)."""

import jax
import jax.numpy as jnp
import numpy as np

from tasks.host_call import host_call


def _host(seen):
    def fn(x, y):
        seen.append((type(x), type(y), x.shape, y.shape))
        return {"sum": (x + y[..., :1]).astype(np.float32), "n": np.full(x.shape[:-1], x.shape[-1], np.int32)}
    return fn


def _shapes(d):
    return {"sum": jax.ShapeDtypeStruct((d,), jnp.float32), "n": jax.ShapeDtypeStruct((), jnp.int32)}


def test_host_call_matches_pure_callback_under_jit_vmap_and_eager():
    seen = []
    fn = _host(seen)
    x = jnp.arange(12.0, dtype=jnp.float32).reshape(3, 4)
    y = jnp.ones((2,), jnp.float32)  # unbatched: broadcast to the batch

    def both(call):
        f = jax.jit(jax.vmap(lambda a: call(fn, _shapes(4), a, y)))
        return f(x)

    ours = both(host_call)
    ref = both(lambda f, s, *a: jax.pure_callback(f, s, *a, vmap_method="broadcast_all"))
    for k in ours:
        np.testing.assert_array_equal(np.asarray(ours[k]), np.asarray(ref[k]))
    np.testing.assert_array_equal(ours["sum"], np.asarray(x) + 1.0)
    np.testing.assert_array_equal(ours["n"], [4, 4, 4])
    # host_call's call got the whole batch, with y broadcast, as NumPy arrays (pure_callback's got jax Arrays)
    assert seen[0] == (np.ndarray, np.ndarray, (3, 4), (3, 2))
    assert seen[1][2:] == ((3, 4), (3, 2)) and seen[1][0] is not np.ndarray

    # nested vmap: both batch axes in front, as broadcast_all; eager (no jit) too
    z = jnp.arange(24.0, dtype=jnp.float32).reshape(2, 3, 4)
    out = jax.vmap(jax.vmap(lambda a: host_call(fn, _shapes(4), a, y)))(z)
    assert seen[-1][2:] == ((2, 3, 4), (2, 3, 2))
    np.testing.assert_array_equal(out["sum"], np.asarray(z) + 1.0)
    single = host_call(fn, _shapes(4), x[0], y)
    np.testing.assert_array_equal(single["sum"], np.asarray(x[0]) + 1.0)


def test_host_call_large_arguments_in_a_scan():
    """1.6 MB arguments (pure_callback's device_put of these is often asynchronous) through 20
    chained calls inside one jitted scan: the host function sees each previous result exactly."""
    seen = []

    def inc(w):
        seen.append(type(w))
        return w + np.uint32(1)

    def body(c, _):
        return host_call(inc, jax.ShapeDtypeStruct(c.shape, c.dtype), c), ()

    out = jax.jit(lambda c: jax.lax.scan(body, c, None, length=20)[0])(jnp.zeros((400_000,), jnp.uint32))
    assert int(out.min()) == 20 == int(out.max())
    assert set(seen) == {np.ndarray}
