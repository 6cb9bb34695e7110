"""Physics manipulation domain: the NumPy side (imports no JAX).

One scene (``scene.xml``), one action mapping, one observation function and one reset sampler,
shared by every physics backend:

* ``MujocoTwin``: classic MuJoCo (C) stepped with NumPy alone: the JAX-free evaluation twin for
  exported policies;
* ``mujoco_env`` (``physics="mujoco"``): the same ``step_states`` called through
  ``tasks.host_call`` (a ``pure_callback``) over a whole env batch (multi-threaded ``mujoco.rollout``);
* ``mjx_env`` (``physics="mjx"`` / ``"warp"``): the array functions below (``observe``,
  ``action_to_ctrl``, ``clamp_windup``, ``sample_init``) are written against an array module
  ``xp`` and are called there with ``jax.numpy``.

State: MuJoCo's full physics state (``mjSTATE_FULLPHYSICS``: time, qpos, qvel, act) as float64.
The observation is a function of (qpos, qvel, act) only (``observe``): the pinch is the gripper
body's origin, so its pose is read off the joint positions exactly, and the cube poses off their
free joints. The scene's sensors report the same quantities (a test checks it).

Grasp sensor: 1.0 while some cube is held, i.e. its centre lies between the finger pads (pinch
frame), the aperture is at most the cube's width across the pads plus a small tolerance, and both
finger servos are squeezing (their position target lies inside the pad position by at least
``SQUEEZE_MIN``): both pads press on the same cube.
"""

from __future__ import annotations

import math
import os
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from tasks.manipulation import layout as L
from tasks.manipulation import task_defs

SCENE_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "scene.xml")

# --- model layout (checked against the compiled model in ``load_model``) ----------------------
NQ_GRIPPER = 6  # slide x, y, z, yaw, finger_left, finger_right
CUBE_QPOS = tuple(NQ_GRIPPER + 7 * i for i in range(L.NUM_CUBES))  # free joints: pos (3) + quat (4)
CUBE_QVEL = tuple(NQ_GRIPPER + 6 * i for i in range(L.NUM_CUBES))
NQ = NQ_GRIPPER + 7 * L.NUM_CUBES
NV = NQ_GRIPPER + 6 * L.NUM_CUBES
NU = 6  # intvelocity servos on the six gripper joints (act[i] targets qpos[i])
STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
STATE_SIZE = 1 + NQ + NV + NU  # time, qpos, qvel, act
QPOS = slice(1, 1 + NQ)
QVEL = slice(1 + NQ, 1 + NQ + NV)
ACT = slice(1 + NQ + NV, STATE_SIZE)

# Anti wind-up: after every agent step each servo target (activation) is clamped to within this
# band around its joint position, so a blocked joint (fingers on a cube, pinch on a cube) reacts
# at once when the command reverses. The finger band also sets the grip force (kp · band).
WINDUP = (0.01, 0.01, 0.01, 0.2, 0.006, 0.006)
SQUEEZE_MIN = 0.0035  # m: a finger servo target this far inside the pad position = squeezing
GRASP_TOL_X = 0.012  # cube centre within the pads' width (pinch-frame x) ...
GRASP_TOL_Y = 0.01  # ... centred between the pads (pinch-frame y) ...
GRASP_Z_LOW = -L.FINGER_BELOW_PINCH - 0.01  # ... and within their height (pinch-frame z)
GRASP_Z_HIGH = L.FINGER_ABOVE_PINCH + 0.005
GRASP_APERTURE_SLACK = 0.003  # aperture ≤ the cube's width across the pads + this

# Reset distribution (the spec; same numbers as the kinematic domain).
RESET_PINCH_LOW = (-0.05, -0.05, 0.12)
RESET_PINCH_HIGH = (0.05, 0.05, 0.18)
RESET_CUBE_RANGE = 0.08
RESET_CUBE_YAW = math.pi / 4
RESET_MIN_DIST = 0.062  # > cube diagonal (0.0566): no overlap whatever the yaws
RESET_TRIES = 64
RESET_FALLBACK_XY = ((-0.06, -0.06), (0.0, 0.06), (0.06, -0.06))
RESET_CUBE_Z = L.CUBE_HALF + 1e-4  # a hair above the floor: no initial penetration
NUM_UNIFORMS = 3 + RESET_TRIES * L.NUM_CUBES * 2 + L.NUM_CUBES

# Scene options a caller may override (``load_model(**overrides)``).
MODEL_OPTIONS = ("timestep", "iterations", "ls_iterations", "noslip_iterations", "impratio", "cone", "solver")


def load_model(
    *, substeps: int | None = None, timestep: float | None = None, **options: Any
) -> tuple[mujoco.MjModel, int]:
    """Compile the scene. Returns (model, physics substeps per agent step).

    ``timestep`` (s) defaults to the scene's 10 ms; ``substeps`` defaults to CONTROL_DT/timestep
    (their product must equal layout.CONTROL_DT). Other keyword arguments set ``model.opt``
    fields (``iterations``, ``ls_iterations``, ``noslip_iterations``, ``impratio``); collision
    tuning: ``palm_collision`` (default True), ``max_geom_pairs`` / ``max_contact_points`` (MJX-jax
    limits per collision-function group, ignored by classic MuJoCo), ``cone`` (0 pyramidal, 1 the
    scene's elliptic), ``solver`` (1 CG, 2 the scene's Newton); ``contacts=False`` disables all contacts (a cost bound for benchmarks only:
    nothing can be grasped).
    """
    xml = open(SCENE_PATH).read()
    contacts = options.pop("contacts", True)
    if not options.pop("palm_collision", True):
        xml = xml.replace('<geom name="palm" class="gripper"', '<geom name="palm" class="gripper" contype="0" conaffinity="0"')
    mjx_limits = {k: options.pop(k) for k in ("max_geom_pairs", "max_contact_points") if k in options}
    if mjx_limits:  # MJX-jax collision limits per geom-type pair group (classic MuJoCo ignores them)
        numerics = "".join(f'<numeric name="{k}" data="{int(v)}"/>' for k, v in mjx_limits.items())
        xml = xml.replace("</mujoco>", f"<custom>{numerics}</custom></mujoco>")
    model = mujoco.MjModel.from_xml_string(xml)
    if timestep is not None:
        model.opt.timestep = float(timestep)
    if substeps is None:
        substeps = int(round(L.CONTROL_DT / model.opt.timestep))
    if abs(substeps * model.opt.timestep - L.CONTROL_DT) > 1e-9:
        raise ValueError(
            f"substeps × timestep must equal CONTROL_DT={L.CONTROL_DT}: {substeps} × {model.opt.timestep}"
        )
    for key, value in options.items():
        if key not in MODEL_OPTIONS:
            raise ValueError(f"unknown physics option {key!r}; valid: timestep, substeps, {', '.join(MODEL_OPTIONS)}")
        setattr(model.opt, key, type(getattr(model.opt, key))(value))
    if not contacts:
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    assert (model.nq, model.nv, model.nu, model.na) == (NQ, NV, NU, NU), "scene layout changed"
    assert mujoco.mj_stateSize(model, STATE_SPEC) == STATE_SIZE
    return model, int(substeps)


# --- array functions (xp = numpy or jax.numpy); all broadcast over leading batch axes --------
def quat_mul(a, b, xp=np):
    aw, ax, ay, az = (a[..., i] for i in range(4))
    bw, bx, by, bz = (b[..., i] for i in range(4))
    return xp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def canonical_quat(q, xp=np):
    """Unit quaternion with w ≥ 0 (q and -q are the same rotation)."""
    q = q / xp.sqrt(xp.sum(q * q, axis=-1, keepdims=True))
    return xp.where(q[..., :1] < 0, -q, q)


def yaw_quat(yaw, xp=np):
    zero = xp.zeros_like(yaw)
    return xp.stack([xp.cos(0.5 * yaw), zero, zero, xp.sin(0.5 * yaw)], axis=-1)


def to_pinch_frame(pos, pinch, yaw, xp=np):
    """World positions [..., n, 3] in the pinch frame (pinch [..., 3], yaw [...])."""
    d = pos - pinch[..., None, :]
    c, s = xp.cos(yaw)[..., None], xp.sin(yaw)[..., None]
    return xp.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], axis=-1)


def cube_poses(qpos, xp=np):
    """Cube positions [..., 3, 3] and canonical quaternions [..., 3, 4] from qpos [..., NQ]."""
    pos = xp.stack([qpos[..., a : a + 3] for a in CUBE_QPOS], axis=-2)
    quat = canonical_quat(xp.stack([qpos[..., a + 3 : a + 7] for a in CUBE_QPOS], axis=-2), xp)
    return pos, quat


def grasp_flag(qpos, act, xp=np):
    """Grasp sensor (module docstring): float [...], 1.0 while a cube is squeezed between the pads."""
    pinch, yaw = qpos[..., 0:3], qpos[..., 3]
    aperture = qpos[..., 4] + qpos[..., 5]
    pos, quat = cube_poses(qpos, xp)
    rel = to_pinch_frame(pos, pinch, yaw, xp)  # [..., 3, 3]
    # Cube yaw relative to the pads, folded into [0, π/4]: width across the pads = 4 cm·(cos + sin).
    cube_yaw = 2.0 * xp.arctan2(quat[..., 3], quat[..., 0])
    rel_yaw = cube_yaw - yaw[..., None]
    folded = xp.abs(xp.arctan2(xp.sin(4.0 * rel_yaw), xp.cos(4.0 * rel_yaw))) / 4.0
    width = L.CUBE_SIZE * (xp.cos(folded) + xp.sin(folded))
    between = (
        (xp.abs(rel[..., 0]) <= GRASP_TOL_X)
        & (xp.abs(rel[..., 1]) <= GRASP_TOL_Y)
        & (rel[..., 2] >= GRASP_Z_LOW)
        & (rel[..., 2] <= GRASP_Z_HIGH)
        & (aperture[..., None] <= width + GRASP_APERTURE_SLACK)
    )
    squeeze = (qpos[..., 4] - act[..., 4] >= SQUEEZE_MIN) & (qpos[..., 5] - act[..., 5] >= SQUEEZE_MIN)
    return (xp.any(between, axis=-1) & squeeze) * 1.0


def observe(qpos, qvel, act, xp=np):
    """Observation [..., OBS_SIZE] in the layout of ``layout`` (same dtype as qpos)."""
    pinch, yaw = qpos[..., 0:3], qpos[..., 3]
    pinch_quat = yaw_quat(yaw, xp)
    aperture = qpos[..., 4:5] + qpos[..., 5:6]
    aperture_vel = qvel[..., 4:5] + qvel[..., 5:6]
    pos, quat = cube_poses(qpos, xp)
    rel_pos = to_pinch_frame(pos, pinch, yaw, xp)
    inv_pinch = pinch_quat * xp.asarray([1.0, -1.0, -1.0, -1.0], dtype=qpos.dtype)
    rel_quat = canonical_quat(quat_mul(inv_pinch[..., None, :], quat, xp), xp)
    parts = [
        qpos[..., 0:4],
        qvel[..., 0:4],
        pinch,
        pinch_quat,
        aperture,
        aperture_vel,
        grasp_flag(qpos, act, xp)[..., None],
    ]
    for c in range(L.NUM_CUBES):
        parts += [pos[..., c, :], quat[..., c, :], rel_pos[..., c, :], rel_quat[..., c, :]]
    return xp.concatenate(parts, axis=-1)


MAX_ABS_QVEL = 50.0  # m/s or rad/s: beyond this the physics has blown up
MAX_ABS_POS = 1.0  # m: a cube this far from the basket centre has been ejected


def unstable(qpos, qvel, xp=np):
    """True [...] where the physics state is non-finite or has blown up (cube ejected, huge speed)."""
    finite = xp.all(xp.isfinite(qpos), axis=-1) & xp.all(xp.isfinite(qvel), axis=-1)
    pos, _ = cube_poses(xp.where(xp.isfinite(qpos), qpos, 0.0), xp)
    sane = xp.all(xp.abs(xp.where(xp.isfinite(qvel), qvel, 0.0)) <= MAX_ABS_QVEL, axis=-1) & xp.all(
        xp.abs(pos) <= MAX_ABS_POS, axis=(-2, -1)
    )
    return ~(finite & sane)


def task_inputs(qpos, act, xp=np) -> task_defs.Inputs:
    pos, _ = cube_poses(qpos, xp)
    return task_defs.Inputs(qpos[..., 0:3], qpos[..., 4] + qpos[..., 5], grasp_flag(qpos, act, xp), pos)


def action_to_ctrl(action, xp=np):
    """Agent action [..., 5] in [-1, 1] -> servo velocity commands [..., NU] (non-finite -> 0)."""
    a = xp.clip(xp.where(xp.isfinite(action), action, 0.0), -1.0, 1.0)
    half_finger = 0.5 * L.MAX_FINGER_SPEED * a[..., 4:5]  # each pad moves at half the aperture rate
    return xp.concatenate(
        [a[..., 0:3] * L.MAX_LINEAR_SPEED, a[..., 3:4] * L.MAX_YAW_RATE, half_finger, half_finger], axis=-1
    )


def clamp_windup(qpos, act, xp=np):
    """Servo targets clamped to within ``WINDUP`` of the joint positions (and to the joint ranges)."""
    q = qpos[..., :NU]
    band = xp.asarray(WINDUP, dtype=act.dtype)
    return xp.clip(act, q - band, q + band)


def sample_init(u, xp=np):
    """Initial (qpos [..., NQ], act [..., NU]) from uniforms u [..., NUM_UNIFORMS] in [0, 1).

    Pinch xy in [-0.05, 0.05], z in [0.12, 0.18], yaw 0, fingers open; cubes on the floor at the
    first of ``RESET_TRIES`` candidate layouts whose centres are pairwise ≥ RESET_MIN_DIST apart,
    xy in [-0.08, 0.08], yaw in [-π/4, π/4].
    """
    lo, hi = xp.asarray(RESET_PINCH_LOW, dtype=u.dtype), xp.asarray(RESET_PINCH_HIGH, dtype=u.dtype)
    pinch = lo + (hi - lo) * u[..., 0:3]
    n_xy = RESET_TRIES * L.NUM_CUBES * 2
    xy = (2.0 * u[..., 3 : 3 + n_xy] - 1.0) * RESET_CUBE_RANGE
    xy = xy.reshape(xy.shape[:-1] + (RESET_TRIES, L.NUM_CUBES, 2))
    yaw = (2.0 * u[..., 3 + n_xy : 3 + n_xy + L.NUM_CUBES] - 1.0) * RESET_CUBE_YAW
    diff = xy[..., :, None, :] - xy[..., None, :, :]
    dist = xp.sqrt(xp.sum(diff * diff, axis=-1)) + xp.eye(L.NUM_CUBES, dtype=u.dtype)
    valid = xp.all(xp.all(dist >= RESET_MIN_DIST, axis=-1), axis=-1)  # [..., TRIES]
    first = xp.argmax(valid, axis=-1)
    chosen = xp.take_along_axis(xy, first[..., None, None, None], axis=-3)[..., 0, :, :]
    fallback = xp.asarray(RESET_FALLBACK_XY, dtype=u.dtype)
    xy = xp.where(xp.any(valid, axis=-1)[..., None, None], chosen, fallback)
    half = L.APERTURE_OPEN / 2
    batch = u.shape[:-1]
    parts = [pinch, xp.zeros(batch + (1,), u.dtype), xp.full(batch + (2,), half, u.dtype)]
    for c in range(L.NUM_CUBES):
        z = xp.full(batch + (1,), RESET_CUBE_Z, u.dtype)
        parts += [xy[..., c, :], z, yaw_quat(yaw[..., c], xp)]
    qpos = xp.concatenate(parts, axis=-1)
    return qpos, qpos[..., :NU]


# --- NumPy state handling ---------------------------------------------------------------------
def init_states(seeds) -> np.ndarray:
    """Full physics states [len(seeds), STATE_SIZE] (float64) of fresh episodes, one per seed."""
    seeds = np.atleast_1d(np.asarray(seeds))
    u = np.stack([np.random.default_rng(int(s)).random(NUM_UNIFORMS) for s in seeds])
    return states_from_uniforms(u)


def states_from_uniforms(u: np.ndarray) -> np.ndarray:
    qpos, act = sample_init(np.asarray(u, np.float64), np)
    state = np.zeros(qpos.shape[:-1] + (STATE_SIZE,))
    state[..., QPOS] = qpos
    state[..., ACT] = act
    return state


def observe_states(states: np.ndarray) -> np.ndarray:
    return observe(states[..., QPOS], states[..., QVEL], states[..., ACT], np)


def reward_success(task: task_defs.TaskDef, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    inp = task_inputs(states[..., QPOS], states[..., ACT], np)
    return np.asarray(task.reward(inp), np.float64), np.asarray(task.success(inp), np.float64)


class Stepper:
    """Steps batches of full physics states by one agent step with ``mujoco.rollout``.

    Holds the compiled model, one MjData per thread and a persistent thread pool. ``step`` is the
    one NumPy step function of the ``mujoco`` backend (twin and callback alike).
    """

    def __init__(self, num_threads: int = 2, **overrides: Any):
        self.model, self.substeps = load_model(**overrides)
        self.num_threads = max(1, int(num_threads))
        self.datas = [mujoco.MjData(self.model) for _ in range(self.num_threads)]
        self._pool = mj_rollout.Rollout(nthread=self.num_threads if self.num_threads > 1 else 0)
        self._buffers: dict[int, np.ndarray] = {}

    @property
    def pool(self):
        """The persistent ``mujoco.rollout.Rollout`` (None once closed): benchmarks call its
        ``rollout`` directly."""
        return self._pool

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    def __del__(self):  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass

    def step(self, states: np.ndarray, actions: np.ndarray, reset_seeds=None) -> tuple[np.ndarray, np.ndarray]:
        """One agent step. states [B, STATE_SIZE] float64, actions [B, 5].

        Returns (new states [B, STATE_SIZE], nan_reset [B] bool). An env whose physics went
        non-finite or unstable (MuJoCo reset it: its clock jumped) restarts from
        ``init_states(reset_seeds[b])`` (seed 0 if none given) and is flagged.
        """
        states = np.ascontiguousarray(states, np.float64)
        b = states.shape[0]
        ctrl = np.ascontiguousarray(action_to_ctrl(np.asarray(actions, np.float64), np)[:, None, :])
        out = self._buffers.get(b)
        if out is None:
            out = self._buffers[b] = np.empty((b, self.substeps, STATE_SIZE))
        bad_in = ~np.all(np.isfinite(states), axis=-1)
        start = np.where(bad_in[:, None], init_states(np.zeros(1, np.int64)), states) if bad_in.any() else states
        self._pool.rollout(
            self.model, self.datas, start, ctrl, nstep=self.substeps, state=out, skip_checks=False
        )
        new = out[:, -1, :].copy()
        expected_time = start[:, 0] + self.substeps * self.model.opt.timestep
        bad = (
            bad_in
            | ~np.all(np.isfinite(new), axis=-1)
            | unstable(new[:, QPOS], new[:, QVEL], np)
            | (np.abs(new[:, 0] - expected_time) > 1e-6)  # MuJoCo reset the data itself
        )
        new[:, ACT] = clamp_windup(new[:, QPOS], new[:, ACT], np)
        if bad.any():
            idx = np.nonzero(bad)[0]
            seeds = np.zeros(len(idx), np.int64) if reset_seeds is None else np.asarray(reset_seeds)[idx]
            new[idx] = init_states(seeds)
        return new, bad


class MujocoTwin:
    """JAX-free evaluation twin: one environment (or a batch) of the physics domain in classic
    MuJoCo, observations / rewards from the same NumPy code as the ``mujoco`` backend.

    >>> twin = MujocoTwin("lift_green"); obs = twin.reset(seed=0)
    >>> obs, reward, done, info = twin.step(policy(obs))
    """

    def __init__(self, task_name: str, episode_length: int = L.DEFAULT_EPISODE_LENGTH, num_threads: int = 1,
                 **overrides: Any):
        self.task = task_defs.get(task_name)
        self.task_name = task_name
        self.episode_length = int(episode_length)
        self.stepper = Stepper(num_threads=num_threads, **overrides)
        self.model = self.stepper.model
        self.state = init_states([0])[0]
        self.steps = 0
        self._rng = np.random.default_rng(0)

    def reset(self, seed: int | np.random.Generator | None = None, state: np.ndarray | None = None) -> np.ndarray:
        """Start an episode: from ``state`` (full physics state) if given, else sampled with
        ``seed`` (an int gives exactly ``init_states([seed])``; a Generator draws a seed)."""
        if state is not None:
            self.state = np.array(state, np.float64).reshape(STATE_SIZE)
        else:
            if isinstance(seed, np.random.Generator):
                seed = int(seed.integers(2**32))
            elif seed is None:
                seed = int(self._rng.integers(2**32))
            self.state = init_states([seed])[0]
        self.steps = 0
        return self.observation()

    def observation(self) -> np.ndarray:
        return observe_states(self.state)

    def step(self, action) -> tuple[np.ndarray, float, bool, dict]:
        new, bad = self.stepper.step(self.state[None], np.asarray(action, np.float64).reshape(1, L.ACTION_SIZE),
                                     reset_seeds=[int(self._rng.integers(2**32))])
        self.state = new[0]
        self.steps += 1
        reward, success = reward_success(self.task, self.state)
        done = self.steps >= self.episode_length
        info = {"success": float(success), "nan_reset": float(bad[0]), "truncation": float(done), "steps": self.steps}
        return self.observation(), float(reward), bool(done), info

    @property
    def qpos(self) -> np.ndarray:
        return self.state[QPOS]

    def mj_data(self) -> mujoco.MjData:
        """An MjData at the current state (forward-computed), e.g. for rendering."""
        data = mujoco.MjData(self.model)
        mujoco.mj_setState(self.model, data, self.state, STATE_SPEC)
        mujoco.mj_forward(self.model, data)
        return data
