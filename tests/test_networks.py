import math

import pytest
import numpy as np
import jax
import jax.numpy as jnp

from parallel_skills.networks import (GaussianPolicy, QCritic, QEnsemble, SchedulerCritic, SchedulerPolicy,
                                      all_pairs, deterministic_action, gaussian_log_prob,
                                      joint_log_probs, length_bias, sample_action)

O, A = 6, 2


def test_gaussian_policy_shapes_and_ranges():
    net = GaussianPolicy(A, hidden=(16, 8), min_std=1e-3)
    obs = jax.random.normal(jax.random.PRNGKey(0), (5, O)) * 10
    params = net.init(jax.random.PRNGKey(1), obs)
    mean, std = net.apply(params, obs)
    assert mean.shape == (5, A) and std.shape == (5, A)
    assert np.all(np.abs(mean) < 1) and np.all(std > 1e-3)
    # head init is tiny -> std ≈ softplus(0) + min_std at init.
    np.testing.assert_allclose(std, math.log(2.0) + 1e-3, atol=1e-2)
    a = sample_action(mean * 0, std * 0 + 10.0, jax.random.PRNGKey(2))
    assert np.all(np.abs(a) <= 1) and np.any(np.abs(a) == 1)
    np.testing.assert_array_equal(deterministic_action(mean, std), mean)


def test_gaussian_log_prob_matches_numpy():
    mean = np.array([[0.1, -0.5], [0.9, 0.0]], np.float32)
    std = np.array([[0.3, 1.2], [0.05, 2.0]], np.float32)
    act = np.array([[1.0, -1.0], [0.95, 0.3]], np.float32)
    expected = np.sum(-0.5 * ((act - mean) / std) ** 2 - np.log(std * np.sqrt(2 * np.pi)), axis=-1)
    np.testing.assert_allclose(gaussian_log_prob(mean, std, act), expected, rtol=1e-5)


def test_scheduler_policy_init_biases():
    net = SchedulerPolicy(num_skills=3, num_lengths=10, hidden=(16,), initial_max_length_prob=0.95)
    obs = jax.random.normal(jax.random.PRNGKey(0), (4, O))
    params = net.init(jax.random.PRNGKey(1), obs)
    li, lk = net.apply(params, obs)
    pk = jax.nn.softmax(lk)
    pi = jax.nn.softmax(li)
    np.testing.assert_allclose(pk[:, -1], 0.95, rtol=1e-5)
    np.testing.assert_allclose(pk[:, :-1], 0.05 / 9, rtol=1e-4)
    np.testing.assert_allclose(pi, 1 / 3, rtol=1e-5)
    np.testing.assert_allclose(np.exp(length_bias(1, 0.95)), [1.0])


def test_all_pairs_and_joint_log_probs():
    i, k_idx, k_val = all_pairs(3, (2, 4))
    np.testing.assert_array_equal(i, [0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(k_idx, [0, 1, 0, 1, 0, 1])
    np.testing.assert_array_equal(k_val, [2, 4, 2, 4, 2, 4])
    li = jnp.array([[0.3, -1.0, 2.0]])
    lk = jnp.array([[0.5, -0.2]])
    joint = np.asarray(joint_log_probs(li, lk))[0]
    lpi = li[0] - jax.scipy.special.logsumexp(li[0])
    lpk = lk[0] - jax.scipy.special.logsumexp(lk[0])
    np.testing.assert_allclose(joint, np.asarray(lpi)[i] + np.asarray(lpk)[k_idx], rtol=1e-5)
    np.testing.assert_allclose(np.exp(joint).sum(), 1.0, rtol=1e-5)


def test_q_critic_shape():
    net = QCritic(hidden=(16, 8))
    obs, act = jnp.ones((3, 4, O)), jnp.zeros((3, 4, A))
    params = net.init(jax.random.PRNGKey(0), obs, act)
    assert net.apply(params, obs, act).shape == (3, 4)


def test_q_ensemble_has_independent_critics():
    net = QEnsemble(hidden=(16, 8), num_critics=3)
    obs, act = jnp.ones((3, 4, O)), jnp.zeros((3, 4, A))
    params = net.init(jax.random.PRNGKey(0), obs, act)
    q = net.apply(params, obs, act)
    assert q.shape == (3, 4, 3)
    assert len(np.unique(np.round(np.asarray(q[0, 0]), 6))) == 3  # own initialisations
    # Critic e of the ensemble is a QCritic with the e-th slice of the parameters.
    one = jax.tree_util.tree_map(lambda x: x[1], params["params"]["critics"])
    np.testing.assert_allclose(QCritic(hidden=(16, 8)).apply({"params": one}, obs, act), q[..., 1], rtol=1e-5)


def test_scheduler_critic_matches_numpy_head():
    """Q(s, c, i, k) = out[i·M + k] of an MLP head on [features, c/maxK] (one unit per pair)."""
    N1, M, maxK = 3, 2, 4
    net = SchedulerCritic(N1, M, maxK, hidden=(16, 8), head_hidden=(12,))
    B, P = 5, 4
    key = jax.random.PRNGKey(0)
    obs = jax.random.normal(key, (B, O))
    c = jax.random.randint(jax.random.PRNGKey(1), (B, P), 1, maxK + 1)
    i = jax.random.randint(jax.random.PRNGKey(2), (B, P), 0, N1)
    k = jax.random.randint(jax.random.PRNGKey(3), (B, P), 0, M)
    params = net.init(key, obs, c, i, k)
    q = np.asarray(net.apply(params, obs, c, i, k))
    assert q.shape == (B, P)
    p = jax.tree_util.tree_map(np.asarray, params["params"])
    from parallel_skills.networks import LayerNormMLP
    feat = np.asarray(LayerNormMLP((16, 8)).apply({"params": params["params"]["torso"]}, obs))
    h = (feat @ p["head_feat"]["kernel"] + p["head_feat"]["bias"])[:, None, :] \
        + (np.asarray(c) / maxK)[..., None] * p["head_c"]["kernel"][0]
    h = np.where(h > 0, h, np.expm1(h))
    table = h @ p["head_out"]["kernel"] + p["head_out"]["bias"]  # [B, P, N1*M]
    expected = np.take_along_axis(table, (np.asarray(i) * M + np.asarray(k))[..., None], -1)[..., 0]
    np.testing.assert_allclose(q, expected, rtol=1e-4, atol=1e-5)


def test_scheduler_critic_table_gives_every_pair_once_per_counter_value():
    """The learner's query (one head row per distinct c, ``pair_values``) equals querying every
    pair (i, k) at c = K[k] one by one, as Eq. 3's expectation and the E-step need."""
    from parallel_skills.networks import all_pairs, pair_values
    N1, lengths = 3, (2, 3, 5)
    M = len(lengths)
    net = SchedulerCritic(N1, M, max(lengths), hidden=(16, 8), head_hidden=(12, 6))
    B = 4
    obs = jax.random.normal(jax.random.PRNGKey(0), (B, O))
    pi, pk, pkv = (np.broadcast_to(a, (B, a.shape[0])) for a in all_pairs(N1, lengths))
    params = net.init(jax.random.PRNGKey(1), obs, pkv, pi, pk)
    per_pair = np.asarray(net.apply(params, obs, pkv, pi, pk))  # [B, P]
    table = net.apply(params, obs, np.broadcast_to(np.asarray(lengths), (B, M)))  # [B, M, P]
    assert table.shape == (B, M, N1 * M)
    np.testing.assert_allclose(np.asarray(pair_values(table, M)), per_pair, rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="one row per skill length"):
        pair_values(table[:, :2], M)
