"""Reward functions of the manipulation domain, one per equation of the paper's App. C.1.3.

Pure array functions shared by every physics backend. They accept NumPy arrays (the JAX-free
evaluation twin) or JAX arrays / tracers (jitted training) and return the same kind; this module
imports no JAX unless it is handed JAX arrays. All functions broadcast over leading batch axes:
positions are [..., 3], scalars are [...].

The appendix leaves the scaling factor ε of the shaped (``1 - tanh²``) rewards unspecified; we fix
it so that the reward falls to 0.1 at a stated margin (``epsilon_for_margin``).
"""

from __future__ import annotations

import math

import numpy as np

from tasks.manipulation import layout

# Tolerances and thresholds exactly as in App. C.1.3.
REACH_TOL = (0.055, 0.055, 0.02)
HOVER_TOL = (0.055, 0.055, 0.02)
FINGER_TOL = 1e-9
LIFT_Z_MIN = 0.08
LIFT_Z_DESIRED = 0.18
STACK_TOL_XY = 0.03
STACK_TOL_Z = 0.01
STACK_D_DESIRED = 0.04  # average side length of the two cubes
PYRAMID_TOL_XY_BOTTOM = 0.08
HOVER_OFFSET = (0.0, 0.0, layout.CUBE_SIZE)


def epsilon_for_margin(margin_scaled: float, value_at_margin: float = 0.1) -> float:
    """ε such that 1 - tanh²(margin_scaled·ε) = value_at_margin."""
    return math.atanh(math.sqrt(1.0 - value_at_margin)) / margin_scaled


# Reach / hover: 0.1 at 0.3 m horizontal distance (0.3 / 0.055 tolerance units).
REACH_EPSILON = epsilon_for_margin(0.3 / REACH_TOL[0])
HOVER_EPSILON = REACH_EPSILON
# Fingers: 0.1 when the aperture is a full stroke away from the target.
FINGER_EPSILON = epsilon_for_margin(layout.APERTURE_OPEN / FINGER_TOL)


def _xp(*arrays):
    """NumPy for NumPy inputs, jax.numpy for anything else (JAX arrays, tracers)."""
    for a in arrays:
        if not isinstance(a, (np.ndarray, np.generic, float, int, bool)):
            import jax.numpy as jnp

            return jnp
    return np


def _shaped(scaled_distance, epsilon, xp):
    """1 if the scaled distance is within tolerance (≤ 1), else 1 - tanh²(d·ε)."""
    shaped = 1.0 - xp.tanh(scaled_distance * epsilon) ** 2
    return xp.where(scaled_distance <= 1.0, 1.0, shaped)


def _scaled_norm(delta, tol, xp):
    return xp.sqrt(xp.sum((delta / xp.asarray(tol, dtype=delta.dtype)) ** 2, axis=-1))


def reach_dense(p_gripper, p_object):
    """Eq. (reach): R_reach = 1 iff ||(p_gripper - p_object)/tol|| ≤ 1, else 1 - tanh²(||·||·ε)."""
    xp = _xp(p_gripper, p_object)
    return _shaped(_scaled_norm(p_gripper - p_object, REACH_TOL, xp), REACH_EPSILON, xp)


def reach_sparse(p_gripper, p_object):
    """Sparse version of Eq. (reach): 1 iff ||(p_gripper - p_object)/tol|| ≤ 1, else 0."""
    xp = _xp(p_gripper, p_object)
    d = _scaled_norm(p_gripper - p_object, REACH_TOL, xp)
    return (d <= 1.0).astype(p_gripper.dtype)


def fingers_dense(aperture, desired):
    """Eq. (open_reward) with p_desired = ``desired``: 1 iff |p - p_desired|/1e-9 ≤ 1, else shaped."""
    xp = _xp(aperture)
    d = xp.abs(aperture - desired) / FINGER_TOL
    return _shaped(d, FINGER_EPSILON, xp)


def open_fingers_dense(aperture):
    """R_open: fingers at the open position."""
    return fingers_dense(aperture, layout.APERTURE_OPEN)


def closed_fingers_dense(aperture):
    """R_closed: Eq. (open_reward) with the closed position as p_desired."""
    return fingers_dense(aperture, layout.APERTURE_CLOSED)


def lift_arm(z_arm):
    """Eq. (lift): 1 iff z ≥ z_desired, else (z - z_min)/(z_desired - z_min), floored at 0."""
    xp = _xp(z_arm)
    frac = (z_arm - LIFT_Z_MIN) / (LIFT_Z_DESIRED - LIFT_Z_MIN)
    return xp.where(z_arm >= LIFT_Z_DESIRED, 1.0, xp.clip(frac, 0.0, 1.0))


def lift_arm_open_dense(z_arm, aperture):
    """R_lift,open = R_lift · R_open."""
    return lift_arm(z_arm) * open_fingers_dense(aperture)


def grasp_dense(aperture, grasp):
    """R_grasp = 0.5 (R_closed + R_grasp,aux), R_grasp,aux = the grasp sensor (0/1)."""
    return 0.5 * (closed_fingers_dense(aperture) + grasp)


def lift_arm_closed_dense(z_arm, aperture, grasp):
    """R_lift,closed = R_lift · R_grasp."""
    return lift_arm(z_arm) * grasp_dense(aperture, grasp)


def lift_object_sparse(z_object):
    """Lift object (sparse): 1 iff z_object ≥ z_desired (0.18)."""
    xp = _xp(z_object)
    return (z_object >= LIFT_Z_DESIRED).astype(xp.asarray(z_object).dtype)


def hover_dense(p_top, p_bottom):
    """Eq. (hover): shaped tolerance on p_top - p_bottom - [0, 0, 0.04]."""
    xp = _xp(p_top, p_bottom)
    delta = p_top - p_bottom - xp.asarray(HOVER_OFFSET, dtype=p_top.dtype)
    return _shaped(_scaled_norm(delta, HOVER_TOL, xp), HOVER_EPSILON, xp)


def stack_sparse(p_top, p_bottom, grasp):
    """R_stack: d_xy ≤ 0.03 and |d_z - 0.04| ≤ 0.01 and the grasp sensor is off."""
    xp = _xp(p_top, p_bottom, grasp)
    d_xy = xp.sqrt(xp.sum((p_top[..., :2] - p_bottom[..., :2]) ** 2, axis=-1))
    d_z = p_top[..., 2] - p_bottom[..., 2]
    ok = (d_xy <= STACK_TOL_XY) & (xp.abs(d_z - STACK_D_DESIRED) <= STACK_TOL_Z) & (grasp == 0)
    return ok.astype(p_top.dtype)


def stack_leave_sparse(p_top, p_bottom, grasp, p_gripper):
    """R_stack,leave = R_stack · (1 - R_reach,sparse(top))."""
    return stack_sparse(p_top, p_bottom, grasp) * (1.0 - reach_sparse(p_gripper, p_top))


def pyramid_sparse(p_top, p_bottom_a, p_bottom_b, grasp):
    """R_pyramid: bottoms within 0.08 (xy); top over their mean within 0.03 (xy), 0.04 ± 0.01 (z)."""
    xp = _xp(p_top, p_bottom_a, p_bottom_b, grasp)
    d_ab = xp.sqrt(xp.sum((p_bottom_a[..., :2] - p_bottom_b[..., :2]) ** 2, axis=-1))
    p_bottom = 0.5 * (p_bottom_a + p_bottom_b)
    return stack_sparse(p_top, p_bottom, grasp) * (d_ab <= PYRAMID_TOL_XY_BOTTOM).astype(p_top.dtype)


def pyramid_leave_sparse(p_top, p_bottom_a, p_bottom_b, grasp, p_gripper):
    """R_pyramid,leave = R_pyramid · (1 - R_reach,sparse(top))."""
    return pyramid_sparse(p_top, p_bottom_a, p_bottom_b, grasp) * (1.0 - reach_sparse(p_gripper, p_top))


def triple_stack_leave_sparse(p_top, p_middle, p_bottom, grasp, p_gripper):
    """R_triple,stack,leave = R_stack(top, middle) · R_stack(middle, bottom) · (1 - R_reach,sparse(top))."""
    return (
        stack_sparse(p_top, p_middle, grasp)
        * stack_sparse(p_middle, p_bottom, grasp)
        * (1.0 - reach_sparse(p_gripper, p_top))
    )
