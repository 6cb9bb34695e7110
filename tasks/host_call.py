"""``host_call``: ``jax.pure_callback(..., vmap_method="broadcast_all")`` whose host function gets
XLA's host buffers as NumPy arrays, for the CPU physics backends (classic MuJoCo stepped from jitted
JAX code: tasks/manipulation/mujoco_env.py, tasks/locomotion/env.py).

Why not ``jax.pure_callback`` itself: before calling the host function, ``pure_callback``
``device_put``s each argument to the CPU device as a ``jax.Array``. For an argument of ≳ 100 kB
that copy is asynchronous (jax 0.10.2: 64 of 400 1.6 MB arguments were not ready when the host
function started), and the host function's first ``np.asarray`` waits for it from inside an XLA
worker thread. When that worker is the one thread XLA has (a process pinned to one core) the wait
never ends: the mujoco backend deadlocked this way in long OP3 get-up searches (batch 200 × ~1 kB
physics states; docs/research/op3_skills.md). ``host_call`` hands the host function the NumPy arrays the XLA
callback receives, with no copy and nothing to wait for, and is otherwise the same primitive:
no JVP / transpose, and under ``vmap`` every argument is broadcast to the batch (leading axis), so
one call receives the whole env batch.

The lowering uses ``jax.interpreters.mlir.emit_python_callback`` (exported, unstable) and the
callback sharding rule of ``jax._src.callback`` (private). If either moves in a later jax, ``host_call``
falls back to ``jax.pure_callback`` (correct, with the wait above) rather than failing.
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

try:  # the fast path's pieces (see the module docstring)
    from jax.extend.core import Primitive
    from jax.interpreters import batching, mlir
    from jax._src.callback import _callback_op_sharding
    from jax._src.core import ShapedArray
    _AVAILABLE = hasattr(mlir, "emit_python_callback")
except ImportError:  # pragma: no cover - depends on the jax version
    _AVAILABLE = False


class _Flat:
    """The host function on flat NumPy arguments, returning a flat tuple (hashable by identity, so the
    primitive's params stay hashable)."""

    def __init__(self, fn: Callable, treedef):
        self.fn, self.treedef = fn, treedef

    def __eq__(self, other) -> bool:
        return isinstance(other, _Flat) and (self.fn, self.treedef) == (other.fn, other.treedef)

    def __hash__(self) -> int:
        return hash((self.fn, self.treedef))

    def __call__(self, *args: np.ndarray) -> list:
        out = self.fn(*args)
        leaves, treedef = jax.tree.flatten(out)
        if treedef != self.treedef:
            raise TypeError(f"host_call: {getattr(self.fn, '__name__', self.fn)} returned structure {treedef}, "
                            f"expected {self.treedef}")
        return leaves


if _AVAILABLE:
    host_call_p = Primitive("parallel_skills_host_call")
    host_call_p.multiple_results = True

    @host_call_p.def_impl
    def _impl(*args, fn: _Flat, result_avals):
        """Eager (outside jit): the arguments are concrete, ready arrays."""
        outs = fn(*(np.asarray(a) for a in args))
        return [jnp.asarray(np.asarray(o, a.dtype).reshape(a.shape)) for o, a in zip(outs, result_avals)]

    @host_call_p.def_abstract_eval
    def _abstract_eval(*avals, fn: _Flat, result_avals):
        del avals, fn
        return list(result_avals)

    def _batch(args, dims, *, fn: _Flat, result_avals):
        """``broadcast_all``: batch axes to the front, unbatched arguments broadcast to the batch."""
        size = next(a.shape[d] for a, d in zip(args, dims) if d is not None)
        args = [jnp.broadcast_to(a, (size,) + a.shape) if d is None else jnp.moveaxis(a, d, 0)
                for a, d in zip(args, dims)]
        avals = tuple(ShapedArray((size,) + a.shape, a.dtype) for a in result_avals)
        return host_call_p.bind(*args, fn=fn, result_avals=avals), [0] * len(avals)

    batching.primitive_batchers[host_call_p] = _batch

    def _lowering(ctx, *args, fn: _Flat, result_avals):
        del result_avals

        def callback(*flat: np.ndarray):
            outs = fn(*flat)
            return tuple(np.asarray(o, a.dtype).reshape(a.shape) for o, a in zip(outs, ctx.avals_out))

        sharding = _callback_op_sharding(ctx.module_context.axis_context, None, ctx.avals_out)
        result, _, _ = mlir.emit_python_callback(ctx, callback, None, list(args), ctx.avals_in, ctx.avals_out,
                                                 has_side_effect=False, returns_token=False, sharding=sharding)
        return result

    mlir.register_lowering(host_call_p, _lowering, cacheable=False)


def host_call(fn: Callable, result_shape_dtypes: Any, *args: jax.Array) -> Any:
    """``fn(*numpy_args)`` from (jitted, vmapped) JAX code; returns arrays shaped like
    ``result_shape_dtypes`` (a pytree of ``jax.ShapeDtypeStruct``), like ``jax.pure_callback(fn,
    result_shape_dtypes, *args, vmap_method="broadcast_all")``: under ``vmap`` ``fn`` gets every
    argument with the batch dims in front and returns results with them in front. ``fn`` must be
    pure (it may be called again or not at all, as for ``pure_callback``)."""
    if not _AVAILABLE:  # pragma: no cover
        return jax.pure_callback(fn, result_shape_dtypes, *args, vmap_method="broadcast_all")
    leaves, treedef = jax.tree.flatten(result_shape_dtypes)
    avals = tuple(ShapedArray(tuple(s.shape), np.dtype(s.dtype)) for s in leaves)
    outs = host_call_p.bind(*(jnp.asarray(a) for a in args), fn=_Flat(fn, treedef), result_avals=avals)
    return jax.tree.unflatten(treedef, outs)
