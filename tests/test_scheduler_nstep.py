"""The scheduler's n-step targets within skill executions (SchedulerConfig.n_step;
nstep.execution_nstep_fields, replay.SchedulerNStepTransition, learners.scheduler_targets) and the
scheduler diagnostics of every iteration / evaluation (docs/research/scheduler.md)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import tasks
from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig, learners
from parallel_skills.nstep import execution_nstep_fields
from parallel_skills.replay import PendingStep, Replay, SchedulerBatch, Transition
from parallel_skills.train import EpisodeAccumulator, TrainedParams, make_evaluation, make_trainer
from tasks.manipulation import scripted

GAMMA = 0.9
K = (10, 20, 30)


def _window(c, k_idx, done=None, seed=0):
    """One env's stream [W, 1] with the given counters and length indices."""
    w = len(c)
    rng = np.random.default_rng(seed)
    tr = Transition.zeros(2, 1, (w, 1))
    tr = tr.replace(c=jnp.asarray(c, jnp.int32)[:, None], k_idx=jnp.asarray(k_idx, jnp.int32)[:, None],
                    reward=jnp.asarray(rng.normal(size=(w, 1)), jnp.float32), discount=jnp.ones((w, 1)),
                    weight=jnp.ones((w, 1)), next_obs=jnp.asarray(rng.normal(size=(w, 1, 2)), jnp.float32))
    done = np.zeros((w, 1), bool) if done is None else np.asarray(done, bool)[:, None]
    return PendingStep(**tr.fields(), done=jnp.asarray(done))


def _replay(n, augmentation):
    return Replay(capacity=64, num_envs=1, obs_size=2, action_size=1, scheduler_batch_size=4, new_skill_batch_size=4,
                  scheduler_n_step=n, scheduler_discount=GAMMA, skill_lengths=K, augmentation=augmentation)


@pytest.mark.parametrize("augmentation", [True, False])
def test_execution_returns_stop_where_an_execution_ends(augmentation):
    """An execution of k = 30 (c = 30 .. 1), then one of k = 10: every return stops at the end of its
    execution (with the augmentation: at the end of its 10-step piece) or after n steps, and
    matches a plain loop."""
    n = 8
    c = list(range(30, 0, -1)) + list(range(10, 0, -1))
    k_idx = [2] * 30 + [0] * 10
    win = _window(c, k_idx)
    replay = _replay(n, augmentation)
    got = jax.device_get(execution_nstep_fields(win, n, GAMMA, replay.execution_ends(win)))
    c_lab = [(x - 1) % 10 + 1 for x in c] if augmentation else c  # the counter the return must respect
    r, nxt = np.asarray(win.reward)[:, 0], np.asarray(win.next_obs)[:, 0]
    for t in range(len(c) - n + 1):
        m = min(n, c_lab[t])
        assert got["nstep_steps"][t, 0] == m, t
        np.testing.assert_allclose(got["nstep_reward"][t, 0], sum(GAMMA ** j * r[t + j] for j in range(m)), rtol=1e-5)
        np.testing.assert_allclose(got["nstep_discount"][t, 0], GAMMA ** (m - 1), rtol=1e-6)
        np.testing.assert_array_equal(got["nstep_next_obs"][t, 0], nxt[t + m - 1])


def test_execution_returns_stop_at_an_episode_end():
    n = 5
    win = _window([30, 29, 28, 27, 26, 25, 24], [2] * 7, done=[0, 1, 0, 0, 0, 0, 0])
    got = jax.device_get(execution_nstep_fields(win, n, GAMMA, _replay(n, False).execution_ends(win)))
    assert got["nstep_steps"][:, 0].tolist() == [2, 1, 5]


def _sched_config(**kw):
    return SchedulerConfig(skill_lengths=K, hidden=(16,), critic_head_hidden=(8,), discount=GAMMA, **kw)


def _targets(batch, config, state):
    networks = learners.scheduler_networks(3, config)
    labels = learners.scheduler_labels(batch, config)
    return learners.scheduler_targets(state, batch, labels, networks, jnp.asarray(K, jnp.int32), config).y


def test_one_step_scheduler_batch_is_the_plain_transition():
    """steps = 1: the n-step code path computes Eq. 3's one-step targets exactly."""
    config = _sched_config()
    state = learners.scheduler_learner_init(jax.random.PRNGKey(0), 2, 3, config)
    rng = np.random.default_rng(1)
    b = 6
    batch = Transition.batch(obs=jnp.asarray(rng.normal(size=(b, 2)), jnp.float32),
                             next_obs=jnp.asarray(rng.normal(size=(b, 2)), jnp.float32),
                             reward=jnp.asarray(rng.normal(size=b), jnp.float32), discount=jnp.ones(b),
                             skill=jnp.asarray([0, 1, 2, 0, 1, 2]), k_idx=jnp.asarray([0, 1, 2, 2, 1, 0]),
                             c=jnp.asarray([1, 5, 30, 11, 20, 3]), is_decision=jnp.zeros(b, bool))
    one = SchedulerBatch(**batch.fields(), steps=jnp.ones(b, jnp.int32))
    np.testing.assert_array_equal(_targets(batch, config, state), _targets(one, config, state))


def test_nstep_target_bootstraps_with_the_counter_after_m_steps():
    """Original labels (c = 30, k = 30) after m = 8 steps continue with Q'(s', 22, i, k); the
    duplicate's (c̄ = 10 .. ) reach the end of their piece when m = c̄: the fresh value V'(s')."""
    config = _sched_config(augmentation=True)
    state = learners.scheduler_learner_init(jax.random.PRNGKey(0), 2, 3, config)
    obs = jnp.asarray([[0.3, -0.2], [0.1, 0.5]], jnp.float32)
    nxt = jnp.asarray([[1.0, 2.0], [-1.0, 0.5]], jnp.float32)
    reward, disc = jnp.asarray([0.7, -0.4]), jnp.asarray([GAMMA ** 7, GAMMA ** 3])
    # row 0: c = 30 (c̄ = 10), m = 8; row 1: c = 24 (c̄ = 4), m = 4 (its piece ends).
    batch = SchedulerBatch(**Transition.batch(obs=obs, next_obs=nxt, reward=reward, discount=disc,
                                              skill=jnp.asarray([1, 2]), k_idx=jnp.asarray([2, 2]),
                                              c=jnp.asarray([30, 24]), is_decision=jnp.zeros(2, bool)).fields(),
                           steps=jnp.asarray([8, 4], jnp.int32))
    y = np.asarray(_targets(batch, config, state))  # [B, 2]: original, duplicate
    policy, critic = learners.scheduler_networks(3, config)
    params = state.target_critic_params

    def q(o, c, i, k):  # Q'(o, c, i, k)
        table = critic.apply(params, o[None], jnp.asarray([[c]], jnp.int32))  # [1, 1, P]
        return float(table[0, 0, i * len(K) + k])

    v = np.asarray(learners.scheduler_state_values(state.target_policy_params, params, nxt, 3, config))
    np.testing.assert_allclose(y[0, 0], 0.7 + GAMMA ** 8 * q(nxt[0], 22, 1, 2), rtol=1e-5)
    np.testing.assert_allclose(y[0, 1], 0.7 + GAMMA ** 8 * q(nxt[0], 2, 1, 0), rtol=1e-5)  # c̄ 10 − 8 = 2
    np.testing.assert_allclose(y[1, 0], -0.4 + GAMMA ** 4 * q(nxt[1], 20, 2, 2), rtol=1e-5)
    np.testing.assert_allclose(y[1, 1], -0.4 + GAMMA ** 4 * v[1], rtol=1e-5)  # the piece ended: fresh


def _tiny(n_step, eval_diagnostics=False):
    cfg = TrainConfig(
        num_envs=4, unroll_length=5, replay_size=2000, eval_episodes=2, eval_diagnostics=eval_diagnostics,
        scheduler=SchedulerConfig(skill_lengths=(2, 3), hidden=(16,), critic_head_hidden=(8,), batch_size=16,
                                  min_replay_size=10, samples_per_insert=4.0, n_step=n_step),
        new_skill=NewSkillConfig(hidden=(16,), batch_size=16, min_replay_size=10, samples_per_insert=4.0))
    env = tasks.make("lift", episode_length=7)
    return env, make_trainer(env, [Skill.from_fn("reach_green", scripted.get("reach_green"))], cfg)


def test_scheduler_nstep_trains_and_one_step_keeps_the_state_layout():
    env, trainer = _tiny(3)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    iteration = jax.jit(trainer.iteration)
    for _ in range(3):
        state, m = iteration(state)
    m = jax.device_get(m)
    assert np.isfinite(m["scheduler/critic_loss"]) and m["scheduler/critic_loss"] > 0
    rows = jax.device_get(state.replay.experience)
    assert set(np.unique(rows.sched_steps[0, 40:60])) <= {1, 2, 3}
    _, one = _tiny(1)
    abstract = jax.eval_shape(one.init, jax.random.PRNGKey(0))
    assert abstract.pending is None and not hasattr(abstract.replay.experience, "sched_reward")
    # An evaluation reads out the new skill (mean and sampled actions) and the greedy scheduler ...
    ev = make_evaluation(env, trainer, 7, seed=0)(state, 3)
    assert set(ev) == {f"eval/{name}_{what}" for name in ("new_skill", "new_skill_sampled", "scheduler")
                       for what in ("success", "return")}
    # ... and with eval_diagnostics also the scheduler as it collects (its critic at the resets), the
    # greedy scheduler with the new skill sampled and the critic-weighted new skill; the others
    # draw the same episodes with or without them.
    _, diag_trainer = _tiny(3, eval_diagnostics=True)
    diag = make_evaluation(env, diag_trainer, 7, seed=0)(state, 3)
    assert {k: diag[k] for k in ev} == ev
    ev = diag
    for key in ("eval/scheduler_sampled_success", "eval/scheduler_sampled_return",
                "eval/scheduler_discounted_return", "eval/scheduler_value_at_reset",
                "eval/new_skill_sampled_success", "eval/new_skill_sampled_return",
                "eval/new_skill_critic_weighted_success", "eval/new_skill_critic_weighted_return",
                "eval/scheduler_new_skill_sampled_success", "eval/scheduler_new_skill_sampled_return"):
        assert np.isfinite(ev[key]), key
    assert 0.0 <= ev["eval/scheduler_sampled_success"] <= 1.0
    assert 0.0 <= ev["eval/new_skill_sampled_success"] <= 1.0
    assert 0.0 <= ev["eval/new_skill_critic_weighted_success"] <= 1.0


def test_with_a_moving_average_the_average_is_what_is_evaluated_run_and_exported(monkeypatch):
    """NewSkillConfig.policy_ema: the new skill read out (``eval/new_skill_*``), run by the greedy
    scheduler and exported (``TrainedParams``) is the average; the online policy is read out beside
    it on the same episodes, and its Gaussian is the sampled read-out (it is what collects)."""
    import importlib
    from types import SimpleNamespace

    train_module = importlib.import_module("parallel_skills.train")  # (the package exports a function of that name)

    calls = []

    def fake(name):
        def evaluate(*args):
            calls.append((name, args))
            return {"success": jnp.zeros(2), "return": jnp.zeros(2)}
        return evaluate

    monkeypatch.setattr(train_module, "make_evaluators",
                        lambda *a, **k: SimpleNamespace(**{n: fake(n) for n in ("new_skill", "new_skill_sampled",
                                                                                  "scheduler")}))
    trainer = SimpleNamespace(config=TrainConfig(eval_episodes=2))
    online = {"w": jnp.ones(())}
    plain = learners.LearnerState(*([online] + [None] * 8))
    averaged = plain.replace(ema_policy_params={"w": jnp.full((), 2.0)})
    assert plain.deployed_policy_params is online and averaged.deployed_policy_params is averaged.ema_policy_params
    state = SimpleNamespace(new_skill=averaged, scheduler=SimpleNamespace(policy_params=None), normalizer=None)
    out = train_module.make_evaluation(None, trainer, 7, seed=0)(state, 3)
    read = {name: args[1 if name == "scheduler" else 0]["w"] for name, args in calls}  # (the last call of each)
    assert float(read["scheduler"]) == 2.0 and float(read["new_skill_sampled"]) == 1.0
    assert [float(args[0]["w"]) for name, args in calls if name == "new_skill"] == [2.0, 1.0]
    assert {k for k in out if "online" in k} == {"eval/new_skill_online_success", "eval/new_skill_online_return"}
    assert TrainedParams.of(SimpleNamespace(new_skill=averaged, scheduler=SimpleNamespace(policy_params=None),
                                            normalizer=None)).new_skill is averaged.ema_policy_params


def test_rewarded_fraction_counts_stored_rows_only():
    replay = Replay(capacity=8, num_envs=2, obs_size=1, action_size=1, scheduler_batch_size=2, new_skill_batch_size=2)
    state = replay.init()
    assert float(replay.rewarded_fraction(state)) == 0.0
    traj = Transition.zeros(1, 1, (3, 2)).replace(reward=jnp.asarray([[1.0, 0.0], [0.0, 0.0], [0.5, 0.0]]))
    state, _ = replay.insert(state, None, traj, jnp.zeros((3, 2), bool))
    assert float(replay.rewarded_fraction(state)) == pytest.approx(2 / 6)


def test_decision_entropies_and_shares_per_decision():
    acc = EpisodeAccumulator()
    m = {"episodes": 0.0, "nonfinite_transitions": 0.0, "skill_histogram": np.array([1.0, 3.0]),
         "length_histogram": np.array([4.0, 0.0]), "skill_steps": np.array([5.0, 5.0]),
         "skill_runs": np.array([1.0, 1.0]), "entropy_i_sum": 2.0, "entropy_k_sum": 0.4,
         "episode_return": 0.0, "episode_success": 0.0}
    acc.add(m)
    acc.add(dict(m, skill_histogram=np.array([0.0, 0.0]), length_histogram=np.array([0.0, 0.0]),
                 entropy_i_sum=0.0, entropy_k_sum=0.0))
    out = acc.summary(m)
    assert out["decision_entropy_i"] == pytest.approx(0.5) and out["decision_entropy_k"] == pytest.approx(0.1)
    assert out["skill_share"] == [0.25, 0.75] and out["length_share"] == [1.0, 0.0]
    assert "entropy_i_sum" not in out
    restored = EpisodeAccumulator.from_dict(acc.to_dict()).summary(m)
    assert restored["decision_entropy_i"] == out["decision_entropy_i"]


def test_scheduler_n_step_must_be_positive():
    with pytest.raises(ValueError, match="n_step"):
        dataclasses.replace(SchedulerConfig(), n_step=0)

