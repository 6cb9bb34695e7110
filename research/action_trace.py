"""The new skill of a run's checkpoint acting alone with its mean action: one action dimension's
mean and std, and chosen observation entries, at every step of a few episodes (where a
deterministic read-out gets stuck; docs/research/scheduler.md §8).

    python -m research.action_trace RUN_DIR --dim 4 --obs finger_angle,grasp --episodes 4 --json OUT.json

With each step's action the trace holds the new skill's critic there (the minimum over its critics, as
CRR's advantage takes it): ``q_mean`` at the mean action, ``q_up`` / ``q_down`` at the mean action with
dimension ``--dim`` set to +1 / −1, and ``v`` the mean over 16 actions sampled from the Gaussian (CRR's
baseline, ``crr.mean_baseline_advantage``). So ``q_up − v`` is the advantage CRR gives an action that opens
the fingers there, and ``q_mean − v`` the mean action's.

``--over TOP,BOTTOM`` (e.g. ``green,yellow``) adds the grasp and both cubes' poses to the trace and
a summary: per episode, the steps where TOP is held over BOTTOM (horizontally within 0.03 m, at
least 0.03 m higher) and the means over them of the traced dimension's mean and std and of the
critic's advantages ``q_mean − v``, ``q_up − v``, ``q_down − v``; ``--summary_json`` writes it (small,
for docs/results; ``--json`` holds every step).

``--dim``: the action index (manipulation: 0-2 pinch velocity, 3 wrist yaw, 4 fingers); ``--obs``:
observation entries of the manipulation layout (``tasks.manipulation.layout.OBS_SLICES``; a
pose is traced as its position). Episodes reset from ``PRNGKey(--seed)`` (``jax.random.split`` into one key per
episode). Prints every ``--every``-th step per episode and the episode's success; ``--json`` writes
every step.
"""

from __future__ import annotations

import json
import os

from training.cli import Parser, UsageError, main_guard, positive_int


def trace(env, trainer, state, dim: int, obs_index: dict, episodes: int, seed: int) -> dict:
    """{"mean", "std", "q_mean", "q_up", "q_down", "v": [T, E] (action ``dim``; the critic values of the
    module docstring); obs name: [T, E, size]; "success": [E]} of ``episodes`` mean-action episodes of
    the checkpoint's new skill. ``obs_index``: name -> slice."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from parallel_skills import learners
    from parallel_skills import normalization as obs_norm

    _, critic = learners.new_skill_networks(int(env.action_size), trainer.config.new_skill)
    critic_params = state.new_skill.critic_params

    def q_min(obs, action):  # [E, O], [E, A] or [E, J, A] -> min over the critics
        return jnp.min(learners.critic_values(critic, critic_params, obs, action), axis=-1)

    new_apply = learners.make_new_skill_apply(int(env.action_size), trainer.config.new_skill)
    params, norm = state.new_skill.policy_params, state.normalizer
    start = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(seed), episodes))
    idx = np.concatenate([np.arange(sl.start, sl.stop) for sl in obs_index.values()]).astype(np.int32)

    def step(carry, _):
        s, key = carry
        key, k_v = jax.random.split(key)
        o = obs_norm.normalize(norm, s.obs)
        mean, std = new_apply(params, o)
        samples = learners.sample_n(mean, std, 16, k_v)
        critic_out = (q_min(o, mean), q_min(o, mean.at[:, dim].set(1.0)), q_min(o, mean.at[:, dim].set(-1.0)),
                      jnp.mean(q_min(learners.tile_obs(o, 16), samples), axis=1))
        nxt = jax.vmap(env.step)(s, mean)
        return (nxt, key), (mean[:, dim], std[:, dim], s.obs[:, idx], nxt.metrics["success"], critic_out)

    _, (m, sd, obs, success, (q_mean, q_up, q_down, v)) = jax.device_get(jax.jit(
        lambda s: jax.lax.scan(step, (s, jax.random.PRNGKey(seed + 1)), None, length=int(env.episode_length)))(start))
    out = {"mean": np.asarray(m), "std": np.asarray(sd), "success": np.asarray(success).max(axis=0),
           "q_mean": np.asarray(q_mean), "q_up": np.asarray(q_up), "q_down": np.asarray(q_down), "v": np.asarray(v)}
    at = 0
    for name, sl in obs_index.items():
        out[name] = np.asarray(obs)[:, :, at:at + sl.stop - sl.start]
        at += sl.stop - sl.start
    return out


OVER_XY, OVER_Z = 0.03, 0.03  # --over: TOP held within OVER_XY (horizontal) and OVER_Z above BOTTOM


def held_over(grasp, top_pos, bottom_pos):
    """bool [...]: the top cube held (grasp [...] > 0.5) over the bottom one, within OVER_XY
    horizontally and more than OVER_Z above it (positions [..., 3]; numpy)."""
    import numpy as np

    d = top_pos - bottom_pos
    return (grasp > 0.5) & (np.linalg.norm(d[..., :2], axis=-1) < OVER_XY) & (d[..., 2] > OVER_Z)


def parse_over(text: str) -> tuple[str, str]:
    """``"green,yellow"`` -> ("green", "yellow"); UsageError (one line) unless two different cube names."""
    from tasks.manipulation import layout as L

    over = text.split(",")
    if len(over) != 2 or over[0] == over[1] or not all(c in L.CUBE_NAMES for c in over):
        raise UsageError(f"--over takes two different cube names TOP,BOTTOM ({', '.join(L.CUBE_NAMES)}), got {text!r}")
    return over[0], over[1]


def over_target_summary(out: dict, top: str, bottom: str) -> dict:
    """--over's summary of a ``trace`` holding "grasp", "<top>_pose", "<bottom>_pose": per episode,
    the success, the number of steps with TOP held over BOTTOM, and the means over those steps of
    the traced dimension's mean / std and the critic's advantages (None where there are none)."""
    import numpy as np

    over = held_over(out["grasp"][..., 0], out[f"{top}_pose"], out[f"{bottom}_pose"])  # [T, E]
    stats = {"mean": out["mean"], "std": out["std"], "q_mean_minus_v": out["q_mean"] - out["v"],
             "q_up_minus_v": out["q_up"] - out["v"], "q_down_minus_v": out["q_down"] - out["v"], "v": out["v"]}
    episodes = []
    for e in range(over.shape[1]):
        t = np.flatnonzero(over[:, e])
        row = {"success": int(out["success"][e]), "steps_over": int(len(t)),
               "first_step_over": int(t[0]) if len(t) else None}
        row.update({k: (round(float(np.mean(v[t, e])), 4) if len(t) else None) for k, v in stats.items()})
        episodes.append(row)
    steps = over.sum()
    pooled = {k: round(float(np.sum(np.where(over, v, 0.0)) / max(steps, 1)), 4) for k, v in stats.items()}
    return {"top": top, "bottom": bottom, "episodes_success": int(out["success"].sum()),
            "episodes": int(over.shape[1]), "episodes_ever_over": int(np.any(over, axis=0).sum()),
            "steps_over": int(steps), "over_step_means": pooled, "per_episode": episodes}


def main(argv=None):
    p = Parser(prog="python -m research.action_trace", description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="a training.run directory holding a checkpoint (manipulation task)")
    p.add_argument("--dim", type=int, default=4, help="action index to trace")
    p.add_argument("--obs", default="finger_angle,grasp", help="comma-separated observation entries")
    p.add_argument("--episodes", type=positive_int, default=4)
    p.add_argument("--every", type=positive_int, default=25, help="print every this many steps")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    p.add_argument("--over", default=None, help="TOP,BOTTOM cube names: summarise the steps TOP is held over BOTTOM")
    p.add_argument("--summary_json", default=None, help="write --over's summary to this file")
    args = p.parse_args(argv)

    def run():
        from tasks.manipulation import layout as L
        from training.run_files import load_checkpointed_run

        names = [n for n in args.obs.split(",") if n]
        over = list(parse_over(args.over)) if args.over else []
        if args.summary_json and not over:
            raise UsageError("--summary_json needs --over TOP,BOTTOM")
        names += [n for n in ["grasp"] + [f"{c}_pose" for c in over] if over and n not in names]
        bad = [n for n in names if n not in L.OBS_SLICES]
        if bad:
            raise UsageError(f"--obs: unknown entry {bad[0]!r}; valid: {', '.join(L.OBS_SLICES)}")
        loaded = load_checkpointed_run(args.run)
        env, trainer, state, host = loaded.env, loaded.trainer(), loaded.state, loaded.host
        if not 0 <= args.dim < int(env.action_size):
            raise UsageError(f"--dim must be an action index in 0..{int(env.action_size) - 1}, got {args.dim}")
        if int(env.observation_size) != L.OBS_SIZE:
            raise UsageError(f"{args.run} is not a manipulation run (observation size {env.observation_size})")
        sl = {n: L.OBS_SLICES[n] for n in names}  # poses: their position only
        sl = {n: slice(s.start, s.start + 3) if n.endswith("pose") or n.endswith("pose_wrt_pinch") else s
              for n, s in sl.items()}
        out = trace(env, trainer, state, args.dim, sl, args.episodes, args.seed)
        for e in range(args.episodes):
            print(f"episode {e}: success {int(out['success'][e])}")
            for t in range(0, out["mean"].shape[0], args.every):
                extra = " ".join(f"{n}=" + ",".join(f"{v:.3f}" for v in out[n][t, e]) for n in names)
                print(f"  t={t:3d} mean={out['mean'][t, e]:+.2f} std={out['std'][t, e]:.2f} "
                      f"q_mean-v={out['q_mean'][t, e] - out['v'][t, e]:+.2f} q_up-v={out['q_up'][t, e] - out['v'][t, e]:+.2f} "
                      f"v={out['v'][t, e]:.2f} {extra}")
        if args.json:
            with open(args.json, "w") as f:
                json.dump({"env_steps": int(host["env_steps"]), "dim": args.dim, "seed": args.seed,
                           **{k: v.round(4).tolist() for k, v in out.items()}}, f)
        if over:
            summary = over_target_summary(out, over[0], over[1])
            print(f"{over[0]} held over {over[1]}: {summary['steps_over']} steps in {summary['episodes_ever_over']} "
                  f"of {summary['episodes']} episodes; means there " + " ".join(
                      f"{k}={v:+.2f}" for k, v in summary["over_step_means"].items()))
            if args.summary_json:
                with open(args.summary_json, "w") as f:
                    json.dump({"run": os.path.basename(os.path.normpath(args.run)), "env_steps": int(host["env_steps"]),
                               "dim": args.dim, "seed": args.seed, **summary}, f, indent=1)
            out["summary"] = summary
        return out

    return main_guard(run)


if __name__ == "__main__":
    main()
