"""Scripted OP3 skills (tasks/locomotion/controllers.py): pure, jit/vmap-able, stateless phase
recovery from constructed observations, parameters load, a few env steps on the C engine."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tasks.locomotion import controllers as C
from tasks.locomotion import env as E


def _obs(prev_action=None, gravity=(0.0, 0.0, -1.0), goal=(1.0, 0.0, 0.7)):
    obs = np.zeros(E.OBS_SIZE, np.float32)
    obs[C.NU + 3:C.NU + 6] = gravity
    if prev_action is not None:
        obs[E.OBS_ACTIONS.start:E.OBS_ACTIONS.start + C.NU] = prev_action
    obs[E.OBS_GOAL] = goal
    return jnp.asarray(obs)


@pytest.mark.parametrize("name", ["getup", "walk"])
def test_jit_vmap_and_range(name):
    fn = C.get(name, C.initial_params(name))
    obs = jnp.stack([_obs(), _obs(gravity=(1.0, 0.0, 0.0)), _obs(gravity=(-1.0, 0.0, 0.0))])
    a = jax.jit(jax.vmap(fn))(obs, jax.random.split(jax.random.PRNGKey(0), 3))
    assert a.shape == (3, C.NU)
    assert bool(jnp.all(jnp.isfinite(a))) and bool(jnp.all(jnp.abs(a) <= 1.0))
    np.testing.assert_allclose(a[0], fn(obs[0], None), atol=1e-6)  # pure: same input, same action


def test_params_vmap_over_candidates():
    make = lambda p, o: C.walk_controller(p)(o)  # noqa: E731 - the search vmaps over parameters too
    ps = jnp.stack([C.initial_params("walk")] * 2)
    a = jax.vmap(make)(ps, jnp.stack([_obs(), _obs()]))
    np.testing.assert_allclose(a[0], a[1])


def test_walk_phase_advances_from_previous_action():
    p = C.initial_params("walk")
    fn = C.walk_controller(p)
    freq = C.WALK_SPEC.unpack(p)["freq"]
    a0 = fn(_obs())  # episode start: the head codes are 0 -> phase 0, envelope ramps up
    phi0, r0 = C.walk_phase(_obs(a0))
    assert 0 < float(r0) < 1
    a1 = fn(_obs(a0))
    phi1, r1 = C.walk_phase(_obs(a1))
    np.testing.assert_allclose(float(phi1 - phi0), 2 * np.pi * freq * C.CONTROL_DT, atol=1e-4)
    assert float(r1) > float(r0)
    # left and right legs are in antiphase: with the full envelope, the mirrored leg actions swap
    # half a period later
    half = 0.5 / float(freq)
    code = lambda phi: np.array([C.WALK_CODE * np.cos(phi), C.WALK_CODE * np.sin(phi)])  # noqa: E731
    prev = np.zeros(C.NU, np.float32)
    prev[:2] = code(0.3)
    b0 = np.asarray(fn(_obs(prev)))
    prev[:2] = code(0.3 + 2 * np.pi * float(freq) * half)
    b1 = np.asarray(fn(_obs(prev)))
    np.testing.assert_allclose(b0[C.LEFT][5:8], -b1[C.RIGHT][5:8], atol=1e-5)  # hip pitch, knee, ankle


def test_getup_phase_machine():
    fn = C.getup_controller(C.initial_params("getup"))
    decode = lambda a: C.decode_fsm(jnp.asarray(a))  # noqa: E731
    # no valid code: lying on the front starts the front sequence, on the back the back sequence
    assert int(decode(fn(_obs(np.full(C.NU, 0.5), gravity=(1.0, 0, 0))))[0]) == 1
    assert int(decode(fn(_obs(None, gravity=(-1.0, 0, 0))))[0]) == 1 + C.K_FRONT
    assert int(decode(fn(_obs(None)))[0]) == 0  # upright: stand
    # the timer counts up inside a phase and the phase advances when it runs out
    steps = C.GETUP_SPEC.unpack(C.initial_params("getup"))["front_steps"]
    a = fn(_obs(None, gravity=(1.0, 0, 0)))
    for _ in range(int(round(float(steps[0]))) - 1):
        a = fn(_obs(a, gravity=(0.7, 0, -0.7)))
    ph, t = decode(a)
    assert int(ph) == 2 and int(t) == 0
    a = fn(_obs(a, gravity=(0.7, 0, -0.7)))
    assert tuple(int(x) for x in decode(a)) == (2, 1)
    # standing (phase 0) but lying on the back again: restart the back sequence
    stand = np.zeros(C.NU, np.float32)
    assert int(decode(fn(_obs(stand, gravity=(-1.0, 0, 0))))[0]) == 1 + C.K_FRONT


def test_checkpoints_load():
    for name in C.names():
        path = C.CHECKPOINT_DIR / f"{name}.json"
        assert path.exists(), f"the shipped checkpoint {path.name} is missing"
        p = C.load(name)
        assert p.shape == (C.spec(name).size,) and np.all(np.isfinite(p))
        rec = json.loads(path.read_text())["record"]
        assert "search" in rec


def test_few_env_steps_mujoco():
    import tasks

    env = tasks.make("op3_getup", physics="mujoco", num_threads=1, episode_length=4)
    fn = C.get("getup")
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    s = jax.vmap(env.reset)(keys)
    step = jax.jit(lambda s: jax.vmap(env.step)(s, jax.vmap(fn)(s.obs)))
    for _ in range(4):
        s = step(s)
    assert bool(jnp.all(jnp.isfinite(s.obs))) and float(jnp.sum(s.info["nan_reset"])) == 0
    phase, _ = jax.vmap(lambda o: C.decode_fsm(C.prev_action(o)))(s.obs)
    assert bool(jnp.all(phase >= 1))  # lying: in a get-up sequence


def test_locomotion_skill_sets_and_training_run_defaults(tmp_path):
    """training.run --task getup_and_walk / goal_scoring: the skill table names the OP3 controllers,
    they load as scripted skills of the env's sizes, and the physics defaults to mujoco."""
    from training import skill_library
    from training.run import build_parser, prepare_new

    assert skill_library.skill_names("getup_and_walk") == ["op3_getup", "op3_walk"]
    assert skill_library.skill_names("goal_scoring") == ["op3_walk"]
    with pytest.raises(ValueError, match="no distractor skills"):
        skill_library.skill_names("getup_and_walk", "distractors")
    skills = skill_library.load_skills(["op3_getup", "op3_walk"], "mujoco", "scripted", E.OBS_SIZE, C.NU)
    for s, name in zip(skills, ["getup", "walk"]):
        ref = C.get(name)(_obs(), jax.random.PRNGKey(0))
        np.testing.assert_array_equal(s.apply(s.params, _obs(), jax.random.PRNGKey(0)), ref)
        assert s.collection_noise is False  # their phase codes ride in the head actions
    with pytest.raises(ValueError, match="no OP3 controller 'op3_run'"):
        skill_library.load_skills(["op3_run"], "mujoco", "scripted")
    with pytest.raises(ValueError, match="mix OP3 and arm controllers"):
        skill_library.load_skills(["op3_walk", "reach_green"], "mujoco", "scripted")
    argv = ["--task", "getup_and_walk", "--num_timesteps", "1000", "--out", str(tmp_path / "r")]
    _, run, _, env = prepare_new(build_parser().parse_args(argv), argv, write=False)
    assert (run.physics, run.skills, env.backend) == ("mujoco", ["op3_getup", "op3_walk"], "mujoco")


def test_shipped_walk_steers_toward_the_goal():
    """The shipped walk's ``steer`` (< 0: the controller's hip-yaw sign) turns the torso toward the
    goal direction: over 8 standing starts and 6 s, the mean cos(heading, goal) is well above that
    of the same gait with steer 0 (which ignores the goal), and nothing falls."""
    from research import op3_skills as O

    env = O.make_env("walk", episode_length=240)
    shipped = C.load("walk")
    assert float(C.spec("walk").unpack(shipped)["steer"]) < 0
    params = np.repeat(np.stack([shipped, O.with_steer(shipped, 0.0)]), 8, axis=0)
    keys = jnp.tile(jax.random.split(jax.random.PRNGKey(3), 8), (2, 1))
    st = jax.device_get(O.make_rollout(env, "walk", 240)(jnp.asarray(params), keys, jax.random.PRNGKey(0)))
    fwd = np.asarray(st["goal_fwd"]).reshape(2, 8).mean(1)
    assert bool(np.all(st["stand_all"])), "the walk fell"
    assert fwd[0] > fwd[1] + 0.2, f"heading·goal steered {fwd[0]:.2f} vs steer 0 {fwd[1]:.2f}"
