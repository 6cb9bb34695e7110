"""Physics manipulation domain on classic MuJoCo (C), inside jitted JAX code: the CPU fast path.

``make_mujoco_env(task)`` returns a Brax-API env whose ``reset`` / ``step`` call
``tasks.host_call`` (``jax.pure_callback`` with ``vmap_method="broadcast_all"``, minus its
device_put of the arguments, which can deadlock a process pinned to one core): under ``vmap`` one callback receives the
whole env batch and steps it with a multi-threaded ``mujoco.rollout`` (``physics_np.Stepper``),
observations / rewards from the NumPy code of ``physics_np`` (the same step function as the
JAX-free ``MujocoTwin``). MuJoCo's float64 full physics state (time, qpos, qvel, act) is carried
inside JAX exactly, bit-cast to uint32 pairs (``State.pipeline_state``, uint32 [2·STATE_SIZE]):
trajectories are bitwise those of the twin whatever JAX's float precision.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import State

from tasks.host_call import host_call
from tasks.manipulation import layout as L
from tasks.manipulation.env_base import ManipulationEnv
from tasks.manipulation import physics_np as P
from tasks.manipulation import task_defs

STATE_WORDS = 2 * P.STATE_SIZE


def encode_states(states: np.ndarray) -> np.ndarray:
    """float64 [..., STATE_SIZE] -> uint32 [..., 2·STATE_SIZE] (bit-exact)."""
    return np.ascontiguousarray(states, np.float64).view(np.uint32)


def decode_states(words) -> np.ndarray:
    """uint32 [..., 2·STATE_SIZE] -> float64 [..., STATE_SIZE] (bit-exact)."""
    return np.ascontiguousarray(np.asarray(words), np.uint32).view(np.float64)


def _derived_seeds(words: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Deterministic per-env seeds (for a reset after a physics blow-up) from the state's bits."""
    w = words.astype(np.uint64)
    mix = np.bitwise_xor.reduce(w * np.uint64(0x9E3779B1) + np.arange(w.shape[-1], dtype=np.uint64), axis=-1)
    return (mix ^ (steps.astype(np.uint64) << np.uint64(20))) & np.uint64(0xFFFFFFFF)


class MujocoManipulationEnv(ManipulationEnv):
    """Brax-API env of the physics manipulation domain stepped by classic MuJoCo in a callback.

    ``step`` never auto-resets: at the time limit ``done`` = 1 and ``info["truncation"]`` = 1.
    A physics blow-up restarts that env from a fresh random state and sets
    ``info["nan_reset"]`` = 1 for the transition; ``metrics["nan_resets"]`` counts them.
    """

    def __init__(self, task_name: str, episode_length: int = L.DEFAULT_EPISODE_LENGTH, num_threads: int = 2,
                 **overrides: Any):
        if int(episode_length) < 1:
            raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
        self.task = task_defs.get(task_name)
        self.task_name = task_name
        self.episode_length = int(episode_length)
        self.stepper = P.Stepper(num_threads=num_threads, **overrides)
        self.model = self.stepper.model
        self.substeps = self.stepper.substeps
        self.calls = 0  # number of host callbacks made (step and reset), for benchmarks

    # --- host side ------------------------------------------------------------------------
    def _host_reset(self, seeds):
        seeds = np.asarray(seeds)
        batch = seeds.shape
        states = P.init_states(seeds.reshape(-1))
        reward, success = P.reward_success(self.task, states)
        obs = P.observe_states(states)
        self.calls += 1
        return (
            encode_states(states).reshape(batch + (STATE_WORDS,)),
            obs.astype(np.float32).reshape(batch + (L.OBS_SIZE,)),
            success.astype(np.float32).reshape(batch),
        )

    def _host_step(self, words, actions, steps):
        words = np.asarray(words)
        batch = words.shape[:-1]
        words = words.reshape(-1, STATE_WORDS)
        states = decode_states(words)
        actions = np.asarray(actions, np.float64).reshape(-1, L.ACTION_SIZE)
        steps = np.asarray(steps).reshape(-1)
        new, bad = self.stepper.step(states, actions, reset_seeds=_derived_seeds(words, steps))
        reward, success = P.reward_success(self.task, new)
        obs = P.observe_states(new)
        self.calls += 1
        return (
            encode_states(new).reshape(batch + (STATE_WORDS,)),
            obs.astype(np.float32).reshape(batch + (L.OBS_SIZE,)),
            reward.astype(np.float32).reshape(batch),
            success.astype(np.float32).reshape(batch),
            bad.astype(np.float32).reshape(batch),
        )

    # --- Brax API -------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        seed = jax.random.bits(rng, (), jnp.uint32)  # raw uint32[2] or typed keys
        shapes = (
            jax.ShapeDtypeStruct((STATE_WORDS,), jnp.uint32),
            jax.ShapeDtypeStruct((L.OBS_SIZE,), jnp.float32),
            jax.ShapeDtypeStruct((), jnp.float32),
        )
        words, obs, success = host_call(self._host_reset, shapes, seed)
        zero = jnp.zeros((), jnp.float32)
        return State(
            pipeline_state=words,
            obs=obs,
            reward=zero,
            done=zero,
            metrics={"reward": zero, "success": success, "nan_resets": zero},
            info={"steps": jnp.zeros((), jnp.int32), "truncation": zero, "nan_reset": zero},
        )

    def step(self, state: State, action: jax.Array) -> State:
        shapes = (
            jax.ShapeDtypeStruct((STATE_WORDS,), jnp.uint32),
            jax.ShapeDtypeStruct((L.OBS_SIZE,), jnp.float32),
            jax.ShapeDtypeStruct((), jnp.float32),
            jax.ShapeDtypeStruct((), jnp.float32),
            jax.ShapeDtypeStruct((), jnp.float32),
        )
        words, obs, reward, success, bad = host_call(
            self._host_step, shapes, state.pipeline_state, action.astype(jnp.float32), state.info["steps"])
        steps = state.info["steps"] + 1
        done = (steps >= self.episode_length).astype(jnp.float32)
        info = dict(state.info, steps=steps, truncation=done, nan_reset=bad)
        metrics = dict(state.metrics, reward=reward, success=success,
                       nan_resets=state.metrics.get("nan_resets", 0.0) + bad)
        return state.replace(pipeline_state=words, obs=obs, reward=reward, done=done, metrics=metrics, info=info)

    @property
    def backend(self) -> str:
        return "mujoco"

    def physics_states(self, state: State) -> np.ndarray:
        """Host copy of the float64 full physics states [..., STATE_SIZE] of a (batched) State."""
        return decode_states(jax.device_get(state.pipeline_state)).copy()

    def encode(self, states: np.ndarray) -> jax.Array:
        """Full physics states float64 [..., STATE_SIZE] -> ``pipeline_state`` words (to start from
        a given state: ``state.replace(pipeline_state=env.encode(s), obs=...)``)."""
        return jnp.asarray(encode_states(states))


def make_mujoco_env(task_name: str, episode_length: int = L.DEFAULT_EPISODE_LENGTH, num_threads: int = 2,
                    **overrides: Any) -> MujocoManipulationEnv:
    """Brax-API env of task ``task_name`` (any of ``task_defs.names()``) on classic MuJoCo through
    ``host_call`` (a ``pure_callback``) + multi-threaded ``mujoco.rollout``. ``overrides``: physics options of
    ``physics_np.load_model`` (timestep, substeps, iterations, ls_iterations, ...)."""
    return MujocoManipulationEnv(task_name, episode_length=episode_length, num_threads=num_threads, **overrides)
