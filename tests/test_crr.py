"""Tests for crr.py and mpo.py (the α-mix Gaussian MPO loss)."""
import math

import numpy as np
import jax
import jax.numpy as jnp

from parallel_skills.crr import crr_policy_loss, crr_weights, mean_baseline_advantage, td_target
from parallel_skills.mpo import gaussian_kl_mean, gaussian_kl_std, gaussian_mpo_loss, sample_e_step


def test_advantage_and_weights():
    q_taken = jnp.array([1.0, 0.0, 30.0, -2.0, 2.0])
    q_sampled = jnp.array([[0.0, 2.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.0], [2.0, 2.0, 2.0, 2.0],
                           [0.0, 0.0, 0.0, 0.0], [1.5, 1.5, 1.5, 1.5]])
    adv = mean_baseline_advantage(q_taken, q_sampled)
    np.testing.assert_allclose(adv, [0.0, 0.0, 28.0, -2.0, 0.5])
    w = crr_weights(adv, "exp", 1.0, 20.0)
    np.testing.assert_allclose(w, [1.0, 1.0, 20.0, math.exp(-2.0), math.exp(0.5)], rtol=1e-6)
    w_beta = crr_weights(jnp.array([2.0, 10.0]), "exp", 2.0, 20.0)
    np.testing.assert_allclose(w_beta, [math.e, 20.0], rtol=1e-6)  # exp(5)=148 clipped
    wi = crr_weights(adv, "indicator")
    np.testing.assert_array_equal(wi, [0.0, 0.0, 1.0, 0.0, 1.0])
    # Huge advantages do not overflow.
    assert np.isfinite(crr_weights(jnp.array([1e6]), "exp", 1.0, 20.0)).all()


def test_policy_loss_and_td_target():
    lp = jnp.array([-1.0, -2.0, -0.5])
    w = jnp.array([1.0, 20.0, 0.0])
    np.testing.assert_allclose(crr_policy_loss(lp, w), (1.0 + 40.0 + 0.0) / 3, rtol=1e-6)
    np.testing.assert_allclose(crr_policy_loss(lp, w, jnp.array([1.0, 0.0, 0.0])), 1.0)
    g = jax.grad(lambda x: crr_policy_loss(x, w))(lp)
    np.testing.assert_allclose(g, -w / 3)
    y = td_target(jnp.array([1.0, 1.0]), jnp.array([1.0, 0.0]), jnp.array([[2.0, 4.0], [5.0, 5.0]]), 0.5)
    np.testing.assert_allclose(y, [2.5, 1.0])


def _np_kl(m1, s1, m2, s2):
    return np.sum(np.log(s2 / s1) + (s1 ** 2 + (m1 - m2) ** 2) / (2 * s2 ** 2) - 0.5, axis=-1)


def test_mpo_e_step_and_kls_vs_numpy():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(3, 5)).astype(np.float32) * 2
    eta = 0.5
    mask = np.ones(3, np.float32)
    w, dual = sample_e_step(jnp.asarray(q), jnp.asarray(eta), 0.1, jnp.asarray(mask))
    wn = np.exp(q / eta - (q / eta).max(-1, keepdims=True))
    wn /= wn.sum(-1, keepdims=True)
    np.testing.assert_allclose(w, wn, rtol=1e-5)
    expected = eta * 0.1 + eta * np.mean(np.log(np.mean(np.exp(q / eta), axis=-1)))
    np.testing.assert_allclose(dual, expected, rtol=1e-5)
    mt, st = rng.normal(size=(3, 2)), rng.uniform(0.1, 1, size=(3, 2))
    mo, so = rng.normal(size=(3, 2)), rng.uniform(0.1, 1, size=(3, 2))
    np.testing.assert_allclose(gaussian_kl_mean(mt, st, mo), _np_kl(mt, st, mo, st), rtol=1e-5)
    np.testing.assert_allclose(gaussian_kl_std(st, so), _np_kl(mt, st, mt, so), rtol=1e-5)


def test_mpo_loss_moves_mean_towards_high_q():
    B, J, A = 4, 16, 2
    key = jax.random.PRNGKey(0)
    tm, ts = jnp.zeros((B, A)), jnp.full((B, A), 0.5)
    actions = tm[:, None] + ts[:, None] * jax.random.normal(key, (B, J, A))
    q = actions[..., 0] * 5.0  # Q increases with the first action dimension.

    def loss_fn(mean):
        loss, _ = gaussian_mpo_loss(mean, ts, tm, ts, actions, q, jnp.asarray(1.0), jnp.asarray(1.0),
                                    jnp.asarray(1.0), 0.1, 5e-3, 1e-5, jnp.ones(B))
        return loss

    g = jax.grad(loss_fn)(tm)
    assert np.all(np.isfinite(g))
    assert np.all(g[:, 0] < 0)  # descent increases the mean of the first dimension.
    loss, stats = gaussian_mpo_loss(tm, ts, tm, ts, actions, q, jnp.asarray(1.0), jnp.asarray(1.0),
                                    jnp.asarray(1.0), 0.1, 5e-3, 1e-5, jnp.zeros(B))
    assert np.isfinite(loss) and float(stats["mpo_kl_mean"]) == 0.0


def test_critic_weighted_action_is_the_candidate_its_critic_values_highest():
    """The read-out of ``eval/new_skill_critic_weighted_success``: the mean when the critic prefers
    it, else the best-valued of the Gaussian's (clipped) samples; never an action outside them."""
    import jax
    import jax.numpy as jnp

    from parallel_skills import networks
    from parallel_skills.crr import critic_weighted_action

    mean, std, key = jnp.asarray([0.2, -0.4]), jnp.asarray([0.5, 0.5]), jax.random.PRNGKey(3)
    near_mean = lambda a: -jnp.sum(jnp.square(a - mean), axis=-1)  # noqa: E731
    np.testing.assert_array_equal(critic_weighted_action(mean, std, near_mean, key, 8), mean)
    first = lambda a: a[:, 0]  # noqa: E731 - the largest first component wins
    picked = critic_weighted_action(mean, std, first, key, 8)
    sampled = networks.sample_action(jnp.broadcast_to(mean, (7, 2)), jnp.broadcast_to(std, (7, 2)), key)
    best = sampled[jnp.argmax(sampled[:, 0])]
    assert float(best[0]) > float(mean[0])  # (this key draws a sample beyond the mean)
    np.testing.assert_array_equal(picked, best)
    assert float(jnp.max(jnp.abs(picked))) <= 1.0
