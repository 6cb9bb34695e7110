"""Diagnostic: what the new skill, its critic and the scheduler of a SkillS ``stack`` run do where
the task is one release away (docs/research/learning.md).

Restores a run's checkpoint (the latest, or ``--step``) and probes it at fixed reference states:
*reset* (``--envs`` envs reset with ``PRNGKey(--seed)``), *hover* (then 200 steps of the scripted
``hover_green_on_yellow``: green held 5 mm above its stacked pose on yellow; opening and lifting
away from here succeeds, holding never does) and *released* (then 20 steps of scripted
``open_fingers``). Prints one table per run:

* new skill at hover: finger command mean / std, P(finger > 0) of a sampled action;
* the new skill alone for 100 steps (mean / sampled action) from hover and released states: the
  fraction of envs with any reward / reward at the end, with the cube released at any step / at
  the end;
* its critic Q (the minimum over the critics, as the learner uses; each critic's value in
  parentheses when there are several) for its own mean action, open [0,0,0,0,1], open+up
  [0,0,1,0,1] and hold [0,0,0,0,-1];
* the Monte-Carlo discounted return of 400 steps from hover, first action open or hold, then the
  new skill's mean action: the ranking the critic's open / hold values should show;
* scheduler P(skill) and P(k = shortest / longest length) at reset and hover, and its critic
  Q(s, c = k, i, k) per skill at hover for the shortest and longest length;
* replay: the new-skill critic's mean Q(s, a) over the buffer and at rewarded transitions, against
  the bound r_max / (1 − γ) no return can exceed.

    python -m research.stack_diagnostic runs/stack-skills-s0 --step 250 --json stack.json
"""

from __future__ import annotations

import argparse
import json
import os

import jax
import jax.numpy as jnp
import numpy as np

ACTIONS = {"own": None, "open": [0, 0, 0, 0, 1], "open+up": [0, 0, 1, 0, 1], "hold": [0, 0, 0, 0, -1]}
HOVER_STEPS, RELEASE_STEPS, ROLLOUT_STEPS, MC_STEPS = 200, 20, 100, 400


def scripted_run(env, name: str, state, steps: int):
    """``steps`` steps of scripted controller ``name`` from the batched env state [N, ...]."""
    from tasks.manipulation import scripted

    fn = jax.vmap(scripted.get(name))

    def act(obs, key):
        return fn(obs, jax.random.split(key, obs.shape[0]))

    return rollout(env, act, state, steps, jax.random.PRNGKey(0))[0]


def reference_states(env, num_envs: int, seed: int) -> dict:
    """Batched env states [num_envs, ...] at reset, hover-complete and released."""
    reset = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(seed), num_envs))
    hover = scripted_run(env, "hover_green_on_yellow", reset, HOVER_STEPS)
    return {"reset": reset, "hover": hover, "released": scripted_run(env, "open_fingers", hover, RELEASE_STEPS)}


def rollout(env, act, state, steps: int, key):
    """Run ``act(obs [N, O], key) -> action [N, A]`` for ``steps`` steps from the batched state:
    (final state, (reward, grasp flag) after each step, [steps, N] each)."""
    from tasks.manipulation import layout

    def body(s, k):
        s = jax.vmap(env.step)(s, act(s.obs, k))
        return s, (s.reward, s.obs[:, layout.GRASP])

    return jax.jit(lambda st, k: jax.lax.scan(body, st, jax.random.split(k, steps)))(state, key)


def q_summary(q) -> dict:
    """q [N, E] -> {"min": mean_n min_e q, "each": [mean_n q_e]}."""
    q = np.asarray(q)
    return {"min": float(q.min(-1).mean()), "each": q.mean(0).tolist()}


def analyse(run_dir: str, step, num_envs: int, seed: int) -> dict:
    """All the measurements of one run's checkpoint (see the module docstring)."""
    from parallel_skills import learners, networks
    from parallel_skills import normalization as obs_norm
    from tasks.manipulation import task_defs

    from training.run_files import load_checkpointed_run

    loaded = load_checkpointed_run(run_dir, step)
    run, cfg, env, ts = loaded.record, loaded.config, loaded.env, loaded.state
    nc, sc = cfg.new_skill, cfg.scheduler
    n_total, act_size = len(run.skills) + 1, int(env.action_size)
    policy, critic = learners.new_skill_networks(act_size, nc)
    sched_policy, sched_critic = learners.scheduler_networks(n_total, sc)
    norm, pp, cp = ts.normalizer, ts.new_skill.policy_params, ts.new_skill.critic_params
    states = reference_states(env, num_envs, seed)
    nobs = {k: obs_norm.normalize(norm, s.obs) for k, s in states.items()}
    res = {"run": run_dir, "iteration": int(ts.iteration), "env_steps": int(ts.env_steps),
           "num_critics": int(nc.num_critics), "skills": list(run.skills) + ["new"]}

    def new_skill(obs):
        return policy.apply(pp, obs_norm.normalize(norm, obs))

    def act(greedy):
        return lambda obs, k: new_skill(obs)[0] if greedy else networks.sample_action(*new_skill(obs), k)

    def fixed(a):
        return lambda obs: jnp.broadcast_to(jnp.asarray(a, jnp.float32), (obs.shape[0], act_size))

    mean, std = policy.apply(pp, nobs["hover"])
    res["finger_hover"] = {"mean": float(mean[:, 4].mean()), "std": float(std[:, 4].mean()),
                           "p_open": float(jnp.mean(1 - jax.scipy.stats.norm.cdf(0.0, mean[:, 4], std[:, 4])))}

    # The new skill alone from hover / released states.
    for start in ("hover", "released"):
        for mode in ("mean", "sample"):
            rew, grasp = (np.asarray(x) for x in rollout(env, act(mode == "mean"), states[start], ROLLOUT_STEPS,
                                                          jax.random.PRNGKey(11))[1])
            res[f"roll_{start}_{mode}"] = {"reward_any": float((rew.max(0) > 0).mean()),
                                           "reward_end": float((rew[-1] > 0).mean()),
                                           "released_any": float((grasp < 0.5).any(0).mean()),
                                           "released_end": float((grasp[-1] < 0.5).mean())}

    # Critic Q at hover / released states.
    for start in ("hover", "released"):
        own = policy.apply(pp, nobs[start])[0]
        res[f"q_{start}"] = {name: q_summary(learners.critic_values(
            critic, cp, nobs[start], own if a is None else fixed(a)(own))) for name, a in ACTIONS.items()}

    # Monte-Carlo return from hover: first action a0, then the new skill's mean action.
    gamma = float(nc.discount)
    for name in ("open", "hold"):
        s1 = jax.vmap(env.step)(states["hover"], fixed(ACTIONS[name])(states["hover"].obs))
        rew, _ = rollout(env, act(True), s1, MC_STEPS - 1, jax.random.PRNGKey(0))[1]
        rew = np.concatenate([np.asarray(s1.reward)[None], np.asarray(rew)], 0)  # [MC_STEPS, N]
        res[f"mc_{name}"] = float(((gamma ** np.arange(MC_STEPS))[:, None] * rew).sum(0).mean())

    # Scheduler: policy at reset / hover, critic per skill at hover for the shortest / longest length.
    lengths = np.asarray(sc.skill_lengths)
    k_min, k_max = int(lengths.argmin()), int(lengths.argmax())
    for start in ("reset", "hover"):
        logits_i, logits_k = sched_policy.apply(ts.scheduler.policy_params, nobs[start])
        p_k = jax.nn.softmax(logits_k, -1).mean(0)
        res[f"sched_{start}"] = {"p_skill": jax.nn.softmax(logits_i, -1).mean(0).tolist(),
                                 "p_k_min": float(p_k[k_min]), "p_k_max": float(p_k[k_max])}
    i, k, kv = (jnp.broadcast_to(jnp.asarray(x), (num_envs, len(x))) for x in networks.all_pairs(n_total, lengths))
    q = np.asarray(sched_critic.apply(ts.scheduler.critic_params, nobs["hover"], kv, i, k)).reshape(
        num_envs, n_total, len(lengths)).mean(0)
    res["sched_q_hover"] = {"k_min": q[:, k_min].tolist(), "k_max": q[:, k_max].tolist(),
                            "lengths": [int(lengths[k_min]), int(lengths[k_max])]}

    # Replay: the critic on stored transitions (obs normalised with the current statistics, as the learner does).
    rp = ts.replay
    size = int(rp.experience.reward.shape[1]) if bool(rp.is_full) else int(rp.current_index)
    ex = {key: np.asarray(getattr(rp.experience, key)[0, :size]) for key in ("obs", "action", "reward")}
    q_fn = jax.jit(lambda o, a: learners.critic_values(critic, cp, obs_norm.normalize(norm, o), a))
    chunk = 16384
    qs = []
    for lo in range(0, size, chunk):  # fixed chunk shape: one compilation
        o, a = ex["obs"][lo:lo + chunk], ex["action"][lo:lo + chunk]
        pad = chunk - len(o)
        qs.append(np.asarray(q_fn(np.pad(o, ((0, pad), (0, 0))), np.pad(a, ((0, pad), (0, 0)))))[:len(o)])
    q = np.concatenate(qs, 0) if qs else np.zeros((0, nc.num_critics))
    rewarded = ex["reward"] > 0
    sparse = task_defs.TASKS[run.task].kind == "sparse"
    r_max = max(float(ex["reward"].max(initial=0.0)), 1.0 if sparse else 0.0)
    bound = r_max / (1.0 - gamma)
    res["replay"] = {"size": size, "rewarded": int(rewarded.sum()), "bound": bound,
                     "q_all": q_summary(q) if size else None,
                     "q_rewarded": q_summary(q[rewarded]) if rewarded.any() else None,
                     "rewarded_above_bound": float((q[rewarded].min(-1) > bound).mean()) if rewarded.any() else None}
    return res


def fmt_q(s, width: int = 6) -> str:
    """"min" or "min (q_0/q_1/...)" of a ``q_summary``."""
    if s is None:
        return "-"
    out = f"{s['min']:{width}.1f}"
    return out + (" (" + "/".join(f"{v:.1f}" for v in s["each"]) + ")" if len(s["each"]) > 1 else "")


def print_table(r: dict) -> None:
    """One run's results as a compact text table."""
    name = os.path.basename(os.path.normpath(r["run"]))
    print(f"\n== {name} @ iteration {r['iteration']} ({r['env_steps']} env steps), {r['num_critics']} critic(s)")
    f = r["finger_hover"]
    print(f"new skill @hover: finger mean {f['mean']:+.3f} std {f['std']:.3f}  P(finger>0) {f['p_open']:.4f}")
    print(f"new skill alone, {ROLLOUT_STEPS} steps   reward any/end   released any/end")
    for start in ("hover", "released"):
        for mode in ("mean", "sample"):
            x = r[f"roll_{start}_{mode}"]
            print(f"  from {start:8s} {mode:6s}      {x['reward_any']:.2f} / {x['reward_end']:.2f}      "
                  f"{x['released_any']:.2f} / {x['released_end']:.2f}")
    cells = {start: [fmt_q(r[f"q_{start}"][a], 1) for a in ACTIONS] for start in ("hover", "released")}
    w = max(len(c) for c in [*ACTIONS, *cells["hover"], *cells["released"]]) + 2
    print(f"{'critic Q, min' + (' (each)' if r['num_critics'] > 1 else ''):24s}" + "".join(f"{a:>{w}s}" for a in ACTIONS))
    for start, row in cells.items():
        print(f"  @{start:21s}" + "".join(f"{c:>{w}s}" for c in row))
    print(f"MC return {MC_STEPS} steps from hover, then new-skill mean: open {r['mc_open']:.1f}  hold {r['mc_hold']:.1f}"
          f"   (critic: open {r['q_hover']['open']['min']:.1f}  hold {r['q_hover']['hold']['min']:.1f})")
    print("scheduler skills: " + ", ".join(f"{i} {s}" for i, s in enumerate(r["skills"])))
    kq = r["sched_q_hover"]
    head = "".join(f"{i:>7d}" for i in range(len(r["skills"])))
    print(f"  {'':16s}{head}   P(k={kq['lengths'][0]}) P(k={kq['lengths'][1]})")
    for start in ("reset", "hover"):
        s = r[f"sched_{start}"]
        print(f"  P(skill) @{start:6s}" + "".join(f"{p:7.3f}" for p in s["p_skill"])
              + f"   {s['p_k_min']:7.3f} {s['p_k_max']:7.3f}")
    for lab, n in (("k_min", kq["lengths"][0]), ("k_max", kq["lengths"][1])):
        print(f"  Q @hover k={n:<5d}" + "".join(f"{v:7.2f}" for v in kq[lab]))
    rp = r["replay"]
    above = "-" if rp["rewarded_above_bound"] is None else f"{rp['rewarded_above_bound']:.2f}"
    print(f"replay ({rp['size']} transitions, {rp['rewarded']} rewarded): new-skill Q mean {fmt_q(rp['q_all'], 1)}"
          f"  at rewarded {fmt_q(rp['q_rewarded'], 1)}  bound r_max/(1-γ) {rp['bound']:.1f}"
          f"  (rewarded above bound: {above})")


def main():
    from training.checkpointing import Checkpointer
    from training.cli import main_guard

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run directories of `training.run --task stack`")
    p.add_argument("--step", type=int, default=None, help="checkpoint iteration (default: each run's latest)")
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--seed", type=int, default=1234, help="PRNG seed of the reference states' resets")
    p.add_argument("--json", default=None, metavar="OUT.json", help="also write the results here")
    args = p.parse_args()

    def run():
        out = {}
        for run_dir in args.runs:
            step = Checkpointer(run_dir).latest_step() if args.step is None else args.step
            if step is None:
                print(f"\n== {run_dir}: no checkpoint, skipped")
                continue
            r = analyse(run_dir, step, args.envs, args.seed)
            print_table(r)
            out[f"{os.path.basename(os.path.normpath(run_dir))}@{r['iteration']}"] = r
            if args.json:
                with open(args.json, "w") as f:
                    json.dump(out, f, indent=1)

    main_guard(run)


if __name__ == "__main__":
    main()
