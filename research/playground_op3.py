"""Outside check (issue #19, item 4): MuJoCo Playground's own ``Op3Joystick`` env, loaded offline from
the installed assets, trains a few SkillS iterations through the Brax API with the shipped walking
skill (``tasks.locomotion.controllers.get("walk")``) behind an observation / action adapter; and
what that adapted skill does alone in Playground's env, measured.

    taskset -c 1 python -m research.playground_op3 --out runs/playground_op3.json

Nothing is downloaded: Playground's robot envs clone MuJoCo Menagerie on first load; here
``mjx_env.MENAGERIE_PATH`` points at the Menagerie copy shipped in the asset wheel that the
locomotion tasks use (``tasks.locomotion.model.asset_root``). The env is Playground's default
``Op3Joystick`` config except ``impl="jax"`` (MJX-jax; warp is slow on CPU). Run pinned to one
core (MJX-jax can deadlock on 2 cores otherwise; ``main`` pins itself to one allowed core).

The two interfaces (checked against Playground 0.2.0's ``locomotion/op3/{joystick,base}.py``):

* this project (tasks/locomotion/env.py): obs [233] = 5 stacked [joint angles 20, torso gyro 3,
  gravity direction in the torso frame 3] newest first, 5 stacked *raw* actions [20] newest first,
  goal [forward, left direction in the heading frame, speed]; 25 ms steps; joint targets
  ``stand + (π/2)·a_f`` with the filter ``a_f ← 0.8·a_f + 0.2·a``.
* Playground: obs [147] = 3 stacked [gyro 3 (imu site = torso frame), "gravity" 3, command 3
  (vx, vy, yaw rate; torso frame), qpos[7:] − default pose 20, last action 20] newest first, each
  entry with uniform noise ±0.05 (padding entries before the first steps are exact zeros); 20 ms
  steps (4 ms physics); targets ``default + 0.3·u``, no filter. Same scene, keyframe
  (``stand_bent_knees`` = our stand pose), gains and solver settings. Its "last action" lags:
  ``step`` builds the observation before it stores the action it applied, so the newest entry
  after step t holds the action of step t − 1 (the action just applied is not observed).

The adapter (``walk_skill``: a pure ``fn(obs [147], key) -> u [20]``, a ``Skill.from_fn``):

* joints = offsets + default pose; gyro as is (same frame). Playground's "gravity" is the upvector
  sensor: the torso's z axis *in the world frame*; ours is gravity in the *torso* frame. Writing
  the torso orientation as yaw ψ after a tilt, ours = (R_z(−ψ)·up_xy, −up_z); ψ is not observed, so
  the adapter takes ψ = 0 (exact at Playground's reset, whose yaw is 0; the lean is rotated by the
  heading turned since; the measurement reports the final yaw).
* the 5-stacks from Playground's 3: zero padding entries take the newer entry (as our reset
  repeats the first observation); the two oldest proprio entries repeat the oldest available.
* the filter lives in the adapter: the newest last action Playground shows (u(t − 2) at step t)
  gives the targets then, ``a_f(t − 2) = u·0.3/(π/2)``; the unobserved raw action of t − 1 is
  recomputed: the walk skill on the previous observation (entries 1.. of this one, which the
  stack holds with the same noise), its phase code estimated from the codes of t − 2 and t − 3
  (their mean, the older one stepped on: equal without noise; averaging keeps the even and odd
  steps from becoming two independent phase chains under noise). Then ``a_f(t − 1)``,
  ``a_f(t) = β·a_f(t − 1) + (1 − β)·a``, ``u = a_f·(π/2)/0.3``, not clipped (the gait needs
  targets beyond Playground's nominal ±1 = ±0.3 rad; Playground only clips targets to the
  actuator range, as ours does). Without observation noise and at a 25 ms period this reproduces
  our env's targets exactly (checked against a direct implementation of its filter); with noise the
  recomputed a(t − 1) and a_f are approximate; after another skill acted at t − 1 (the scheduler
  switched), a_f is off for a step or two. The action stack: a(t − 1) recomputed, a(t − 2),
  a(t − 3) by inverting the filter over consecutive observed last actions (noise amplified ×5;
  the walk skill does not read them), the rest repeat the oldest.
* the gait phase the skill keeps in its head actions (code radius 0.01) would drown in
  Playground's ±0.05 observation noise: the head channels carry the raw code ×``HEAD_GAIN``
  (unfiltered), so the head moves by up to 0.3·``HEAD_GAIN``·0.01 = 0.15 rad (≈ 0.016 rad in ours).
* timing (``retime``): the skill advances its phase by 2π·freq·25 ms per step; the adapter turns
  the decoded code back by 2π·freq·5 ms so the gait keeps its frequency at 20 ms steps, and uses
  β = 0.8^(20/25) (the filter's time constant). The envelope still ramps in over ramp_steps
  steps (25 % sooner in time).
* goal: direction = (vx, vy)/|·| (forward if 0), speed = |(vx, vy)|; the yaw rate is dropped. The
  shipped skill ignores the goal anyway: it always walks forward.

Training uses ``skill_noise_std=0``: the trainer adds its collection noise to the frozen skills'
actions and clips them to [-1, 1], which would both cut the gait's targets to ±0.3 rad and scramble
the head code. The new skill and the scheduler see Playground's own observation.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

ENV_NAME = "Op3Joystick"
MENAGERIE_RELPATH = "mujoco/playground/assets/mujoco_menagerie"
PG_FRAME = 49  # one Playground observation entry
PG_GYRO, PG_UP, PG_CMD, PG_JOINTS, PG_LAST_ACT = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 29), slice(29, 49)
HEAD = (0, 1)  # head pan, head tilt: the walk skill's phase code
HEAD_GAIN = 50.0  # Playground head action per unit of the skill's raw head code
FAITHFUL = {"retime": 1.0, "clip": 0.0, "zero": 0.0}
# Measured variants: the adapter; without retiming (the skill's own 25 ms phase step and 0.8 filter
# per 20 ms step); its actions clipped to Playground's nominal [-1, 1]; zero action (holds the
# default pose: the reference for standing still).
VARIANTS = {
    "adapter": FAITHFUL,
    "no_retime": dict(FAITHFUL, retime=0.0),
    "clipped": dict(FAITHFUL, clip=1.0),
    "zero_action": dict(FAITHFUL, zero=1.0),
}


# --- loading Playground's env offline --------------------------------------------------------------
def use_installed_menagerie():
    """Point Playground's Menagerie path at the copy in the installed asset wheel (no clone)."""
    from etils import epath
    from mujoco_playground._src import mjx_env

    from tasks.locomotion import model

    path = model.asset_root() / MENAGERIE_RELPATH
    if not (path / "robotis_op3").is_dir():
        raise ValueError(f"no robotis_op3 in {path} (wrong asset package version?): {model.EXTRA_HINT}")
    mjx_env.MENAGERIE_PATH = epath.Path(path)
    return path


def load_env(**overrides):
    """Playground's ``Op3Joystick`` (default config, ``impl="jax"`` unless overridden)."""
    use_installed_menagerie()
    from mujoco_playground import registry

    return registry.load(ENV_NAME, config_overrides={"impl": "jax", **overrides})


@dataclasses.dataclass(frozen=True)
class Interface:
    """What the adapter needs of a Playground OP3 env: default pose [20], action scale (rad per
    unit), control period (s), observation history length."""

    default_pose: np.ndarray
    action_scale: float
    dt: float
    history: int

    @staticmethod
    def of(env) -> "Interface":
        cfg = env._config
        iface = Interface(np.asarray(env._default_pose, np.float32), float(cfg.action_scale), float(env.dt),
                          int(cfg.obs_history_size))
        if (iface.history < 3 or env.observation_size != iface.history * PG_FRAME
                or env.action_size != len(iface.default_pose)):
            raise ValueError(f"unexpected {ENV_NAME} sizes: obs {env.observation_size}, actions {env.action_size}")
        return iface


# --- observation: Playground [147] -> this project [233] -------------------------------------------
def frames(pg_obs, history: int):
    """Playground's stacked entries [history, 49], newest first, each all-zero padding entry
    (before an episode's first steps) replaced by the newer entry; and which entries were
    padding [history] (entry 1 at an episode's first step, entry 2 also at its second)."""
    f = pg_obs.reshape(history, PG_FRAME)
    padded = jnp.all(f == 0.0, axis=-1)
    rows = [f[0]]
    for i in range(1, history):
        rows.append(jnp.where(padded[i], rows[-1], f[i]))
    return jnp.stack(rows), padded


def torso_gravity(up):
    """Playground's upvector (torso z axis, world frame) [..., 3] -> gravity direction in the torso
    frame [..., 3], taking the unobserved yaw as 0: (up_x, up_y, −up_z)."""
    return up * jnp.array([1.0, 1.0, -1.0], up.dtype)


def pad_oldest(stack, size: int):
    """Newest-first stack [n, d] -> [size, d], the oldest entry repeated."""
    return jnp.concatenate([stack, jnp.repeat(stack[-1:], size - stack.shape[0], axis=0)])


def filtered_of(u, iface: Interface):
    """Our filtered action a_f of Playground actions u [..., 20] (same joint targets)."""
    from tasks.locomotion import env as E

    return u * (iface.action_scale / E.ACTION_SCALE)


def older_raw_actions(u, iface: Interface, beta):
    """Raw actions [n − 1, 20] (newest first) from Playground's observed last actions u [n, 20]
    (newest first): the filter inverted, a = (a_f − β·a_f(prev)) / (1 − β); head channels: the
    code (u / HEAD_GAIN)."""
    af = filtered_of(u, iface)
    raw = (af[:-1] - beta * af[1:]) / (1.0 - beta)
    head = jnp.asarray(HEAD)
    return raw.at[:, head].set(u[:-1, head] / HEAD_GAIN)


def goal_of_command(cmd):
    """(forward, left direction in the heading frame, speed) [3] of Playground's command [3]."""
    speed = jnp.linalg.norm(cmd[:2])
    direction = jnp.where(speed > 1e-6, cmd[:2] / jnp.maximum(speed, 1e-6), jnp.array([1.0, 0.0]))
    return jnp.concatenate([direction, speed[None]])


def project_obs(f, iface: Interface, beta, newest_raw):
    """This project's OP3 observation [233] from Playground entries ``f`` [n, 49] (newest first,
    padding replaced) and the raw action of the last step ``newest_raw`` [20] (not observed in
    Playground: its entries carry the actions of two and more steps back)."""
    from tasks.locomotion import env as E

    proprio = jnp.concatenate([f[:, PG_JOINTS] + iface.default_pose, f[:, PG_GYRO], torso_gravity(f[:, PG_UP])], -1)
    acts = jnp.concatenate([newest_raw[None], older_raw_actions(f[:, PG_LAST_ACT], iface, beta)])
    obs = jnp.concatenate([pad_oldest(proprio, E.STACK).reshape(-1), pad_oldest(acts, E.STACK).reshape(-1),
                           goal_of_command(f[0, PG_CMD])])
    return obs.astype(jnp.float32)


# --- the adapted walking skill ---------------------------------------------------------------------
def rotate_code(obs, angle):
    """Turn the newest raw action's head code (phase) by ``angle`` [rad]; obs [233]."""
    from tasks.locomotion import env as E

    i = E.OBS_ACTIONS.start
    c, s = obs[i + HEAD[0]], obs[i + HEAD[1]]
    ca, sa = jnp.cos(angle), jnp.sin(angle)
    return obs.at[i + HEAD[0]].set(ca * c - sa * s).at[i + HEAD[1]].set(sa * c + ca * s)


def step_code(code, advance, ramp):
    """The walk skill's head code [2] one step on, as the skill steps it: phase φ (0 if the code
    is ~0) turned by ``advance`` [rad], envelope r (radius / ``WALK_CODE``) raised by ``ramp`` up
    to 1."""
    from tasks.locomotion import controllers as C

    r = jnp.linalg.norm(code) / C.WALK_CODE
    phi = jnp.where(r > 1e-6, jnp.arctan2(code[1], code[0]), 0.0) + advance
    return C.WALK_CODE * jnp.minimum(r + ramp, 1.0) * jnp.stack([jnp.cos(phi), jnp.sin(phi)])


def phase_estimate(code2, code3, advance, ramp):
    """The skill's head code [2] at t − 2: the mean of the code of t − 2 and that of t − 3 stepped
    on (``step_code``). Equal to the former without noise; the mean keeps the two interleaved
    chains (each step's phase would otherwise follow the one two steps back) one chain."""
    return 0.5 * (code2 + step_code(code3, advance, ramp))


def walk_skill(iface: Interface, params=None, settings=None):
    """The shipped walking skill for Playground: a pure ``fn(obs [147], key) -> u [20]``.

    Playground's observation at step t holds the actions up to t − 2 (``step`` builds it before
    storing the action it applied), so the action of step t − 1 is recomputed: the walk skill on
    the previous observation (entries 1.. of this one, with the same noise), its phase estimated
    from the actions of t − 2 and t − 3 (``phase_estimate``). Close to the action applied then while
    the walk skill acted at t − 1 too (equal without observation noise); after another skill acted,
    the filter state is off for a step or two. At an episode's first step the previous action is
    the hold (0).

    ``settings`` (floats or traced scalars, default ``FAITHFUL``): ``retime`` 1 keeps the gait's
    frequency and the filter's time constant at Playground's control period, 0 steps them as at
    25 ms; ``clip`` 1 clips u to [-1, 1]; ``zero`` 1 acts 0 (holds the default pose)."""
    from tasks.locomotion import controllers as C
    from tasks.locomotion import env as E

    params = C.load("walk") if params is None else np.asarray(params, np.float32)
    s = {k: jnp.asarray(v, jnp.float32) for k, v in dict(FAITHFUL, **(settings or {})).items()}
    controller = C.get("walk", params)
    freq = float(C.WALK_SPEC.unpack(params)["freq"])
    retimed_beta = E.FILTER_STRENGTH ** (iface.dt / C.CONTROL_DT)
    beta = s["retime"] * retimed_beta + (1.0 - s["retime"]) * E.FILTER_STRENGTH
    shift = -s["retime"] * 2.0 * math.pi * freq * (C.CONTROL_DT - iface.dt)
    advance = 2.0 * math.pi * freq * C.CONTROL_DT + shift  # the phase step per Playground step
    ramp = 1.0 / max(float(C.WALK_SPEC.unpack(params)["ramp_steps"]), 1.0)
    head = jnp.asarray(HEAD)

    def fn(obs, key):
        f, padded = frames(obs, iface.history)
        older = older_raw_actions(f[:, PG_LAST_ACT], iface, beta)  # a(t-2), a(t-3)
        # second step: the action of t - 3 is the start's hold, not a step of the skill's chain
        code = jnp.where(padded[2], older[0, head], phase_estimate(older[0, head], older[1, head], advance, ramp))
        a_prev = controller(rotate_code(project_obs(f[1:], iface, beta, older[0].at[head].set(code)), shift), key)
        a_prev = jnp.where(padded[1], 0.0, a_prev)  # a(t-1); the hold at an episode's first step
        a = controller(rotate_code(project_obs(f, iface, beta, a_prev), shift), key)
        af_prev = beta * filtered_of(f[0, PG_LAST_ACT], iface) + (1.0 - beta) * a_prev  # targets commanded now
        u = (beta * af_prev + (1.0 - beta) * a) * (E.ACTION_SCALE / iface.action_scale)
        u = u.at[head].set(HEAD_GAIN * a[head])
        u = jnp.where(s["clip"] > 0.5, jnp.clip(u, -1.0, 1.0), u)
        return jnp.where(s["zero"] > 0.5, jnp.zeros_like(u), u)

    return fn


# --- the adapted skill alone -----------------------------------------------------------------------
def _yaw(quat):
    w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
    return jnp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def rollout(env, iface: Interface, settings: dict, num_envs: int, steps: int, seed: int):
    """Each variant (``settings``: name -> dict) alone for ``steps`` steps in ``num_envs`` envs
    (resets from PRNGKey(seed), the same for every variant): one jitted step of all variants × envs,
    looped in Python (compiles far faster than a scan here). Returns the variant names and
    per-step arrays [V, T, E]: done, forward velocity (torso frame), x, y, yaw, reward, max |u|."""
    names = list(settings)
    stacked = {k: jnp.asarray([settings[n][k] for n in names], jnp.float32) for k in FAITHFUL}
    keys = jax.random.split(jax.random.PRNGKey(seed), num_envs)
    both = lambda f: jax.vmap(jax.vmap(f))  # noqa: E731  over variants, then envs

    @jax.jit
    def reset(stacked):
        return jax.vmap(lambda _: jax.vmap(env.reset)(keys))(stacked["retime"])

    @jax.jit
    def step(state, stacked):
        u = jax.vmap(lambda s, obs: jax.vmap(walk_skill(iface, settings=s))(obs, keys))(stacked, state.obs)
        state = both(env.step)(state, u)
        d = state.data
        return state, (state.done, both(env.get_local_linvel)(d)[..., 0], d.qpos[..., 0], d.qpos[..., 1],
                       _yaw(d.qpos[..., 3:7]), state.reward, jnp.max(jnp.abs(u), axis=-1))

    state, recs = reset(stacked), []
    for _ in range(steps):
        state, rec = step(state, stacked)
        recs.append(jax.device_get(rec))
    return names, [np.swapaxes(np.stack([r[i] for r in recs]), 0, 1) for i in range(len(recs[0]))]


def walking_figures(rec, dt: float) -> dict:
    """Figures of one variant from its per-step arrays [T, E] (up to each env's first termination)."""
    done, vel, x, y, yaw, reward, umax = rec
    steps, num_envs = done.shape
    fell = done.max(0) > 0
    end = np.where(fell, done.argmax(0) + 1, steps)  # steps until (including) the first termination
    alive = np.arange(steps)[:, None] < end[None]
    last = end - 1
    cols = np.arange(num_envs)
    return {
        "envs": int(num_envs), "steps": int(steps), "seconds": steps * dt,
        "fell": int(fell.sum()),
        "mean_time_to_fall_s": float(np.mean(end[fell]) * dt) if fell.any() else None,
        "mean_forward_velocity": float(np.sum(vel * alive) / np.sum(alive)),
        "mean_x_velocity": float(np.mean(x[last, cols] / (end * dt))),  # world x from the origin (start yaw 0)
        "final_abs_yaw_deg": float(np.degrees(np.mean(np.abs(yaw[last, cols])))),
        "final_lateral_y": float(np.mean(y[last, cols])),
        "mean_reward_per_step": float(np.sum(reward * alive) / np.sum(alive)),
        "max_abs_action": float(np.max(umax * alive)),
    }


def measure(env, iface: Interface, num_envs: int, steps: int, seed: int) -> dict:
    t0 = time.perf_counter()
    names, recs = rollout(env, iface, VARIANTS, num_envs, steps, seed)
    out = {n: walking_figures([r[v] for r in recs], iface.dt) for v, n in enumerate(names)}
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    return out


# --- SkillS through the Brax API -------------------------------------------------------------------
def train_config(num_envs: int, unroll: int):
    """A small SkillS TrainConfig for CPU (skill noise off: see the module docstring)."""
    from parallel_skills import NewSkillConfig, SchedulerConfig, TrainConfig

    return TrainConfig(
        num_envs=num_envs, unroll_length=unroll, replay_size=2000, skill_noise_std=0.0,
        scheduler=SchedulerConfig(skill_lengths=(5, 20), hidden=(32,), critic_head_hidden=(32,), batch_size=16,
                                  min_replay_size=10, samples_per_insert=1.0),
        new_skill=NewSkillConfig(hidden=(32,), batch_size=16, min_replay_size=10, samples_per_insert=1.0),
    )


def _scalars(m: dict) -> dict:
    keep = {k: float(v) for k, v in m.items() if np.ndim(v) == 0 and ("loss" in k or k in (
        "reward_mean", "episodes", "new_skill_selection_rate", "nonfinite_transitions"))}
    return dict(sorted(keep.items()))


def train(env, iface: Interface, iterations: int, num_envs: int, unroll: int, episode_length: int, seed: int):
    """``iterations`` SkillS iterations on ``EpisodeWrapper(env)`` with the adapted walking skill
    as the one frozen skill. Returns one dict per iteration (env steps, losses, skill histogram)."""
    from brax.envs.wrappers.training import EpisodeWrapper

    from parallel_skills import Skill
    from parallel_skills.train import make_trainer

    skills = [Skill.from_fn("op3_walk_playground", walk_skill(iface))]
    trainer = make_trainer(EpisodeWrapper(env, episode_length, 1), skills, train_config(num_envs, unroll))
    state = jax.jit(trainer.init)(jax.random.PRNGKey(seed))
    step = jax.jit(trainer.iteration)
    rows = []
    for it in range(iterations):
        t0 = time.perf_counter()
        state, m = step(state)
        m = jax.device_get(m)
        row = {"iteration": it + 1, "env_steps": int(state.env_steps), "wall_s": round(time.perf_counter() - t0, 1),
               "skill_histogram": {n: float(c) for n, c in zip(["op3_walk", "new_skill"], m["skill_histogram"])},
               "skill_steps": {n: float(c) for n, c in zip(["op3_walk", "new_skill"], m["skill_steps"])},
               **_scalars(m)}
        row["all_losses_finite"] = bool(all(np.isfinite(v) for k, v in row.items() if k.endswith("_loss")))
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


# --- command line ----------------------------------------------------------------------------------
def pin_one_core():
    """Pin the process to one allowed core (MJX-jax on 2 cores can deadlock); returns the core."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) > 1:
        os.sched_setaffinity(0, {cores[0]})
    return cores[0]


def run(args) -> dict:
    from training.run import enable_compilation_cache

    enable_compilation_cache()
    core = pin_one_core()
    t0 = time.perf_counter()
    env = load_env()
    iface = Interface.of(env)
    summary = {"command": "python -m research.playground_op3 " + " ".join(args.argv), "core": core,
               "env": {"name": ENV_NAME, "impl": "jax", "obs": int(env.observation_size),
                       "actions": int(env.action_size), "dt": iface.dt, "action_scale": iface.action_scale,
                       "obs_noise": float(env._config.obs_noise), "load_s": round(time.perf_counter() - t0, 1)},
               "adapter": {"head_gain": HEAD_GAIN, "settings": FAITHFUL}}
    print(json.dumps(summary["env"]), flush=True)
    if args.iterations > 0:
        t1 = time.perf_counter()
        rows = train(env, iface, args.iterations, args.envs, args.unroll, args.episode_length, args.seed)
        summary["training"] = {"iterations": rows, "num_envs": args.envs, "unroll_length": args.unroll,
                               "episode_length": args.episode_length, "wall_s": round(time.perf_counter() - t1, 1),
                               "all_losses_finite": all(r["all_losses_finite"] for r in rows)}
    if args.walk_steps > 0:
        summary["walking"] = measure(env, iface, args.walk_envs, args.walk_steps, args.seed)
        for name in VARIANTS:
            print(name, json.dumps(summary["walking"][name]), flush=True)
    summary["wall_s"] = round(time.perf_counter() - t0, 1)
    return summary


def summary_lines(summary: dict) -> list[str]:
    """A few human-readable lines of ``run``'s summary."""
    lines = []
    tr = summary.get("training")
    if tr:
        for r in tr["iterations"]:
            losses = ", ".join(f"{k} {v:.4g}" for k, v in r.items() if k.endswith("_loss"))
            lines.append(f"SkillS iteration {r['iteration']}: env steps {r['env_steps']}; {losses}; decisions "
                         f"{r['skill_histogram']}; steps acted {r['skill_steps']}")
        lines.append(f"training: all losses finite: {tr['all_losses_finite']} ({tr['wall_s']} s incl. compile)")
    for name in VARIANTS if "walking" in summary else ():
        w = summary["walking"][name]
        lines.append(f"alone, {name}: {w['envs']} envs x {w['seconds']:g} s: fell {w['fell']}, forward velocity "
                     f"{w['mean_forward_velocity']:.3f} m/s (torso frame), x velocity {w['mean_x_velocity']:.3f} m/s, "
                     f"final |yaw| {w['final_abs_yaw_deg']:.1f} deg, max |u| {w['max_abs_action']:.2f}")
    lines.append(f"wall time {summary['wall_s']} s")
    return lines


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m research.playground_op3",
                                description=__doc__.splitlines()[0])
    p.add_argument("--iterations", type=int, default=3, help="SkillS iterations (0: skip training)")
    p.add_argument("--envs", type=int, default=4, help="training envs")
    p.add_argument("--unroll", type=int, default=10, help="env steps per env per iteration")
    p.add_argument("--episode_length", type=int, default=100, help="EpisodeWrapper time limit (steps)")
    p.add_argument("--walk_envs", type=int, default=4, help="envs per measured variant")
    p.add_argument("--walk_steps", type=int, default=500, help="steps of the walking measurement (0: skip)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="write the summary as JSON here")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = p.parse_args(argv)
    args.argv = argv
    summary = run(args)
    print("\n".join(summary_lines(summary)), flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(summary, f, indent=1)
    return summary


if __name__ == "__main__":
    main()
