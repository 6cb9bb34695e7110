"""Reward terms of the locomotion domain (paper App. C, "Rewards - Locomotion"), pure JAX functions
of ``Features`` (what the reward reads off the physics) and the goal.

    R_walk = R_orient + R_velocity + R_upright + R_action + R_pose + R_ground + 1,

given only while the robot stands (0 otherwise). The paper leaves the weights open; the ones here
(docs/locomotion.md) keep every term at most ≈ 1 in size and make an upright robot standing still
in the reference pose earn R_walk ≥ 0.3 > 0 (the not-standing reward) whatever the goal.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

UPRIGHT_MARGIN = math.radians(12.5)  # R_upright = 1 within 12.5° of vertical ...
UPRIGHT_ZERO = 2 * UPRIGHT_MARGIN  # ... decaying linearly (in angle) to 0 at 25°
GROUND_DISTANCE = 0.04  # non-foot body parts within 4 cm of the floor: R_ground = -2
GROUND_PENALTY = -2.0
W_ORIENT = 1.0
W_VELOCITY = 1.0
W_UPRIGHT = 1.0
W_ACTION = 0.5  # × mean over the 20 joints of the squared change of the (raw, [-1, 1]) action
W_POSE = 0.05  # × sum over the 20 joints of the squared deviation from the standing pose (rad²)
ALIVE = 1.0
STAND_HEIGHT = 0.18  # torso height (m) above which, with tilt ≤ STAND_TILT, the robot stands
STAND_TILT = math.radians(30.0)
LYING_HEIGHT = 0.08  # typical torso height lying on the floor (op3_getup's height term starts here)
TRACK_TOLERANCE = 0.2  # walk success: feet planar velocity within 0.2 m/s of the target velocity


class Features(NamedTuple):
    """What observations and rewards read off a physics state (one env; batch dims allowed).
    joints [20] (rad); gyro [3] torso angular velocity (torso frame); gravity [3] unit gravity
    direction in the torso frame; up_z [] cos of the torso tilt; heading [2] unit forward direction
    of the torso in the floor plane (world); height [] torso height (m); feet_xy [2, 2] the feet
    sites' floor positions (world); ground [] lowest height of non-foot body parts (m)."""

    joints: jax.Array
    gyro: jax.Array
    gravity: jax.Array
    up_z: jax.Array
    heading: jax.Array
    height: jax.Array
    feet_xy: jax.Array
    ground: jax.Array


def tilt(up_z):
    return jnp.arccos(jnp.clip(up_z, -1.0, 1.0))


def standing(f: Features):
    return (f.height >= STAND_HEIGHT) & (tilt(f.up_z) <= STAND_TILT)


def r_orient(heading, goal_dir):
    """Dot product of the target orientation and the robot's heading (both unit, world)."""
    return jnp.sum(heading * goal_dir, axis=-1)


def r_velocity(feet_vel, goal_dir, goal_speed):
    """-‖target velocity - planar velocity of the feet‖ (feet_vel [2]: mean of both feet)."""
    return -jnp.linalg.norm(goal_speed[..., None] * goal_dir - feet_vel, axis=-1)


def r_upright(up_z):
    """1 within 12.5° of vertical, linearly down to 0 at 25°."""
    return jnp.clip((UPRIGHT_ZERO - tilt(up_z)) / (UPRIGHT_ZERO - UPRIGHT_MARGIN), 0.0, 1.0)


def r_maxvelocity(feet_vel, heading):
    """GoalScoring's R_maxvelocity: the planar velocity of the feet (mean of both, [2]) along the
    robot's forward direction (heading, unit, world); negative when walking backwards."""
    return jnp.sum(feet_vel * heading, axis=-1)


def r_action(action, prev_action):
    return -jnp.mean((action - prev_action) ** 2, axis=-1)


def r_pose(joints, stand_pose):
    return -jnp.sum((joints - stand_pose) ** 2, axis=-1)


def r_ground(ground):
    return jnp.where(ground < GROUND_DISTANCE, GROUND_PENALTY, 0.0)


def walk_terms(f: Features, feet_vel, action, prev_action, goal_dir, goal_speed, stand_pose) -> dict:
    """The weighted terms of R_walk (each already multiplied by its weight), ungated."""
    return {
        "r_orient": W_ORIENT * r_orient(f.heading, goal_dir),
        "r_velocity": W_VELOCITY * r_velocity(feet_vel, goal_dir, goal_speed),
        "r_upright": W_UPRIGHT * r_upright(f.up_z),
        "r_action": W_ACTION * r_action(action, prev_action),
        "r_pose": W_POSE * r_pose(f.joints, stand_pose),
        "r_ground": r_ground(f.ground),
    }


def walk_reward(terms: dict, is_standing):
    """R_walk = sum of the terms + 1 while standing, else 0."""
    total = sum(terms.values()) + ALIVE
    return jnp.where(is_standing, total, 0.0)


def getup_reward(f: Features):
    """op3_getup: torso height (from lying to standing height, in [0, 1]) × uprightness
    ((1 + cos tilt) / 2): 1 standing upright, 0–0.25 lying on the front or back (torso 0.08–0.13 m)."""
    h = jnp.clip((f.height - LYING_HEIGHT) / (STAND_HEIGHT - LYING_HEIGHT), 0.0, 1.0)
    return h * 0.5 * (1.0 + f.up_z)


def tracking(feet_vel, goal_dir, goal_speed):
    """The feet move at the target velocity within TRACK_TOLERANCE."""
    return -r_velocity(feet_vel, goal_dir, goal_speed) <= TRACK_TOLERANCE
