"""n-step TD fields for the new skill's critic (parallel_skills.nstep) and their insertion by the
collector, n − 1 steps late, across unrolls."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import tasks
from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig
from parallel_skills.nstep import nstep_fields, own_nstep_fields
from parallel_skills.train import make_trainer
from tasks.manipulation import scripted

GAMMA = 0.9


@struct.dataclass
class Window:
    """The fields ``nstep_fields`` reads (a ``replay.PendingStep`` has them among others)."""

    reward: jax.Array
    discount: jax.Array
    next_obs: jax.Array
    done: jax.Array
    weight: jax.Array


@struct.dataclass
class SkillWindow(Window):
    skill: jax.Array


def _fields(window, n, gamma):
    return jax.jit(nstep_fields, static_argnums=(1, 2))(Window(**window), n, gamma)


def _reference(window, n, gamma, own_index=None):
    """Plain loop over (t, b): walk forward until n steps or the episode's end (``own_index``: or
    until the next step is another skill's than ``window["skill"] == own_index``)."""
    w, b = window["reward"].shape
    t_out = w - n + 1
    out = {k: [] for k in ("nstep_reward", "nstep_discount", "nstep_next_obs", "nstep_weight")}
    for t in range(t_out):
        row = {k: [] for k in out}
        for e in range(b):
            ret, wt = 0.0, 1.0
            for j in range(n):
                s = t + j
                ret += gamma ** j * window["reward"][s, e]
                wt *= window["weight"][s, e]
                last = s
                if window["done"][s, e]:
                    break
                if own_index is not None and s + 1 < w and window["skill"][s + 1, e] != own_index:
                    break
            m = last - t + 1
            row["nstep_reward"].append(ret)
            row["nstep_discount"].append(gamma ** (m - 1) * window["discount"][last, e])
            row["nstep_next_obs"].append(window["next_obs"][last, e])
            row["nstep_weight"].append(wt)
        for k in out:
            out[k].append(np.stack(row[k]))
    return {k: np.stack(v) for k, v in out.items()}


def _random_window(rng, w, b, o=3):
    done = rng.random((w, b)) < 0.25
    terminated = done & (rng.random((w, b)) < 0.5)  # the rest are time-limit truncations
    return dict(reward=rng.normal(size=(w, b)).astype(np.float32),
                discount=np.where(terminated, 0.0, 1.0).astype(np.float32),
                next_obs=rng.normal(size=(w, b, o)).astype(np.float32),
                done=done, weight=(rng.random((w, b)) > 0.1).astype(np.float32))


@pytest.mark.parametrize("n", [1, 2, 5])
def test_nstep_fields_match_a_plain_loop(n):
    window = _random_window(np.random.default_rng(n), w=12 + n - 1, b=6)
    got = jax.device_get(_fields({k: jnp.asarray(v) for k, v in window.items()}, n, GAMMA))
    want = _reference(window, n, GAMMA)
    for k in want:
        np.testing.assert_allclose(got[k], want[k], rtol=1e-5, atol=1e-6, err_msg=k)
    if n == 1:  # one step: the transition's own fields
        np.testing.assert_array_equal(got["nstep_discount"], window["discount"])
        np.testing.assert_array_equal(got["nstep_next_obs"], window["next_obs"])


@pytest.mark.parametrize("n", [1, 3, 5])
def test_own_nstep_fields_stop_before_another_skills_step(n):
    """``own_nstep_fields``: the return of step t takes step t whoever acted, then steps t + j only
    while the new skill (index 2 here) took them; it bootstraps where another skill's step is next."""
    rng = np.random.default_rng(10 + n)
    window = _random_window(rng, w=12 + n - 1, b=6)
    window["skill"] = rng.integers(0, 3, size=window["reward"].shape).astype(np.int32)
    fn = jax.jit(own_nstep_fields, static_argnums=(1, 2, 3))
    got = jax.device_get(fn(SkillWindow(**{k: jnp.asarray(v) for k, v in window.items()}), n, GAMMA, 2))
    want = _reference(window, n, GAMMA, own_index=2)
    for k in want:
        np.testing.assert_allclose(got[k], want[k], rtol=1e-5, atol=1e-6, err_msg=k)
    behaviour = _reference(window, n, GAMMA)
    if n > 1:  # the cut changed some returns, and none where the new skill took every step
        assert not np.allclose(want["nstep_reward"], behaviour["nstep_reward"])
    all_new = dict(window, skill=np.full_like(window["skill"], 2))
    got_all = jax.device_get(fn(SkillWindow(**{k: jnp.asarray(v) for k, v in all_new.items()}), n, GAMMA, 2))
    np.testing.assert_allclose(got_all["nstep_reward"], behaviour["nstep_reward"], rtol=1e-5, atol=1e-6)


def test_nstep_return_stops_at_termination_and_bootstraps_after_truncation():
    n = 4
    z = np.zeros((n, 1), np.float32)
    base = dict(reward=np.array([[1.0], [2.0], [4.0], [8.0]], np.float32), discount=z + 1, weight=z + 1,
                next_obs=np.arange(n, dtype=np.float32).reshape(n, 1, 1), done=np.zeros((n, 1), bool))
    f = _fields
    full = f(base, n, 0.5)  # no episode end: 1 + 1 + 1 + 1, bootstrap γ^4 from s_4
    assert float(full["nstep_reward"][0, 0]) == 4.0
    assert float(full["nstep_discount"][0, 0]) * 0.5 == 0.5 ** 4
    assert float(full["nstep_next_obs"][0, 0, 0]) == 3.0
    ended = dict(base, done=np.array([[False], [True], [False], [False]]))
    trunc = f(ended, n, 0.5)  # truncated at step 1: 1 + 0.5·2, bootstrap γ^2 from its last obs
    assert float(trunc["nstep_reward"][0, 0]) == 2.0
    assert float(trunc["nstep_discount"][0, 0]) == 0.5
    assert float(trunc["nstep_next_obs"][0, 0, 0]) == 1.0
    term = f(dict(ended, discount=np.array([[1.0], [0.0], [1.0], [1.0]], np.float32)), n, 0.5)
    assert float(term["nstep_reward"][0, 0]) == 2.0 and float(term["nstep_discount"][0, 0]) == 0.0


@pytest.mark.parametrize("returns", ["behaviour", "own"])
def test_collector_inserts_nstep_transitions_late_and_across_unrolls(returns):
    """The replay's new-skill fields are the n-step returns of the collected stream: recompute them
    from the trajectories of three unrolls (episodes of 7 steps end inside unrolls of 5); with
    ``n_step_returns`` "own", returns that stop before the frozen skill's steps (index 0; the new
    skill is index 1)."""
    n, b, t = 3, 4, 5
    cfg = TrainConfig(
        num_envs=b, unroll_length=t, replay_size=1000,
        scheduler=SchedulerConfig(skill_lengths=(2, 3), hidden=(16,), critic_head_hidden=(8,)),
        new_skill=NewSkillConfig(hidden=(16,), n_step=n, discount=GAMMA, n_step_returns=returns))
    env = tasks.make("lift", episode_length=7)
    trainer = make_trainer(env, [Skill.from_fn("reach_green", scripted.get("reach_green"))], cfg)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    collect = jax.jit(trainer.collect_insert)
    trajs = []
    for u in range(3):
        state, traj, stats = collect(state, jax.random.PRNGKey(u))
        trajs.append(jax.device_get(dict(vars(traj), done=stats.done)))
    stream = {k: np.concatenate([tr[k] for tr in trajs]) for k in trajs[0]}  # [3T, B, ...]
    own = 1 if returns == "own" else None
    want = _reference(stream, n, GAMMA, own_index=own)  # steps 0 .. 3T − n
    if own is not None:  # both skills acted, so some returns were cut (sparse lift: no reward yet,
        # the cut shows in the bootstrap's discount γ^(m−1) and state)
        assert (stream["skill"] == 0).any() and (stream["skill"] == 1).any()
        assert not np.allclose(want["nstep_discount"], _reference(stream, n, GAMMA)["nstep_discount"])
    # Replay rows: T·B per unroll, flattened (t, b); the first n − 1 rows of each env are placeholders.
    rows = jax.device_get(state.replay.experience)
    got = {k: v[0, :3 * t * b].reshape((3 * t, b) + v.shape[2:]) for k, v in vars(rows).items()}
    np.testing.assert_array_equal(got["nstep_weight"][:n - 1], 0.0)
    np.testing.assert_array_equal(got["weight"][:n - 1], 0.0)
    for k in want:
        np.testing.assert_allclose(got[k][n - 1:], want[k][:3 * t - n + 1], rtol=1e-5, atol=1e-6, err_msg=k)
    for k in ("obs", "action", "skill", "c", "weight"):  # the scheduler's fields, n − 1 steps late
        np.testing.assert_array_equal(got[k][n - 1:], stream[k][:3 * t - n + 1], err_msg=k)
    assert stream["done"][6].all() and stream["done"][13].all()  # episode ends inside the stream
    # The pending steps are the last n − 1 collected ones.
    np.testing.assert_array_equal(jax.device_get(state.pending.obs), stream["obs"][-(n - 1):])


def test_nstep_learner_iteration_runs_and_one_step_keeps_the_state_layout():
    cfg = TrainConfig(
        num_envs=4, unroll_length=5, replay_size=2000,
        scheduler=SchedulerConfig(skill_lengths=(2, 3), hidden=(16,), critic_head_hidden=(8,), batch_size=16,
                                  min_replay_size=10, samples_per_insert=4.0),
        new_skill=NewSkillConfig(hidden=(16,), batch_size=16, min_replay_size=10, samples_per_insert=4.0, n_step=4))
    env = tasks.make("lift", episode_length=7)
    skills = [Skill.from_fn("reach_green", scripted.get("reach_green"))]
    trainer = make_trainer(env, skills, cfg)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    iteration = jax.jit(trainer.iteration)
    for _ in range(3):
        state, m = iteration(state)
    m = jax.device_get(m)
    assert np.isfinite(m["new_skill/critic_loss"]) and m["new_skill/critic_loss"] > 0
    one = make_trainer(env, skills, dataclasses.replace(cfg, new_skill=dataclasses.replace(cfg.new_skill, n_step=1)))
    abstract = jax.eval_shape(one.init, jax.random.PRNGKey(0))
    assert abstract.pending is None and not hasattr(abstract.replay.experience, "nstep_reward")
