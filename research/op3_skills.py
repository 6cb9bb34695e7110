"""Tune and evaluate the scripted OP3 skills (tasks/locomotion/controllers.py; docs/research/op3_skills.md).

    python -m research.op3_skills search --skill getup --generations 30
    python -m research.op3_skills evaluate --skill getup --episodes 64

``search``: cross-entropy method (diagonal Gaussian over the flat parameter vector) on the classic
MuJoCo C engine (physics="mujoco", one host thread). Every generation evaluates ``--pop``
candidates (plus the current mean) on the same episodes (common random numbers), one jit(vmap) of
env.step over candidates × episodes. The best parameters so far go to checkpoints/op3/<skill>.json
after every generation, the search state to runs/op3_skills/<skill>_cem.npz (``--resume``).

Episodes: get-up on ``op3_getup`` resets chosen to cover the prone bank (16 front + 16 back
settled states; a random yaw each), walk on ``op3_walk`` resets (standing) with Gaussian noise on
the joint actions (the controller is deterministic and every standing start is the same up to yaw,
so the noise is what makes the gait robust).

``evaluate``: the acceptance measure of issue #19 on ``--episodes`` resets from ``--seed``
(jax.random.split(PRNGKey(seed), episodes)), full episodes:
  get-up: upright (tilt ≤ 12.5°) and standing height (torso ≥ 0.18 m) within 200 steps; also
          whether it stays standing (env ``standing``) for the rest of the episode.
  walk:   mean planar speed of the feet along the torso heading over the 400 steps ≥ 0.3 m/s and
          never not standing; for the shipped walk (it follows the goal speed) taken with
          ``--goal_speed 0.7``, the walking command.
``--write`` stores the measured numbers in the checkpoint's record.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import tasks
from tasks.locomotion import controllers as C
from tasks.locomotion import env as E
from tasks.locomotion import starts as S

TASK = {"getup": "op3_getup", "walk": "op3_walk"}
WALK_SPEED = 0.3
STATE_DIR = Path("runs") / "op3_skills"


def make_env(skill: str, episode_length: int | None = None, bank_seed: int | None = None,
             goal_speed: float | None = None):
    kw = {} if episode_length is None else {"episode_length": episode_length}
    if bank_seed is not None:
        kw["prone_bank_seed"] = bank_seed
    if goal_speed is not None:
        kw["goal_speed"] = goal_speed
    return tasks.make(TASK[skill], physics="mujoco", num_threads=1, **kw)


# --- rollouts ---------------------------------------------------------------------------------------
def make_rollout(env, skill: str, steps: int, noise: float = 0.0):
    """jit fn(params [B, D], keys [B, 2], noise_key) -> per-episode statistics (dict of [B])."""
    make = {"getup": C.getup_controller, "walk": C.walk_controller}[skill]

    def policy(prm, obs):
        return make(prm)(obs)

    joint_mask = jnp.ones(C.NU).at[C.HEAD_PAN].set(0.0).at[C.HEAD_TILT].set(0.0)

    @jax.jit
    def rollout(params, keys, noise_key):
        b = keys.shape[0]
        s = jax.vmap(env.reset)(keys)
        zero = jnp.zeros(b)
        carry0 = dict(s=s, first=jnp.full(b, steps + 1, jnp.int32), alive=jnp.ones(b, bool), t_alive=zero,
                      dist_alive=zero, dist=zero, rew=zero, stand_after=zero, stand_all=jnp.ones(b, bool),
                      ok_after=jnp.ones(b, bool), nan=zero, up_mean=zero, rew_max=zero, goal_fwd=zero)

        def body(c, t):
            s = c["s"]
            a = jax.vmap(policy)(params, s.obs)
            if noise > 0:
                a = a + noise * joint_mask * jax.random.normal(jax.random.fold_in(noise_key, t), a.shape)
            s2 = jax.vmap(env.step)(s, a)
            g = jax.vmap(C.gravity)(s2.obs)
            stand = s2.metrics["standing"] > 0.5
            upright = (-g[:, 2]) >= C.COS_UPRIGHT
            success = stand & upright
            first = jnp.where((c["first"] > steps) & success, t + 1, c["first"])
            # heading from the goal observation (fwd, left) and the world goal direction
            gd = s2.info["goal_dir"]
            fwd, left = s2.obs[:, E.OBS_GOAL][:, 0], s2.obs[:, E.OBS_GOAL][:, 1]
            heading = fwd[:, None] * gd + left[:, None] * jnp.stack([gd[:, 1], -gd[:, 0]], -1)
            disp = jnp.sum((jnp.mean(s2.info["feet_xy"], 1) - jnp.mean(s.info["feet_xy"], 1)) * heading, -1)
            disp = jnp.where(s2.info["nan_reset"] > 0, 0.0, disp)
            alive = c["alive"] & stand
            after = first <= t + 1
            return dict(s=s2, first=first, alive=alive, t_alive=c["t_alive"] + alive,
                        dist_alive=c["dist_alive"] + jnp.where(alive, disp, 0.0), dist=c["dist"] + disp,
                        rew=c["rew"] + s2.reward, stand_after=c["stand_after"] + (after & stand),
                        stand_all=c["stand_all"] & stand, ok_after=c["ok_after"] & (~after | stand),
                        nan=c["nan"] + s2.info["nan_reset"], up_mean=c["up_mean"] + (-g[:, 2]) / steps,
                        rew_max=jnp.maximum(c["rew_max"], s2.reward), goal_fwd=c["goal_fwd"] + fwd / steps), None

        c, _ = jax.lax.scan(body, carry0, jnp.arange(steps))
        c.pop("s")
        return c

    return rollout


def bank_keys(env, per_entry: int, seed: int):
    """Reset keys [2·BANK_PER_SIDE·per_entry, 2] covering each prone bank entry ``per_entry`` times
    (identified by the start joints, which the random yaw leaves unchanged)."""
    bank = np.asarray(env.sampler.bank_qpos)[:, 7:]
    n = bank.shape[0]
    cand = jax.random.split(jax.random.PRNGKey(seed), 64 * n * per_entry)
    obs = np.asarray(jax.jit(jax.vmap(lambda k: env.reset(k).obs[:C.NU]))(cand))
    idx = np.argmin(np.abs(obs[:, None, :] - bank[None]).max(-1), axis=1)
    picks = []
    for i in range(n):
        hits = np.flatnonzero(idx == i)[:per_entry]
        if len(hits) < per_entry:
            raise RuntimeError(f"bank entry {i}: only {len(hits)} keys found")
        picks.extend(hits)
    return np.asarray(cand)[np.array(picks)]


# --- fitness -----------------------------------------------------------------------------------------
def fitness(skill: str, st: dict, steps: int, dt: float, kind: str = "speed") -> np.ndarray:
    """Per-episode search objective. get-up: success, speed of it, staying up (+ shaping). walk,
    ``kind`` "speed": time standing, forward speed (capped at 0.4 m/s), no fall; "return": time
    standing, the op3_walk return per step (R_walk for the goals drawn), no fall."""
    st = {k: np.asarray(v) for k, v in st.items()}
    if skill == "getup":
        ok = st["first"] <= steps
        early = np.where(ok, 1.0 - st["first"] / steps, 0.0)
        stay = np.where(ok, st["stand_after"] / np.maximum(steps - st["first"] + 1, 1), 0.0)
        # shaping while nothing succeeds: mean uprightness (cos tilt, -1 upside down) and the best
        # op3_getup reward (height x uprightness) reached
        return 2.0 * ok + early + stay + st["rew"] / steps + 0.5 * st["up_mean"] + st["rew_max"]
    alive = st["t_alive"] / steps
    if kind == "return":
        return alive + st["rew"] / steps + 2.0 * st["stand_all"]
    speed = st["dist_alive"] / (steps * dt)
    return alive + 3.0 * np.minimum(speed, 0.4) + 2.0 * st["stand_all"]


def summary(skill: str, st: dict, steps: int, dt: float) -> dict:
    st = {k: np.asarray(v) for k, v in st.items()}
    if skill == "getup":
        ok = st["first"] <= steps
        stays = ok & st["ok_after"]
        return dict(success=float(ok.mean()), stays_standing=float(stays.mean()),
                    standing_at_end_frac=float(np.mean(st["stand_after"] > 0) if ok.any() else 0.0),
                    mean_time_s=float(st["first"][ok].mean() * dt) if ok.any() else None,
                    max_time_s=float(st["first"][ok].max() * dt) if ok.any() else None,
                    nan_resets=float(st["nan"].sum()))
    speed = st["dist"] / (steps * dt)
    ok = st["stand_all"] & (speed >= WALK_SPEED)
    return dict(success=float(ok.mean()), no_fall=float(st["stand_all"].mean()), mean_speed=float(speed.mean()),
                min_speed=float(speed.min()), nan_resets=float(st["nan"].sum()),
                heading_goal=float(st["goal_fwd"].mean()), episode_return=float(st["rew"].mean()))


# --- checkpoint -----------------------------------------------------------------------------------
def ckpt_path(skill: str) -> Path:
    return C.CHECKPOINT_DIR / f"{skill}.json"


def write_ckpt(skill: str, params, record: dict):
    path = ckpt_path(skill)
    path.parent.mkdir(parents=True, exist_ok=True)
    old = json.loads(path.read_text()) if path.exists() else {}
    rec = dict(old.get("record", {}), **record)
    out = {"skill": skill, "controller": f"tasks.locomotion.controllers.get({skill!r}, params)",
           "param_names": [f"{n}{list(s) if s else ''}" for n, s in C.spec(skill).parts],
           "params": [float(x) for x in np.asarray(params)], "record": rec}
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(out, indent=1) + "\n")
    os.replace(tmp, path)


def command_line() -> str:
    return "python -m research.op3_skills " + " ".join(shlex.quote(a) for a in sys.argv[1:])


def init_std(skill: str, fitness_kind: str = "speed") -> np.ndarray:
    """Initial CEM std per parameter (0: fixed). The walk's ``steer`` is searched (0.01) only for
    the "return" fitness, whose R_orient term rewards turning toward the goal; ``follow_speed``
    (a switch) never."""
    spec = C.spec(skill)
    d = {}
    if skill == "getup":
        d = dict(front_left=0.25, front_right=0.25, front_steps=5.0, back_left=0.25, back_right=0.25,
                 back_steps=5.0, lying_gx=0.03, stand_pitch_gain=0.2, stand_roll_gain=0.2)
    else:
        d = dict(freq=0.25, ramp_steps=8.0, lift=0.06, stride=0.05, hip_sway=0.05, ank_sway=0.05, sway_phase=0.6,
                 lift_phase=0.4, hip_off=0.06, knee_off=0.06, ank_off=0.06, hip_roll_off=0.04, arm_swing=0.08,
                 k_hip_p=0.2, k_hip_pd=0.03, k_ank_p=0.2, k_ank_pd=0.03, k_hip_r=0.2, k_hip_rd=0.03, k_ank_r=0.2,
                 k_ank_rd=0.03, steer=0.01 if fitness_kind == "return" else 0.0, follow_speed=0.0)
    return spec.pack(d)


# --- commands ----------------------------------------------------------------------------------------
def search(args):
    skill = args.skill
    steps = args.steps or (200 if skill == "getup" else 200)
    env = make_env(skill, steps)
    dt = env.dt
    spec = C.spec(skill)
    STATE_DIR.mkdir(parents=True, exist_ok=True)
    state_path = STATE_DIR / f"{skill}_cem.npz"
    rng = np.random.default_rng(args.seed)
    if args.resume and state_path.exists():
        z = np.load(state_path)
        mu, sd, gen0, best_f, best = z["mu"], z["sd"], int(z["gen"]), float(z["best_f"]), z["best"]
        env_steps, wall0 = int(z["env_steps"]), float(z["wall"])
        rng = np.random.default_rng(args.seed + gen0)
        print(f"resumed at generation {gen0}, best {best_f:.3f}")
    else:
        mu = C.load(skill) if args.init == "checkpoint" else C.initial_params(skill)
        if skill == "walk" and args.follow_speed:
            mu = with_param(mu, "follow_speed", 1.0)
        sd = init_std(skill, args.fitness) * args.std_scale
        gen0, best_f, best, env_steps, wall0 = 0, -np.inf, mu.copy(), 0, 0.0
    best_summ = None  # the search episodes' summary of ``best``; a resume takes the record's
    if gen0 and ckpt_path(skill).exists():
        best_summ = json.loads(ckpt_path(skill).read_text()).get("record", {}).get(args.record, {}).get(
            "search_episodes_summary_of_best")
    if skill == "getup":
        bank = bank_keys(env, 2, args.seed).reshape(2, S.BANK_PER_SIDE, 2, 2)  # [side, entry, copy, key]
        n_ep = args.episodes
    else:
        bank, n_ep = None, args.episodes
    pop = args.pop + 1  # + the mean
    rollout = make_rollout(env, skill, steps, noise=args.noise if skill == "walk" else 0.0)
    n_elite = max(2, int(round(args.elite * args.pop)))
    t_start = time.time()
    for gen in range(gen0, args.generations):
        cands = mu[None] + sd[None] * rng.standard_normal((args.pop, spec.size)).astype(np.float32)
        cands = np.concatenate([mu[None], cands]).astype(np.float32)
        if bank is not None:  # half front, half back entries (random entries and yaw copies)
            kr = np.random.default_rng(args.seed * 7919 + gen)
            keys = np.concatenate([bank[side, kr.choice(S.BANK_PER_SIDE, n_ep // 2, replace=n_ep // 2 > S.BANK_PER_SIDE),
                                        kr.integers(0, 2)] for side in (0, 1)])
        else:
            keys = np.asarray(jax.random.split(jax.random.PRNGKey(args.seed * 1000 + gen), n_ep))
        params = np.repeat(cands, n_ep, axis=0)
        st = rollout(jnp.asarray(params), jnp.tile(jnp.asarray(keys), (pop, 1)), jax.random.PRNGKey(gen))
        f = fitness(skill, st, steps, dt, args.fitness).reshape(pop, n_ep)
        fm = f.mean(1)
        env_steps += pop * n_ep * steps
        order = np.argsort(-fm)
        elite = cands[order[:n_elite]]
        w = np.log(n_elite + 0.5) - np.log(np.arange(1, n_elite + 1))
        w = w / w.sum()
        new_mu = (w[:, None] * elite).sum(0)
        new_sd = np.sqrt((w[:, None] * (elite - mu[None]) ** 2).sum(0))
        sd = np.maximum(args.smooth * sd + (1 - args.smooth) * new_sd, init_std(skill, args.fitness) * args.min_std)
        mu = new_mu.astype(np.float32)
        summ = summary(skill, {k: np.asarray(v).reshape(pop, n_ep)[order[0]] for k, v in st.items()}, steps, dt)
        summ_mean = summary(skill, {k: np.asarray(v).reshape(pop, n_ep)[0] for k, v in st.items()}, steps, dt)
        if fm[order[0]] > best_f:
            best_f, best, best_summ = float(fm[order[0]]), cands[order[0]].copy(), summ
        wall = wall0 + time.time() - t_start
        print(f"gen {gen:3d} best {fm[order[0]]:.3f} mean-cand {fm[0]:.3f} median {np.median(fm):.3f} "
              f"best {summ} | mean {summ_mean} | {env_steps / 1e6:.2f}M steps {wall:.0f}s", flush=True)
        np.savez(state_path, mu=mu, sd=sd, gen=gen + 1, best_f=best_f, best=best, env_steps=env_steps, wall=wall)
        write_ckpt(skill, best, {args.record: dict(
            command=command_line(), method="CEM (diagonal Gaussian, log-rank elite weights)", generations=gen + 1,
            pop=args.pop, elite=n_elite, episodes_per_candidate=n_ep, episode_steps=steps,
            action_noise=args.noise if skill == "walk" else 0.0, env_steps=int(env_steps), wall_time_s=round(wall, 1),
            seed=args.seed, best_fitness=best_f, fitness=args.fitness, physics="mujoco",
            search_episodes_summary_of_best=best_summ)})


def evaluate(args):
    skill = args.skill
    env = make_env(skill, bank_seed=args.bank_seed, goal_speed=args.goal_speed)
    steps = env.episode_length
    params = C.load(skill, args.params) if args.params or ckpt_path(skill).exists() else C.initial_params(skill)
    if args.init_params:
        params = C.initial_params(skill)
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
    rollout = make_rollout(env, skill, steps, noise=args.noise)
    t0 = time.time()
    st = rollout(jnp.asarray(np.repeat(params[None], args.episodes, 0)), keys, jax.random.PRNGKey(0))
    st = jax.device_get(st)
    wall = time.time() - t0
    res = summary(skill, st, steps, env.dt)
    if args.bank_seed is not None:
        res["prone_bank_seed"] = args.bank_seed
    if args.goal_speed is not None:
        res["goal_speed"] = args.goal_speed
    res.update(episodes=args.episodes, seed=args.seed, episode_steps=steps, physics="mujoco", action_noise=args.noise,
               command=command_line(), wall_time_s=round(wall, 1))
    if skill == "getup":
        # which starts fail (1 front, 2 back)
        kinds = np.asarray(jax.vmap(lambda k: env.reset(k).info["start"])(keys))
        ok = np.asarray(st["first"]) <= steps
        res["success_front"] = float(ok[kinds == 1].mean()) if (kinds == 1).any() else None
        res["success_back"] = float(ok[kinds == 2].mean()) if (kinds == 2).any() else None
    print(json.dumps(res, indent=1))
    if args.write:
        name = "evaluation" if args.noise == 0 else f"evaluation_noise_{args.noise:g}"
        name += "" if args.bank_seed is None else f"_bank_seed_{args.bank_seed}"
        name += "" if args.goal_speed is None else f"_goal_speed_{args.goal_speed:g}"
        write_ckpt(skill, params, {name: res})


def with_param(params, name: str, value: float) -> np.ndarray:
    """The walk parameters ``params`` [D] with parameter ``name`` replaced by ``value``."""
    d = C.spec("walk").unpack(np.array(params, np.float32))
    d[name] = np.float32(value)
    return C.spec("walk").pack(d)


def with_steer(params, value: float) -> np.ndarray:
    """The walk parameters ``params`` [D] with their ``steer`` gain replaced by ``value``."""
    return with_param(params, "steer", value)


def _floats(text: str) -> list:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers separated by commas, got {text!r}") from None


def steer(args):
    """Choose the walk's ``steer`` gain (its other parameters fixed): evaluate each of ``--values``
    on ``--seed`` (success, speed, heading·goal = mean over the episode of cos(angle between the
    torso heading and the goal direction), op3_walk return; and under ``--noise_check`` action
    noise, reported only), take the value with the highest
    heading·goal among those that keep success ≥ ``--min_success``, and check it on ``--heldout_seed``."""
    env = make_env("walk")
    steps = env.episode_length
    base = C.load("walk")
    rollout = make_rollout(env, "walk", steps)
    noisy = make_rollout(env, "walk", steps, noise=args.noise_check) if args.noise_check > 0 else None

    def run(value, seed, fn=rollout):
        prm = with_steer(base, value)
        keys = jax.random.split(jax.random.PRNGKey(seed), args.episodes)
        st = jax.device_get(fn(jnp.asarray(np.repeat(prm[None], args.episodes, 0)), keys, jax.random.PRNGKey(0)))
        return prm, summary("walk", st, steps, env.dt)

    t0 = time.time()
    grid = []
    for v in args.values:
        _, res = run(v, args.seed)
        grid.append(dict(steer=float(v), **res))
        if noisy is not None:  # robustness, reported only: not part of the choice
            grid[-1][f"noise_{args.noise_check:g}"] = run(v, args.seed, noisy)[1]
        print(json.dumps(grid[-1]), flush=True)
    ok = [g for g in grid if g["success"] >= args.min_success]
    if not ok:
        raise SystemExit(f"no steer value in {args.values} keeps success >= {args.min_success}")
    best = max(ok, key=lambda g: g["heading_goal"])
    prm, held = run(best["steer"], args.heldout_seed)
    _, held0 = run(0.0, args.heldout_seed)
    rec = dict(command=command_line(), episodes=args.episodes, seed=args.seed, grid=grid, chosen=best["steer"],
               rule=f"highest heading_goal with success >= {args.min_success} on seed {args.seed}",
               heldout=dict(seed=args.heldout_seed, chosen=held, steer_0=held0), wall_time_s=round(time.time() - t0, 1))
    print(json.dumps(dict(chosen=best["steer"], heldout=rec["heldout"]), indent=1))
    if args.write:
        write_ckpt("walk", prm, {"steering": rec})


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m research.op3_skills", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("search")
    s.add_argument("--skill", choices=sorted(TASK), required=True)
    s.add_argument("--generations", type=int, default=30)
    s.add_argument("--pop", type=int, default=24)
    s.add_argument("--elite", type=float, default=0.25)
    s.add_argument("--episodes", type=int, default=32, help="per candidate (getup: even; half front, half back starts)")
    s.add_argument("--steps", type=int, default=None, help="episode steps during the search")
    s.add_argument("--noise", type=float, default=0.1, help="walk: action noise std (joints)")
    s.add_argument("--std_scale", type=float, default=1.0)
    s.add_argument("--min_std", type=float, default=0.05, help="floor of the search std, × its initial value")
    s.add_argument("--smooth", type=float, default=0.2, help="weight of the old std")
    s.add_argument("--init", choices=("hand", "checkpoint"), default="hand")
    s.add_argument("--fitness", choices=("speed", "return"), default="speed",
                   help="walk: forward speed (stages 1-2) or the op3_walk return, R_walk (stage 4)")
    s.add_argument("--follow_speed", action="store_true",
                   help="walk: start the search with follow_speed on (stride scaled by the goal speed; kept fixed)")
    s.add_argument("--record", default="search", help="name of the search record in the checkpoint json")
    s.add_argument("--resume", action="store_true")
    s.add_argument("--seed", type=int, default=0)
    e = sub.add_parser("evaluate")
    e.add_argument("--skill", choices=sorted(TASK), required=True)
    e.add_argument("--episodes", type=int, default=64)
    e.add_argument("--seed", type=int, default=12345)
    e.add_argument("--params", default=None, help="checkpoint json (default checkpoints/op3/<skill>.json)")
    e.add_argument("--init_params", action="store_true", help="evaluate the hand-made initial parameters")
    e.add_argument("--noise", type=float, default=0.0, help="Gaussian noise std on the joint actions (robustness)")
    e.add_argument("--bank_seed", type=int, default=None,
                   help="getup: draw the prone starts from a bank of this seed (default: the env's, which the search "
                        "tuned on; another seed is a held-out check)")
    e.add_argument("--goal_speed", type=float, choices=E.GOAL_SPEEDS, default=None,
                   help="a fixed target speed (m/s) instead of both equally likely")
    e.add_argument("--write", action="store_true", help="store the result in the checkpoint record")
    t = sub.add_parser("steer", help="choose the walk's steer gain on a grid (docs/research/op3_skills.md)")
    t.add_argument("--values", type=_floats,
                   default=[0.0, -0.02, -0.03, -0.045, -0.06, -0.08, 0.03, 0.045])
    t.add_argument("--episodes", type=int, default=64)
    t.add_argument("--seed", type=int, default=12345)
    t.add_argument("--heldout_seed", type=int, default=777)
    t.add_argument("--min_success", type=float, default=0.95)
    t.add_argument("--noise_check", type=float, default=0.05,
                   help="also report each value under this joint-action noise std (0: skip)")
    t.add_argument("--write", action="store_true", help="store the chosen gain and the grid in checkpoints/op3/walk.json")
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    {"search": search, "evaluate": evaluate, "steer": steer}[args.cmd](args)


if __name__ == "__main__":
    main()
