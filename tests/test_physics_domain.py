"""Physics manipulation domain: scene, NumPy twin, MuJoCo callback env, MJX (jax / warp) envs.

CI-sized: small batches, short horizons. MJX-jax on a 2-core CPU can deadlock at larger batches
(shared/STACK.md), so MJX code paths here run pinned to one core with batches ≤ 8 and timeouts.
Long measurements live in bench/physics_throughput.py.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from tasks.manipulation import layout as L
from tasks.manipulation import physics_np as P
from tasks.manipulation import task_defs

if not jax.config.jax_compilation_cache_dir:  # conftest.py normally sets it
    jax.config.update("jax_compilation_cache_dir", os.path.expanduser("~/.cache/parallel_skills_jax"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

MJX_BATCH = 8  # ≤ 8 (MJX-jax deadlock risk on 2 cores); one batch shape = one physics compile
SPARSE_TASKS = [n for n in task_defs.names() if task_defs.get(n).kind == "sparse"]


def scripted_lift_np(obs, cube="green"):
    """Minimal NumPy scripted lift (independent of scripted.py): above the cube with fingers open,
    descend, close, lift."""
    pinch, cpos, q = obs[L.PINCH_POS], obs[L.cube_pos(cube)], obs[L.cube_quat(cube)]
    yaw, grasp = obs[L.YAW], obs[L.GRASP]
    dyaw = (2 * np.arctan2(q[3], q[0]) - yaw + np.pi / 4) % (np.pi / 2) - np.pi / 4
    gain = 0.7 / (L.MAX_LINEAR_SPEED * L.CONTROL_DT)
    a = np.zeros(5)
    if grasp > 0.5:
        a[2], a[4] = (0.25 - pinch[2]) * gain, -1.0
    else:
        dxy = cpos[:2] - pinch[:2]
        a[:2] = dxy * gain
        if np.linalg.norm(dxy) > 0.006 or abs(dyaw) > 0.1:
            a[2] = (cpos[2] + 0.07 - pinch[2]) * gain
            a[3] = 0.7 * dyaw / (L.MAX_YAW_RATE * L.CONTROL_DT)
            a[4] = 1.0
        else:
            dz = cpos[2] - pinch[2]
            a[2] = dz * gain
            a[4] = 1.0 if abs(dz) > 0.005 else -1.0
    return np.clip(a, -1.0, 1.0)


# --- scene and NumPy twin -----------------------------------------------------------------------
def test_bench_physics_options():
    """The collision / solver options of bench/physics_throughput.py's variants reach the model."""
    model, _ = P.load_model()
    assert model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC and model.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON
    assert not model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    model, _ = P.load_model(cone=0, solver=1, contacts=False)
    assert model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL and model.opt.solver == mujoco.mjtSolver.mjSOL_CG
    assert model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, P.init_states([0])[0], P.STATE_SPEC)
    for _ in range(50):
        mujoco.mj_step(model, data)
    assert data.ncon == 0 and data.qpos[P.NQ - 5] < 0  # no contacts: a cube falls through the floor
    with pytest.raises(ValueError, match="unknown physics option 'cones'"):
        P.load_model(cones=0)


def test_scene_layout_and_sensors_match_observation():
    model, substeps = P.load_model()
    assert substeps * model.opt.timestep == pytest.approx(L.CONTROL_DT)
    state = P.init_states([3])[0]
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, state, P.STATE_SPEC)
    for _ in range(7):  # move things a bit so that poses are generic
        data.ctrl[:] = [0.03, -0.02, 0.01, 0.5, -0.02, -0.02]
        mujoco.mj_step(model, data)
    mujoco.mj_forward(model, data)
    obs = P.observe(data.qpos.copy(), data.qvel.copy(), data.act.copy())
    assert obs.shape == (L.OBS_SIZE,)

    def sensor(name):
        return data.sensor(name).data.copy()

    def same_quat(a, b):
        return min(np.abs(a - b).max(), np.abs(a + b).max()) < 1e-9

    np.testing.assert_allclose(obs[L.PINCH_POS], sensor("pinch_pos"), atol=1e-12)
    assert same_quat(obs[L.OBS_SLICES["pinch_pose"]][3:], sensor("pinch_quat"))
    for name in L.CUBE_NAMES:
        np.testing.assert_allclose(obs[L.cube_pos(name)], sensor(f"{name}_pos"), atol=1e-12)
        assert same_quat(obs[L.cube_quat(name)], sensor(f"{name}_quat"))
        np.testing.assert_allclose(obs[L.cube_rel_pos(name)], sensor(f"{name}_wrt_pinch"), atol=1e-12)
        assert same_quat(obs[L.cube_rel_quat(name)], sensor(f"{name}_quat_wrt_pinch"))
    # Aperture: distance between the inner pad faces.
    left = data.geom("pad_left").xpos - data.geom("pad_left").xmat.reshape(3, 3)[:, 1] * 0.005
    right = data.geom("pad_right").xpos + data.geom("pad_right").xmat.reshape(3, 3)[:, 1] * 0.005
    assert np.linalg.norm(left - right) == pytest.approx(obs[L.FINGER], abs=1e-9)


def test_reset_distribution():
    states = P.init_states(np.arange(64))
    obs = P.observe_states(states)
    pinch = obs[:, L.PINCH_POS]
    assert np.all(np.abs(pinch[:, :2]) <= 0.05) and np.all((pinch[:, 2] >= 0.12) & (pinch[:, 2] <= 0.18))
    np.testing.assert_allclose(obs[:, L.YAW], 0.0)
    np.testing.assert_allclose(obs[:, L.FINGER], L.APERTURE_OPEN)
    cubes = np.stack([obs[:, L.cube_pos(n)] for n in L.CUBE_NAMES], 1)
    assert np.all(np.abs(cubes[..., :2]) <= 0.08)
    d = np.linalg.norm(cubes[:, :, None, :2] - cubes[:, None, :, :2], axis=-1) + np.eye(3)
    assert d.min() >= P.RESET_MIN_DIST
    yaw = 2 * np.arctan2(np.stack([obs[:, L.cube_quat(n)][:, 3] for n in L.CUBE_NAMES], 1),
                         np.stack([obs[:, L.cube_quat(n)][:, 0] for n in L.CUBE_NAMES], 1))
    assert np.all(np.abs(yaw) <= np.pi / 4 + 1e-9)
    # Deterministic per seed.
    np.testing.assert_array_equal(P.init_states([5]), P.init_states([5]))


def test_velocity_tracking_and_fingers():
    twin = P.MujocoTwin("reach_green")
    obs0 = twin.reset(seed=1)
    for _ in range(20):
        obs, *_ = twin.step(np.array([1.0, -0.5, 0.5, 0.5, -1.0]))
    moved = obs[L.PINCH_POS] - obs0[L.PINCH_POS]
    expected = np.array([1.0, -0.5, 0.5]) * L.MAX_LINEAR_SPEED * 20 * L.CONTROL_DT
    np.testing.assert_allclose(moved, expected, atol=0.004)
    assert obs[L.YAW] == pytest.approx(0.5 * 20 * L.CONTROL_DT, abs=0.05)
    # Closing at full speed for 1 s closes the 8.5 cm aperture (nothing between the pads).
    assert obs[L.FINGER] < 0.005
    np.testing.assert_allclose(obs[L.OBS_SLICES["joint_vel"]], [0.05, -0.025, 0.025, 0.5], atol=0.005)


@pytest.mark.timeout(120)
def test_twin_scripted_lift():
    twin = P.MujocoTwin("lift_green", episode_length=220)
    successes = 0
    for seed in range(4):
        obs = twin.reset(seed=seed)
        ok = False
        for _ in range(220):
            obs, reward, done, info = twin.step(scripted_lift_np(obs))
            ok |= info["success"] > 0
            assert np.all(np.isfinite(obs))
        successes += ok
    assert successes >= 3


def test_twin_nan_injection_resets():
    twin = P.MujocoTwin("lift_green")
    twin.reset(seed=0)
    bad = twin.state.copy()
    bad[P.QVEL][:] = np.nan
    twin.reset(state=bad)
    obs, reward, done, info = twin.step(np.zeros(5))
    assert info["nan_reset"] == 1.0 and np.all(np.isfinite(obs)) and np.isfinite(reward)
    obs, reward, done, info = twin.step(np.zeros(5))
    assert info["nan_reset"] == 0.0
    # A blown-up (ejected) cube counts too.
    s = twin.state.copy()
    s[P.QPOS][P.CUBE_QPOS[1]] = 50.0
    twin.reset(state=s)
    _, _, _, info = twin.step(np.zeros(5))
    assert info["nan_reset"] == 1.0


# --- MuJoCo callback env --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def mujoco_env():
    from tasks.manipulation.mujoco_env import make_mujoco_env

    return make_mujoco_env("lift_green", episode_length=12, num_threads=2)


@pytest.mark.timeout(120)
def test_callback_env_bitwise_equals_twin_in_scan(mujoco_env):
    env = mujoco_env
    n, T = 4, 15
    keys = jax.random.split(jax.random.PRNGKey(3), n)
    actions = jax.random.uniform(jax.random.PRNGKey(4), (T, n, L.ACTION_SIZE), minval=-1.0, maxval=1.0)

    @jax.jit
    def rollout(keys, actions):
        s0 = jax.vmap(env.reset)(keys)

        def body(s, a):
            s = jax.vmap(env.step)(s, a)
            return s, (s.pipeline_state, s.obs, s.reward, s.done, s.info["truncation"], s.metrics["success"])

        return s0, jax.lax.scan(body, s0, actions)

    s0, (_, (words, obs, reward, done, trunc, success)) = rollout(keys, actions)
    assert obs.shape == (T, n, L.OBS_SIZE) and obs.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(done[:, 0]), (np.arange(1, T + 1) >= 12).astype(np.float32))
    np.testing.assert_array_equal(np.asarray(trunc), np.asarray(done))
    seeds = np.asarray(jax.vmap(lambda k: jax.random.bits(k, (), jnp.uint32))(keys))
    twin = P.MujocoTwin("lift_green", episode_length=12)
    for b in range(n):
        o = twin.reset(seed=int(seeds[b]))
        np.testing.assert_array_equal(o.astype(np.float32), np.asarray(s0.obs[b]))
        for t in range(T):
            o, r, d, info = twin.step(np.asarray(actions[t, b], np.float32).astype(np.float64))
            np.testing.assert_array_equal(twin.state.view(np.uint32), np.asarray(words[t, b]))
            np.testing.assert_array_equal(o.astype(np.float32), np.asarray(obs[t, b]))
            assert np.float32(r) == reward[t, b] and np.float32(info["success"]) == success[t, b]


@pytest.mark.timeout(60)
def test_callback_env_unbatched_and_nan_reset(mujoco_env):
    env = mujoco_env
    s = jax.jit(env.reset)(jax.random.PRNGKey(0))
    s = jax.jit(env.step)(s, jnp.ones(5))
    assert s.obs.shape == (L.OBS_SIZE,) and float(s.info["nan_reset"]) == 0.0
    states = env.physics_states(s)
    states[P.QPOS][0] = np.nan
    s_bad = s.replace(pipeline_state=env.encode(states))
    s2 = jax.jit(env.step)(s_bad, jnp.zeros(5))
    assert float(s2.info["nan_reset"]) == 1.0 and float(s2.metrics["nan_resets"]) == 1.0
    assert np.all(np.isfinite(np.asarray(s2.obs))) and np.isfinite(float(s2.reward))
    assert np.all(np.isfinite(env.physics_states(s2)))


# --- MJX (impl jax / warp) ----------------------------------------------------------------------
@pytest.mark.timeout(400)
@pytest.mark.parametrize("impl", ["jax", "warp"])
def test_mjx_sparse_tasks_reset_step_vmap(impl, one_core, full_optimisation):
    from tasks.manipulation.mjx_env import make_mjx_env

    n = MJX_BATCH
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    actions = jnp.tile(jnp.array([0.5, -0.5, -1.0, 0.3, -1.0]), (n, 1))
    for name in SPARSE_TASKS:
        env = make_mjx_env(name, impl=impl, episode_length=2, max_envs=n)
        assert env.backend == ("mjx" if impl == "jax" else "warp")
        assert (env.observation_size, env.action_size) == (L.OBS_SIZE, L.ACTION_SIZE)
        s = jax.vmap(env.reset)(keys)  # eager vmap: the shared jitted physics compiles once
        for t in range(2):
            s = jax.vmap(env.step)(s, actions)
        assert s.obs.shape == (n, L.OBS_SIZE) and np.all(np.isfinite(np.asarray(s.obs)))
        assert s.metrics["success"].shape == (n,) and set(np.unique(np.asarray(s.metrics["success"]))) <= {0.0, 1.0}
        np.testing.assert_array_equal(np.asarray(s.info["steps"]), 2)
        np.testing.assert_array_equal(np.asarray(s.done), 1.0)
        np.testing.assert_array_equal(np.asarray(s.info["truncation"]), 1.0)
        np.testing.assert_array_equal(np.asarray(s.info["nan_reset"]), 0.0)
    # The pinch moved as commanded (two agent steps at the given velocity, minus servo lag).
    obs0 = jax.vmap(env.reset)(keys).obs
    moved = np.asarray(s.obs[:, L.PINCH_POS] - obs0[:, L.PINCH_POS])
    expected = np.array([0.5, -0.5, -1.0]) * L.MAX_LINEAR_SPEED * 2 * L.CONTROL_DT
    np.testing.assert_allclose(moved, np.broadcast_to(expected, moved.shape), atol=0.003)


@pytest.mark.timeout(300)
def test_mjx_nan_injection_resets(one_core, full_optimisation):
    from tasks.manipulation.mjx_env import make_mjx_env

    n = MJX_BATCH  # the batch shape of the other MJX tests: the shared physics compiles once
    env = make_mjx_env("stack", impl="jax", episode_length=5)
    s = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(1), n))
    data = s.pipeline_state
    s = s.replace(pipeline_state=data.replace(qvel=data.qvel.at[0].set(jnp.nan)))
    s = jax.vmap(env.step)(s, jnp.zeros((n, L.ACTION_SIZE)))
    expected = np.zeros(n)
    expected[0] = 1.0
    np.testing.assert_array_equal(np.asarray(s.info["nan_reset"]), expected)
    np.testing.assert_array_equal(np.asarray(s.metrics["nan_resets"]), expected)
    assert np.all(np.isfinite(np.asarray(s.obs))) and np.all(np.isfinite(np.asarray(s.reward)))
    assert np.all(np.isfinite(np.asarray(s.pipeline_state.qpos)))
    # Non-finite actions are treated as zero, never propagated.
    s = jax.vmap(env.step)(s, jnp.full((n, L.ACTION_SIZE), jnp.nan))
    np.testing.assert_array_equal(np.asarray(s.info["nan_reset"]), np.zeros(n))
    assert np.all(np.isfinite(np.asarray(s.obs)))


@pytest.mark.timeout(300)
def test_mjx_agrees_with_mujoco_twin(one_core, full_optimisation):
    """Same initial state, same (scripted lift) action sequence: MJX (float32) stays close to the
    classic MuJoCo twin (float64) over 50 agent steps: approach, descent and the start of the grasp."""
    from tasks.manipulation.mjx_env import make_mjx_env

    env = make_mjx_env("lift_green", impl="jax", episode_length=100)
    twin = P.MujocoTwin("lift_green")
    obs_twin = [twin.reset(seed=2)]
    actions = []
    for _ in range(50):
        actions.append(scripted_lift_np(obs_twin[-1]))
        obs_twin.append(twin.step(actions[-1])[0])
    twin.reset(seed=2)
    state = P.init_states([2])[0]
    s = env.state_from(env.data_from(state[P.QPOS], state[P.ACT]), jax.random.PRNGKey(0))
    np.testing.assert_allclose(np.asarray(s.obs), obs_twin[0], atol=1e-6)
    # The same batch shape as the other MJX tests: 8 copies, placed on the device as the step's own
    # outputs are (otherwise its second call compiles again).
    s = jax.device_put(jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (MJX_BATCH,) + x.shape), s),
                       jax.devices()[0])
    step = jax.jit(jax.vmap(env.step))
    dev = []
    for t, a in enumerate(actions):
        s = step(s, jnp.broadcast_to(jnp.asarray(a, jnp.float32), (MJX_BATCH, L.ACTION_SIZE)))
        o = np.asarray(s.obs[0])
        dev.append(max(np.abs(o[L.PINCH_POS] - obs_twin[t + 1][L.PINCH_POS]).max(),
                       *(np.abs(o[L.cube_pos(c)] - obs_twin[t + 1][L.cube_pos(c)]).max() for c in L.CUBE_NAMES),
                       abs(o[L.FINGER] - obs_twin[t + 1][L.FINGER])))
    assert max(dev) < 2e-3, f"max deviation {max(dev):.2e} m"
