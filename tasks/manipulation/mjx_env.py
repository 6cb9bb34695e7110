"""Physics manipulation domain on MuJoCo MJX (``impl="jax"``) or MJX-Warp (``impl="warp"``).

The same scene, action mapping, observation, grasp flag and reset sampler as the classic MuJoCo
backend (``physics_np``, called here with ``jax.numpy``), stepped by ``mjx.step`` in float32:
jittable and vmappable, on GPU the fast path. On a 2-core CPU MJX-jax can deadlock at large
batches unless the process is pinned to one core (shared/STACK.md): ``pin_to_one_core()``.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import State
from mujoco import mjx

from tasks.manipulation import layout as L
from tasks.manipulation.env_base import ManipulationEnv
from tasks.manipulation import physics_np as P
from tasks.manipulation import task_defs

IMPLS = ("jax", "warp")
_INTEGRATION_FIELDS = ("time", "qpos", "qvel", "act", "qacc_warmstart", "ctrl")


def pin_to_one_core(core: int | None = None) -> None:
    """Pin this process to one CPU core (avoids the MJX-jax batched-Cholesky deadlock on CPU)."""
    if hasattr(os, "sched_setaffinity"):
        cores = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cores[0] if core is None else core})


def _data_from(data0, qpos, act, qvel=None):
    qvel = jnp.zeros(P.NV, jnp.float32) if qvel is None else jnp.asarray(qvel, jnp.float32)
    return data0.replace(qpos=jnp.asarray(qpos, jnp.float32), qvel=qvel, act=jnp.asarray(act, jnp.float32))


def _fresh_data(data0, rng):
    u = jax.random.uniform(rng, (P.NUM_UNIFORMS,), jnp.float32)
    qpos, act = P.sample_init(u, jnp)
    return _data_from(data0, qpos, act)


_PHYSICS_CACHE: dict = {}


WARP_CONTACTS_PER_ENV = 48  # contact buffer per env (MJX-Warp shares one buffer across the batch)
WARP_NJMAX = 256  # constraint rows per env


def _physics(impl: str, overrides: tuple, max_envs: int = 256):
    """(mjx model, template data, jitted agent-step physics) for one (impl, physics options),
    shared by every task: all tasks of a process compile the physics once (eager / vmapped calls;
    inside an outer jit it is inlined)."""
    key = (impl, overrides, max_envs if impl == "warp" else None)
    if key not in _PHYSICS_CACHE:
        mj_model, substeps = P.load_model(**dict(overrides))
        model = mjx.put_model(mj_model, impl=impl)
        if impl == "warp":  # the contact buffer is shared by all envs of a vmapped batch
            data0 = mjx.make_data(mj_model, impl=impl, naconmax=WARP_CONTACTS_PER_ENV * max_envs, njmax=WARP_NJMAX)
        else:
            data0 = mjx.make_data(mj_model, impl=impl)  # template, made outside any trace

        @jax.jit
        def physics(data, action, rng):
            """One agent step: (data, action [5], rng) -> (data, blown-up flag, rng)."""
            data = data.replace(ctrl=P.action_to_ctrl(action.astype(jnp.float32), jnp))

            def substep(d, _):
                return mjx.step(model, d), None

            data, _ = jax.lax.scan(substep, data, None, length=substeps)
            data = data.replace(act=P.clamp_windup(data.qpos, data.act, jnp))
            bad = P.unstable(data.qpos, data.qvel, jnp) | ~jnp.all(jnp.isfinite(data.act))
            rng, key = jax.random.split(rng)
            fresh = _fresh_data(data0, key)
            # Only the integration state is swapped (everything else is recomputed from it by the
            # next mjx.step; a whole-pytree select also trips MJX-Warp's FFI buffers under vmap).
            data = data.replace(
                **{k: jnp.where(bad, getattr(fresh, k), getattr(data, k)) for k in _INTEGRATION_FIELDS}
            )
            return data, bad, rng

        _PHYSICS_CACHE[key] = (model, data0, physics)
    return _PHYSICS_CACHE[key]


class MjxManipulationEnv(ManipulationEnv):
    """Brax-API env of the physics manipulation domain on MJX (impl ``jax`` or ``warp``).

    ``pipeline_state`` is the ``mjx.Data``. ``step`` never auto-resets: at the time limit ``done``
    = 1 and ``info["truncation"]`` = 1. A non-finite or blown-up physics state restarts that env
    from a fresh random state, sets ``info["nan_reset"]`` = 1 and increments
    ``metrics["nan_resets"]``; observations and rewards are always finite.
    """

    def __init__(self, task_name: str, impl: str = "jax", episode_length: int = L.DEFAULT_EPISODE_LENGTH,
                 max_envs: int = 256, **overrides: Any):
        if impl not in IMPLS:
            raise ValueError(f"unknown MJX impl {impl!r}; valid: {', '.join(IMPLS)}")
        if int(episode_length) < 1:
            raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
        self.task = task_defs.get(task_name)
        self.task_name = task_name
        self.impl = impl
        self.episode_length = int(episode_length)
        self.mj_model, self.substeps = P.load_model(**overrides)  # validates the options
        self.max_envs = int(max_envs)
        self.model, self._data0, self._physics = _physics(impl, tuple(sorted(overrides.items())), self.max_envs)

    # --- helpers -------------------------------------------------------------------------
    def _fresh_data(self, rng: jax.Array):
        return _fresh_data(self._data0, rng)

    def data_from(self, qpos: jax.Array, act: jax.Array, qvel: jax.Array | None = None):
        """An ``mjx.Data`` at the given joint state (e.g. a twin's state, for agreement tests)."""
        return _data_from(self._data0, qpos, act, qvel)

    def _reward(self, data):
        inp = P.task_inputs(data.qpos, data.act, jnp)
        return self.task.reward(inp).astype(jnp.float32), self.task.success(inp).astype(jnp.float32)

    def _obs(self, data):
        return P.observe(data.qpos, data.qvel, data.act, jnp).astype(jnp.float32)

    def state_from(self, data, rng: jax.Array) -> State:
        """A fresh-episode ``State`` at physics ``data``."""
        _, success = self._reward(data)
        zero = jnp.zeros((), jnp.float32)
        return State(
            pipeline_state=data,
            obs=self._obs(data),
            reward=zero,
            done=zero,
            metrics={"reward": zero, "success": success, "nan_resets": zero},
            info={"steps": jnp.zeros((), jnp.int32), "truncation": zero, "nan_reset": zero, "rng": rng},
        )

    # --- Brax API ------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        rng, key = jax.random.split(rng)
        return self.state_from(self._fresh_data(key), rng)

    def step(self, state: State, action: jax.Array) -> State:
        data, bad, rng = self._physics(state.pipeline_state, action, state.info["rng"])
        reward, success = self._reward(data)
        steps = state.info["steps"] + 1
        done = (steps >= self.episode_length).astype(jnp.float32)
        badf = bad.astype(jnp.float32)
        info = dict(state.info, steps=steps, truncation=done, nan_reset=badf, rng=rng)
        metrics = dict(state.metrics, reward=reward, success=success,
                       nan_resets=state.metrics.get("nan_resets", 0.0) + badf)
        return state.replace(pipeline_state=data, obs=self._obs(data), reward=reward, done=done,
                             metrics=metrics, info=info)

    @property
    def backend(self) -> str:
        return "mjx" if self.impl == "jax" else "warp"


def make_mjx_env(task_name: str, impl: str = "jax", episode_length: int = L.DEFAULT_EPISODE_LENGTH,
                 max_envs: int = 256, **overrides: Any) -> MjxManipulationEnv:
    """Brax-API env of task ``task_name`` (any of ``task_defs.names()``) on MJX, ``impl`` "jax" or
    "warp". ``overrides``: physics options of ``physics_np.load_model`` (timestep, substeps,
    iterations, ls_iterations, ...). ``max_envs`` (warp only): the largest vmapped batch; MJX-Warp
    shares one contact buffer across the batch, sized ``WARP_CONTACTS_PER_ENV × max_envs``
    (contacts beyond it are dropped with an overflow warning)."""
    return MjxManipulationEnv(task_name, impl=impl, episode_length=episode_length, max_envs=max_envs, **overrides)
