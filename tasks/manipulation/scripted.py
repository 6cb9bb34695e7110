"""Scripted controllers for every skill of the paper's skill table (App. C, Table "Skills") and
for the four sparse tasks.

Each controller is a *stateless* pure function ``fn(obs [OBS_SIZE], key) -> action [5]`` in
[-1, 1]: its phase is read off the observation (grasp flag, cube poses), so it is a Markov policy
like any learned skill and can be wrapped with ``parallel_skills.Skill.from_fn``. It acts on one
observation; ``jax.vmap`` it for a batch. Works on every physics backend sharing ``layout``;
``ControllerParams`` holds the gains a physics backend may need to adapt.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable

import jax
import jax.numpy as jnp

from tasks.manipulation import geometry as G
from tasks.manipulation import layout as L


@dataclasses.dataclass(frozen=True)
class ControllerParams:
    # Proportional gains (1 = deadbeat on the kinematic domain). Below 1 the commands are smooth
    # functions of the observation over a band of ~step/gain around each target, not bang-bang.
    gain: float = 0.3
    yaw_gain: float = 0.3
    xy_tol: float = 0.004  # aligned over a target when within this (m)
    yaw_tol: float = 0.05  # rad
    z_tol: float = 0.004
    clearance: float = 0.012  # fingertips / held cube clear other cubes by this (m)
    carry_z: float = 0.22  # lift target height of the pinch
    release_gap: float = 0.004  # open when the held cube is this close above its resting height
    funnel_slope: float = 10.0  # approach: allowed pinch height above the cube per m of xy error
    funnel_yaw: float = 0.3  # ... and per rad of yaw error
    avoid_neighbours: bool = False  # grasp yaw: nearest alignment (False) or clear of other cubes


Controller = Callable[[jax.Array, jax.Array], jax.Array]


# --- reading the observation ----------------------------------------------------------------
class _View:
    def __init__(self, obs):
        self.p = obs[L.PINCH_POS]
        self.yaw = obs[L.YAW]
        self.ap = obs[L.FINGER]
        self.grasp = obs[L.GRASP] > 0.5
        self.cubes = jnp.stack([obs[L.cube_pos(n)] for n in L.CUBE_NAMES])  # [3, 3]
        quats = jnp.stack([obs[L.cube_quat(n)] for n in L.CUBE_NAMES])
        self.cube_yaw = 2.0 * jnp.arctan2(quats[:, 3], quats[:, 0])
        rel = jnp.stack([obs[L.cube_rel_pos(n)] for n in L.CUBE_NAMES])
        # The held cube sits between the pads: within a couple of cm of the pinch.
        self.near = jnp.linalg.norm(rel, axis=-1) < 0.025

    def holding(self, c: int):
        return self.grasp & self.near[c]

    def top(self, exclude=()):
        """Highest cube top, excluding the given cube indices (floor = 0)."""
        mask = jnp.array([i not in exclude for i in range(L.NUM_CUBES)])
        return jnp.max(jnp.where(mask, self.cubes[:, 2] + L.CUBE_HALF, 0.0))


def _action(v: _View, target_p, target_yaw, finger, prm: ControllerParams):
    """Proportional velocity command toward (target_p, target_yaw); finger in {-1, 0, 1}."""
    step = L.MAX_LINEAR_SPEED * L.CONTROL_DT
    lin = jnp.clip(prm.gain * (target_p - v.p) / step, -1.0, 1.0)
    yaw_err = G.wrap_angle(target_yaw - v.yaw)
    ang = jnp.clip(prm.yaw_gain * yaw_err / (L.MAX_YAW_RATE * L.CONTROL_DT), -1.0, 1.0)
    return jnp.concatenate([lin, ang[None], jnp.asarray(finger, jnp.float32)[None]])


def _aligned_yaw(v: _View, cube_yaw):
    """Gripper yaw that aligns the pads with a cube's faces (nearest of the four)."""
    return v.yaw + G.wrap_quarter(cube_yaw - v.yaw)


def _grasp_yaw(v: _View, c: int, prm: ControllerParams):
    """Gripper yaw for grasping cube c. ``prm.avoid_neighbours`` False: the nearest yaw that
    aligns the pads with its faces (a sawtooth of the relative yaw, simple to imitate). True: of
    the two pad orientations that align with its faces, the one whose pads stay farther from the
    other cubes (safer among cubes, but a discontinuous function of all cube positions, which
    neural policies imitate poorly)."""
    if not prm.avoid_neighbours:
        return _aligned_yaw(v, v.cube_yaw[c])
    cube = v.cubes[c]
    base = G.wrap_quarter(v.cube_yaw[c])
    others = jnp.array([i != c for i in range(L.NUM_CUBES)])

    def clearance(theta):
        normal = jnp.stack([-jnp.sin(theta), jnp.cos(theta)])
        off = 0.5 * PREGRASP_APERTURE + L.FINGER_THICKNESS
        pads = jnp.stack([cube[:2] + off * normal, cube[:2] - off * normal])  # [2, 2]
        d = jnp.linalg.norm(pads[:, None, :] - v.cubes[None, :, :2], axis=-1)  # [2, 3]
        return jnp.min(jnp.where(others[None], d, 1.0))

    theta = jnp.where(clearance(base) >= clearance(base + jnp.pi / 2) - 1e-3, base, base + jnp.pi / 2)
    # Pads are symmetric: θ and θ + π are the same grasp; take the nearer one.
    return v.yaw + (G.wrap_angle(2.0 * (theta - v.yaw)) / 2.0)


PREGRASP_APERTURE = 0.056  # open just enough to pass around a cube: a small footprint


def _approach(v: _View, c: int, prm: ControllerParams, close: bool):
    """Approach cube c down a funnel and grasp-align; close the fingers there if ``close``.

    The pinch heads for the cube centre while its height stays above a funnel that rises with
    the horizontal and yaw misalignment (``funnel_slope`` m/m, ``funnel_yaw`` m/rad), capped at a
    safe travel height: far away it travels high, over the cube it descends. Unlike a phase
    machine (rise, travel, align, descend), every command is a continuous function of the
    observation (up to the closing switch), which a neural policy can imitate (see
    docs/research/skills.md)."""
    cube = v.cubes[c]
    yaw_t = _grasp_yaw(v, c, prm)
    safe_z = jnp.maximum(v.top() + L.FINGER_BELOW_PINCH + prm.clearance, cube[2] + 0.045)
    dxy = jnp.linalg.norm(cube[:2] - v.p[:2])
    yaw_err = jnp.abs(G.wrap_angle(yaw_t - v.yaw))
    funnel = cube[2] + prm.funnel_slope * jnp.maximum(dxy - prm.xy_tol, 0.0) \
        + prm.funnel_yaw * jnp.maximum(yaw_err - prm.yaw_tol, 0.0)
    target = jnp.concatenate([cube[:2], jnp.minimum(funnel, safe_z)[None]])
    at_cube = (dxy <= prm.xy_tol) & (yaw_err <= prm.yaw_tol) & (jnp.abs(v.p[2] - cube[2]) <= prm.z_tol)
    finger = jnp.clip((PREGRASP_APERTURE - v.ap) / (L.MAX_FINGER_SPEED * L.CONTROL_DT), -1.0, 1.0)
    finger = jnp.where(at_cube & close, -1.0, finger)
    return _action(v, target, yaw_t, finger, prm)


def _place(v: _View, c: int, target_xy, target_z, target_cube_yaw, prm: ControllerParams, release: bool,
           grip_axis=None):
    """Carry held cube c so that its centre reaches (target_xy, target_z) with the given yaw;
    open the fingers there if ``release``. ``grip_axis``: the gripper's x axis direction (mod π)."""
    cube = v.cubes[c]
    d_cube_yaw = G.wrap_quarter(target_cube_yaw - v.cube_yaw[c])
    yaw_t = v.yaw + d_cube_yaw
    if grip_axis is not None:
        yaw_t = v.yaw + G.wrap_angle(2.0 * (grip_axis - v.yaw)) / 2.0
    safe_cube_z = jnp.maximum(v.top(exclude=(c,)) + L.CUBE_HALF + prm.clearance, target_z)
    dxy_vec = target_xy - cube[:2]
    over = (jnp.linalg.norm(dxy_vec) <= prm.xy_tol) & (jnp.abs(d_cube_yaw) <= prm.yaw_tol)
    low = cube[2] < safe_cube_z - 0.01
    # Pinch targets that put the cube where we want it.
    travel_xy = jnp.where(low, v.p[:2], v.p[:2] + dxy_vec)
    travel = jnp.concatenate([travel_xy, (v.p[2] + safe_cube_z - cube[2])[None]])
    descend = jnp.concatenate([v.p[:2] + dxy_vec, (v.p[2] + target_z - cube[2])[None]])
    arrived = over & (cube[2] - target_z <= prm.release_gap)
    target = jnp.where(over, descend, travel)
    finger = jnp.where(arrived & release, 1.0, -1.0)
    return _action(v, target, yaw_t, finger, prm)


def _leave(v: _View, c: int, prm: ControllerParams):
    """Open the fingers and rise above cube c (out of the reach tolerance)."""
    target = jnp.concatenate([v.p[:2], (v.cubes[c, 2] + 0.08)[None]])
    return _action(v, target, v.yaw, 1.0, prm)


def _drop_other(v: _View, prm: ControllerParams):
    """Holding the wrong cube: open the fingers (it settles) and rise a little."""
    target = jnp.concatenate([v.p[:2], (v.p[2] + 0.02)[None]])
    return _action(v, target, v.yaw, 1.0, prm)


def _select(cases):
    """First action whose condition holds; the last case is the default. cases: [(cond, action)]."""
    out = cases[-1][1]
    for cond, act in reversed(cases[:-1]):
        out = jnp.where(cond, act, out)
    return out


def _holding_other(v: _View, c: int):
    return v.grasp & ~v.near[c]


def _on(v: _View, top: int, bottom: int, xy_tol=0.01, z_tol=0.006):
    d = v.cubes[top] - v.cubes[bottom]
    return (jnp.linalg.norm(d[:2]) <= xy_tol) & (jnp.abs(d[2] - L.CUBE_SIZE) <= z_tol)


# --- skills -------------------------------------------------------------------------------------
def reach(c: int, prm: ControllerParams, obs, key):
    """Reach cube c: pinch at its centre, pads aligned, fingers open (the pre-grasp pose)."""
    v = _View(obs)
    return _select([(v.grasp, _drop_other(v, prm)), (True, _approach(v, c, prm, close=False))])


def open_fingers(prm: ControllerParams, obs, key):
    v = _View(obs)
    return _action(v, v.p, v.yaw, 1.0, prm)


def lift_arm(open_: bool, prm: ControllerParams, obs, key):
    """Lift the arm to ``carry_z`` with open fingers, or close the fingers first, then lift."""
    v = _View(obs)
    up = jnp.concatenate([v.p[:2], jnp.array([prm.carry_z])])
    if open_:
        return _action(v, up, v.yaw, 1.0, prm)
    closing = (v.ap > L.CUBE_SIZE + 0.001) & ~v.grasp
    return jnp.where(closing, _action(v, v.p, v.yaw, -1.0, prm), _action(v, up, v.yaw, -1.0, prm))


def lift(c: int, prm: ControllerParams, obs, key):
    """Lift cube c above 0.18 m (sparse lift): grasp it, then raise the pinch to ``carry_z``."""
    v = _View(obs)
    up = jnp.concatenate([v.p[:2], jnp.array([prm.carry_z])])
    return _select(
        [
            (v.holding(c), _action(v, up, v.yaw, -1.0, prm)),
            (_holding_other(v, c), _drop_other(v, prm)),
            (True, _approach(v, c, prm, close=True)),
        ]
    )


def _stack_phase(v: _View, top: int, bottom: int, prm: ControllerParams, release: bool):
    target_z = v.cubes[bottom, 2] + L.CUBE_SIZE + (0.0 if release else 0.005)
    return _select(
        [
            (v.holding(top), _place(v, top, v.cubes[bottom, :2], target_z, v.cube_yaw[bottom], prm, release)),
            (_holding_other(v, top), _drop_other(v, prm)),
            (True, _approach(v, top, prm, close=True)),
        ]
    )


def hover(top: int, bottom: int, prm: ControllerParams, obs, key):
    """Hold cube ``top`` just above cube ``bottom`` (dense hover reward)."""
    return _stack_phase(_View(obs), top, bottom, prm, release=False)


def stack(top: int, bottom: int, prm: ControllerParams, obs, key):
    """Stack ``top`` on ``bottom``, release, and leave (sparse stack-and-leave)."""
    v = _View(obs)
    done = _on(v, top, bottom) & ~v.grasp
    return _select([(done, _leave(v, top, prm)), (True, _stack_phase(v, top, bottom, prm, release=True))])


def triple_stack(prm: ControllerParams, obs, key):
    """Yellow on blue, then green on yellow, then leave."""
    g, y, b = (L.CUBE_INDEX[n] for n in ("green", "yellow", "blue"))
    v = _View(obs)
    base = _on(v, y, b) & ~v.holding(y)
    return _select(
        [
            (base & _on(v, g, y) & ~v.grasp, _leave(v, g, prm)),
            (base, _stack_phase(v, g, y, prm, release=True)),
            (True, _stack_phase(v, y, b, prm, release=True)),
        ]
    )


PYRAMID_GAP = 0.046  # centre distance of the two bottom cubes (side by side, 6 mm apart)


def pyramid(prm: ControllerParams, obs, key):
    """Put yellow beside blue (faces aligned), then green on top of both, then leave."""
    g, y, b = (L.CUBE_INDEX[n] for n in ("green", "yellow", "blue"))
    v = _View(obs)
    # Yellow goes next to blue along one of blue's face normals, carried with the gripper's x axis
    # along that normal (the pads never pass between the cubes): of the four sides, the one
    # farthest from green and the basket walls.
    angles = v.cube_yaw[b] + jnp.arange(4) * (jnp.pi / 2)
    dirs = jnp.stack([jnp.cos(angles), jnp.sin(angles)], axis=-1)  # [4, 2]
    spots = v.cubes[b, :2] + PYRAMID_GAP * dirs
    wall = (L.BASKET_HALF - L.CUBE_HALF * 1.5) - jnp.max(jnp.abs(spots), axis=-1)
    from_green = jnp.linalg.norm(spots - v.cubes[g, :2], axis=-1) - 0.07
    side = jnp.argmax(jnp.minimum(wall, from_green))
    beside_xy, grip_axis = spots[side], angles[side]
    d_yb = v.cubes[y] - v.cubes[b]
    base_ok = (
        (jnp.linalg.norm(d_yb[:2]) <= 0.06)
        & (jnp.abs(d_yb[2]) <= 0.004)
        & (v.cubes[y, 2] < L.CUBE_HALF + 0.004)
        & ~v.holding(y)
    )
    mid = 0.5 * (v.cubes[y] + v.cubes[b])
    d_g = v.cubes[g] - mid
    top_ok = (jnp.linalg.norm(d_g[:2]) <= 0.01) & (jnp.abs(d_g[2] - L.CUBE_SIZE) <= 0.006) & ~v.grasp
    place_yellow = _select(
        [
            (v.holding(y), _place(v, y, beside_xy, jnp.asarray(L.CUBE_HALF), v.cube_yaw[b], prm, True, grip_axis)),
            (_holding_other(v, y), _drop_other(v, prm)),
            (True, _approach(v, y, prm, close=True)),
        ]
    )
    place_green = _select(
        [
            (v.holding(g), _place(v, g, mid[:2], mid[2] + L.CUBE_SIZE, v.cube_yaw[b], prm, True)),
            (_holding_other(v, g), _drop_other(v, prm)),
            (True, _approach(v, g, prm, close=True)),
        ]
    )
    return _select([(base_ok & top_ok, _leave(v, g, prm)), (base_ok, place_green), (True, place_yellow)])


# --- registry -----------------------------------------------------------------------------------
def _registry() -> dict[str, Callable[..., jax.Array]]:
    reg: dict[str, Callable] = {
        "open_fingers": open_fingers,
        "lift_arm_open": functools.partial(lift_arm, True),
        "lift_arm_closed": functools.partial(lift_arm, False),
        "pyramid": pyramid,
        "triple_stack": triple_stack,
    }
    for name, c in L.CUBE_INDEX.items():
        reg[f"reach_{name}"] = functools.partial(reach, c)
        reg[f"lift_{name}"] = functools.partial(lift, c)
        for other, d in L.CUBE_INDEX.items():
            if d != c:
                reg[f"hover_{name}_on_{other}"] = functools.partial(hover, c, d)
                reg[f"stack_{name}_on_{other}"] = functools.partial(stack, c, d)
    reg["lift"] = reg["lift_green"]
    reg["stack"] = reg["stack_green_on_yellow"]
    return reg


_REGISTRY = _registry()


def names() -> list[str]:
    return sorted(_REGISTRY)


def get(name: str, params: ControllerParams | None = None) -> Controller:
    """The scripted controller ``name`` as a pure ``fn(obs, key) -> action``."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown scripted controller {name!r}; valid: {', '.join(names())}")
    prm = params or ControllerParams()
    fn = _REGISTRY[name]

    def controller(obs, key=None):
        return fn(prm, obs, key)

    controller.__name__ = f"scripted_{name}"
    return controller
