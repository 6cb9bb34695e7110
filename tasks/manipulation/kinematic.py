"""Kinematic blocks domain: the manipulation domain of the paper's App. C without a physics engine.

Pure JAX, jittable and vmappable, with the observation layout, action semantics, task names and
reward functions of every other backend (``layout``, ``rewards``, ``task_defs``).

Model (one agent step, dt = 0.05 s):
  1. Fingers move by ``action[4]·MAX_FINGER_SPEED·dt``. Closing onto a cube that sits between the
     pads (centred within ``GRASP_TOL_XY`` / ``GRASP_TOL_Z`` in the pinch frame, faces aligned
     within ``GRASP_TOL_YAW``) grasps it on the step a pad would reach it: the pads stop at the
     cube's width and the cube is centred and aligned between them (if that does not push it, or
     the pads at its width, into another cube). Any other finger motion that would make a pad
     penetrate a cube is blocked.
     Opening past the cube's width releases a held cube, which settles (see 3), unless it would
     settle into the gripper (a pad holds it back: the fingers stay at its width).
  2. The pinch moves by the commanded Cartesian velocity and the wrist turns by the yaw rate,
     carrying a held cube. A move that would make a finger pad, the palm or the held cube
     penetrate a cube (or the held cube the floor) is replaced by its horizontal-only part, else
     its vertical-only part, else no motion: the gripper never passes through cubes.
  3. A released cube falls onto the highest support under it: the floor, or the cubes whose
     footprints overlap its own. It rests there if its centre lies over a support (over one cube's
     footprint, or between two supporting cubes); otherwise it slides off beside the support and
     falls again. Cubes never interpenetrate (a property test checks it).

The grasp flag is the paper's grasp sensor: 1 while a cube is held.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import State
from flax import struct

from tasks.manipulation import geometry as G
from tasks.manipulation import layout as L
from tasks.manipulation.env_base import ManipulationEnv
from tasks.manipulation import skill_starts
from tasks.manipulation import task_defs

EPS = 1e-4  # penetration tolerance of the overlap tests (m)
GRASP_TOL_XY = 0.01  # cube centre within 1 cm of the pinch, horizontally (pinch frame)
GRASP_TOL_Z = 0.015  # and within 1.5 cm vertically
GRASP_TOL_YAW = 0.35  # faces aligned with the pads within 0.35 rad (mod π/2)
RESET_CUBE_RANGE = 0.08  # cube centres uniform in [-0.08, 0.08]² at reset
RESET_MIN_DIST = 0.062  # > cube diagonal (0.0566): no overlap whatever the yaws
RESET_TRIES = 32

_CUBE_H = jnp.array([L.CUBE_HALF] * 3)


@struct.dataclass
class KinematicState:
    """Full state of one environment. pinch [3]; yaw, aperture []; vel [5] (last step's rates of
    x, y, z, yaw, aperture); cube_pos [3, 3]; cube_yaw [3]; held [] int32 (cube index, -1 none)."""

    pinch: jax.Array
    yaw: jax.Array
    aperture: jax.Array
    vel: jax.Array
    cube_pos: jax.Array
    cube_yaw: jax.Array
    held: jax.Array


def _cs(yaw):
    return jnp.stack([jnp.cos(yaw), jnp.sin(yaw)], axis=-1)


def _gripper_boxes(pinch, yaw, aperture):
    """Finger pads and palm as boxes: centres [3, 3], half extents [3, 3], (cos, sin) [2]."""
    cs = _cs(yaw)
    off_y = 0.5 * aperture + 0.5 * L.FINGER_THICKNESS
    z_mid = 0.5 * (L.FINGER_ABOVE_PINCH - L.FINGER_BELOW_PINCH)
    z_half = 0.5 * (L.FINGER_ABOVE_PINCH + L.FINGER_BELOW_PINCH)
    local = jnp.stack(
        [
            jnp.stack([0.0, off_y, z_mid]),
            jnp.stack([0.0, -off_y, z_mid]),
            jnp.stack([0.0, 0.0, L.FINGER_ABOVE_PINCH + 0.005]),
        ]
    )
    centres = pinch + G.rotate_xy(local, cs[0], cs[1])
    pad_h = jnp.stack([0.5 * L.FINGER_WIDTH, 0.5 * L.FINGER_THICKNESS, z_half])
    palm_h = jnp.stack([0.5 * L.FINGER_WIDTH, off_y + 0.5 * L.FINGER_THICKNESS, 0.005 + 0.0 * aperture])
    halves = jnp.stack([pad_h, pad_h, palm_h])
    return centres, halves, cs


def gripper_hits_cubes(pinch, yaw, aperture, cube_pos, cube_cs, ignore):
    """True if a finger pad or the palm penetrates a cube other than ``ignore`` (bool [3])."""
    centres, halves, cs = _gripper_boxes(pinch, yaw, aperture)
    hit = G.boxes_overlap(
        centres[:, None, :], halves[:, None, :], cs[None, None, :],
        cube_pos[None, :, :], _CUBE_H[None, None, :], cube_cs[None, :, :], EPS,
    )  # [3 boxes, 3 cubes]
    return jnp.any(hit & ~ignore[None, :])


def _cube_hits_cubes(index, pos, cs, cube_pos, cube_cs):
    """True if a cube at (pos, cs) penetrates another cube than ``index``, or the floor."""
    hit = G.boxes_overlap(pos[None], _CUBE_H[None], cs[None], cube_pos, _CUBE_H[None], cube_cs, EPS)
    others = jnp.arange(L.NUM_CUBES) != index
    below_floor = pos[2] - L.CUBE_HALF < -EPS
    return jnp.any(hit & others) | below_floor


def _config_blocked(pinch, yaw, aperture, held, rel_pos, rel_yaw, cube_pos, cube_yaw):
    """Whether a gripper pose (carrying cube ``held`` at ``rel_pos`` / ``rel_yaw`` in the pinch
    frame) penetrates something. Returns (blocked, held cube position [3], held cube yaw [])."""
    cube_cs = _cs(cube_yaw)
    holding = held >= 0
    idx = jnp.maximum(held, 0)
    cs = _cs(yaw)
    hpos = pinch + G.rotate_xy(rel_pos, cs[0], cs[1])
    hyaw = yaw + rel_yaw
    is_held = (jnp.arange(L.NUM_CUBES) == held) & holding
    blocked = gripper_hits_cubes(pinch, yaw, aperture, cube_pos, cube_cs, is_held)
    blocked = blocked | (holding & _cube_hits_cubes(idx, hpos, _cs(hyaw), cube_pos, cube_cs))
    return blocked, hpos, hyaw


def _pinch_frame(pinch, yaw, pos):
    """Positions [..., 3] in the pinch frame."""
    return G.rotate_xy(pos - pinch, jnp.cos(yaw), -jnp.sin(yaw))


def settle(index, cube_pos, cube_yaw):
    """Drop cube ``index`` onto the highest support under it (App.: blocks can stack and fall)."""
    cube_cs = _cs(cube_yaw)
    others = jnp.arange(L.NUM_CUBES) != index

    def rest_height(xy):
        pos = jnp.concatenate([xy, jnp.array([L.CUBE_HALF])])
        tall = pos.at[2].set(0.5)  # a column from the floor up: footprint overlap only
        h = jnp.array([L.CUBE_HALF, L.CUBE_HALF, 0.5])
        over = G.boxes_overlap(tall[None], h[None], cube_cs[index][None], cube_pos, _CUBE_H[None], cube_cs, EPS)
        over = over & others
        tops = jnp.where(over, cube_pos[:, 2] + L.CUBE_HALF, 0.0)
        return jnp.max(tops) + L.CUBE_HALF, over, tops

    xy = cube_pos[index, :2]
    z, over, tops = rest_height(xy)
    on_floor = z <= L.CUBE_HALF + 1e-6
    support = over & (tops >= z - L.CUBE_HALF - 1e-3)
    # Over one support's footprint?
    local = _pinch_frame_xy(cube_pos[:, :2], cube_yaw, xy)  # [3, 2] centre in each cube's frame
    inside = jnp.all(jnp.abs(local) <= L.CUBE_HALF, axis=-1) & support
    # Between two supports (the two other cubes)?
    a_i, b_i = _other_two(index)
    pa, pb = cube_pos[a_i, :2], cube_pos[b_i, :2]
    seg = pb - pa
    t = jnp.clip(jnp.dot(xy - pa, seg) / jnp.maximum(jnp.dot(seg, seg), 1e-9), 0.0, 1.0)
    between = support[a_i] & support[b_i] & (jnp.linalg.norm(pa + t * seg - xy) <= L.CUBE_HALF)
    stable = on_floor | jnp.any(inside) | between
    # Unstable: slide off beside the supports, away from their centroid, and fall again.
    w = support.astype(jnp.float32)
    centroid = jnp.sum(cube_pos[:, :2] * w[:, None], axis=0) / jnp.maximum(jnp.sum(w), 1.0)
    away = xy - centroid
    away = away / jnp.maximum(jnp.linalg.norm(away), 1e-6)
    slid_xy = centroid + away * (2 * L.CUBE_HALF * jnp.sqrt(2.0) + 0.002)
    slid_xy = jnp.clip(slid_xy, -L.BASKET_HALF + L.CUBE_HALF * 1.42, L.BASKET_HALF - L.CUBE_HALF * 1.42)
    slid_z, _, _ = rest_height(slid_xy)
    new_xy = jnp.where(stable, xy, slid_xy)
    new_z = jnp.where(stable, z, slid_z)
    return cube_pos.at[index].set(jnp.concatenate([new_xy, new_z[None]]))


def _pinch_frame_xy(centres, yaws, point):
    """``point`` [2] expressed in the frames of boxes at ``centres`` [n, 2] with ``yaws`` [n]."""
    d = point[None, :] - centres
    c, s = jnp.cos(yaws), jnp.sin(yaws)
    return jnp.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=-1)


def _other_two(index):
    a = jnp.where(index == 0, 1, 0)
    b = jnp.where(index == 2, 1, 2)
    return a, b


def dynamics(s: KinematicState, action: jax.Array) -> KinematicState:
    """One agent step of the kinematic model (module docstring). action [5] in [-1, 1]."""
    dt = L.CONTROL_DT
    action = jnp.clip(jnp.where(jnp.isfinite(action), action, 0.0), -1.0, 1.0)
    lo, hi = jnp.array(L.WORKSPACE_LOW), jnp.array(L.WORKSPACE_HIGH)
    holding = s.held >= 0
    cube_cs = _cs(s.cube_yaw)

    # Held cube in the pinch frame (zero when nothing is held).
    idx = jnp.maximum(s.held, 0)
    rel_pos = jnp.where(holding, _pinch_frame(s.pinch, s.yaw, s.cube_pos[idx]), 0.0)
    rel_yaw = jnp.where(holding, s.cube_yaw[idx] - s.yaw, 0.0)

    # 1. Fingers.
    ap_cmd = jnp.clip(s.aperture + action[4] * L.MAX_FINGER_SPEED * dt, L.APERTURE_CLOSED, L.APERTURE_OPEN)
    closing = ap_cmd < s.aperture
    # Opening the pads releases the held cube, unless they would open into another cube, or the
    # cube would settle into the gripper (a cube sliding off its supports is held back by a pad).
    # ``settled`` moves the held cube alone, so one test covers both: the open pads against the
    # other cubes where they are and the held one where it would come to rest.
    settled = settle(idx, s.cube_pos, s.cube_yaw)
    release = holding & (ap_cmd > L.CUBE_SIZE + 1e-6) & ~gripper_hits_cubes(
        s.pinch, s.yaw, ap_cmd, settled, cube_cs, jnp.zeros(L.NUM_CUBES, bool))
    # Grasp candidates: cubes centred and aligned between the pads.
    rel_all = _pinch_frame(s.pinch, s.yaw, s.cube_pos)  # [3, 3]
    misalign = G.wrap_quarter(s.cube_yaw - s.yaw)
    graspable = (
        (jnp.abs(rel_all[:, 0]) <= GRASP_TOL_XY)
        & (jnp.abs(rel_all[:, 1]) <= GRASP_TOL_XY)
        & (jnp.abs(rel_all[:, 2]) <= GRASP_TOL_Z)
        & (jnp.abs(misalign) <= GRASP_TOL_YAW)
    )
    g = jnp.argmax(graspable)
    # The pads centre and align the cube (pinch frame: y = 0, faces parallel to the pads).
    snap_rel = rel_all[g].at[1].set(0.0)
    snap_yaw = s.yaw + jnp.round((s.cube_yaw[g] - s.yaw) / (jnp.pi / 2)) * (jnp.pi / 2)
    cs = _cs(s.yaw)
    snap_pos = s.pinch + G.rotate_xy(snap_rel, cs[0], cs[1])
    snap_ok = ~_cube_hits_cubes(g, snap_pos, _cs(snap_yaw), s.cube_pos, cube_cs)
    # The closing step grasps once a pad would reach the cube: the first pad to touch pushes it to
    # the centre while the other closes on it. (Requiring the commanded aperture itself to reach the
    # cube's width would trap an off-centre cube: the pads stop at first contact, above that width.)
    pad_reaches = (ap_cmd <= L.CUBE_SIZE) | gripper_hits_cubes(
        s.pinch, s.yaw, ap_cmd, s.cube_pos, cube_cs, jnp.arange(L.NUM_CUBES) != g)
    # The pads closed on the snapped cube must not enter another cube (a corner of one poking in
    # between the pads stops them first: no grasp, and the free closing below is blocked).
    # (Cube g itself is ignored, so its pose before or after the snap does not matter.)
    pads_clear = ~gripper_hits_cubes(s.pinch, s.yaw, jnp.asarray(L.CUBE_SIZE), s.cube_pos, cube_cs,
                                     jnp.arange(L.NUM_CUBES) == g)
    grasp_now = (~holding) & closing & pad_reaches & graspable[g] & snap_ok & pads_clear

    cube_pos = jnp.where(grasp_now, s.cube_pos.at[g].set(snap_pos), s.cube_pos)
    cube_yaw = jnp.where(grasp_now, s.cube_yaw.at[g].set(snap_yaw), s.cube_yaw)
    held = jnp.where(grasp_now, g, jnp.where(release, -1, s.held))
    rel_pos = jnp.where(grasp_now, snap_rel, rel_pos)
    rel_yaw = jnp.where(grasp_now, snap_yaw - s.yaw, rel_yaw)

    # Free finger motion (not grasping, not releasing, not held): blocked by cubes.
    free_ap_blocked = gripper_hits_cubes(
        s.pinch, s.yaw, ap_cmd, cube_pos, _cs(cube_yaw), jnp.zeros(L.NUM_CUBES, bool)
    )
    aperture = jnp.where(
        grasp_now | (holding & ~release),
        L.CUBE_SIZE,
        jnp.where(release | ~free_ap_blocked, ap_cmd, s.aperture),
    )
    # A release drops the cube before the gripper moves on (no grasp this step: cube_pos is s.cube_pos).
    cube_pos = jnp.where(release, settled, cube_pos)

    # 2. Gripper translation and yaw, carrying the held cube.
    dp = action[:3] * L.MAX_LINEAR_SPEED * dt
    dyaw = action[3] * L.MAX_YAW_RATE * dt
    candidates_dp = jnp.stack([dp, dp * jnp.array([1.0, 1.0, 0.0]), dp * jnp.array([0.0, 0.0, 1.0])])
    candidates_dyaw = jnp.stack([dyaw, dyaw, 0.0])
    cand_pinch = jnp.clip(s.pinch[None] + candidates_dp, lo, hi)
    cand_yaw = G.wrap_angle(s.yaw + candidates_dyaw)  # continuous wrist joint
    blocked, hpos, hyaw = jax.vmap(_config_blocked, in_axes=(0, 0, None, None, None, None, None, None))(
        cand_pinch, cand_yaw, aperture, held, rel_pos, rel_yaw, cube_pos, cube_yaw
    )
    ok = ~blocked
    choice = jnp.argmax(ok)
    any_ok = jnp.any(ok)
    pinch = jnp.where(any_ok, cand_pinch[choice], s.pinch)
    yaw = jnp.where(any_ok, cand_yaw[choice], s.yaw)
    holding = held >= 0
    hidx = jnp.maximum(held, 0)
    cube_pos = jnp.where(holding & any_ok, cube_pos.at[hidx].set(hpos[choice]), cube_pos)
    cube_yaw = jnp.where(holding & any_ok, cube_yaw.at[hidx].set(hyaw[choice]), cube_yaw)
    cube_yaw = G.wrap_angle(cube_yaw)

    vel = jnp.concatenate([(pinch - s.pinch) / dt, (G.wrap_angle(yaw - s.yaw) / dt)[None], ((aperture - s.aperture) / dt)[None]])
    return KinematicState(pinch, yaw, aperture, vel, cube_pos, cube_yaw, held)


def observe(s: KinematicState) -> jax.Array:
    """Observation vector [OBS_SIZE] in the layout of ``layout``."""
    pinch_quat = G.yaw_quat(s.yaw)
    rel = _pinch_frame(s.pinch, s.yaw, s.cube_pos)
    parts = [
        s.pinch, s.yaw[None], s.vel[:4],
        s.pinch, pinch_quat,
        s.aperture[None], s.vel[4:5],
        (s.held >= 0).astype(jnp.float32)[None],
    ]
    for c in range(L.NUM_CUBES):
        parts += [s.cube_pos[c], G.yaw_quat(s.cube_yaw[c]), rel[c], G.yaw_quat(s.cube_yaw[c] - s.yaw)]
    return jnp.concatenate(parts).astype(jnp.float32)


def task_inputs(s: KinematicState) -> task_defs.Inputs:
    return task_defs.Inputs(s.pinch, s.aperture, (s.held >= 0).astype(jnp.float32), s.cube_pos)


def sample_initial_state(rng: jax.Array) -> KinematicState:
    """Gripper above the basket, fingers open; cubes at random non-overlapping floor poses
    (``START_STATES["table"]``)."""
    k_g, k_c, k_y = jax.random.split(rng, 3)
    pinch = jax.random.uniform(k_g, (3,), minval=jnp.array([-0.05, -0.05, 0.12]), maxval=jnp.array([0.05, 0.05, 0.18]))
    xy = jax.random.uniform(k_c, (RESET_TRIES, L.NUM_CUBES, 2), minval=-RESET_CUBE_RANGE, maxval=RESET_CUBE_RANGE)
    d = jnp.linalg.norm(xy[:, :, None, :] - xy[:, None, :, :], axis=-1) + jnp.eye(L.NUM_CUBES) * 1.0
    valid = jnp.all(d >= RESET_MIN_DIST, axis=(1, 2))
    fallback = jnp.array([[-0.06, -0.06], [0.0, 0.06], [0.06, -0.06]])
    xy = jnp.where(jnp.any(valid), xy[jnp.argmax(valid)], fallback)
    cube_pos = jnp.concatenate([xy, jnp.full((L.NUM_CUBES, 1), L.CUBE_HALF)], axis=-1)
    cube_yaw = jax.random.uniform(k_y, (L.NUM_CUBES,), minval=-jnp.pi / 4, maxval=jnp.pi / 4)
    return KinematicState(
        pinch=pinch,
        yaw=jnp.zeros(()),
        aperture=jnp.asarray(L.APERTURE_OPEN, jnp.float32),
        vel=jnp.zeros(5),
        cube_pos=cube_pos,
        cube_yaw=cube_yaw,
        held=jnp.asarray(-1, jnp.int32),
    )


# Reset distributions (``KinematicBlocks(start_states=...)``, ``training.run --start_states``):
START_STATES = {
    "table": "every cube on the floor, apart (the paper's resets)",
    "mixed": "a third as 'table'; a third with one cube resting on another (a random ordered pair, "
             "centred within 5 mm); a third with one cube beside another, faces touching within "
             "1-8 mm (the states a chain's later stages bring its skills to)",
}
# A chain's precondition: "TOP_on_BOTTOM" (each ordered pair of cubes), e.g. yellow_on_blue, the
# state stack_green_on_yellow starts from in triple stack.
PAIR_START_STATES = {f"{t}_on_{b}": (L.CUBE_INDEX[t], L.CUBE_INDEX[b])
                     for t in L.CUBE_NAMES for b in L.CUBE_NAMES if t != b}
for _name in list(PAIR_START_STATES):
    _t, _b = _name.split("_on_")
    START_STATES[_name] = (f"half as 'table'; half with {_t} resting on {_b} (centred within 5 mm): "
                           f"a chain's precondition for the skill that comes after")
    # "..._loose": the precondition as a learnt skill leaves it (the neural stack_yellow_on_blue
    # leaves yellow a median 12 mm off blue's centre, 0.4 rad turned, fingers closed: docs/research/skills.md).
    PAIR_START_STATES[_name + "_loose"] = PAIR_START_STATES[_name]
    START_STATES[_name + "_loose"] = (f"as {_name}, {_t}'s centre within 14 mm of {_b}'s (each axis), "
                                      f"turned by up to π/4, the fingers anywhere from closed to open")
START_STATES_ALLOWED = ("table, mixed, or TOP_on_BOTTOM of two of green, yellow, blue (e.g. yellow_on_blue), "
                        "or that with _loose (e.g. yellow_on_blue_loose), or after:NAME:K / after:NAME:KMIN-KMAX "
                        "(where library skill NAME leaves the table resets: tasks/manipulation/skill_starts.py)")
PAIR_TRIES = 8  # table resets tried for a pair's placement
ARRANGE_TABLE, ARRANGE_STACKED, ARRANGE_ADJACENT = 0, 1, 2
ADJACENT_GAP = (0.001, 0.008)  # m between the touching faces of an adjacent pair
STACKED_OFFSET = 0.005  # m, the top cube's centre within this of the bottom's (each axis)
LOOSE_OFFSET = 0.014  # m, the same for the "_loose" pairs (≤ 19.8 mm off: over the bottom cube in any yaw)
LOOSE_YAW = float(jnp.pi / 4)  # rad, the "_loose" top cube turned by up to this (faces repeat every π/2)


def check_start_states(start_states: str) -> None:
    """ValueError (one line) unless ``start_states`` is a key of ``START_STATES`` or a valid
    ``after:NAME:K`` (``skill_starts.parse``)."""
    if skill_starts.is_after(start_states):
        skill_starts.parse(start_states)
    elif start_states not in START_STATES:
        raise ValueError(f"start_states must be one of {START_STATES_ALLOWED}, got {start_states!r}")


PAIRS = jnp.array([(a, b) for a in range(L.NUM_CUBES) for b in range(L.NUM_CUBES) if a != b])  # (top, bottom)


def pair_candidates(s: KinematicState, rng: jax.Array, arrangement, loose: bool = False):
    """Every (ordered pair, side) placement of ``arrangement`` from the table reset ``s``:
    (cube_pos [C, 3, 3], cube_yaw [C, 3], valid [C]) with C = 6 pairs × 4 sides. Stacked: the top
    cube centred on the bottom one within ``STACKED_OFFSET``, resting on it, faces aligned (the
    side is ignored); adjacent: on the floor beside that side of the bottom cube, faces touching
    across a gap in ``ADJACENT_GAP``, same yaw. Valid: inside the basket, touching neither the
    third cube nor the gripper. ``loose``: stacked within ``LOOSE_OFFSET``, turned by up to
    ``LOOSE_YAW``."""
    top, bottom = jnp.repeat(PAIRS[:, 0], 4), jnp.repeat(PAIRS[:, 1], 4)
    side = jnp.tile(jnp.arange(4), PAIRS.shape[0])
    k_off, k_gap = jax.random.split(rng)
    base, yaw = s.cube_pos[bottom], s.cube_yaw[bottom]  # [C, 3], [C]
    reach = LOOSE_OFFSET if loose else STACKED_OFFSET
    off = jax.random.uniform(k_off, (2,), minval=-reach, maxval=reach)
    if loose:  # (the adjacent arrangement keeps its faces parallel)
        turn = jax.random.uniform(jax.random.fold_in(k_off, 1), (), minval=-LOOSE_YAW, maxval=LOOSE_YAW)
        yaw = jnp.where(arrangement == ARRANGE_STACKED, yaw + turn, yaw)
    stacked = jnp.concatenate([base[:, :2] + off, base[:, 2:] + 2 * L.CUBE_HALF], axis=-1)
    gap = jax.random.uniform(k_gap, (), minval=ADJACENT_GAP[0], maxval=ADJACENT_GAP[1])
    angle = yaw + 0.5 * jnp.pi * side
    beside = base[:, :2] + (2 * L.CUBE_HALF + gap) * jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)
    adjacent = jnp.concatenate([beside, base[:, 2:]], axis=-1)
    pos = jnp.where(arrangement == ARRANGE_STACKED, stacked, adjacent)

    def place(t, p, y):
        cube_pos, cube_yaw = s.cube_pos.at[t].set(p), s.cube_yaw.at[t].set(y)
        cs = _cs(cube_yaw)
        clear = ~_cube_hits_cubes(t, p, cs[t], cube_pos, cs)
        inside = jnp.all(jnp.abs(p[:2]) <= L.BASKET_HALF - L.CUBE_HALF * 1.42)
        free = ~gripper_hits_cubes(s.pinch, s.yaw, s.aperture, cube_pos, cs, jnp.zeros(L.NUM_CUBES, bool))
        return cube_pos, cube_yaw, clear & inside & free

    return jax.vmap(place)(top, pos, yaw)


def arrange_pair(s: KinematicState, rng: jax.Array, arrangement, pair=None, loose: bool = False) -> KinematicState:
    """``s`` (a table reset) with one cube moved onto (``ARRANGE_STACKED``) or beside
    (``ARRANGE_ADJACENT``) another: a placement drawn uniformly from the valid ones of
    ``pair_candidates`` (of the ordered pair ``pair`` = (top, bottom) only, if given);
    ``ARRANGE_TABLE``, or no valid placement: ``s`` unchanged. ``loose``: see ``pair_candidates``."""
    k_cand, k_pick = jax.random.split(rng)
    cube_pos, cube_yaw, valid = pair_candidates(s, k_cand, arrangement, loose)
    if pair is not None:
        valid = valid & (jnp.repeat(PAIRS[:, 0], 4) == pair[0]) & (jnp.repeat(PAIRS[:, 1], 4) == pair[1])
    pick = jnp.argmax(jnp.where(valid, jax.random.uniform(k_pick, valid.shape), -1.0))
    ok = (arrangement != ARRANGE_TABLE) & valid[pick]
    return s.replace(cube_pos=jnp.where(ok, cube_pos[pick], s.cube_pos),
                     cube_yaw=jnp.where(ok, cube_yaw[pick], s.cube_yaw))


def sample_start_state(rng: jax.Array, start_states: str = "table") -> KinematicState:
    """A reset of the distribution ``start_states`` (a key of ``START_STATES``); ``"table"`` is
    ``sample_initial_state(rng)`` itself."""
    if start_states == "table":
        return sample_initial_state(rng)
    k_table, k_mode, k_pair = jax.random.split(rng, 3)
    if start_states in PAIR_START_STATES:  # the pair fits only some table resets: try a few
        loose = start_states.endswith("_loose")
        tries = jax.vmap(lambda k: arrange_pair(sample_initial_state(k), k_pair, ARRANGE_STACKED,
                                                PAIR_START_STATES[start_states], loose))(
            jax.random.split(k_table, PAIR_TRIES))
        top = PAIR_START_STATES[start_states][0]
        placed = tries.cube_pos[:, top, 2] > L.CUBE_HALF + 0.5 * L.CUBE_SIZE
        stacked = jax.tree_util.tree_map(lambda x: x[jnp.argmax(placed)], tries)
        if loose:  # the fingers as a skill may leave them
            k_ap = jax.random.fold_in(k_pair, 7)
            stacked = stacked.replace(aperture=jax.random.uniform(k_ap, (), minval=0.0, maxval=L.APERTURE_OPEN))
        use = jax.random.bernoulli(k_mode)  # half the resets
        return jax.tree_util.tree_map(lambda a, b: jnp.where(use, a, b), stacked, sample_initial_state(k_table))
    arrangement = jax.random.randint(k_mode, (), 0, 3)
    return arrange_pair(sample_initial_state(k_table), k_pair, arrangement)


class KinematicBlocks(ManipulationEnv):
    """Brax-API env of the kinematic blocks domain for one named task.

    ``step`` does not auto-reset: at the time limit ``done`` = 1 and ``info["truncation"]`` = 1
    (trainers reset, and bootstrap from the true last observation). ``metrics["success"]`` is the
    task's success test at this step (0/1).
    """

    def __init__(self, task: str, episode_length: int = L.DEFAULT_EPISODE_LENGTH, start_states: str = "table"):
        if int(episode_length) < 1:
            raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
        check_start_states(start_states)
        self.task = task_defs.get(task)
        self.task_name = task
        self.episode_length = int(episode_length)
        self.start_states = start_states
        self.after_pool = None  # the "after:NAME:K" resets' pool (skill_starts)
        if skill_starts.is_after(start_states):
            spec = skill_starts.parse(start_states)  # (checked above: the spec and the skill file)
            act = skill_starts.load_policy(spec, L.OBS_SIZE, L.ACTION_SIZE)
            self.after_pool = skill_starts.build_pool(spec, act, sample_initial_state, dynamics, observe)

    def reset(self, rng: jax.Array) -> State:
        if self.after_pool is None:
            s = sample_start_state(rng, self.start_states)
        else:
            s = skill_starts.sample(rng, self.after_pool, sample_initial_state)
        reward, success = self._reward(s)
        zero = jnp.zeros(())
        return State(
            pipeline_state=s,
            obs=observe(s),
            reward=zero,
            done=zero,
            metrics={"reward": zero, "success": success},
            info={"steps": jnp.zeros((), jnp.int32), "truncation": zero},
        )

    def step(self, state: State, action: jax.Array) -> State:
        s = dynamics(state.pipeline_state, action)
        reward, success = self._reward(s)
        steps = state.info["steps"] + 1
        done = (steps >= self.episode_length).astype(jnp.float32)
        info = dict(state.info, steps=steps, truncation=done)
        return state.replace(
            pipeline_state=s,
            obs=observe(s),
            reward=reward,
            done=done,
            metrics=dict(state.metrics, reward=reward, success=success),
            info=info,
        )

    def _reward(self, s: KinematicState):
        inp = task_inputs(s)
        return self.task.reward(inp).astype(jnp.float32), self.task.success(inp).astype(jnp.float32)

    @property
    def backend(self) -> str:
        return "kinematic"


def cubes_interpenetrate(s: Any) -> jax.Array:
    """True if any two cubes overlap by more than the tolerance (for property tests)."""
    cs = _cs(s.cube_yaw)
    hit = G.boxes_overlap(
        s.cube_pos[:, None], _CUBE_H[None, None], cs[:, None], s.cube_pos[None], _CUBE_H[None, None], cs[None], EPS
    )
    return jnp.any(hit & ~jnp.eye(L.NUM_CUBES, dtype=bool))
