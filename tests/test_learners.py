import dataclasses
import functools

import numpy as np
import jax
import jax.numpy as jnp
import pytest

from parallel_skills.augmentation import with_augmentation
from parallel_skills.config import NewSkillConfig, SchedulerConfig, updates_per_iteration
from parallel_skills.learners import (make_new_skill_apply, make_scheduler_apply, new_skill_learner_init,
                                      new_skill_learner_update, scheduler_learner_init, scheduler_learner_update)
from parallel_skills.replay import Transition

O, A, N1, K, B = 6, 2, 3, (2, 4), 16
SCFG = SchedulerConfig(skill_lengths=K, hidden=(32, 32), critic_head_hidden=(16,), learning_rate=1e-3,
                       target_actor_period=5, target_critic_period=5, discount=0.5)
NCFG = NewSkillConfig(hidden=(32, 32), learning_rate=1e-3, target_actor_period=5,
                      target_critic_period=5, discount=0.5)
NCFG_MIX = NewSkillConfig(hidden=(32, 32), learning_rate=1e-3, mpo_alpha=0.5, mpo_num_samples=8,
                          discount=0.5)


def _scheduler_batch(key, all_decisions=None):
    ks = jax.random.split(key, 6)
    k_idx = jax.random.randint(ks[0], (B,), 0, len(K))
    c = jnp.minimum(jax.random.randint(ks[1], (B,), 1, 5), jnp.asarray(K)[k_idx])
    is_decision = c == jnp.asarray(K)[k_idx]
    return Transition.batch(obs=jax.random.normal(ks[2], (B, O)), next_obs=jax.random.normal(ks[3], (B, O)),
                            reward=jax.random.uniform(ks[4], (B,)),
                            discount=(jnp.arange(B) % 5 != 0).astype(jnp.float32),
                            skill=jax.random.randint(ks[5], (B,), 0, N1), k_idx=k_idx.astype(jnp.int32),
                            c=c.astype(jnp.int32), is_decision=is_decision, weight=jnp.ones(B))


def _new_skill_batch(key):
    ks = jax.random.split(key, 4)
    return Transition.batch(obs=jax.random.normal(ks[0], (B, O)),
                            action=jnp.clip(jax.random.normal(ks[1], (B, A)), -1, 1),
                            reward=jax.random.uniform(ks[2], (B,)), discount=jnp.ones(B),
                            next_obs=jax.random.normal(ks[3], (B, O)))


def _scan_updates(update, config, n):
    @jax.jit
    def run(state, batch, key):
        def body(s, k):
            return update(s, batch, k, config)
        return jax.lax.scan(body, state, jax.random.split(key, n))
    return run


@pytest.fixture(scope="session")
def sched_run():
    return _scan_updates(scheduler_learner_update, SCFG, 50)


@pytest.fixture(scope="session")
def newskill_run():
    return _scan_updates(new_skill_learner_update, NCFG, 50)


def _finite(tree):
    return all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree_util.tree_leaves(tree))


def test_scheduler_init_probs_and_apply():
    state = scheduler_learner_init(jax.random.PRNGKey(0), O, N1, SCFG)
    obs = jax.random.normal(jax.random.PRNGKey(1), (5, O))
    apply = make_scheduler_apply(N1, SCFG)
    li, lk = apply(state.policy_params, obs)
    np.testing.assert_allclose(jax.nn.softmax(lk)[:, -1], 0.95, rtol=1e-5)
    np.testing.assert_allclose(jax.nn.softmax(li), 1 / 3, rtol=1e-5)


def test_scheduler_updates_finite_and_critic_loss_decreases(sched_run):
    state = scheduler_learner_init(jax.random.PRNGKey(0), O, N1, SCFG)
    batch = _scheduler_batch(jax.random.PRNGKey(1))
    assert 0 < int(batch.is_decision.sum()) < B
    both = with_augmentation(batch, K)  # [2B]: the rows the learner trains on (originals + duplicates)
    assert 0 < float(both.weight[B:].sum()) < B
    new_state, metrics = sched_run(state, batch, jax.random.PRNGKey(2))
    expected = {"critic_loss", "q_mean", "q_max", "temperature", "alpha", "kl", "policy_entropy_i",
                "policy_entropy_k", "decision_fraction", "policy_loss"}
    assert expected <= set(metrics)
    assert _finite(metrics) and _finite(new_state)
    loss = np.asarray(metrics["critic_loss"])
    assert loss[-5:].mean() < 0.5 * loss[:5].mean(), loss
    assert int(new_state.steps) == 50
    w, d = np.asarray(both.weight), np.asarray(both.is_decision)
    np.testing.assert_allclose(metrics["decision_fraction"][0], (w * d).sum() / w.sum(), rtol=1e-6)
    # Targets were hard-copied at step 50 (period 5).
    for a, b in zip(jax.tree_util.tree_leaves(new_state.target_critic_params),
                    jax.tree_util.tree_leaves(new_state.critic_params)):
        np.testing.assert_array_equal(a, b)


def test_scheduler_no_decision_rows_gives_zero_policy_loss(sched_run):
    state = scheduler_learner_init(jax.random.PRNGKey(0), O, N1, SCFG)
    # No decision rows in either labelling: drop the rows that are decisions in one of them.
    batch = _scheduler_batch(jax.random.PRNGKey(1))
    both = with_augmentation(batch, K)
    decides = both.is_decision[:B] | (both.is_decision[B:] & (both.weight[B:] > 0))
    batch = batch.replace(weight=jnp.where(decides, 0.0, batch.weight).astype(jnp.float32))
    new_state, metrics = sched_run(state, batch, jax.random.PRNGKey(2))
    np.testing.assert_array_equal(metrics["policy_loss"], 0.0)
    np.testing.assert_array_equal(metrics["decision_fraction"], 0.0)
    assert _finite(new_state) and _finite(metrics)
    # Policy and duals untouched (zero gradients -> zero Adam updates).
    for a, b in zip(jax.tree_util.tree_leaves(new_state.policy_params),
                    jax.tree_util.tree_leaves(state.policy_params)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(new_state.dual_params.log_temperature, SCFG.init_log_temperature)
    np.testing.assert_array_equal(new_state.dual_params.log_alpha, SCFG.init_log_alpha)


def test_scheduler_policy_moves_towards_best_pair(sched_run):
    """Rewards only for skill 2: after updates on decision states, π(i=2) rises from 1/3."""
    state = scheduler_learner_init(jax.random.PRNGKey(0), O, N1, SCFG)
    base = _scheduler_batch(jax.random.PRNGKey(3))
    base = base.replace(reward=(base.skill == 2).astype(jnp.float32), is_decision=jnp.ones(B, bool),
                        c=jnp.asarray(K, jnp.int32)[base.k_idx])
    new_state, _ = sched_run(state, base, jax.random.PRNGKey(4))
    li, _ = make_scheduler_apply(N1, SCFG)(new_state.policy_params, base.obs)
    assert float(jax.nn.softmax(li)[:, 2].mean()) > 0.4


def test_scheduler_learns_augmented_labels_as_duplicate_rows():
    """The learner's augmentation (labels [B, 2], states evaluated once) is the update on the
    batch followed by its augmented duplicate rows ([2B], augmentation.with_augmentation) without
    augmentation: same parameters and metrics up to float reordering."""
    state = scheduler_learner_init(jax.random.PRNGKey(0), O, N1, SCFG)
    batch = _scheduler_batch(jax.random.PRNGKey(5))
    update = jax.jit(scheduler_learner_update, static_argnames="config")
    s_aug, m_aug = update(state, batch, jax.random.PRNGKey(6), config=SCFG)
    s_rows, m_rows = update(state, with_augmentation(batch, K), jax.random.PRNGKey(6),
                            config=dataclasses.replace(SCFG, augmentation=False))
    for a, b in zip(jax.tree_util.tree_leaves(s_aug), jax.tree_util.tree_leaves(s_rows)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    for name in m_rows:
        np.testing.assert_allclose(m_aug[name], m_rows[name], rtol=1e-5, atol=1e-6, err_msg=name)
    assert float(m_aug["critic_loss"]) > 0 and float(m_aug["decision_fraction"]) > 0
    # Without augmentation the duplicate rows are not learnt from: a different update.
    s_plain, _ = update(state, batch, jax.random.PRNGKey(6), config=dataclasses.replace(SCFG, augmentation=False))
    assert not np.allclose(s_plain.critic_params["params"]["head_out"]["kernel"],
                           s_aug.critic_params["params"]["head_out"]["kernel"])


def test_new_skill_init_apply_and_updates(newskill_run):
    state = new_skill_learner_init(jax.random.PRNGKey(0), O, A, NCFG)
    batch = _new_skill_batch(jax.random.PRNGKey(1))
    apply = make_new_skill_apply(A, NCFG)
    mean, std = apply(state.policy_params, batch.obs)
    assert mean.shape == (B, A) and std.shape == (B, A)
    new_state, metrics = newskill_run(state, batch, jax.random.PRNGKey(2))
    assert {"critic_loss", "q_mean", "crr_weight_mean", "policy_log_std_mean", "advantage_mean"} <= set(metrics)
    assert _finite(metrics) and _finite(new_state)
    loss = np.asarray(metrics["critic_loss"])
    assert loss[-5:].mean() < 0.5 * loss[:5].mean(), loss
    # CRR increases the likelihood of the batch actions on average.
    from parallel_skills.networks import gaussian_log_prob
    m1, s1 = apply(new_state.policy_params, batch.obs)
    assert float(gaussian_log_prob(m1, s1, batch.action).mean()) > float(
        gaussian_log_prob(mean, std, batch.action).mean())


def test_new_skill_td_target_is_the_minimum_over_critics():
    """Clipped double Q: with target critics that differ by +50 on critic 1, the online critics
    regress on γ·min (≈ critic 0's value), not on the mean (≈ +25) or on each its own target."""
    cfg = NewSkillConfig(hidden=(32, 32), learning_rate=3e-3, target_critic_period=10_000, discount=0.5,
                         num_critics=2)
    state = new_skill_learner_init(jax.random.PRNGKey(0), O, A, cfg)
    bias = state.target_critic_params["params"]["critics"]["head"]["bias"]  # [E, 1]
    assert bias.shape == (2, 1)
    target = jax.tree_util.tree_map(lambda x: x, state.target_critic_params)
    target["params"]["critics"]["head"]["bias"] = bias.at[1].add(50.0)
    state = state.replace(target_critic_params=target)
    batch = _new_skill_batch(jax.random.PRNGKey(1)).replace(reward=jnp.zeros(B))
    new_state, metrics = _scan_updates(new_skill_learner_update, cfg, 200)(state, batch, jax.random.PRNGKey(2))
    from parallel_skills.learners import new_skill_networks

    _, critic = new_skill_networks(A, cfg)
    q = np.asarray(critic.apply(new_state.critic_params, batch.obs, batch.action))  # [B, 2]
    assert q.shape == (B, 2)
    assert np.abs(q).max() < 2.0, q  # both near 0.5·Q'_0 (small), far from 25 or 50


def test_new_skill_td_target_with_the_mean_action_values_the_read_out():
    """td_target_action "mean": y = r + γ·d·Q'(s', μ'(s')) exactly (the deterministic read-out's
    value); "sampled" (the paper's) averages Q' over actions drawn around μ', a different target."""
    from parallel_skills.learners import critic_values, new_skill_networks, new_skill_targets

    batch = _new_skill_batch(jax.random.PRNGKey(1))
    ys = {}
    for mode in ("sampled", "mean"):
        cfg = NewSkillConfig(hidden=(32, 32), discount=0.9, td_target_action=mode)
        state = new_skill_learner_init(jax.random.PRNGKey(0), O, A, cfg)
        networks = new_skill_networks(A, cfg)
        ys[mode] = np.asarray(new_skill_targets(state, batch, networks, jax.random.PRNGKey(3),
                                                jax.random.PRNGKey(4), cfg).y)
    policy, critic = networks
    mu_next, _ = policy.apply(state.target_policy_params, batch.next_obs)
    q_mu = np.asarray(critic_values(critic, state.target_critic_params, batch.next_obs, mu_next))[:, 0]
    expected = np.asarray(batch.reward) + 0.9 * np.asarray(batch.discount) * q_mu
    np.testing.assert_allclose(ys["mean"], expected, rtol=1e-5, atol=1e-6)
    assert np.abs(ys["sampled"] - ys["mean"]).max() > 1e-4
    with pytest.raises(ValueError, match="td_target_action"):
        NewSkillConfig(td_target_action="greedy")


def test_one_critic_keeps_the_single_critic_layout():
    """num_critics=1 (the default) is the pre-ensemble learner (same parameter tree), so older runs
    resume; their config.json, which lacks the field, reads as one critic."""
    cfg = NewSkillConfig(hidden=(32, 32), num_critics=1)
    state = new_skill_learner_init(jax.random.PRNGKey(0), O, A, cfg)
    assert set(state.critic_params["params"]) == {"torso", "head"}
    new_state, metrics = _scan_updates(new_skill_learner_update, cfg, 3)(
        state, _new_skill_batch(jax.random.PRNGKey(1)), jax.random.PRNGKey(2))
    assert _finite(metrics) and _finite(new_state)
    import dataclasses
    from parallel_skills import TrainConfig
    from training.rundir import train_config_from_json

    old = dataclasses.asdict(TrainConfig())
    del old["new_skill"]["num_critics"]
    assert train_config_from_json(old, "config.json").new_skill.num_critics == 1


def test_a_record_of_a_removed_field_is_refused_naming_it():
    """docs/research/pruned.md: a run recorded with a field the code no longer has does not read as
    a config (resume, evaluate, --config RUN/config.json); the one line names the field."""
    import dataclasses

    from parallel_skills import TrainConfig
    from training.cli import UsageError
    from training.rundir import train_config_from_json

    old = dataclasses.asdict(TrainConfig())
    old["new_skill"]["removed_option"] = 0.0
    with pytest.raises(UsageError, match=r"unknown new_skill config field\(s\) \['removed_option'\] in config.json"):
        train_config_from_json(old, "config.json")


def test_new_skill_mpo_mix_runs():
    state = new_skill_learner_init(jax.random.PRNGKey(0), O, A, NCFG_MIX)
    batch = _new_skill_batch(jax.random.PRNGKey(1))
    run = _scan_updates(new_skill_learner_update, NCFG_MIX, 3)
    new_state, metrics = run(state, batch, jax.random.PRNGKey(2))
    assert "mpo_kl_mean" in metrics
    assert _finite(metrics) and _finite(new_state)
    assert float(new_state.dual_params.log_temperature) != NCFG_MIX.mpo_init_log_temperature


def test_vmap_over_seeds():
    """Both learners trace under vmap over seeds (eval_shape: traced, not compiled)."""
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    batch = _new_skill_batch(jax.random.PRNGKey(1))
    states = jax.eval_shape(jax.vmap(lambda k: new_skill_learner_init(k, O, A, NCFG)), keys)
    upd = jax.vmap(functools.partial(new_skill_learner_update, config=NCFG), in_axes=(0, None, 0))
    _, metrics = jax.eval_shape(upd, states, batch, keys)
    assert metrics["critic_loss"].shape == (2,)
    sbatch = _scheduler_batch(jax.random.PRNGKey(1))
    sstates = jax.eval_shape(jax.vmap(lambda k: scheduler_learner_init(k, O, N1, SCFG)), keys)
    supd = jax.vmap(functools.partial(scheduler_learner_update, config=SCFG), in_axes=(0, None, 0))
    new_states, smetrics = jax.eval_shape(supd, sstates, sbatch, keys)
    assert smetrics["kl"].shape == (2,) and new_states.steps.shape == (2,)


def test_updates_per_iteration():
    assert updates_per_iteration(50, 16 * 10, 256) == 31
    assert updates_per_iteration(1, 4, 256) == 1


def test_scheduler_without_the_new_skill_choice_never_chooses_it():
    """new_skill_choice=False (paper Fig. 6a ablation): the new skill's probability is exactly 0 at
    init and stays exactly 0 (online and target policy) through updates on data that reward it."""
    cfg = dataclasses.replace(SCFG, new_skill_choice=False)
    state = scheduler_learner_init(jax.random.PRNGKey(0), O, N1, cfg)
    base = _scheduler_batch(jax.random.PRNGKey(3))
    # Reward the new skill (index N1 - 1) only: without the mask the policy would move towards it.
    base = base.replace(reward=(base.skill == N1 - 1).astype(jnp.float32) + 0.5 * (base.skill == 0),
                        is_decision=jnp.ones(B, bool), c=jnp.asarray(K, jnp.int32)[base.k_idx])
    new_state, metrics = _scan_updates(scheduler_learner_update, cfg, 30)(state, base, jax.random.PRNGKey(4))
    assert _finite(metrics) and _finite(new_state)
    apply = make_scheduler_apply(N1, cfg)
    for params in (state.policy_params, new_state.policy_params, new_state.target_policy_params):
        li, _ = apply(params, base.obs)
        assert np.all(np.asarray(jax.nn.softmax(li)[:, -1]) == 0.0)
    li, _ = apply(new_state.policy_params, base.obs)
    np.testing.assert_allclose(jax.nn.softmax(li)[:, :-1].sum(-1), 1.0, rtol=1e-6)  # the others share it all
    assert not np.allclose(li[:, 0], 0.0)  # and the policy over them did learn


def test_new_skill_policy_ema_averages_the_iterates_and_nothing_else():
    """``NewSkillConfig.policy_ema`` τ: after each update ema ← ema + τ·(θ − ema); τ = 0 keeps none
    (no leaves, the state as without the field); the update of everything else is unchanged."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from parallel_skills import learners
    from parallel_skills.config import NewSkillConfig

    config = NewSkillConfig(hidden=(8,), policy_ema=0.25)
    state = learners.new_skill_learner_init(jax.random.PRNGKey(0), 5, 2, config)
    plain = learners.new_skill_learner_init(jax.random.PRNGKey(0), 5, 2, NewSkillConfig(hidden=(8,)))
    assert plain.ema_policy_params is None
    leaves = lambda t: len(jax.tree_util.tree_leaves(t))  # noqa: E731
    assert leaves(state) == leaves(plain) + leaves(state.policy_params)
    state = state.replace(ema_policy_params=jax.tree_util.tree_map(jnp.zeros_like, state.policy_params))
    ones = lambda t: jax.tree_util.tree_map(jnp.ones_like, t)  # noqa: E731
    grads = (ones(state.policy_params), ones(state.critic_params), ones(state.dual_params))
    after = learners.learner_step(state, grads, config, update_duals=False)
    after_plain = learners.learner_step(plain, grads, NewSkillConfig(hidden=(8,)), update_duals=False)
    for e, p in zip(jax.tree_util.tree_leaves(after.ema_policy_params), jax.tree_util.tree_leaves(after.policy_params)):
        np.testing.assert_allclose(e, 0.25 * p, rtol=1e-6)
    for a, b in zip(jax.tree_util.tree_leaves(after.replace(ema_policy_params=None)), jax.tree_util.tree_leaves(after_plain)):
        np.testing.assert_array_equal(a, b)
