"""Scripted OP3 skills for the locomotion domain (issue #19): a get-up controller and a walking
controller, the two skills the paper's GetUpAndWalk composes (docs/research/op3_skills.md).

Each controller is a *stateless* pure JAX function ``fn(obs [233], key) -> action [20]`` in
[-1, 1] (a Markov policy like any learned skill; wrap it with ``parallel_skills.Skill.from_fn``).
It acts on one observation; ``jax.vmap`` it for a batch. The key is unused (deterministic).

**Memory through the observed previous action.** The observation holds the last five *raw*
actions exactly (``env.OBS_ACTIONS``, newest first). Both controllers write a tiny code into the
two head joints' actions (head pan = channel 0, head tilt = channel 1) and read it back from the
newest observed action on the next step, so a phase (walk) or a finite-state-machine phase and its
timer (get-up) ride in the observation. The codes are small (head targets move by < 0.05 rad), so
the head barely moves. A code that makes no sense (another skill acted before, or an episode
start) decodes to a valid state: the controllers recover from any observation.

Parameters are flat float vectors (``GETUP_SPEC`` / ``WALK_SPEC`` name their parts; the CEM
search in ``research/op3_skills.py`` tunes them); ``load(path)`` reads a tuned
checkpoint (``checkpoints/op3/{getup,walk}.json``), ``get(name, params)`` builds a controller.

Joint order (``model.JOINT_NAMES``): head_pan, head_tilt, l_sho_pitch, l_sho_roll, l_el,
r_sho_pitch, r_sho_roll, r_el, l_hip_yaw, l_hip_roll, l_hip_pitch, l_knee, l_ank_pitch,
l_ank_roll, r_hip_yaw, r_hip_roll, r_hip_pitch, r_knee, r_ank_pitch, r_ank_roll. Every right joint
has the mirrored axis of its left counterpart, so the mirror image (about the sagittal plane) of
a left joint value v is -v on the right joint, both in radians and in action units (the
standing pose is mirror symmetric). Action units: target = stand_pose + (π/2)·a_f.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from tasks.locomotion import env as E
from tasks.locomotion import model as M

Controller = Callable[[jax.Array, jax.Array], jax.Array]

NU = M.NU
HEAD_PAN, HEAD_TILT = 0, 1
# Left-side joints (indices into the 20 actions) and their right mirrors, in the order of a
# 9-vector "side pose": shoulder pitch, shoulder roll, elbow, hip yaw, hip roll, hip pitch, knee,
# ankle pitch, ankle roll.
LEFT = np.array([2, 3, 4, 8, 9, 10, 11, 12, 13])
RIGHT = np.array([5, 6, 7, 14, 15, 16, 17, 18, 19])
SIDE = 9
SHO_P, SHO_R, ELB, HIP_Y, HIP_R, HIP_P, KNEE, ANK_P, ANK_R = range(SIDE)
CONTROL_DT = M.CONTROL_DT
COS_UPRIGHT = math.cos(math.radians(12.5))


# --- reading the observation ----------------------------------------------------------------------
def prev_action(obs):
    """The newest raw action (the one applied on the last step) [20]."""
    return obs[E.OBS_ACTIONS][:NU]


def joints(obs):
    return obs[0:NU]


def gyro(obs):
    """Torso angular velocity, torso frame [3] (x forward, y left, z up)."""
    return obs[NU:NU + 3]


def gravity(obs):
    """Unit gravity direction in the torso frame [3]: (0, 0, -1) upright, (+1, 0, 0) lying on the
    front (face down), (-1, 0, 0) lying on the back; g_x > 0 leaning forward, g_y > 0 leaning left."""
    return obs[NU + 3:NU + 6]


def goal(obs):
    """(target direction forward, left in the heading frame, target speed)."""
    return obs[E.OBS_GOAL]


def assemble(left, right, head=(0.0, 0.0)):
    """A 20-action from 9-vectors of the left joints and the right joints (right in *mirrored*
    units: the right joint gets -right, so left == right is a mirror-symmetric pose)."""
    a = jnp.zeros(NU, jnp.float32)
    a = a.at[LEFT].set(left).at[RIGHT].set(-right)
    return a.at[HEAD_PAN].set(head[0]).at[HEAD_TILT].set(head[1])


# --- parameter vectors ----------------------------------------------------------------------------
class Spec:
    """Named slices of a flat parameter vector: ``Spec([(name, shape), ...])``."""

    def __init__(self, parts: Sequence[tuple[str, tuple[int, ...]]]):
        self.parts = [(n, tuple(s)) for n, s in parts]
        self.slices, off = {}, 0
        for n, s in self.parts:
            size = int(np.prod(s)) if s else 1
            self.slices[n] = (slice(off, off + size), s)
            off += size
        self.size = off

    def unpack(self, v) -> dict:
        return {n: v[sl].reshape(s) for n, (sl, s) in self.slices.items()}

    def pack(self, d: dict) -> np.ndarray:
        v = np.zeros(self.size, np.float32)
        for n, (sl, s) in self.slices.items():
            v[sl] = np.broadcast_to(np.asarray(d[n], np.float32), s).reshape(-1)
        return v


# --- get-up ---------------------------------------------------------------------------------------
# Finite-state machine: phase 0 = stand (balance), phases 1..K_FRONT = the front sequence (lying on
# the front -> squat -> up), K_FRONT+1..K_FRONT+K_BACK = the back sequence. The phase is coded in
# the head-pan action (PHASE_CODE · phase), the steps spent in it in the head-tilt action
# (TIMER_CODE · steps).
K_FRONT = 4
K_BACK = 4
N_PHASES = 1 + K_FRONT + K_BACK
PHASE_CODE = 1e-3
TIMER_CODE = 1e-4
MAX_TIMER = 1000  # steps

GETUP_SPEC = Spec([
    ("front_left", (K_FRONT, SIDE)), ("front_right", (K_FRONT, SIDE)), ("front_steps", (K_FRONT,)),
    ("back_left", (K_BACK, SIDE)), ("back_right", (K_BACK, SIDE)), ("back_steps", (K_BACK,)),
    ("lying_gx", ()),  # |g_x| above this: lying on the front (+) / back (-); restarts a sequence
    ("stand_pitch_gain", ()), ("stand_roll_gain", ()),  # balance feedback while standing (phase 0)
])


def _getup_init() -> dict:
    """Hand-made starting point of the search (action units, left joints; right = mirror)."""
    def pose(sho_p=0., sho_r=0., elb=0., hip_y=0., hip_r=0., hip_p=0., knee=0., ank_p=0., ank_r=0.):
        return [sho_p, sho_r, elb, hip_y, hip_r, hip_p, knee, ank_p, ank_r]

    # Lying on the front (torso x axis down): the arms swung forward (shoulder pitch -, roll +
    # brings them down, elbows straight) lever the pelvis up into a pike (hands and feet on the
    # floor, hips high; measured: torso ≈ 0.21 m high, head down), the knees bend to bring the feet
    # under the body, the arms push back to move the weight onto the feet, then a crouch.
    front = [pose(sho_p=-0.6, sho_r=0.45, elb=0.4, hip_p=-1.0, knee=-0.3, ank_p=-0.6),
             pose(sho_p=-0.6, sho_r=0.45, elb=0.4, hip_p=-1.0, knee=0.6, ank_p=0.0),
             pose(sho_p=0.3, sho_r=0.45, elb=0.4, hip_p=-0.8, knee=1.0, ank_p=0.3),
             pose(hip_p=-0.3, knee=0.4, ank_p=0.1)]
    # Lying on the back (torso x axis up): arms back (toward the floor) with the legs tucked lever
    # the pelvis up over the head (a backward roll toward lying on the front, where the front
    # sequence takes over), then legs extended, arms forward, crouch.
    back = [pose(sho_p=1.0, sho_r=0.45, elb=0.4, hip_p=-1.0, knee=1.0),
            pose(sho_p=1.0, sho_r=0.45, elb=0.4, hip_p=-1.0, knee=0.0),
            pose(sho_p=0.0, sho_r=0.45, elb=0.4, hip_p=-1.0, knee=1.0),
            pose(hip_p=-0.3, knee=0.4, ank_p=0.1)]
    return dict(front_left=front, front_right=front, front_steps=[16, 16, 20, 30],
                back_left=back, back_right=back, back_steps=[20, 20, 20, 20],
                lying_gx=0.8, stand_pitch_gain=0.0, stand_roll_gain=0.0)


GETUP_INIT = GETUP_SPEC.pack(_getup_init())


def decode_fsm(a_prev):
    phase = jnp.round(a_prev[HEAD_PAN] / PHASE_CODE).astype(jnp.int32)
    timer = jnp.round(a_prev[HEAD_TILT] / TIMER_CODE).astype(jnp.int32)
    valid = (phase >= 0) & (phase < N_PHASES) & (timer >= 0) & (timer <= MAX_TIMER)
    return jnp.where(valid, phase, -1), jnp.where(valid, timer, 0)


def getup_controller(params) -> Controller:
    """Get-up skill. Reads: the newest gravity direction (which side it lies on, whether it is
    upright), the torso angular velocity (standing balance) and the previous raw action's head
    codes (its own phase and the steps spent in it).

    Phase logic per step: an invalid code (episode start, another skill acted) -> phase 0 if
    upright, else the start of the front / back sequence by the side it lies on. Lying clearly on
    one side (|g_x| > lying_gx) while in phase 0 or in the other side's sequence restarts that
    side's sequence. A sequence phase lasts its number of steps (≥ 1), then the next; after the
    last one, phase 0: the standing pose with pitch/roll balance feedback at the ankles."""
    p = GETUP_SPEC.unpack(jnp.asarray(params, jnp.float32))
    lefts = jnp.concatenate([jnp.zeros((1, SIDE)), p["front_left"], p["back_left"]])
    rights = jnp.concatenate([jnp.zeros((1, SIDE)), p["front_right"], p["back_right"]])
    steps = jnp.concatenate([jnp.full((1,), 1e9), p["front_steps"], p["back_steps"]])
    steps = jnp.maximum(jnp.round(steps), 1.0)
    first_back = 1 + K_FRONT

    def fn(obs, key=None):
        del key
        g = gravity(obs)
        phase, timer = decode_fsm(prev_action(obs))
        front, back = g[0] > p["lying_gx"], g[0] < -p["lying_gx"]
        in_front = (phase >= 1) & (phase < first_back)
        in_back = phase >= first_back
        upright = g[2] < -0.7
        # (re)start
        start = jnp.where(front, 1, jnp.where(back, first_back, jnp.where(upright, 0, 1)))
        restart = (phase < 0) | (front & ~in_front) | (back & ~in_back)
        phase = jnp.where(restart, start, phase)
        timer = jnp.where(restart, 0, timer)
        # advance
        done = (timer + 1) >= steps[phase]
        last = (phase == K_FRONT) | (phase == first_back + K_BACK - 1)
        nxt = jnp.where(last, 0, phase + 1)
        new_phase = jnp.where(done & (phase > 0), nxt, phase)
        new_timer = jnp.where(new_phase != phase, 0, jnp.minimum(timer + 1, MAX_TIMER))
        left, right = lefts[new_phase], rights[new_phase]
        # standing balance (phase 0): lean forward (g_x > 0) -> ankles/hips correct by the gains
        stand = new_phase == 0
        fb_p = jnp.where(stand, p["stand_pitch_gain"] * g[0], 0.0)
        fb_r = jnp.where(stand, p["stand_roll_gain"] * g[1], 0.0)
        corr_l = jnp.zeros(SIDE).at[ANK_P].add(fb_p).at[ANK_R].add(fb_r)
        corr_r = jnp.zeros(SIDE).at[ANK_P].add(fb_p).at[ANK_R].add(-fb_r)
        a = assemble(left + corr_l, right + corr_r,
                     (new_phase.astype(jnp.float32) * PHASE_CODE, new_timer.astype(jnp.float32) * TIMER_CODE))
        return jnp.clip(a, -1.0, 1.0)

    return fn


# --- walk -----------------------------------------------------------------------------------------
# Gait oscillator: phase φ and an amplitude envelope r ∈ [0, 1] ride in the head actions as
# WALK_CODE · r · (cos φ, sin φ); each step φ += 2π·freq·dt and r rises by 1/ramp_steps (a standing
# start ramps the gait in). The left leg uses φ, the right φ + π; in a leg's phase ψ the foot lifts
# (knee bends, hip and ankle keep the sole parallel) while sin ψ > 0 and swings forward
# (stride·(-cos ψ)); the hips and ankles roll the body sideways (sway·sin(φ + sway_phase)) to put
# the weight on the stance foot. Balance feedback from the gravity direction and the gyro on hip
# pitch, ankle pitch, hip roll and ankle roll.
WALK_CODE = 0.01

WALK_SPEC = Spec([
    ("freq", ()), ("ramp_steps", ()),
    ("lift", ()), ("stride", ()), ("hip_sway", ()), ("ank_sway", ()), ("sway_phase", ()),
    ("lift_phase", ()),  # lift pattern's phase relative to the stride
    ("hip_off", ()), ("knee_off", ()), ("ank_off", ()), ("hip_roll_off", ()), ("arm_swing", ()),
    ("k_hip_p", ()), ("k_hip_pd", ()), ("k_ank_p", ()), ("k_ank_pd", ()),
    ("k_hip_r", ()), ("k_hip_rd", ()), ("k_ank_r", ()), ("k_ank_rd", ()),
    ("steer", ()),  # hip-yaw turn per rad of goal direction (< 0: toward the goal; 0: ignore it)
    ("follow_speed", ()),  # > 0.5: stride scaled by goal speed / 0.7 (0: always walk)
])

# Hand-made starting point: a small grid over stride, lift, frequency and lean (hip_off < 0: hips
# flexed, torso leaning forward) found this forward gait (≈ 0.31 m/s for 5 s without a fall).
WALK_INIT = WALK_SPEC.pack(dict(
    freq=2.2, ramp_steps=40.0, lift=0.3, stride=0.25, hip_sway=0.08, ank_sway=0.08, sway_phase=0.0,
    lift_phase=0.0, hip_off=-0.2, knee_off=0.0, ank_off=0.0, hip_roll_off=0.0, arm_swing=0.0,
    k_hip_p=0.0, k_hip_pd=0.0, k_ank_p=0.0, k_ank_pd=0.0, k_hip_r=0.0, k_hip_rd=0.0, k_ank_r=0.0, k_ank_rd=0.0,
    steer=0.0, follow_speed=0.0))


def walk_phase(obs):
    """(phase φ, envelope r) decoded from the previous action's head codes."""
    a = prev_action(obs)
    c, s = a[HEAD_PAN] / WALK_CODE, a[HEAD_TILT] / WALK_CODE
    r = jnp.sqrt(c * c + s * s)
    phi = jnp.where(r > 1e-6, jnp.arctan2(s, c), 0.0)
    return phi, jnp.clip(r, 0.0, 1.0)


def walk_controller(params) -> Controller:
    """Walking skill. Reads: the previous raw action's head codes (gait phase and envelope), the
    newest gravity direction and torso angular velocity (balance), and, if ``steer`` ≠ 0 /
    ``follow_speed`` > 0.5, the goal (direction forward/left in the heading frame, speed)."""
    p = WALK_SPEC.unpack(jnp.asarray(params, jnp.float32))

    def fn(obs, key=None):
        del key
        phi, r = walk_phase(obs)
        phi = phi + 2.0 * jnp.pi * p["freq"] * CONTROL_DT
        r = jnp.minimum(r + 1.0 / jnp.maximum(p["ramp_steps"], 1.0), 1.0)
        g, w = gravity(obs), gyro(obs)
        gl = goal(obs)
        speed = jnp.where(p["follow_speed"] > 0.5, gl[2] / E.GOAL_SPEEDS[1], 1.0)
        turn = jnp.clip(p["steer"] * jnp.arctan2(gl[1], gl[0]), -1.0, 1.0)

        def leg(psi):
            lift = r * p["lift"] * jnp.maximum(jnp.sin(psi + p["lift_phase"]), 0.0)
            swing = r * speed * p["stride"] * (-jnp.cos(psi))
            yaw = r * turn * (-jnp.cos(psi))
            # left-joint units: hip pitch + = leg back, knee + = bend, ankle (left axis -y): foot
            # parallel to the floor when Δankle = Δhip + Δknee
            d_hip = -swing - lift + p["hip_off"]
            d_knee = 2.0 * lift + p["knee_off"]
            d_ank = d_hip + d_knee + p["ank_off"] - p["hip_off"] - p["knee_off"]
            return yaw, d_hip, d_knee, d_ank, swing

        yl, hl, kl, al, sl = leg(phi)
        yr, hr, kr, ar, sr = leg(phi + jnp.pi)
        # balance: pitch (lean forward g_x > 0; gyro y), same physical correction on both legs
        fb_hip = p["k_hip_p"] * g[0] + p["k_hip_pd"] * w[1]
        fb_ank = p["k_ank_p"] * g[0] + p["k_ank_pd"] * w[1]
        # sway and roll feedback (lean left g_y > 0; gyro x): the same physical roll on both
        # legs = opposite mirrored units
        sway = r * jnp.sin(phi + p["sway_phase"])
        roll_h = p["hip_sway"] * sway + p["k_hip_r"] * g[1] + p["k_hip_rd"] * w[0]
        roll_a = p["ank_sway"] * sway + p["k_ank_r"] * g[1] + p["k_ank_rd"] * w[0]
        left = jnp.stack([-p["arm_swing"] * sr, 0.0, 0.0, yl, -roll_h + p["hip_roll_off"], hl + fb_hip, kl,
                          al + fb_ank, -roll_a])
        right = jnp.stack([-p["arm_swing"] * sl, 0.0, 0.0, -yr, roll_h + p["hip_roll_off"], hr + fb_hip, kr,
                           ar + fb_ank, roll_a])
        a = assemble(left, right, (WALK_CODE * r * jnp.cos(phi), WALK_CODE * r * jnp.sin(phi)))
        return jnp.clip(a, -1.0, 1.0)

    return fn


# --- registry -------------------------------------------------------------------------------------
_REGISTRY = {"getup": (GETUP_SPEC, GETUP_INIT, getup_controller), "walk": (WALK_SPEC, WALK_INIT, walk_controller)}
CHECKPOINT_DIR = Path(__file__).resolve().parents[2] / "checkpoints" / "op3"


def names() -> list[str]:
    return sorted(_REGISTRY)


def spec(name: str) -> Spec:
    return _lookup(name)[0]


def initial_params(name: str) -> np.ndarray:
    return np.array(_lookup(name)[1])


def _lookup(name):
    if name not in _REGISTRY:
        raise ValueError(f"unknown OP3 controller {name!r}; valid: {', '.join(names())}")
    return _REGISTRY[name]


def load(name: str, path: str | Path | None = None) -> np.ndarray:
    """Tuned parameters of ``name`` from its checkpoint json (default checkpoints/op3/<name>.json)."""
    path = Path(path) if path is not None else CHECKPOINT_DIR / f"{name}.json"
    rec = json.loads(Path(path).read_text())
    v = np.asarray(rec["params"], np.float32)
    if v.shape != (spec(name).size,):
        raise ValueError(f"{path}: {v.shape[0]} parameters, the {name} controller takes {spec(name).size}")
    return v


def get(name: str, params=None) -> Controller:
    """The controller ``name`` ("getup" or "walk") as a pure ``fn(obs, key) -> action``; params: a
    flat vector (default: the tuned checkpoint if present, else the hand-made initial guess)."""
    _, init, make = _lookup(name)
    if params is None:
        try:
            params = load(name)
        except FileNotFoundError:
            params = init
    fn = make(params)
    fn.__name__ = f"op3_{name}"
    return fn
