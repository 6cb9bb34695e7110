"""Each appendix reward against hand-computed values, just inside / just outside its tolerance."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from tasks.manipulation import layout as L
from tasks.manipulation import rewards as R

O = np.zeros(3)


def shaped(d, eps):
    return 1.0 - math.tanh(d * eps) ** 2


def test_reach_dense_boundary():
    # Tolerance [0.055, 0.055, 0.02]: scaled norm exactly 1 along each axis is inside.
    for axis, tol in enumerate(R.REACH_TOL):
        inside = np.zeros(3); inside[axis] = tol * 0.999
        outside = np.zeros(3); outside[axis] = tol * 1.001
        assert R.reach_dense(inside, O) == 1.0
        assert R.reach_dense(outside, O) == pytest.approx(shaped(1.001, R.REACH_EPSILON))
        assert R.reach_dense(outside, O) < 1.0
    # Combined axes: (0.04/0.055, 0, 0.015/0.02) has norm ≈ 1.048 > 1.
    p = np.array([0.04, 0.0, 0.015])
    d = math.hypot(0.04 / 0.055, 0.015 / 0.02)
    assert d > 1
    assert R.reach_dense(p, O) == pytest.approx(shaped(d, R.REACH_EPSILON))
    # The stated margin: 0.1 at 0.3 m horizontally.
    assert R.reach_dense(np.array([0.3, 0.0, 0.0]), O) == pytest.approx(0.1)


def test_reach_sparse_boundary():
    assert R.reach_sparse(np.array([0.0, 0.0, 0.0199]), O) == 1.0
    assert R.reach_sparse(np.array([0.0, 0.0, 0.0201]), O) == 0.0
    assert R.reach_sparse(np.array([0.0549, 0.0, 0.0]), O) == 1.0
    assert R.reach_sparse(np.array([0.0551, 0.0, 0.0]), O) == 0.0


def test_fingers_open_closed():
    assert R.open_fingers_dense(np.float64(L.APERTURE_OPEN)) == 1.0
    assert R.open_fingers_dense(np.float64(L.APERTURE_OPEN - 0.5e-9)) == 1.0
    just_out = np.float64(L.APERTURE_OPEN - 2e-9)
    assert R.open_fingers_dense(just_out) == pytest.approx(shaped(2.0, R.FINGER_EPSILON))
    assert R.open_fingers_dense(just_out) < 1.0
    assert R.open_fingers_dense(np.float64(0.0)) == pytest.approx(0.1)  # the stated margin
    assert R.closed_fingers_dense(np.float64(0.0)) == 1.0
    assert R.closed_fingers_dense(np.float64(0.04)) == pytest.approx(shaped(0.04 / 1e-9, R.FINGER_EPSILON))


def test_lift_arm():
    assert R.lift_arm(np.float64(0.18)) == 1.0
    assert R.lift_arm(np.float64(0.1799)) == pytest.approx(0.0999 / 0.1)
    assert R.lift_arm(np.float64(0.13)) == pytest.approx(0.5)
    assert R.lift_arm(np.float64(0.08)) == 0.0
    assert R.lift_arm(np.float64(0.05)) == 0.0  # below z_min: no reward (not negative)


def test_lift_open_closed_products():
    z, open_ = np.float64(0.13), np.float64(L.APERTURE_OPEN)
    assert R.lift_arm_open_dense(z, open_) == pytest.approx(0.5)
    closed = np.float64(0.0)
    # R_grasp = 0.5 (R_closed + grasp): 0.5 without a grasp, 1 with.
    assert R.lift_arm_closed_dense(z, closed, np.float64(0.0)) == pytest.approx(0.25)
    assert R.lift_arm_closed_dense(z, closed, np.float64(1.0)) == pytest.approx(0.5)


def test_lift_object_sparse():
    assert R.lift_object_sparse(np.float64(0.18)) == 1.0
    assert R.lift_object_sparse(np.float64(0.1799)) == 0.0


def test_hover_dense():
    bottom = np.array([0.0, 0.0, 0.02])
    assert R.hover_dense(bottom + [0.0, 0.0, 0.04 + 0.0199], bottom) == 1.0
    d = 0.0201 / 0.02
    assert R.hover_dense(bottom + [0.0, 0.0, 0.04 + 0.0201], bottom) == pytest.approx(shaped(d, R.HOVER_EPSILON))
    assert R.hover_dense(bottom + [0.0549, 0.0, 0.04], bottom) == 1.0
    assert R.hover_dense(bottom + [0.0551, 0.0, 0.04], bottom) < 1.0


def test_stack_sparse_tolerances():
    b = np.array([0.0, 0.0, 0.02])
    g0 = np.float64(0.0)
    assert R.stack_sparse(b + [0.0299, 0, 0.04], b, g0) == 1.0
    assert R.stack_sparse(b + [0.0301, 0, 0.04], b, g0) == 0.0
    assert R.stack_sparse(b + [0.0, 0, 0.0499], b, g0) == 1.0
    assert R.stack_sparse(b + [0.0, 0, 0.0501], b, g0) == 0.0
    assert R.stack_sparse(b + [0.0, 0, 0.0301], b, g0) == 1.0
    assert R.stack_sparse(b + [0.0, 0, 0.0299], b, g0) == 0.0
    assert R.stack_sparse(b + [0.0, 0, 0.04], b, np.float64(1.0)) == 0.0  # still grasped


def test_stack_leave_factor():
    b = np.array([0.0, 0.0, 0.02])
    top = b + [0.0, 0.0, 0.04]
    g0 = np.float64(0.0)
    # Gripper within the reach tolerance of the top cube: no reward; just outside (z): reward.
    assert R.stack_leave_sparse(top, b, g0, top + [0, 0, 0.0199]) == 0.0
    assert R.stack_leave_sparse(top, b, g0, top + [0, 0, 0.0201]) == 1.0


def test_pyramid_sparse():
    a = np.array([-0.0225, 0.0, 0.02])
    bb = np.array([0.0225, 0.0, 0.02])
    top = np.array([0.0, 0.0, 0.06])
    g0, far = np.float64(0.0), top + [0, 0, 0.1]
    assert R.pyramid_leave_sparse(top, a, bb, g0, far) == 1.0
    assert R.pyramid_leave_sparse(top, a, bb, g0, top) == 0.0  # gripper still at the top cube
    # Bottom cubes just within / beyond 0.08 apart (top kept over their mean).
    a2, b2 = np.array([-0.03995, 0, 0.02]), np.array([0.03995, 0, 0.02])
    assert R.pyramid_sparse(top, a2, b2, g0) == 1.0
    a3, b3 = np.array([-0.04005, 0, 0.02]), np.array([0.04005, 0, 0.02])
    assert R.pyramid_sparse(top, a3, b3, g0) == 0.0
    assert R.pyramid_sparse(top + [0.0299, 0, 0], a, bb, g0) == 1.0
    assert R.pyramid_sparse(top + [0.0301, 0, 0], a, bb, g0) == 0.0


def test_triple_stack():
    bottom = np.array([0.0, 0.0, 0.02])
    middle = bottom + [0.0, 0.0, 0.04]
    top = middle + [0.0, 0.0, 0.04]
    g0, far = np.float64(0.0), top + [0, 0, 0.05]
    assert R.triple_stack_leave_sparse(top, middle, bottom, g0, far) == 1.0
    assert R.triple_stack_leave_sparse(top, middle, bottom, g0, top) == 0.0
    assert R.triple_stack_leave_sparse(top, middle + [0.031, 0, 0], bottom, g0, far) == 0.0
    assert R.triple_stack_leave_sparse(top, middle, bottom, np.float64(1.0), far) == 0.0


def test_numpy_and_jax_agree():
    rng = np.random.default_rng(0)
    p, q = rng.uniform(-0.1, 0.2, (16, 3)), rng.uniform(-0.1, 0.2, (16, 3))
    np.testing.assert_allclose(
        np.asarray(R.reach_dense(jnp.asarray(p, jnp.float32), jnp.asarray(q, jnp.float32))),
        R.reach_dense(p, q), rtol=1e-5, atol=1e-6,
    )
    assert isinstance(R.reach_dense(p, q), np.ndarray)
