"""Fixed schedules of the two OP3 skills on GetUpAndWalk: what a scheduler could earn with them, and
what handing over between them costs (docs/locomotion.md, "Why the schedulers stood with the stage-3 walk").

    python -m research.op3_schedules getup walk getup_then_walk walk_then_getup:103 random:10

Each schedule drives the shipped scripted skills (checkpoints/op3/) on ``getup_and_walk`` (C engine,
``--episodes`` resets from ``--seed``, 600-step episodes, no noise), choosing the skill per step:

* ``getup`` / ``walk``: that skill alone.
* ``getup_then_walk``: the get-up until the robot has been standing (env ``standing``) for
  ``--settle`` steps in a row, then the walk; back to the get-up whenever it is not standing.
* ``walk_then_getup:N``: the walk for N steps, then the get-up (a hand-over at gait phase N).
* ``random:K``: a fair coin between the two every K steps (a uniform scheduler with one length).

Printed per schedule: mean episode return (std), success (the task's, at any step), the fraction of
steps the walk ran, falls per episode (standing -> not standing), return per start (standing, front,
back), and each reward term summed over the episode (mean over episodes). ``--json`` writes them.
"""

from __future__ import annotations

import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from training.cli import Parser, UsageError, main_guard

TERMS = ("r_orient", "r_velocity", "r_upright", "r_action", "r_pose", "r_ground")
START_NAMES = ("standing", "front", "back")


def parse_schedule(text: str) -> tuple:
    """``NAME`` or ``NAME:N`` -> (name, N or None); UsageError naming the valid forms."""
    name, _, arg = text.partition(":")
    forms = "getup, walk, getup_then_walk, walk_then_getup:N, random:K"
    if name in ("getup", "walk", "getup_then_walk") and not arg:
        return name, None
    if name in ("walk_then_getup", "random") and arg.isdigit() and int(arg) > 0:
        return name, int(arg)
    raise UsageError(f"bad schedule {text!r}: use one of {forms} (N, K positive integers)")


def choose(name: str, arg, t, stand_run, prev, coin, settle: int):
    """The skill per env (0 get-up, 1 walk) [B] at step t of the episode."""
    ones = jnp.ones_like(prev)
    if name == "getup":
        return 0 * ones
    if name == "walk":
        return ones
    if name == "getup_then_walk":
        return jnp.where(stand_run >= settle, 1, 0) * ones
    if name == "walk_then_getup":
        return jnp.where(t < arg, 1, 0) * ones
    return jnp.where(t % arg == 0, coin, prev)  # random:K


def make_rollout(env, schedule: tuple, steps: int, settle: int):
    """jit fn(keys [B, 2], coin_key) -> per-episode statistics (dict of [B])."""
    from tasks.locomotion import controllers as C

    getup, walk = C.get("getup"), C.get("walk")
    name, arg = schedule

    @jax.jit
    def rollout(keys, coin_key):
        s = jax.vmap(env.reset)(keys)
        b = keys.shape[0]
        zero = jnp.zeros(b)
        c0 = dict(s=s, choice=jnp.zeros(b, jnp.int32), stand_run=zero, ret=zero, success=zero, walk=zero,
                  falls=zero, **{k: zero for k in TERMS})

        def body(c, t):
            s = c["s"]
            standing = s.metrics["standing"] > 0.5
            stand_run = jnp.where(standing, c["stand_run"] + 1, 0.0)
            coin = jax.random.bernoulli(jax.random.fold_in(coin_key, t), 0.5, (b,)).astype(jnp.int32)
            ch = choose(name, arg, t, stand_run, c["choice"], coin, settle)
            a = jnp.where(ch[:, None] == 1, jax.vmap(walk)(s.obs), jax.vmap(getup)(s.obs))
            s2 = jax.vmap(env.step)(s, a)
            fell = standing & (s2.metrics["standing"] < 0.5)
            out = dict(s=s2, choice=ch, stand_run=stand_run, ret=c["ret"] + s2.reward,
                       success=jnp.maximum(c["success"], s2.metrics["success"]), walk=c["walk"] + ch,
                       falls=c["falls"] + fell)
            out.update({k: c[k] + s2.metrics[k] for k in TERMS})
            return out, None

        c, _ = jax.lax.scan(body, c0, jnp.arange(steps))
        out = {k: v for k, v in c.items() if k not in ("s", "choice", "stand_run")}
        out["walk"] = out["walk"] / steps
        out["start"] = s.info["start"]
        return out

    return rollout


def summarise(st: dict) -> dict:
    st = {k: np.asarray(v) for k, v in st.items()}
    rec = {"return": float(st["ret"].mean()), "return_std": float(st["ret"].std()),
           "success": float(st["success"].mean()), "walk_fraction": float(st["walk"].mean()),
           "falls_per_episode": float(st["falls"].mean()),
           "terms": {k: float(st[k].mean()) for k in TERMS}}
    for i, n in enumerate(START_NAMES):
        m = st["start"] == i
        rec[f"return_{n}"] = float(st["ret"][m].mean()) if m.any() else None
        rec[f"falls_{n}"] = float(st["falls"][m].mean()) if m.any() else None
        rec[f"episodes_{n}"] = int(m.sum())
    return rec


def main(argv=None):
    p = Parser(description=__doc__.split("\n\n")[0])
    p.add_argument("schedules", nargs="+", help="getup, walk, getup_then_walk, walk_then_getup:N, random:K")
    p.add_argument("--episodes", type=int, default=48)
    p.add_argument("--seed", type=int, default=12345)
    p.add_argument("--settle", type=int, default=20, help="getup_then_walk: standing steps before the walk")
    p.add_argument("--json", default=None, help="write the figures to this file")
    args = p.parse_args(argv)
    schedules = [parse_schedule(s) for s in args.schedules]
    if args.episodes < 1 or args.settle < 0:
        raise UsageError(f"--episodes must be ≥ 1 and --settle ≥ 0 (got {args.episodes}, {args.settle})")
    import tasks

    env = tasks.make("getup_and_walk", physics="mujoco", num_threads=1)
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
    results = {}
    for text, sched in zip(args.schedules, schedules):
        t0 = time.time()
        st = jax.device_get(make_rollout(env, sched, env.episode_length, args.settle)(keys, jax.random.PRNGKey(args.seed + 1)))
        rec = summarise(st)
        rec["wall_time_s"] = round(time.time() - t0, 1)
        results[text] = rec
        per_start = " ".join(f"{n} {rec[f'return_{n}']:.0f}" for n in START_NAMES if rec[f"return_{n}"] is not None)
        terms = " ".join(f"{k[2:]} {v:.0f}" for k, v in rec["terms"].items())
        print(f"{text:20s} return {rec['return']:6.0f} ({rec['return_std']:3.0f})  success {rec['success']:.2f}  "
              f"walk {rec['walk_fraction']:.2f}  falls/ep {rec['falls_per_episode']:.2f}  | {per_start} | {terms}",
              flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(episodes=args.episodes, seed=args.seed, settle=args.settle, results=results), f, indent=1)


if __name__ == "__main__":
    main_guard(main)
