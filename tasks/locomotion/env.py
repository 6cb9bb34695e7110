"""Brax-API OP3 locomotion envs (paper Sec. 5 / App. C): ``getup_and_walk`` and the dense skill
tasks ``op3_getup`` and ``op3_walk`` (``goal_scoring``: tasks/locomotion/goal_scoring.py, on the
backends below with the arena model), on two physics backends sharing everything but the physics:

* ``mujoco``: classic MuJoCo (C, float64) stepped in a host callback (``tasks.host_call``: a
  ``jax.pure_callback`` with ``vmap_method="broadcast_all"`` that hands the host NumPy arrays; one
  callback steps the whole env batch); the float64 physics state (time, qpos,
  qvel, act, warm start) is carried bit-exactly as uint32 words (``State.pipeline_state``).
* ``mjx``: MuJoCo MJX (impl jax, float32); ``pipeline_state`` is the ``mjx.Data``. On a 2-core CPU
  run it pinned to one core (shared/STACK.md: MJX-jax can deadlock otherwise).

Per agent step (25 ms, 40 Hz): the action a ∈ [-1, 1]^20 (non-finite entries read as 0) goes
through the exponential filter a_f ← 0.8·a_f + 0.2·a; the position servos' joint targets are
``stand_pose + ACTION_SCALE·a_f`` (clipped to the actuators' ±π); 5 physics steps of 5 ms. The
observation (OBS_SIZE = 233) is the last five proprioceptive observations (joint angles [20], torso
angular velocity [3] and gravity direction [3] in the torso frame; newest first), the last five
actions (raw, newest first) and the goal: the target direction in the torso's heading frame [2]
and the target speed [1]. At reset both stacks repeat the first observation and the action that
holds the start pose. Observations, rewards and the goal process are JAX code shared by the two
backends (features from the same JAX forward kinematics of the new qpos on both).

``step`` never auto-resets (the trainer does): at the time limit ``done`` = ``info["truncation"]``
= 1; there is no early termination. A blown-up physics state restarts that env from a fresh start
(``info["nan_reset"]`` = 1, ``metrics["nan_resets"]`` counts; reward 0 for that transition).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs.base import Env, State
from mujoco import mjx

from tasks.host_call import host_call
from tasks.locomotion import model as M
from tasks.locomotion import rewards as R
from tasks.locomotion import starts as S

STACK = 5
PROPRIO_SIZE = M.NU + 3 + 3  # joint angles, torso angular velocity, gravity direction (torso frame)
GOAL_SIZE = 3
OBS_SIZE = STACK * PROPRIO_SIZE + STACK * M.NU + GOAL_SIZE
OBS_PROPRIO = slice(0, STACK * PROPRIO_SIZE)  # [STACK, PROPRIO_SIZE] newest first
OBS_ACTIONS = slice(STACK * PROPRIO_SIZE, STACK * PROPRIO_SIZE + STACK * M.NU)  # [STACK, NU] newest first
OBS_GOAL = slice(OBS_SIZE - GOAL_SIZE, OBS_SIZE)
FILTER_STRENGTH = 0.8  # a_f ← 0.8·a_f + 0.2·a
ACTION_SCALE = math.pi / 2  # rad of joint target per unit of (filtered) action around the standing pose
GOAL_SPEEDS = (0.0, 0.7)  # m/s, equally likely
GOAL_MEAN_TIME = 5.0  # s, mean of the exponential time a goal is kept
MAX_QVEL = 1e3  # |qvel| above this counts as a physics blow-up


@dataclasses.dataclass(frozen=True)
class LocoTask:
    name: str
    reward: str  # "walk" (R_walk while standing), "getup" or "goal_scoring" (tasks/locomotion/goal_scoring.py)
    prone_fraction: float
    episode_length: int
    description: str


TASKS = {
    t.name: t
    for t in (
        LocoTask("getup_and_walk", "walk", 2.0 / 3.0, 600,
                 "GetUpAndWalk (App. C): R_walk while standing; 2/3 of episodes start prone (front or back)"),
        LocoTask("op3_getup", "getup", 1.0, 200,
                 "Get-up skill (dense): torso height × uprightness, from prone starts; success: standing"),
        LocoTask("op3_walk", "walk", 0.0, 400, "Walk skill (dense): R_walk while standing, from standing starts"),
        LocoTask("goal_scoring", "goal_scoring", 0.0, 600,
                 "GoalScoring (App. C): walled arena, ball, goal, a short wall; R_score (1000 per goal) + "
                 "R_upright + R_maxvelocity; terminates if the robot leaves its half or falls"),
    )
}


def names() -> list[str]:
    return sorted(TASKS)


def get(name: str) -> LocoTask:
    if name not in TASKS:
        raise ValueError(f"unknown locomotion task {name!r}; valid: {', '.join(names())}")
    return TASKS[name]


# --- shared JAX pieces ---------------------------------------------------------------------------
def proprio(f: R.Features):
    return jnp.concatenate([f.joints, f.gyro, f.gravity])


def goal_obs(heading, goal_dir, goal_speed):
    """Target direction in the torso's heading frame (x forward, y left) and the target speed."""
    fwd = jnp.sum(heading * goal_dir)
    left = heading[0] * goal_dir[1] - heading[1] * goal_dir[0]
    return jnp.stack([fwd, left, goal_speed])


def sample_goal(key):
    k_dir, k_speed, k_time = jax.random.split(key, 3)
    angle = jax.random.uniform(k_dir, (), jnp.float32, -jnp.pi, jnp.pi)
    speed = jnp.where(jax.random.bernoulli(k_speed), GOAL_SPEEDS[1], GOAL_SPEEDS[0]).astype(jnp.float32)
    time_left = GOAL_MEAN_TIME * jax.random.exponential(k_time, (), jnp.float32)
    return jnp.stack([jnp.cos(angle), jnp.sin(angle)]), speed, time_left


def filter_action(a_filt, action):
    return FILTER_STRENGTH * a_filt + (1.0 - FILTER_STRENGTH) * action


def push(stack, x):
    """Newest-first stack [STACK, ...]: x on top, the oldest dropped."""
    return jnp.concatenate([x[None], stack[:-1]], axis=0)


def quat_mat(q):
    """Unit-normalised quaternion (w, x, y, z) [..., 4] -> rotation matrix [..., 3, 3]."""
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return jnp.stack([
        jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def _axis_angle_mats(axes, angles):
    """Rotations by ``angles`` [n] about the unit ``axes`` [n, 3] (Rodrigues) -> [n, 3, 3]."""
    x, y, z = axes[:, 0], axes[:, 1], axes[:, 2]
    o = jnp.zeros_like(x)
    k = jnp.stack([jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2)
    s, c = jnp.sin(angles)[:, None, None], jnp.cos(angles)[:, None, None]
    return jnp.eye(3) + s * k + (1.0 - c) * (k @ k)


class _Kinematics:
    """``features(qpos, qvel) -> Features`` (JAX, float32). Forward kinematics of the OP3 tree (a free
    root, hinge joints below; as MuJoCo's ``mj_kinematics``, a test checks it against MuJoCo), one
    batched step per tree level: ``mjx.kinematics`` computes the same but compiles for ≈ 10 s here."""

    def __init__(self, mj_model: mujoco.MjModel, lay: M.Layout):
        m = mj_model
        free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        if (len(free) != 1 or m.jnt_bodyid[free[0]] != lay.torso or m.body_parentid[lay.torso] != 0
                or any(m.body_jntnum[b] != 1 for b in range(1, m.nbody))
                or any(m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE for j in range(m.njnt) if j != free[0])):
            raise ValueError("OP3 kinematics: a free torso and one hinge joint per other body expected")
        self.nbody = m.nbody
        self.root_adr = int(m.jnt_qposadr[free[0]])
        depth = np.zeros(m.nbody, int)
        for b in range(1, m.nbody):
            depth[b] = depth[m.body_parentid[b]] + 1
        self.levels = []  # per tree level below the torso: bodies and their constants
        for lev in range(2, depth.max() + 1):
            bodies = np.flatnonzero(depth == lev)
            rots = np.zeros((len(bodies), 9))
            for i, b in enumerate(bodies):
                mujoco.mju_quat2Mat(rots[i], m.body_quat[b])
            jnts = m.body_jntadr[bodies]
            self.levels.append(dict(
                bodies=bodies, parents=m.body_parentid[bodies], pos=jnp.asarray(m.body_pos[bodies], jnp.float32),
                rot=jnp.asarray(rots.reshape(-1, 3, 3), jnp.float32), adr=m.jnt_qposadr[jnts],
                axis=jnp.asarray(m.jnt_axis[jnts], jnp.float32), anchor=jnp.asarray(m.jnt_pos[jnts], jnp.float32)))
        self.foot_site_body = np.asarray(m.site_bodyid[lay.foot_sites])
        self.foot_site_pos = jnp.asarray(m.site_pos[lay.foot_sites], jnp.float32)
        self.knees = np.asarray(lay.knee_bodies)
        self.torso = int(lay.torso)
        self.geom_body = np.asarray(lay.body_geom_body)
        # Non-foot collision-mesh vertices in their bodies' frames: [G, V, 3]
        self.verts = jnp.asarray(np.einsum("gij,gvj->gvi", lay.body_geom_rot, lay.body_geom_verts)
                                 + lay.body_geom_pos[:, None, :], jnp.float32)

    def bodies_pose(self, qpos):
        """World positions [nbody, 3] and rotation matrices [nbody, 3, 3] of all bodies."""
        a = self.root_adr
        pos = jnp.zeros((self.nbody, 3)).at[self.torso].set(qpos[a:a + 3])
        mat = jnp.tile(jnp.eye(3), (self.nbody, 1, 1)).at[self.torso].set(quat_mat(qpos[a + 3:a + 7]))
        for lv in self.levels:
            pp, pr = pos[lv["parents"]], mat[lv["parents"]]
            p = pp + jnp.einsum("nij,nj->ni", pr, lv["pos"])
            r = pr @ lv["rot"]
            anchor = p + jnp.einsum("nij,nj->ni", r, lv["anchor"])
            r = r @ _axis_angle_mats(lv["axis"], qpos[lv["adr"]])
            p = anchor - jnp.einsum("nij,nj->ni", r, lv["anchor"])
            pos, mat = pos.at[lv["bodies"]].set(p), mat.at[lv["bodies"]].set(r)
        return pos, mat

    def __call__(self, qpos, qvel) -> R.Features:
        xpos, xmat = self.bodies_pose(qpos)
        rot = xmat[self.torso]
        fwd = rot[:2, 0]
        norm = jnp.linalg.norm(fwd)
        heading = jnp.where(norm > 1e-6, fwd / jnp.maximum(norm, 1e-6), jnp.array([1.0, 0.0]))
        rz = xmat[self.geom_body][:, 2, :]  # [G, 3]: world z of the bodies' axes
        lowest = xpos[self.geom_body][:, 2] + jnp.min(jnp.einsum("gj,gvj->gv", rz, self.verts), axis=-1)
        ground = jnp.minimum(jnp.min(lowest), jnp.min(xpos[self.knees][:, 2]))
        feet = (xpos[self.foot_site_body] + jnp.einsum("nij,nj->ni", xmat[self.foot_site_body], self.foot_site_pos))[:, :2]
        return R.Features(joints=qpos[7:], gyro=qvel[3:6], gravity=-rot[2, :], up_z=rot[2, 2], heading=heading,
                          height=qpos[2], feet_xy=feet, ground=ground)


class LocomotionEnv(Env):
    """Shared Brax-API logic; backends implement ``_init_physics`` and ``_step_physics``. ``arena``
    (class attribute): the physics model is the GoalScoring arena (``model.load_arena_model``: the
    robot, a ball, an obstacle as mocap body) instead of the robot alone; the robot's layout and
    kinematics are those of the robot-only model either way (the robot comes first in both)."""

    arena = False
    START_NAMES = S.START_NAMES  # info["start"] values (training.evaluate --usage_plot panels)

    def __init__(self, task_name: str, episode_length: int | None = None, prone_fraction: float | None = None,
                 prone_bank_seed: int = S.BANK_SEED, goal_speed: float | None = None, **physics_options: Any):
        self.task = get(task_name)
        self.task_name = task_name
        if goal_speed is not None and float(goal_speed) not in GOAL_SPEEDS:
            raise ValueError(f"goal_speed must be one of {GOAL_SPEEDS} (m/s) or None (both, equally likely), "
                             f"got {goal_speed}")
        self.goal_speed = None if goal_speed is None else float(goal_speed)  # None: sampled
        self.episode_length = int(self.task.episode_length if episode_length is None else episode_length)
        if self.episode_length < 1:
            raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
        self.model_key = tuple(sorted(physics_options.items()))
        robot_model, self.substeps = M.load_model(**physics_options)
        self.mj_model = M.load_arena_model(**physics_options)[0] if self.arena else robot_model
        self.layout = M.layout(self.model_key)
        self.stand_pose = jnp.asarray(self.layout.stand_pose, jnp.float32)
        frac = self.task.prone_fraction if prone_fraction is None else float(prone_fraction)
        self.sampler = S.StartSampler(frac, self.model_key, prone_bank_seed)
        self.features = _Kinematics(robot_model, self.layout)
        self.control_dt = self.substeps * float(self.mj_model.opt.timestep)

    # --- Brax env API ----------------------------------------------------------------------
    @property
    def observation_size(self) -> int:
        return OBS_SIZE

    @property
    def action_size(self) -> int:
        return M.NU

    @property
    def dt(self) -> float:
        return self.control_dt

    @property
    def backend(self) -> str:  # pragma: no cover - set by subclasses
        raise NotImplementedError

    def ctrl_of(self, a_filt):
        return jnp.clip(self.stand_pose + ACTION_SCALE * a_filt, -math.pi, math.pi)

    def hold_action(self, hold):
        """The (filter) action whose joint targets are ``hold``."""
        return jnp.clip((hold - self.stand_pose) / ACTION_SCALE, -1.0, 1.0)

    def sample_goal(self, key):
        """``sample_goal``, its speed replaced by the env's fixed ``goal_speed`` if one is set."""
        goal_dir, goal_speed, goal_left = sample_goal(key)
        if self.goal_speed is not None:
            goal_speed = jnp.full_like(goal_speed, self.goal_speed)
        return goal_dir, goal_speed, goal_left

    def _task_start(self, f: R.Features, hold, kind, key):
        """Task part of ``info`` at an episode start with features ``f``."""
        a0 = self.hold_action(hold)
        goal_dir, goal_speed, goal_left = self.sample_goal(key)
        return {
            "a_filt": a0,
            "obs_hist": jnp.tile(proprio(f)[None], (STACK, 1)),
            "act_hist": jnp.tile(a0[None], (STACK, 1)),
            "feet_xy": f.feet_xy,
            "goal_dir": goal_dir,
            "goal_speed": goal_speed,
            "goal_left": goal_left,
            "start": kind,
        }

    def _obs(self, f: R.Features, t: dict):
        return jnp.concatenate([t["obs_hist"].reshape(-1), t["act_hist"].reshape(-1),
                                goal_obs(f.heading, t["goal_dir"], t["goal_speed"])]).astype(jnp.float32)

    def _reward(self, f: R.Features, feet_vel, action, t: dict):
        terms = R.walk_terms(f, feet_vel, action, t["act_hist"][0], t["goal_dir"], t["goal_speed"], self.stand_pose)
        stand = R.standing(f)
        if self.task.reward == "walk":
            reward = R.walk_reward(terms, stand)
            success = stand & R.tracking(feet_vel, t["goal_dir"], t["goal_speed"])
        else:
            reward = R.getup_reward(f)
            success = stand
        metrics = {k: v.astype(jnp.float32) for k, v in terms.items()}
        metrics["standing"] = stand.astype(jnp.float32)
        return reward.astype(jnp.float32), success.astype(jnp.float32), metrics

    _TASK_KEYS = ("a_filt", "obs_hist", "act_hist", "feet_xy", "goal_dir", "goal_speed", "goal_left", "start")

    def reset(self, rng: jax.Array) -> State:
        rng, k_start, k_goal = jax.random.split(rng, 3)
        qpos, hold, kind = self.sampler.sample(k_start)
        qvel = jnp.zeros(M.NV, jnp.float32)
        ps = self._init_physics(qpos, hold)
        f = self.features(qpos, qvel)
        t = self._task_start(f, hold, kind, k_goal)
        _, success, terms = self._reward(f, jnp.zeros(2), t["act_hist"][0], t)
        zero = jnp.zeros((), jnp.float32)
        metrics = {"reward": zero, "success": success, "nan_resets": zero, **{k: zero for k in terms}}
        info = {"steps": jnp.zeros((), jnp.int32), "truncation": zero, "nan_reset": zero, "rng": rng, **t}
        return State(pipeline_state=ps, obs=self._obs(f, t), reward=zero, done=zero, metrics=metrics, info=info)

    def step(self, state: State, action: jax.Array) -> State:
        info = state.info
        action = action.astype(jnp.float32)
        action = jnp.where(jnp.isfinite(action), jnp.clip(action, -1.0, 1.0), 0.0)
        a_filt = filter_action(info["a_filt"], action)
        rng, k_fresh, k_goal, k_fresh_goal = jax.random.split(info["rng"], 4)
        fresh_qpos, fresh_hold, fresh_kind = self.sampler.sample(k_fresh)
        ps, qpos, qvel, bad = self._step_physics(state.pipeline_state, self.ctrl_of(a_filt), fresh_qpos, fresh_hold)
        f = self.features(qpos, qvel)
        t = {k: info[k] for k in self._TASK_KEYS}
        feet_vel = jnp.mean(f.feet_xy - t["feet_xy"], axis=0) / self.control_dt
        reward, success, terms = self._reward(f, feet_vel, action, t)
        # Advance the task state: stacks, filter, feet, goal (resampled when its time is up).
        goal_left = t["goal_left"] - self.control_dt
        new_dir, new_speed, new_left = self.sample_goal(k_goal)
        expired = goal_left <= 0.0
        nxt = dict(t, a_filt=a_filt, obs_hist=push(t["obs_hist"], proprio(f)), act_hist=push(t["act_hist"], action),
                   feet_xy=f.feet_xy, goal_dir=jnp.where(expired, new_dir, t["goal_dir"]),
                   goal_speed=jnp.where(expired, new_speed, t["goal_speed"]),
                   goal_left=jnp.where(expired, new_left, goal_left))
        fresh = self._task_start(f, fresh_hold, fresh_kind, k_fresh_goal)
        nxt = jax.tree.map(lambda a, b: jnp.where(bad, a, b), fresh, nxt)
        badf = bad.astype(jnp.float32)
        reward = jnp.where(bad, 0.0, reward)
        steps = info["steps"] + 1
        done = (steps >= self.episode_length).astype(jnp.float32)
        info = dict(info, steps=steps, truncation=done, nan_reset=badf, rng=rng, **nxt)
        metrics = dict(state.metrics, reward=reward, success=success,
                       nan_resets=state.metrics["nan_resets"] + badf, **terms)
        return state.replace(pipeline_state=ps, obs=self._obs(f, nxt), reward=reward, done=done, metrics=metrics,
                             info=info)


# --- MJX backend ---------------------------------------------------------------------------------
_INTEGRATION_FIELDS = ("time", "qpos", "qvel", "act", "qacc_warmstart", "ctrl")
_MJX_CACHE: dict = {}


def _mjx_physics(model_key: tuple, arena: bool = False):
    """(mjx model, template data, jitted agent-step physics), shared by all tasks of a process.
    ``arena``: the GoalScoring scene; the fresh state then also sets the mocap positions."""
    if (model_key, arena) not in _MJX_CACHE:
        mj_model, substeps = (M.load_arena_model if arena else M.load_model)(**dict(model_key))
        model = mjx.put_model(mj_model, impl="jax")
        data0 = mjx.make_data(mj_model, impl="jax")
        fields = _INTEGRATION_FIELDS + (("mocap_pos",) if arena else ())

        def fresh_data(qpos, hold, mocap_pos=None):
            data = data0.replace(qpos=qpos, qvel=jnp.zeros(mj_model.nv, jnp.float32), ctrl=hold)
            return data if mocap_pos is None else data.replace(mocap_pos=mocap_pos)

        @jax.jit
        def physics(data, ctrl, fresh_qpos, fresh_hold, fresh_mocap=None):
            data = data.replace(ctrl=ctrl)
            data, _ = jax.lax.scan(lambda d, _: (mjx.step(model, d), None), data, None, length=substeps)
            bad = ~(jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
                    & jnp.all(jnp.abs(data.qvel) < MAX_QVEL))
            fresh = fresh_data(fresh_qpos, fresh_hold, fresh_mocap)
            data = data.replace(**{k: jnp.where(bad, getattr(fresh, k), getattr(data, k)) for k in fields})
            return data, bad

        _MJX_CACHE[(model_key, arena)] = (model, data0, fresh_data, physics)
    return _MJX_CACHE[(model_key, arena)]


class MjxLocomotionEnv(LocomotionEnv):
    def __init__(self, task_name: str, **kw: Any):
        super().__init__(task_name, **kw)
        self.model, self._data0, self._fresh_data, self._physics = _mjx_physics(self.model_key, self.arena)

    @property
    def backend(self) -> str:
        return "mjx"

    def _init_physics(self, qpos, hold, mocap_pos=None):
        return self._fresh_data(qpos, hold, mocap_pos)

    def _step_physics(self, data, ctrl, fresh_qpos, fresh_hold, fresh_mocap=None):
        data, bad = self._physics(data, ctrl, fresh_qpos, fresh_hold, fresh_mocap)
        return data, data.qpos, data.qvel, bad


# --- classic MuJoCo backend ----------------------------------------------------------------------
STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS | mujoco.mjtState.mjSTATE_WARMSTART


class _HostStepper:
    """Steps batches of float64 physics states (time, qpos, qvel, act, warm start; the mocap
    positions too if the model has mocap bodies) on the host."""

    def __init__(self, mj_model: mujoco.MjModel, substeps: int, num_threads: int):
        self.model, self.substeps = mj_model, substeps
        self.nq, self.nv = mj_model.nq, mj_model.nv
        self.spec = STATE_SPEC | (mujoco.mjtState.mjSTATE_MOCAP_POS if mj_model.nmocap else 0)
        self.size = mujoco.mj_stateSize(mj_model, self.spec)
        # The state's components are concatenated in the order of their bits.
        self.mocap_adr = mujoco.mj_stateSize(mj_model, self.spec & (mujoco.mjtState.mjSTATE_MOCAP_POS - 1))
        self.num_threads = max(1, int(num_threads))
        self.datas = [mujoco.MjData(mj_model) for _ in range(self.num_threads)]
        self.pool = concurrent.futures.ThreadPoolExecutor(self.num_threads) if self.num_threads > 1 else None
        self.calls = 0

    def fresh(self, qpos, mocap_pos=None) -> np.ndarray:
        """States [B, size] at qpos [B, nq] (and mocap positions [B, nmocap, 3]), at rest, time 0, no
        warm start."""
        qpos = np.asarray(qpos, np.float64).reshape(-1, self.nq)
        out = np.zeros((qpos.shape[0], self.size))
        out[:, 1:1 + self.nq] = qpos
        if mocap_pos is not None:
            n = 3 * self.model.nmocap
            out[:, self.mocap_adr:self.mocap_adr + n] = np.asarray(mocap_pos, np.float64).reshape(-1, n)
        return out

    def _run(self, data, states, ctrl, fresh, bad, lo, hi):
        m, dt = self.model, self.model.opt.timestep
        for b in range(lo, hi):
            mujoco.mj_setState(m, data, states[b], self.spec)
            data.ctrl[:] = ctrl[b]
            t0 = data.time
            for _ in range(self.substeps):
                mujoco.mj_step(m, data)
            mujoco.mj_getState(m, data, states[b], self.spec)
            qv = states[b, 1 + self.nq:1 + self.nq + self.nv]
            if (not np.all(np.isfinite(states[b])) or np.abs(qv).max() >= MAX_QVEL
                    or abs(data.time - t0 - self.substeps * dt) > 1e-6):  # MuJoCo reset the data itself
                bad[b] = True
                states[b] = fresh[b]

    def step(self, states, ctrl, fresh_qpos, fresh_mocap=None):
        states = np.array(states, np.float64).reshape(-1, self.size)
        ctrl = np.asarray(ctrl, np.float64).reshape(-1, M.NU)
        fresh = self.fresh(fresh_qpos, fresh_mocap)
        bad = ~np.all(np.isfinite(states), axis=-1)
        states[bad] = fresh[bad]
        n = states.shape[0]
        if self.pool is None or n < 2:
            self._run(self.datas[0], states, ctrl, fresh, bad, 0, n)
        else:
            bounds = np.linspace(0, n, min(self.num_threads, n) + 1).astype(int)
            futs = [self.pool.submit(self._run, self.datas[i], states, ctrl, fresh, bad, bounds[i], bounds[i + 1])
                    for i in range(len(bounds) - 1)]
            for fu in futs:
                fu.result()
        self.calls += 1
        return states, bad


def encode_states(states: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(states, np.float64).view(np.uint32)


def decode_states(words) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(words), np.uint32).view(np.float64)


class MujocoLocomotionEnv(LocomotionEnv):
    def __init__(self, task_name: str, num_threads: int = 2, **kw: Any):
        super().__init__(task_name, **kw)
        self.stepper = _HostStepper(self.mj_model, self.substeps, num_threads)
        self.words = 2 * self.stepper.size

    @property
    def backend(self) -> str:
        return "mujoco"

    def _host_init(self, qpos, mocap_pos=None):
        qpos = np.asarray(qpos)
        return encode_states(self.stepper.fresh(qpos, mocap_pos)).reshape(qpos.shape[:-1] + (self.words,))

    def _host_step(self, words, ctrl, fresh_qpos, fresh_mocap=None):
        words = np.asarray(words)
        batch = words.shape[:-1]
        states, bad = self.stepper.step(decode_states(words.reshape(-1, self.words)), ctrl, fresh_qpos, fresh_mocap)
        nq, nv = self.stepper.nq, self.stepper.nv
        q = states[:, 1:1 + nq].astype(np.float32)
        v = states[:, 1 + nq:1 + nq + nv].astype(np.float32)
        return (encode_states(states).reshape(batch + (self.words,)), q.reshape(batch + (nq,)),
                v.reshape(batch + (nv,)), bad.reshape(batch))

    def _init_physics(self, qpos, hold, mocap_pos=None):
        shape = jax.ShapeDtypeStruct((self.words,), jnp.uint32)
        args = (qpos,) if mocap_pos is None else (qpos, mocap_pos)
        return host_call(self._host_init, shape, *args)

    def _step_physics(self, words, ctrl, fresh_qpos, fresh_hold, fresh_mocap=None):
        shapes = (jax.ShapeDtypeStruct((self.words,), jnp.uint32),
                  jax.ShapeDtypeStruct((self.stepper.nq,), jnp.float32),
                  jax.ShapeDtypeStruct((self.stepper.nv,), jnp.float32), jax.ShapeDtypeStruct((), jnp.bool_))
        args = (words, ctrl, fresh_qpos) + (() if fresh_mocap is None else (fresh_mocap,))
        return host_call(self._host_step, shapes, *args)

    def physics_states(self, state: State) -> np.ndarray:
        """Host copy of the float64 physics states [..., size] (time, qpos, qvel, act, warm start; the
        mocap positions in the arena)."""
        return decode_states(jax.device_get(state.pipeline_state)).copy()

    def encode(self, states: np.ndarray) -> jax.Array:
        return jnp.asarray(encode_states(states))


def make_locomotion_env(task_name: str, physics: str = "mujoco", **overrides: Any) -> LocomotionEnv:
    """Brax-API env of locomotion task ``task_name`` on ``physics`` "mujoco" or "mjx". Overrides:
    ``episode_length``, ``prone_fraction``, ``prone_bank_seed`` (the seed of the prone starts' bank),
    ``goal_speed`` (a fixed target speed, 0 or 0.7 m/s, instead of both equally likely), physics
    options of ``model.load_model`` (timestep, substeps, iterations, ls_iterations) and, for mujoco,
    ``num_threads``."""
    task = get(task_name)
    M.asset_root()  # the one-line error naming the extra, before anything else
    if task.reward == "goal_scoring":
        from tasks.locomotion.goal_scoring import make_goal_scoring_env

        return make_goal_scoring_env(task_name, physics=physics, **overrides)
    if physics == "mujoco":
        return MujocoLocomotionEnv(task_name, **overrides)
    if physics == "mjx":
        return MjxLocomotionEnv(task_name, **overrides)
    raise ValueError(f"locomotion tasks run on physics 'mujoco' or 'mjx', not {physics!r}")
