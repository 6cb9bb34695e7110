"""Observation layout and constants of the manipulation domain (paper App. C, Table "Observations").

Shared by every physics backend (``kinematic``, ``mjx``, ``warp``, ``mujoco``) so that skills and
experiments move between them. Importing this module imports neither JAX nor MuJoCo.

Frame: world z up; the basket floor is the plane z = 0, centred on the origin. Lengths in metres,
angles in radians, quaternions (w, x, y, z).

Observation vector (size ``OBS_SIZE`` = 60), in this order:

=====================  ====  =====================================================================
entry                  size  meaning
=====================  ====  =====================================================================
joint_pos              4     gripper joints: slide x, slide y, slide z (= pinch position), wrist yaw
                             (a continuous joint, reported wrapped to [-π, π))
joint_vel              4     their velocities (m/s, rad/s)
pinch_pose             7     pinch position (3) + quaternion (4)
finger_angle           1     finger aperture: distance between the finger pads (m), 0 = closed
finger_vel             1     its rate of change (m/s)
grasp                  1     grasp sensor: 1.0 while a cube is held between the fingers, else 0.0
<cube>_pose            7     for cube in (green, yellow, blue): position (3) + quaternion (4)
<cube>_pose_wrt_pinch  7     the cube's pose in the pinch frame: position (3) + quaternion (4)
=====================  ====  =====================================================================

Per cube the two 7-vectors are contiguous: green pose, green pose wrt pinch, yellow pose, ...

Action (size ``ACTION_SIZE`` = 5) in [-1, 1]: Cartesian pinch velocity (x, y, z) scaled by
``MAX_LINEAR_SPEED``, wrist yaw rate scaled by ``MAX_YAW_RATE``, finger velocity scaled by
``MAX_FINGER_SPEED`` (positive opens).
"""

from __future__ import annotations

# --- time -----------------------------------------------------------------------------------
CONTROL_DT = 0.05  # 20 Hz agent
DEFAULT_EPISODE_LENGTH = 600

# --- gripper --------------------------------------------------------------------------------
MAX_LINEAR_SPEED = 0.05  # m/s per axis
MAX_YAW_RATE = 1.0  # rad/s
MAX_FINGER_SPEED = 0.1  # m/s of aperture change
APERTURE_OPEN = 0.085  # m, fully open (Robotiq 2F-85 stroke)
APERTURE_CLOSED = 0.0
FINGER_THICKNESS = 0.01  # m, pad thickness (along the closing axis)
FINGER_WIDTH = 0.02  # m, pad width (perpendicular to the closing axis, horizontal)
FINGER_BELOW_PINCH = 0.015  # m, fingertips reach this far below the pinch point
FINGER_ABOVE_PINCH = 0.04  # m, pads extend this far above the pinch point
WORKSPACE_LOW = (-0.14, -0.14, 0.015)
WORKSPACE_HIGH = (0.14, 0.14, 0.30)

# --- basket and cubes -----------------------------------------------------------------------
BASKET_HALF = 0.10  # 20 x 20 cm floor
CUBE_SIZE = 0.04
CUBE_HALF = CUBE_SIZE / 2
CUBE_NAMES = ("green", "yellow", "blue")
NUM_CUBES = len(CUBE_NAMES)
CUBE_INDEX = {name: i for i, name in enumerate(CUBE_NAMES)}

# --- observation layout ---------------------------------------------------------------------
_FIELDS = [
    ("joint_pos", 4),
    ("joint_vel", 4),
    ("pinch_pose", 7),
    ("finger_angle", 1),
    ("finger_vel", 1),
    ("grasp", 1),
]
for _name in CUBE_NAMES:
    _FIELDS += [(f"{_name}_pose", 7), (f"{_name}_pose_wrt_pinch", 7)]

OBS_SLICES: dict[str, slice] = {}
_offset = 0
for _name, _size in _FIELDS:
    OBS_SLICES[_name] = slice(_offset, _offset + _size)
    _offset += _size
OBS_SIZE = _offset
ACTION_SIZE = 5

# Handy sub-slices.
PINCH_POS = slice(OBS_SLICES["pinch_pose"].start, OBS_SLICES["pinch_pose"].start + 3)
GRASP = OBS_SLICES["grasp"].start
FINGER = OBS_SLICES["finger_angle"].start
YAW = OBS_SLICES["joint_pos"].start + 3


def cube_pos(name: str) -> slice:
    """Slice of the cube's world position (3) in the observation."""
    start = OBS_SLICES[f"{name}_pose"].start
    return slice(start, start + 3)


def cube_quat(name: str) -> slice:
    start = OBS_SLICES[f"{name}_pose"].start + 3
    return slice(start, start + 4)


def cube_rel_pos(name: str) -> slice:
    """Slice of the cube's position in the pinch frame (3)."""
    start = OBS_SLICES[f"{name}_pose_wrt_pinch"].start
    return slice(start, start + 3)


def cube_rel_quat(name: str) -> slice:
    start = OBS_SLICES[f"{name}_pose_wrt_pinch"].start + 3
    return slice(start, start + 4)
