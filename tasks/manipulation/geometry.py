"""Yaw-only box geometry in pure JAX: poses, quaternions and separating-axis overlap tests.

Every box here is rotated about the world z axis only (cubes resting or held, finger pads), so
two boxes overlap iff their z intervals overlap and their xy footprints (rotated rectangles)
overlap, which the separating axis theorem decides with the four edge normals.
"""

from __future__ import annotations

import jax.numpy as jnp


def yaw_quat(yaw):
    """Quaternion (w, x, y, z) of a rotation by ``yaw`` about z. yaw [...] -> [..., 4]."""
    half = 0.5 * yaw
    zero = jnp.zeros_like(yaw)
    return jnp.stack([jnp.cos(half), zero, zero, jnp.sin(half)], axis=-1)


def rotate_xy(vec, cos, sin):
    """Rotate the xy part of vec [..., 3] by the angle with cosine/sine [...]."""
    x = cos * vec[..., 0] - sin * vec[..., 1]
    y = sin * vec[..., 0] + cos * vec[..., 1]
    return jnp.stack([x, y, vec[..., 2]], axis=-1)


def wrap_angle(angle):
    """Wrap to [-π, π)."""
    return (angle + jnp.pi) % (2 * jnp.pi) - jnp.pi


def wrap_quarter(angle):
    """Wrap to [-π/4, π/4): the yaw misalignment of a square's faces."""
    q = jnp.pi / 2
    return (angle + q / 2) % q - q / 2


def boxes_overlap(c1, h1, cs1, c2, h2, cs2, eps):
    """True where two z-rotated boxes interpenetrate by more than ``eps``.

    c [..., 3] centres, h [..., 3] half extents, cs [..., 2] (cos yaw, sin yaw) of each box.
    Broadcasts over leading axes. Returns bool [...].
    """
    d = c2 - c1
    z_overlap = jnp.abs(d[..., 2]) < h1[..., 2] + h2[..., 2] - eps
    u1 = cs1
    v1 = jnp.stack([-cs1[..., 1], cs1[..., 0]], axis=-1)
    u2 = cs2
    v2 = jnp.stack([-cs2[..., 1], cs2[..., 0]], axis=-1)
    dxy = d[..., :2]

    def dot(a, b):
        return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]

    # Cross terms |u1·u2| etc. are shared between axes.
    uu = jnp.abs(dot(u1, u2))
    uv = jnp.abs(dot(u1, v2))
    vu = jnp.abs(dot(v1, u2))
    vv = jnp.abs(dot(v1, v2))
    h1x, h1y, h2x, h2y = h1[..., 0], h1[..., 1], h2[..., 0], h2[..., 1]
    sep_u1 = jnp.abs(dot(dxy, u1)) >= h1x + h2x * uu + h2y * uv - eps
    sep_v1 = jnp.abs(dot(dxy, v1)) >= h1y + h2x * vu + h2y * vv - eps
    sep_u2 = jnp.abs(dot(dxy, u2)) >= h2x + h1x * uu + h1y * vu - eps
    sep_v2 = jnp.abs(dot(dxy, v2)) >= h2y + h1x * uv + h1y * vv - eps
    return z_overlap & ~(sep_u1 | sep_v1 | sep_u2 | sep_v2)
