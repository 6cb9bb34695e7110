"""GoalScoring (paper App. C) for the OP3 humanoid, on both backends (``mujoco``, ``mjx``).

A 4 m × 4 m walled arena ([-2, 2]², ``model.load_arena_model``) with a ball; the robot plays in
its own half (x ≤ 0); the goal is the floor region x ∈ [1.5, 2], |y| ≤ 0.5, against the centre of
the back wall of the other half; a short wall (the obstacle, 0.6 m × 5 cm × 0.2 m, a mocap body so
that its position lives in the per-env physics state) stands at a random place between the robot and
the goal, in front of the goal mouth.

    R = R_score + R_upright + R_maxvelocity

R_score = 1000 on the step the ball's centre enters the goal region, then unavailable until the
ball is back in the robot's half (re-armed there); R_upright as in R_walk (weight 1);
R_maxvelocity = the feet's planar velocity along the robot's forward direction (m/s, weight 1; the
mean of both feet's displacement over the 25 ms step, as in R_velocity). The episode terminates with
zero reward when the robot's torso leaves its half (x > 0, or outside the arena) or a non-foot body
part comes within 4 cm of the floor (R_ground's test). Termination is absorbing: stepping on after
it gives reward 0 and done 1 until the next reset (so whole-episode evaluations that do not reset
on ``done`` add nothing after it).

Observation (OBS_SIZE = 246): the 233 entries shared by all OP3 tasks (same meaning and layout, so a
walking skill transfers: ``env.OBS_PROPRIO``, ``env.OBS_ACTIONS``, ``env.OBS_GOAL``) with the goal
slot set to "walk to the ball": the unit direction from the torso to the ball in the heading frame
and the target speed 0.7 m/s; then 13 task features (``OBS_TASK``), positions relative to the torso,
all planar vectors in the heading frame (x forward, y left):
ball position [fwd, left, height] (3), ball velocity [fwd, left, up] (3), goal centre (2),
the obstacle's two ends (2 × 2), and whether R_score is armed (1).

``metrics["success"]``: 1 from the step the first goal of the episode is scored on (a goal scored so
far); ``metrics["goals"]``: goals scored in the episode so far. docs/locomotion.md has the choices
(starts, episode length, weights) and their reasons.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import State

from tasks.locomotion import env as E
from tasks.locomotion import model as M
from tasks.locomotion import rewards as R

SCORE_REWARD = 1000.0
W_UPRIGHT = 1.0
W_MAXVELOCITY = 1.0
TARGET_SPEED = 0.7  # m/s, the goal slot's target speed (the walking skill's "walk" speed)
ARENA = M.ARENA_HALF
GOAL_X_MIN = ARENA - M.GOAL_DEPTH  # goal region: x in [1.5, 2], |y| <= 0.5
GOAL_HALF_WIDTH = M.GOAL_WIDTH / 2
GOAL_CENTRE = (ARENA - M.GOAL_DEPTH / 2, 0.0)
# Starts: the robot standing (uniform yaw) in the back of its half, the ball at rest between it and
# the halfway line (≥ 0.3 m in x ahead of the torso: never touching the robot), the obstacle in the
# other half in front of the goal mouth (it always covers ≥ 0.3 m of the 1 m mouth).
ROBOT_START = ((-1.6, -1.0), (-1.1, 1.0))  # (x_min, y_min), (x_max, y_max) of the torso
BALL_START = ((-0.8, -1.0), (-0.3, 1.0))
OBSTACLE_START = ((0.6, -0.5), (1.1, 0.5))  # the obstacle's centre (its long side along y)
EPISODE_LENGTH = 600

TASK_OBS_SIZE = 13
OBS_SIZE = E.OBS_SIZE + TASK_OBS_SIZE
OBS_TASK = slice(E.OBS_SIZE, OBS_SIZE)
OBS_BALL = slice(E.OBS_SIZE, E.OBS_SIZE + 3)
OBS_BALL_VEL = slice(E.OBS_SIZE + 3, E.OBS_SIZE + 6)
OBS_GOAL_POS = slice(E.OBS_SIZE + 6, E.OBS_SIZE + 8)
OBS_OBSTACLE = slice(E.OBS_SIZE + 8, E.OBS_SIZE + 12)
OBS_ARMED = slice(E.OBS_SIZE + 12, E.OBS_SIZE + 13)
BALL_QPOS = slice(M.NQ, M.NQ + 7)  # the ball's free joint: position [3], quaternion [4]
BALL_QVEL = slice(M.NV, M.NV + 6)  # linear velocity (world) [3], angular velocity [3]


# --- pure JAX pieces (tests call them on constructed states) --------------------------------------
def in_goal(ball_xy):
    return (ball_xy[..., 0] >= GOAL_X_MIN) & (ball_xy[..., 0] <= ARENA) & (jnp.abs(ball_xy[..., 1]) <= GOAL_HALF_WIDTH)


def in_own_half(xy):
    """Inside the robot's half of the arena: x in [-2, 0], |y| <= 2."""
    return (xy[..., 0] <= 0.0) & (xy[..., 0] >= -ARENA) & (jnp.abs(xy[..., 1]) <= ARENA)


def score_update(ball_xy, armed):
    """(scored, armed after this step): a goal when the ball is in the goal region while armed; then
    disarmed until the ball is back in the robot's half (x < 0)."""
    scored = armed & in_goal(ball_xy)
    return scored, (armed & ~scored) | (ball_xy[..., 0] < 0.0)


def terminates(f: R.Features, torso_xy):
    """The robot left its half (torso position) or a non-foot body part is within 4 cm of the floor."""
    return (~in_own_half(torso_xy)) | (f.ground < R.GROUND_DISTANCE)


def heading_frame(heading, v):
    """Planar world vector(s) v [..., 2] in the heading frame (x forward, y left)."""
    fwd = heading[..., 0] * v[..., 0] + heading[..., 1] * v[..., 1]
    left = heading[..., 0] * v[..., 1] - heading[..., 1] * v[..., 0]
    return jnp.stack([fwd, left], axis=-1)


def obstacle_ends(obstacle_xy):
    """The obstacle's two ends [2, 2] (its long side is along y)."""
    dy = jnp.array([0.0, M.OBSTACLE_HALF[1]])
    return jnp.stack([obstacle_xy - dy, obstacle_xy + dy])


def _uniform_xy(key, box):
    return jax.random.uniform(key, (2,), jnp.float32, jnp.array(box[0]), jnp.array(box[1]))


class _GoalScoring:
    """GoalScoring's task logic over a backend (``E.MujocoLocomotionEnv`` / ``E.MjxLocomotionEnv``)."""

    arena = True

    def __init__(self, task_name: str = "goal_scoring", prone_fraction: float | None = None, **kw: Any):
        if prone_fraction not in (None, 0, 0.0):
            raise ValueError("goal_scoring starts standing (a prone start would terminate at once); "
                             "prone_fraction must be 0")
        super().__init__(task_name, prone_fraction=0.0, **kw)
        if self.mj_model.nq != M.NQ + 7 or self.mj_model.nmocap != 1:
            raise ValueError("goal_scoring needs the arena model (robot, ball, obstacle)")

    @property
    def observation_size(self) -> int:
        return OBS_SIZE

    # --- starts ------------------------------------------------------------------------------------
    def sample_start(self, key):
        """(qpos [nq], hold [NU], mocap_pos [1, 3], obstacle_xy [2]): the robot standing at a random
        place and yaw in the back of its half, the ball at rest ahead of it, the obstacle in front of
        the goal."""
        k_robot, k_xy, k_ball, k_obst = jax.random.split(key, 4)
        qpos, hold, _ = self.sampler.sample(k_robot)  # standing at the origin, uniform yaw
        robot_xy = _uniform_xy(k_xy, ROBOT_START)
        ball_xy = _uniform_xy(k_ball, BALL_START)
        obstacle_xy = _uniform_xy(k_obst, OBSTACLE_START)
        qpos = jnp.concatenate([qpos[:2] + robot_xy, qpos[2:], ball_xy, jnp.array([M.BALL_RADIUS, 1.0, 0.0, 0.0, 0.0])])
        mocap = jnp.concatenate([obstacle_xy, jnp.array([M.OBSTACLE_HALF[2]])])[None]
        return qpos.astype(jnp.float32), hold, mocap.astype(jnp.float32), obstacle_xy

    def _task_state(self, f: R.Features, hold, obstacle_xy):
        a0 = self.hold_action(hold)
        return {
            "a_filt": a0,
            "obs_hist": jnp.tile(E.proprio(f)[None], (E.STACK, 1)),
            "act_hist": jnp.tile(a0[None], (E.STACK, 1)),
            "feet_xy": f.feet_xy,
            "obstacle": obstacle_xy,
            "armed": jnp.ones((), jnp.bool_),
        }

    _TASK_KEYS = ("a_filt", "obs_hist", "act_hist", "feet_xy", "obstacle", "armed")

    # --- observation -------------------------------------------------------------------------------
    def _gs_obs(self, f: R.Features, qpos, qvel, t: dict):
        torso = qpos[:2]
        ball = qpos[BALL_QPOS][:3]
        ball_vel = qvel[BALL_QVEL][:3]
        to_ball = ball[:2] - torso
        dist = jnp.linalg.norm(to_ball)
        direction = jnp.where(dist > 1e-6, to_ball / jnp.maximum(dist, 1e-6), f.heading)
        shared = [t["obs_hist"].reshape(-1), t["act_hist"].reshape(-1),
                  E.goal_obs(f.heading, direction, jnp.float32(TARGET_SPEED))]
        task = [heading_frame(f.heading, to_ball), ball[2:3], heading_frame(f.heading, ball_vel[:2]), ball_vel[2:3],
                heading_frame(f.heading, jnp.array(GOAL_CENTRE) - torso),
                heading_frame(f.heading, obstacle_ends(t["obstacle"]) - torso).reshape(-1),
                t["armed"].astype(jnp.float32)[None]]
        return jnp.concatenate(shared + task).astype(jnp.float32)

    def _robot(self, qpos, qvel):
        return self.features(qpos[:M.NQ], qvel[:M.NV])

    # --- Brax env API ------------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        rng, k_start = jax.random.split(rng)
        qpos, hold, mocap, obstacle_xy = self.sample_start(k_start)
        qvel = jnp.zeros(self.mj_model.nv, jnp.float32)
        ps = self._init_physics(qpos, hold, mocap)
        f = self._robot(qpos, qvel)
        t = self._task_state(f, hold, obstacle_xy)
        zero = jnp.zeros((), jnp.float32)
        metrics = {k: zero for k in ("reward", "success", "goals", "nan_resets", "r_score", "r_upright",
                                     "r_maxvelocity", "standing", "terminated")}
        info = {"steps": jnp.zeros((), jnp.int32), "truncation": zero, "nan_reset": zero, "rng": rng,
                "terminated": zero, "goals": zero, "start": jnp.int32(0), **t}
        return State(pipeline_state=ps, obs=self._gs_obs(f, qpos, qvel, t), reward=zero, done=zero,
                     metrics=metrics, info=info)

    def step(self, state: State, action: jax.Array) -> State:
        info = state.info
        action = action.astype(jnp.float32)
        action = jnp.where(jnp.isfinite(action), jnp.clip(action, -1.0, 1.0), 0.0)
        a_filt = E.filter_action(info["a_filt"], action)
        rng, k_fresh = jax.random.split(info["rng"])
        fresh_qpos, fresh_hold, fresh_mocap, fresh_obstacle = self.sample_start(k_fresh)
        ps, qpos, qvel, bad = self._step_physics(state.pipeline_state, self.ctrl_of(a_filt), fresh_qpos, fresh_hold,
                                                 fresh_mocap)
        f = self._robot(qpos, qvel)
        t = {k: info[k] for k in self._TASK_KEYS}
        feet_vel = jnp.mean(f.feet_xy - t["feet_xy"], axis=0) / self.control_dt
        ball_xy = qpos[BALL_QPOS][:2]
        # A blow-up restarts the physics (fresh start): no termination, no goal on that step.
        was_terminated = info["terminated"] > 0
        now_terminates = terminates(f, qpos[:2]) & ~bad
        live = ~was_terminated & ~now_terminates & ~bad
        scored, armed = score_update(ball_xy, t["armed"])
        scored = scored & live
        r_score = SCORE_REWARD * scored.astype(jnp.float32)
        r_upright = W_UPRIGHT * R.r_upright(f.up_z)
        r_maxvel = W_MAXVELOCITY * R.r_maxvelocity(feet_vel, f.heading)
        reward = jnp.where(live, r_score + r_upright + r_maxvel, 0.0).astype(jnp.float32)
        nxt = dict(t, a_filt=a_filt, obs_hist=E.push(t["obs_hist"], E.proprio(f)),
                   act_hist=E.push(t["act_hist"], action), feet_xy=f.feet_xy, armed=armed)
        fresh = self._task_state(f, fresh_hold, fresh_obstacle)
        nxt = jax.tree.map(lambda a, b: jnp.where(bad, a, b), fresh, nxt)
        terminated = (was_terminated | now_terminates).astype(jnp.float32)
        goals = info["goals"] + scored.astype(jnp.float32)
        steps = info["steps"] + 1
        time_up = steps >= self.episode_length
        done = jnp.maximum(terminated, time_up.astype(jnp.float32))
        truncation = (time_up & (terminated == 0)).astype(jnp.float32)
        badf = bad.astype(jnp.float32)
        info = dict(info, steps=steps, truncation=truncation, nan_reset=badf, rng=rng, terminated=terminated,
                    goals=goals, **nxt)
        metrics = dict(state.metrics, reward=reward, success=(goals > 0).astype(jnp.float32), goals=goals,
                       nan_resets=state.metrics["nan_resets"] + badf, r_score=r_score,
                       r_upright=jnp.where(live, r_upright, 0.0).astype(jnp.float32),
                       r_maxvelocity=jnp.where(live, r_maxvel, 0.0).astype(jnp.float32),
                       standing=R.standing(f).astype(jnp.float32), terminated=terminated)
        return state.replace(pipeline_state=ps, obs=self._gs_obs(f, qpos, qvel, nxt), reward=reward, done=done,
                             metrics=metrics, info=info)


class MujocoGoalScoringEnv(_GoalScoring, E.MujocoLocomotionEnv):
    pass


class MjxGoalScoringEnv(_GoalScoring, E.MjxLocomotionEnv):
    pass


def make_goal_scoring_env(task_name: str = "goal_scoring", physics: str = "mujoco", **overrides: Any):
    """GoalScoring on ``physics`` "mujoco" or "mjx"; overrides as ``env.make_locomotion_env`` (no
    ``prone_fraction``)."""
    if physics == "mujoco":
        return MujocoGoalScoringEnv(task_name, **overrides)
    if physics == "mjx":
        return MjxGoalScoringEnv(task_name, **overrides)
    raise ValueError(f"locomotion tasks run on physics 'mujoco' or 'mjx', not {physics!r}")
