"""Tests for baseline_losses.py (DAGGER, KL-reg to the skill mixture, RHPO with frozen skills).

Expected values are computed here in float64 numpy / math, written out independently of the
implementation (explicit loops over components, densities instead of log-densities, numeric
integration, Monte Carlo)."""
import math

import numpy as np
import jax
import jax.numpy as jnp

from parallel_skills.baseline_losses import (categorical_kl, dagger_cross_entropy, kl_reg_mpo_loss,
                                             mixture_log_prob, prior_e_step, rhpo_components,
                                             rhpo_log_prob, rhpo_mpo_loss, sample_mixture, sample_rhpo)
from parallel_skills.mpo import sample_e_step

SIGMA0 = 0.3


def _pdf(x, mean, std):
    """Univariate normal density."""
    return math.exp(-0.5 * ((x - mean) / std) ** 2) / (std * math.sqrt(2.0 * math.pi))


def _np_mixture_density(probs, means, stds, action):
    """Σ_c p_c Π_d N(a_d; μ_cd, σ_cd) by explicit loops. probs [C], means/stds [C, A], action [A]."""
    total = 0.0
    for c in range(len(probs)):
        density = probs[c]
        for d in range(len(action)):
            density *= _pdf(action[d], means[c][d], stds[c][d])
        total += density
    return total


# --------------------------------------------------------------------------- skill-mixture prior

def test_mixture_log_prob_vs_explicit_loop():
    means = np.array([[[0.2, -0.5], [-0.7, 0.9]], [[0.0, 0.0], [1.0, -1.0]]])  # [B=2, N=2, A=2]
    actions = np.array([[[0.1, -0.4], [-0.6, 1.0], [0.5, 0.5]],
                        [[0.0, 0.1], [0.9, -0.8], [-1.0, 1.0]]])  # [B, J=3, A]
    stds = np.full((2, 2), SIGMA0)
    expected = np.array([[math.log(_np_mixture_density([0.5, 0.5], means[b], stds, actions[b, j]))
                          for j in range(3)] for b in range(2)])
    got = mixture_log_prob(jnp.asarray(means, jnp.float32), SIGMA0, jnp.asarray(actions, jnp.float32))
    assert got.shape == (2, 3)
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    got_single = mixture_log_prob(jnp.asarray(means, jnp.float32), SIGMA0,
                                  jnp.asarray(actions[:, 0], jnp.float32))
    assert got_single.shape == (2,)
    np.testing.assert_allclose(got_single, expected[:, 0], rtol=1e-5)


def test_mixture_log_prob_is_stable_far_from_the_skills():
    # log N ≈ −356 and −272: the densities underflow in float32, not their logsumexp.
    means = np.array([[[0.0], [1.0]]])
    expected = math.log(0.5 * _pdf(8.0, 0.0, SIGMA0) + 0.5 * _pdf(8.0, 1.0, SIGMA0))  # float64
    got = mixture_log_prob(jnp.asarray(means, jnp.float32), SIGMA0, jnp.array([[8.0]]))
    np.testing.assert_allclose(got, [expected], rtol=1e-5)


def test_sample_mixture_moments_and_no_clipping():
    means = jnp.array([[[-0.5, 0.9], [0.5, 0.9]], [[2.0, 0.0], [2.0, 0.0]]])  # [B=2, N=2, A=2]
    a = np.asarray(jax.jit(sample_mixture, static_argnums=3)(means, SIGMA0, jax.random.PRNGKey(0), 20000))
    assert a.shape == (2, 20000, 2)
    # Row 0, dim 0: ½N(−.5, σ0²) + ½N(.5, σ0²): mean 0, var .25 + σ0²; half the mass above 0.
    np.testing.assert_allclose(a[0, :, 0].mean(), 0.0, atol=0.02)
    np.testing.assert_allclose(a[0, :, 0].var(), 0.25 + SIGMA0 ** 2, atol=0.02)
    np.testing.assert_allclose((a[0, :, 0] > 0).mean(), 0.5, atol=0.02)
    # Row 0, dim 1: N(.9, σ0²), P(a > 1) = 1 − Φ(1/3) = 0.369: not clipped.
    np.testing.assert_allclose(a[0, :, 1].mean(), 0.9, atol=0.02)
    np.testing.assert_allclose((a[0, :, 1] > 1.0).mean(), 0.3694, atol=0.02)
    # Row 1 uses its own skills: N((2, 0), σ0²).
    np.testing.assert_allclose(a[1].mean(0), [2.0, 0.0], atol=0.02)
    np.testing.assert_allclose(a[1].var(0), [SIGMA0 ** 2] * 2, atol=0.01)


# --------------------------------------------------------------------------- DAGGER

def test_dagger_hand_value_and_mask():
    # μ = 0, σ = 1, teachers ±1, σ0 = .5: ½log 2π + ((1 + 1)/2 + .25)/2.
    hand = 0.5 * math.log(2 * math.pi) + 0.625
    mean = jnp.array([[0.0], [5.0]])
    std = jnp.array([[1.0], [0.1]])
    teachers = jnp.array([[[-1.0], [1.0]], [[-9.0], [9.0]]])
    got = dagger_cross_entropy(mean, std, teachers, 0.5, jnp.array([1.0, 0.0]))
    np.testing.assert_allclose(got, hand, rtol=1e-6)
    assert float(dagger_cross_entropy(mean, std, teachers, 0.5, jnp.zeros(2))) == 0.0


def test_dagger_closed_form_vs_numeric_integration_1d():
    mu, sigma, teachers = 0.2, 0.5, (-0.4, 0.7)
    grid = np.linspace(-10.0, 10.0, 200001)
    teacher_pdf = 0.5 * sum(np.exp(-0.5 * ((grid - m) / SIGMA0) ** 2) / (SIGMA0 * math.sqrt(2 * math.pi))
                            for m in teachers)
    log_student = -0.5 * ((grid - mu) / sigma) ** 2 - math.log(sigma * math.sqrt(2 * math.pi))
    expected = -np.trapezoid(teacher_pdf * log_student, grid)
    teacher_means = jnp.array([[[teachers[0]], [teachers[1]]]])
    got = dagger_cross_entropy(jnp.array([[mu]]), jnp.array([[sigma]]), teacher_means, SIGMA0, jnp.ones(1))
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def test_dagger_closed_form_vs_monte_carlo_2d():
    rng = np.random.default_rng(0)
    mean = np.array([[0.1, -0.3], [0.5, 0.5]])
    std = np.array([[0.4, 0.8], [1.2, 0.3]])
    teachers = np.array([[[0.5, -0.5], [-0.2, 0.6]], [[0.9, 0.1], [0.3, 0.4]]])  # [B=2, N=2, A=2]
    n = 200000
    per_row = []
    for b in range(2):
        skill = rng.integers(0, 2, size=n)
        a = teachers[b][skill] + SIGMA0 * rng.standard_normal((n, 2))
        z = (a - mean[b]) / std[b]
        log_student = np.sum(-0.5 * z ** 2 - np.log(std[b] * math.sqrt(2 * math.pi)), -1)
        per_row.append(-log_student.mean())
    got = dagger_cross_entropy(jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32),
                               jnp.asarray(teachers, jnp.float32), SIGMA0, jnp.ones(2))
    np.testing.assert_allclose(got, np.mean(per_row), rtol=5e-3)


def test_dagger_gradient_moves_the_student_towards_the_teachers():
    teachers = jnp.array([[[1.0], [2.0]]])

    def loss(mean, std):
        return dagger_cross_entropy(mean, std, teachers, 0.5, jnp.ones(1))

    mean, std = jnp.array([[0.0]]), jnp.array([[1.0]])
    g_mean, g_std = jax.grad(loss, argnums=(0, 1))(mean, std)
    # ∂/∂μ = −mean_i(μ_i − μ)/σ² = −1.5 ; ∂/∂σ = 1/σ − (mean_i(μ_i − μ)² + σ0²)/σ³ = 1 − 2.75.
    np.testing.assert_allclose(g_mean, [[-1.5]], rtol=1e-6)
    np.testing.assert_allclose(g_std, [[-1.75]], rtol=1e-6)
    assert loss(jnp.array([[0.5]]), std) < loss(mean, std)


# --------------------------------------------------------------------------- KL-reg to the mixture

def test_prior_e_step_with_prior_proposal_is_sample_e_step():
    rng = np.random.default_rng(1)
    q = jnp.asarray(rng.normal(size=(3, 5)) * 3, jnp.float32)
    log_prior = jnp.asarray(rng.normal(size=(3, 5)) - 2.0, jnp.float32)  # densities, not normalised over j
    mask = jnp.array([1.0, 0.0, 1.0])
    eta = jnp.asarray(0.7)
    weights, dual = prior_e_step(q, log_prior, log_prior, eta, 0.1, mask)
    mpo_weights, mpo_dual = sample_e_step(q, eta, 0.1, mask)
    np.testing.assert_allclose(weights, mpo_weights, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(dual, mpo_dual, rtol=1e-6)


def test_prior_e_step_hand_values():
    # π0(a_j) = (.1, .2, .4), ρ(a_j) = .2 ⇒ π0/ρ = (.5, 1, 2), w̃ = (.5, 1, 2)/3.5; Q = (1, 0, 2), η = .5.
    unnormalised = [0.5 * math.exp(2.0), 1.0, 2.0 * math.exp(4.0)]  # π0/ρ·exp(Q/η)
    expected_weights = [u / sum(unnormalised) for u in unnormalised]
    expected_dual = 0.5 * 0.1 + 0.5 * math.log(sum(unnormalised) / 3.5)  # η·ε + η·log Σ w̃ exp(Q/η)
    q = jnp.array([[1.0, 0.0, 2.0], [50.0, -50.0, 0.0]])  # row 1 is masked
    log_prior = jnp.log(jnp.array([[0.1, 0.2, 0.4], [0.9, 0.01, 0.3]]))
    log_proposal = jnp.log(jnp.array([[0.2, 0.2, 0.2], [0.1, 0.5, 0.2]]))
    weights, dual = prior_e_step(q, log_prior, log_proposal, jnp.asarray(0.5), 0.1, jnp.array([1.0, 0.0]))
    np.testing.assert_allclose(weights[0], expected_weights, rtol=1e-5)
    np.testing.assert_allclose(weights.sum(-1), [1.0, 1.0], rtol=1e-6)
    np.testing.assert_allclose(dual, expected_dual, rtol=1e-5)


def test_kl_reg_mpo_loss_hand_value_gradient_and_mask():
    # Row 0: a = (0, 1), q = (.25, .75), N(μ=.5, σ=2): −Σ q log N = .5²/(2·4) + log 2 + ½log 2π.
    hand = 0.03125 + math.log(2.0) + 0.5 * math.log(2 * math.pi)
    actions = jnp.array([[[0.0], [1.0]], [[9.0], [-9.0]]])
    weights = jnp.array([[0.25, 0.75], [0.5, 0.5]])
    std = jnp.array([[2.0], [0.1]])
    mask = jnp.array([1.0, 0.0])

    def loss(mean):
        return kl_reg_mpo_loss(mean, std, actions, weights, mask)

    (value, stats), grad = jax.value_and_grad(loss, has_aux=True)(jnp.array([[0.5], [0.0]]))
    np.testing.assert_allclose(value, hand, rtol=1e-6)
    np.testing.assert_allclose(stats["kl_reg_loss"], hand, rtol=1e-6)
    np.testing.assert_allclose(stats["kl_reg_ess"], 1.0 / (0.25 ** 2 + 0.75 ** 2), rtol=1e-6)
    # ∂/∂μ = −Σ q (a − μ)/σ² = −(.25·(−.5) + .75·.5)/4 ; the masked row gets none.
    np.testing.assert_allclose(grad, [[-0.0625], [0.0]], rtol=1e-6)


# --------------------------------------------------------------------------- RHPO

def test_rhpo_log_prob_vs_explicit_loop_and_uniform_case():
    rng = np.random.default_rng(2)
    logits = rng.normal(size=(2, 3))
    means = rng.uniform(-1, 1, size=(2, 3, 2))
    stds = rng.uniform(0.2, 0.8, size=(2, 3, 2))
    actions = rng.uniform(-1, 1, size=(2, 4, 2))
    expected = np.zeros((2, 4))
    for b in range(2):
        probs = np.exp(logits[b]) / np.exp(logits[b]).sum()
        for j in range(4):
            expected[b, j] = math.log(_np_mixture_density(probs, means[b], stds[b], actions[b, j]))
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    got = rhpo_log_prob(f32(logits), f32(means), f32(stds), f32(actions))
    assert got.shape == (2, 4)
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    np.testing.assert_allclose(rhpo_log_prob(f32(logits), f32(means), f32(stds), f32(actions[:, 1])),
                               expected[:, 1], rtol=1e-5)
    # Uniform logits and a shared std: the skill-mixture prior.
    uniform = rhpo_log_prob(jnp.zeros((2, 3)), f32(means), jnp.full((2, 3, 2), SIGMA0), f32(actions))
    np.testing.assert_allclose(uniform, mixture_log_prob(f32(means), SIGMA0, f32(actions)), rtol=1e-6)


def test_sample_rhpo_moments():
    # p = (.2, .8), N(−1, .1²) and N(1, .5²): mean .6, var Σ p(σ² + μ²) − .6² = .842.
    logits = jnp.log(jnp.array([[0.2, 0.8]])) + 3.0
    means = jnp.array([[[-1.0], [1.0]]])
    stds = jnp.array([[[0.1], [0.5]]])
    sample = jax.jit(sample_rhpo, static_argnums=4)
    a = np.asarray(sample(logits, means, stds, jax.random.PRNGKey(3), 20000))[0, :, 0]
    np.testing.assert_allclose(a.mean(), 0.6, atol=0.03)
    np.testing.assert_allclose(a.var(), 0.842, atol=0.04)
    # P(a < −.5) = .2·Φ(5) + .8·Φ(−3) = .2011.
    np.testing.assert_allclose((a < -0.5).mean(), 0.2011, atol=0.015)


def test_categorical_kl_hand_values():
    logits_old = jnp.log(jnp.array([[0.5, 0.5], [0.3, 0.7]])) + 1.0  # shifts do not matter
    logits = jnp.log(jnp.array([[0.25, 0.75], [0.3, 0.7]])) - 2.0
    expected = [0.5 * math.log(0.5 / 0.25) + 0.5 * math.log(0.5 / 0.75), 0.0]
    np.testing.assert_allclose(categorical_kl(logits_old, logits), expected, rtol=1e-5, atol=1e-7)


def _rhpo_problem():
    """B = 2 states, N = 2 frozen skills, A = 2, J = 4 samples; online == target."""
    rng = np.random.default_rng(4)
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    return dict(
        online_logits=f32(rng.normal(size=(2, 3))),
        online_mean=f32(rng.uniform(-0.5, 0.5, size=(2, 2))),
        online_std=f32(rng.uniform(0.3, 0.6, size=(2, 2))),
        frozen_means=f32(rng.uniform(-1, 1, size=(2, 2, 2))),
        actions=f32(rng.uniform(-1, 1, size=(2, 4, 2))),
        q=f32(rng.normal(size=(2, 4))))


def _rhpo_loss(p, mask, online=None):
    """rhpo_mpo_loss with target = p's policy and online = ``online`` (default: the target)."""
    if online is None:
        online = (p["online_logits"], p["online_mean"], p["online_std"])
    return rhpo_mpo_loss(*online, p["online_logits"], p["online_mean"], p["online_std"],
                         p["frozen_means"], SIGMA0, p["actions"], p["q"],
                         temperature=jnp.asarray(0.8), alpha_cat=jnp.asarray(2.0),
                         alpha_mean=jnp.asarray(3.0), alpha_std=jnp.asarray(4.0), epsilon=0.1,
                         epsilon_cat=0.01, epsilon_mean=5e-3, epsilon_std=1e-5, mask=mask)


def test_rhpo_mpo_loss_at_the_target_policy():
    p = _rhpo_problem()
    loss, stats = _rhpo_loss(p, jnp.ones(2))
    assert np.isfinite(float(loss))
    for k in ("rhpo_kl_cat", "rhpo_kl_mean", "rhpo_kl_std"):
        np.testing.assert_allclose(stats[k], 0.0, atol=1e-7)
    # With online == target the three decoupled terms are all −mean_b Σ_j w_bj log π(a_bj|s_b).
    expected = 0.0
    for b in range(2):
        w = np.exp(np.asarray(p["q"][b], np.float64) / 0.8)
        w /= w.sum()
        logits = np.asarray(p["online_logits"][b], np.float64)
        probs = np.exp(logits) / np.exp(logits).sum()
        means = np.concatenate([np.asarray(p["frozen_means"][b]), np.asarray(p["online_mean"][b])[None]])
        stds = np.concatenate([np.full((2, 2), SIGMA0), np.asarray(p["online_std"][b])[None]])
        for j in range(4):
            density = _np_mixture_density(probs, means, stds, np.asarray(p["actions"][b, j]))
            expected -= 0.5 * w[j] * math.log(density)  # 0.5: mean over the B = 2 rows
    for k in ("rhpo_loss_cat", "rhpo_loss_mean", "rhpo_loss_std"):
        np.testing.assert_allclose(stats[k], expected, rtol=1e-5)
    # Each multiplier's gradient is ε − KL̄ = ε.
    grads = jax.grad(lambda a: rhpo_mpo_loss(
        p["online_logits"], p["online_mean"], p["online_std"], p["online_logits"], p["online_mean"],
        p["online_std"], p["frozen_means"], SIGMA0, p["actions"], p["q"], jnp.asarray(0.8), a[0], a[1], a[2],
        0.1, 0.01, 5e-3, 1e-5, jnp.ones(2))[0])(jnp.array([2.0, 3.0, 4.0]))
    np.testing.assert_allclose(grads, [0.01, 5e-3, 1e-5], rtol=1e-4)


def test_rhpo_mpo_loss_masked_rows_and_empty_mask():
    p = _rhpo_problem()
    mask = jnp.array([1.0, 0.0])
    base, _ = _rhpo_loss(p, mask)
    wild = {k: v.at[1].set(v[1] * 7.0 + 3.0) for k, v in p.items()}
    wild = {**wild, "online_std": p["online_std"].at[1].set(5.0)}
    moved, _ = _rhpo_loss(wild, mask)
    np.testing.assert_allclose(moved, base, rtol=1e-6)
    empty, _ = _rhpo_loss(p, jnp.zeros(2))
    assert float(empty) == 0.0


def test_rhpo_mpo_loss_gradients():
    p = _rhpo_problem()
    online = (p["online_logits"] * 1.5, p["online_mean"] - 0.1, p["online_std"] * 1.2)

    def loss(online, frozen_means):
        return _rhpo_loss({**p, "frozen_means": frozen_means}, jnp.ones(2), online)[0]

    g_online, g_frozen = jax.jit(jax.grad(loss, argnums=(0, 1)))(online, p["frozen_means"])
    for g in g_online:  # the categorical and the trainable component are trained
        assert np.all(np.isfinite(g)) and np.abs(g).max() > 1e-4
    np.testing.assert_array_equal(g_frozen, 0.0)  # the skills are frozen (stop-gradient)
    # rhpo_components puts the trainable component last.
    means, stds = rhpo_components(p["frozen_means"], SIGMA0, p["online_mean"], p["online_std"])
    np.testing.assert_array_equal(means[:, 2], p["online_mean"])
    np.testing.assert_array_equal(stds[:, :2], SIGMA0 * np.ones((2, 2, 2), np.float32))
