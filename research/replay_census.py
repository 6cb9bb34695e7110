"""What the new skill's CRR fit sees where a cube is held over another: the stored transitions at
those states in a run's checkpointed replay, counted by the skill that acted and by the sign of one
action dimension, with the checkpoint's CRR weights f(A) (docs/research/skills.md, "What the critic says").

    python -m research.replay_census RUN_DIR --over green,yellow --json OUT.json

``RUN_DIR``: a ``training.run`` directory of a manipulation task whose checkpoint holds its replay
(``replay_checkpoint``, the default). Rows where TOP is held over BOTTOM (``action_trace``'s test:
held, within 0.03 m horizontally, more than 0.03 m above) are split by the sign of action ``--dim``
(manipulation: 4 the fingers, where one positive step releases a held cube): "up" (> 0) and
"down" (≤ 0). For each part and each acting skill: the number of rows, the sum of their CRR
weights f(A) (A = min-critic Q(s, a) − mean over ``new_skill.num_action_samples`` policy samples,
as ``learners.new_skill_loss`` computes it, with the run's ``crr_mode`` / ``crr_beta`` /
``crr_clip``), and the weighted mean of the dimension, which is where CRR's weighted maximum
likelihood pulls the Gaussian's mean at those states; beside it the policy's mean there.
"""

from __future__ import annotations

import json
import os

from training.cli import Parser, UsageError, main_guard


def over_rows(obs, top: str, bottom: str):
    """bool [R]: raw observations [R, O] where cube ``top`` is held over ``bottom``
    (``action_trace.held_over``)."""
    from tasks.manipulation import layout as L
    from research.action_trace import held_over

    return held_over(obs[:, L.GRASP], obs[:, L.cube_pos(top)], obs[:, L.cube_pos(bottom)])


def census(run, top: str, bottom: str, dim: int, key_seed: int = 0, chunk: int = 4096) -> dict:
    """The module docstring's table for a ``run_files.load_checkpointed_run`` result."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from parallel_skills import learners
    from parallel_skills import normalization as obs_norm
    from parallel_skills.crr import crr_weights, mean_baseline_advantage
    from parallel_skills.train import make_replay

    cfg = run.config.new_skill
    replay = make_replay(run.env, run.config, len(run.skills))
    exp = run.state.replay.experience
    size = int(replay.size(run.state.replay))
    obs = np.asarray(exp.obs).reshape(-1, exp.obs.shape[-1])[:size]
    action = np.asarray(exp.action).reshape(-1, exp.action.shape[-1])[:size]
    skill = np.asarray(exp.skill).reshape(-1)[:size]
    weight = np.asarray(exp.weight).reshape(-1)[:size]
    rows = np.flatnonzero(over_rows(obs, top, bottom) & (weight > 0))
    policy, critic = learners.new_skill_networks(int(run.env.action_size), cfg)
    ns, norm, j = run.state.new_skill, run.state.normalizer, int(cfg.num_action_samples)

    @jax.jit
    def crr_of(o, a, key):
        o = obs_norm.normalize(norm, o)
        mean, std = policy.apply(ns.policy_params, o)
        a_j = learners.sample_n(mean, std, j, key)
        q = jnp.min(learners.critic_values(critic, ns.critic_params, o, a), axis=-1)
        q_j = jnp.min(learners.critic_values(critic, ns.critic_params, learners.tile_obs(o, j), a_j), axis=-1)
        adv = mean_baseline_advantage(q, q_j)
        return crr_weights(adv, cfg.crr_mode, cfg.crr_beta, cfg.crr_clip), adv, mean[:, dim]

    w, adv, pmean = [], [], []
    key = jax.random.PRNGKey(key_seed)
    for start in range(0, len(rows), chunk):
        r = rows[start:start + chunk]
        pad = chunk - len(r)
        o = np.concatenate([obs[r], np.zeros((pad, obs.shape[1]), obs.dtype)])
        a = np.concatenate([action[r], np.zeros((pad, action.shape[1]), action.dtype)])
        wi, ai, mi = jax.device_get(crr_of(o, a, jax.random.fold_in(key, start)))
        w.append(np.asarray(wi)[:len(r)]), adv.append(np.asarray(ai)[:len(r)]), pmean.append(np.asarray(mi)[:len(r)])
    w = np.concatenate(w) if w else np.zeros(0)
    adv = np.concatenate(adv) if adv else np.zeros(0)
    pmean = np.concatenate(pmean) if pmean else np.zeros(0)
    a_dim = action[rows, dim]
    names = list(run.record.skills) + ["new_skill"]

    def part(mask) -> dict:
        out = {"rows": int(mask.sum()), "crr_weight_sum": round(float(w[mask].sum()), 3),
               "mean_advantage": round(float(adv[mask].mean()), 4) if mask.any() else None,
               "by_skill": {}}
        for i, name in enumerate(names):
            m = mask & (skill[rows] == i)
            if m.any():
                out["by_skill"][name] = {"rows": int(m.sum()), "crr_weight_sum": round(float(w[m].sum()), 3)}
        return out

    up = a_dim > 0
    total_w = float(w.sum())
    return {"top": top, "bottom": bottom, "dim": dim, "replay_rows": size, "rows_over": int(len(rows)),
            "up": part(up), "down": part(~up),
            "unweighted_mean_of_dim": round(float(a_dim.mean()), 4) if len(rows) else None,
            "crr_weighted_mean_of_dim": round(float((w * a_dim).sum() / total_w), 4) if total_w > 0 else None,
            "policy_mean_of_dim": round(float(pmean.mean()), 4) if len(rows) else None,
            "crr": {"mode": cfg.crr_mode, "beta": cfg.crr_beta, "clip": cfg.crr_clip, "samples": j}}


def main(argv=None):
    p = Parser(prog="python -m research.replay_census", description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="a training.run directory whose checkpoint holds its replay (manipulation task)")
    p.add_argument("--over", default="green,yellow", help="TOP,BOTTOM cube names")
    p.add_argument("--dim", type=int, default=4, help="the action index split by sign (4: the fingers)")
    p.add_argument("--seed", type=int, default=0, help="seed of the policy samples in the CRR baseline")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)

    def run():
        from tasks.manipulation import layout as L
        from research.action_trace import parse_over
        from training.run_files import load_checkpointed_run

        over = parse_over(args.over)
        if not os.path.isdir(args.run):
            raise UsageError(f"run directory {args.run} does not exist")
        loaded = load_checkpointed_run(args.run)
        if int(loaded.env.observation_size) != L.OBS_SIZE:
            raise UsageError(f"{args.run} is not a manipulation run (observation size {loaded.env.observation_size})")
        if not 0 <= args.dim < int(loaded.env.action_size):
            raise UsageError(f"--dim must be an action index in 0..{int(loaded.env.action_size) - 1}, got {args.dim}")
        out = census(loaded, over[0], over[1], args.dim, args.seed)
        print(f"{out['rows_over']} of {out['replay_rows']} stored rows hold {over[0]} over {over[1]}: "
              f"action {args.dim} > 0 in {out['up']['rows']} (CRR weight {out['up']['crr_weight_sum']:.1f}), "
              f"<= 0 in {out['down']['rows']} (CRR weight {out['down']['crr_weight_sum']:.1f}); mean of it "
              f"{out['unweighted_mean_of_dim']}, CRR-weighted {out['crr_weighted_mean_of_dim']}, "
              f"the policy's mean there {out['policy_mean_of_dim']}")
        if args.json:
            with open(args.json, "w") as f:
                json.dump({"run": os.path.basename(os.path.normpath(args.run)), "env_steps": int(loaded.host["env_steps"]),
                           "seed": args.seed, **out}, f, indent=1)
        return out

    return main_guard(run)


if __name__ == "__main__":
    main()
