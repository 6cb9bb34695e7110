"""The new skill of a run's checkpoint acting alone with its mean action: one action dimension's
mean and std, and chosen observation entries, at every step of a few episodes (where a
deterministic read-out gets stuck; docs/scheduler.md §8).

    python -m training.experiments.action_trace RUN_DIR --dim 4 --obs finger_angle,grasp --episodes 4 --json OUT.json

With each step's action the trace holds the new skill's critic there (the minimum over its critics, as
CRR's advantage takes it): ``q_mean`` at the mean action, ``q_up`` / ``q_down`` at the mean action with
dimension ``--dim`` set to +1 / −1, and ``v`` the mean over 16 actions sampled from the Gaussian (CRR's
baseline, ``crr.crr_advantage``). So ``q_up − v`` is the advantage CRR gives an action that opens
the fingers there, and ``q_mean − v`` the mean action's.

``--dim``: the action index (manipulation: 0-2 pinch velocity, 3 wrist yaw, 4 fingers); ``--obs``:
observation entries of the manipulation layout (``tasks.manipulation.layout.OBS_SLICES``; a
pose is traced as its position). Episodes reset from ``PRNGKey(--seed)`` (``jax.random.split`` into one key per
episode). Prints every ``--every``-th step per episode and the episode's success; ``--json`` writes
every step.
"""

from __future__ import annotations

import json

from training.cli import Parser, UsageError, main_guard, positive_int


def trace(env, trainer, state, dim: int, obs_index: dict, episodes: int, seed: int) -> dict:
    """{"mean", "std", "q_mean", "q_up", "q_down", "v": [T, E] (action ``dim``; the critic values of the
    module docstring); obs name: [T, E, size]; "success": [E]} of ``episodes`` mean-action episodes of
    the checkpoint's new skill. ``obs_index``: name -> slice."""
    import jax
    import numpy as np

    import jax.numpy as jnp

    from parallel_skills import learners, networks
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
        samples = networks.sample_action(jnp.broadcast_to(mean[:, None], (episodes, 16, mean.shape[-1])),
                                         jnp.broadcast_to(std[:, None], (episodes, 16, mean.shape[-1])), k_v)
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


def main(argv=None):
    p = Parser(prog="python -m training.experiments.action_trace", description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="a training.run directory holding a checkpoint (manipulation task)")
    p.add_argument("--dim", type=int, default=4, help="action index to trace")
    p.add_argument("--obs", default="finger_angle,grasp", help="comma-separated observation entries")
    p.add_argument("--episodes", type=positive_int, default=4)
    p.add_argument("--every", type=positive_int, default=25, help="print every this many steps")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)

    def run():
        from tasks.manipulation import layout as L
        from training.experiments.readouts import load_run_state

        names = [n for n in args.obs.split(",") if n]
        bad = [n for n in names if n not in L.OBS_SLICES]
        if bad:
            raise UsageError(f"--obs: unknown entry {bad[0]!r}; valid: {', '.join(L.OBS_SLICES)}")
        env, trainer, state, host = load_run_state(args.run)
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
        return out

    return main_guard(run)


if __name__ == "__main__":
    main()
