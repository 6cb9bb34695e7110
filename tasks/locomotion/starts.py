"""Initial states: standing (the ``stand_bent_knees`` keyframe) or lying prone on the front or back.

Prone starts come from a bank made once per process with classic MuJoCo (float64, fixed seed, so
deterministic): the robot, its joints at the standing pose plus uniform noise in ±0.3 rad, held
there by its position servos, is rotated 90° about its pitch axis (face down or face up), lowered
until its lowest body point is 1 cm above the floor and simulated for 1 s, which lets it settle.
A reset picks a bank entry (front or back with equal probability) or the standing keyframe and
turns it by a uniformly random yaw about the vertical axis through the origin (an exact symmetry of
the physics on a flat floor, so a settled state stays settled), with zero velocities. The joint
targets the servos held while settling start the action filter (``hold``), so the robot starts at
rest instead of jumping to the zero action's pose.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from tasks.locomotion import model as M

BANK_PER_SIDE = 16
BANK_SEED = 0
BANK_JOINT_NOISE = 0.3  # rad
SETTLE_TIME = 1.0  # s
START_STANDING, START_FRONT, START_BACK = 0, 1, 2
START_NAMES = {START_STANDING: "standing start", START_FRONT: "lying on the front", START_BACK: "lying on the back"}


def _lowest_point(model, data, lay: M.Layout) -> float:
    """Lowest point of every collision geom (meshes by their vertices; the foot boxes by corners)."""
    zs = []
    for g in range(model.ngeom):
        if model.geom_group[g] != 3:
            continue
        rz = data.geom_xmat[g].reshape(3, 3)[2]
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
            m = model.geom_dataid[g]
            v = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
            zs.append(data.geom_xpos[g, 2] + (v @ rz).min())
        else:  # box
            zs.append(data.geom_xpos[g, 2] - np.abs(rz * model.geom_size[g]).sum())
    return float(min(zs))


@functools.lru_cache(maxsize=4)
def prone_bank(model_key: tuple = (), seed: int = BANK_SEED) -> tuple[np.ndarray, np.ndarray]:
    """(qpos [2, BANK_PER_SIDE, NQ], held joint targets [2, BANK_PER_SIDE, NU]): settled states lying
    on the front ([0]) and on the back ([1]), at the origin, facing +x before the yaw turn. ``seed``
    draws the joint noise (another seed: starts a skill tuned on the default bank has never seen)."""
    model, _ = M.load_model(**dict(model_key))
    lay = M.layout(model_key)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    qpos = np.zeros((2, BANK_PER_SIDE, M.NQ))
    hold = np.zeros((2, BANK_PER_SIDE, M.NU))
    steps = int(round(SETTLE_TIME / model.opt.timestep))
    for side, pitch in enumerate((np.pi / 2, -np.pi / 2)):  # +90° about y: forward (x) points down
        for i in range(BANK_PER_SIDE):
            mujoco.mj_resetData(model, data)
            q = lay.stand_qpos.copy()
            q[7:] += rng.uniform(-BANK_JOINT_NOISE, BANK_JOINT_NOISE, M.NU)
            q[3:7] = [np.cos(pitch / 2), 0.0, np.sin(pitch / 2), 0.0]
            q[2] = 0.5
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            data.qpos[2] -= _lowest_point(model, data, lay) - 0.01
            data.ctrl[:] = q[7:]
            for _ in range(steps):
                mujoco.mj_step(model, data)
            qpos[side, i] = data.qpos
            hold[side, i] = q[7:]
    return qpos, hold


def quat_mul(a, b):
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return jnp.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                      aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def turn_yaw(qpos, yaw):
    """qpos turned by ``yaw`` about the vertical axis through the origin."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    x, y = qpos[0], qpos[1]
    q = quat_mul(jnp.stack([jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)]), qpos[3:7])
    return jnp.concatenate([jnp.stack([c * x - s * y, s * x + c * y, qpos[2]]), q, qpos[7:]])


class StartSampler:
    """``sample(key) -> (qpos [NQ], hold [NU] joint targets, kind [] int32)`` in JAX; prone with
    probability ``prone_fraction`` (front / back equally likely), else standing."""

    def __init__(self, prone_fraction: float, model_key: tuple = (), bank_seed: int = BANK_SEED):
        if not 0.0 <= prone_fraction <= 1.0:
            raise ValueError(f"prone_fraction must be in [0, 1], got {prone_fraction}")
        self.prone_fraction = float(prone_fraction)
        lay = M.layout(model_key)
        self.stand_qpos = jnp.asarray(lay.stand_qpos, jnp.float32)
        self.stand_pose = jnp.asarray(lay.stand_pose, jnp.float32)
        if self.prone_fraction > 0:
            bank_q, bank_h = prone_bank(model_key, int(bank_seed))
            self.bank_qpos = jnp.asarray(bank_q.reshape(-1, M.NQ), jnp.float32)
            self.bank_hold = jnp.asarray(bank_h.reshape(-1, M.NU), jnp.float32)
        else:
            self.bank_qpos = self.bank_hold = None

    def sample(self, key):
        k_kind, k_idx, k_yaw = jax.random.split(key, 3)
        yaw = jax.random.uniform(k_yaw, (), jnp.float32, -jnp.pi, jnp.pi)
        if self.bank_qpos is None:
            return turn_yaw(self.stand_qpos, yaw), self.stand_pose, jnp.int32(START_STANDING)
        prone = jax.random.uniform(k_kind, ()) < self.prone_fraction
        idx = jax.random.randint(k_idx, (), 0, self.bank_qpos.shape[0])
        kind = jnp.where(prone, jnp.where(idx < BANK_PER_SIDE, START_FRONT, START_BACK), START_STANDING)
        qpos = jnp.where(prone, self.bank_qpos[idx], self.stand_qpos)
        hold = jnp.where(prone, self.bank_hold[idx], self.stand_pose)
        return turn_yaw(qpos, yaw), hold, kind.astype(jnp.int32)
