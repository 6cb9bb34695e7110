import numpy as np
import jax
import jax.numpy as jnp

from parallel_skills.hcmpo import critic_target, e_step_weights, m_step_loss, positive, temperature_dual_loss

GAMMA = 0.9


def test_critic_target_continue_fresh_termination_truncation():
    reward = jnp.array([1.0, 1.0, 1.0, 1.0, 0.5])
    discount = jnp.array([1.0, 0.0, 1.0, 0.0, 1.0])  # 0 = termination, 1 = truncation / mid-episode
    c = jnp.array([3, 3, 1, 1, 1])
    q_cont = jnp.array([2.0, 2.0, 100.0, 100.0, -7.0])
    q_fresh = jnp.array([[1.0, 3.0], [1.0, 3.0], [1.0, 3.0], [1.0, 3.0], [0.0, 4.0]])
    probs = jnp.array([[0.5, 0.5], [0.5, 0.5], [0.25, 0.75], [0.25, 0.75], [1.0, 0.0]])
    y = critic_target(reward, discount, c, q_cont, q_fresh, probs, GAMMA)
    # continuation: 1 + .9*2 ; continuation terminal: 1 ; decision: 1 + .9*(.25+2.25) ;
    # decision terminal: 1 ; truncated decision bootstraps: .5 + .9*0.
    np.testing.assert_allclose(y, [2.8, 1.0, 1 + 0.9 * 2.5, 1.0, 0.5], rtol=1e-6)


def _np_weights(q, logp, eta):
    logits = q / eta + logp
    logits -= logits.max(-1, keepdims=True)
    w = np.exp(logits)
    return w / w.sum(-1, keepdims=True)


def test_e_step_weights_and_dual_vs_numpy():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(4, 6)).astype(np.float32) * 3
    prior_logits = rng.normal(size=(4, 6)).astype(np.float32)
    logp = prior_logits - np.log(np.exp(prior_logits).sum(-1, keepdims=True))
    eta = 0.7
    w = e_step_weights(jnp.asarray(q), jnp.asarray(logp), jnp.asarray(eta))
    np.testing.assert_allclose(w, _np_weights(q, logp, eta), rtol=1e-5, atol=1e-7)
    mask = np.array([1.0, 0.0, 1.0, 1.0], np.float32)
    g = temperature_dual_loss(jnp.asarray(eta), jnp.asarray(q), jnp.asarray(logp), 0.1, jnp.asarray(mask))
    per_state = np.log(np.sum(np.exp(logp) * np.exp(q / eta), axis=-1))
    expected = eta * 0.1 + eta * per_state[mask > 0].mean()
    np.testing.assert_allclose(g, expected, rtol=1e-5)
    grad = jax.grad(lambda log_eta: temperature_dual_loss(positive(log_eta), jnp.asarray(q * 1e3),
                                                          jnp.asarray(logp), 0.1, jnp.asarray(mask)))(
        jnp.asarray(-5.0))
    assert np.isfinite(grad)
    # Analytic dual derivative g'(η) = ε + mean[lse] − mean[E_q[Q]]/η ; check against autodiff.
    d = jax.grad(temperature_dual_loss)(jnp.asarray(eta), jnp.asarray(q), jnp.asarray(logp), 0.1,
                                        jnp.asarray(mask))
    wn = _np_weights(q, logp, eta)
    expected_d = 0.1 + per_state[mask > 0].mean() - (wn * q).sum(-1)[mask > 0].mean() / eta
    np.testing.assert_allclose(d, expected_d, rtol=1e-4)


def test_masked_rows_do_not_affect_losses():
    rng = np.random.default_rng(1)
    q = jnp.asarray(rng.normal(size=(3, 4)), jnp.float32)
    logp = jax.nn.log_softmax(jnp.asarray(rng.normal(size=(3, 4)), jnp.float32))
    online = jax.nn.log_softmax(jnp.asarray(rng.normal(size=(3, 4)), jnp.float32))
    mask = jnp.array([1.0, 0.0, 1.0])
    w = e_step_weights(q, logp, 1.0)
    base = m_step_loss(online, w, logp, jnp.asarray(2.0), 5e-3, mask)
    g0 = temperature_dual_loss(jnp.asarray(1.0), q, logp, 0.1, mask)
    # Perturb the masked row wildly.
    q2 = q.at[1].set(1e4)
    online2 = online.at[1].set(jax.nn.log_softmax(jnp.array([50.0, -50.0, 0.0, 0.0])))
    w2 = e_step_weights(q2, logp, 1.0)
    pert = m_step_loss(online2, w2, logp, jnp.asarray(2.0), 5e-3, mask)
    g1 = temperature_dual_loss(jnp.asarray(1.0), q2, logp, 0.1, mask)
    np.testing.assert_allclose(base[0], pert[0], rtol=1e-6)
    np.testing.assert_allclose(base[1], pert[1], rtol=1e-6)
    np.testing.assert_allclose(g0, g1, rtol=1e-6)


def test_m_step_loss_values_and_empty_mask():
    logp_old = jnp.log(jnp.array([[0.5, 0.25, 0.25]]))
    logp_new = jnp.log(jnp.array([[0.2, 0.4, 0.4]]))
    w = jnp.array([[0.6, 0.3, 0.1]])
    alpha = 3.0
    loss, kl = m_step_loss(logp_new, w, logp_old, jnp.asarray(alpha), 0.01, jnp.ones(1))
    kl_np = 0.5 * np.log(0.5 / 0.2) + 2 * 0.25 * np.log(0.25 / 0.4)
    ce = -(0.6 * np.log(0.2) + 0.3 * np.log(0.4) + 0.1 * np.log(0.4))
    np.testing.assert_allclose(kl, kl_np, rtol=1e-5)
    np.testing.assert_allclose(loss, ce + alpha * kl_np + alpha * (0.01 - kl_np), rtol=1e-5)
    # Gradient wrt alpha is the dual term only: ε − KL.
    ga = jax.grad(lambda a: m_step_loss(logp_new, w, logp_old, a, 0.01, jnp.ones(1))[0])(jnp.asarray(alpha))
    np.testing.assert_allclose(ga, 0.01 - kl_np, rtol=1e-4)
    # No decision rows: exactly zero, zero gradients.
    zero = jnp.zeros(1)
    loss0, kl0 = m_step_loss(logp_new, w, logp_old, jnp.asarray(alpha), 0.01, zero)
    assert float(loss0) == 0.0 and float(kl0) == 0.0
    g0 = temperature_dual_loss(jnp.asarray(1.0), w, logp_old, 0.1, zero)
    assert float(g0) == 0.0
    grads = jax.grad(lambda lp, a: m_step_loss(lp, w, logp_old, a, 0.01, zero)[0], argnums=(0, 1))(
        logp_new, jnp.asarray(alpha))
    assert all(np.all(np.asarray(g) == 0) for g in grads)

