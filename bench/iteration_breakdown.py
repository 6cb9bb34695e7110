"""Where an iteration's time goes, at a recipe's resolved config: acting (collect + replay insert),
each learner's updates, and one evaluation (new skill alone + scheduler alone), measured in one run
on the same state (replay filled by a few iterations first). The CPU goals of docs/research/scaling.md
are about this split: on a CPU the learners are FLOP-bound, so their share is what a recipe buys.

    python bench/iteration_breakdown.py                      # the device's default recipe, lift
    python bench/iteration_breakdown.py --recipe parallel --num_envs 1024
    python bench/iteration_breakdown.py --recipe parallel --num_envs 4096 --flops   # FLOPs, no timing

``--flops``: XLA's own FLOP count (``cost_analysis``) of one compiled learner update of each learner
and of the acting part, times the updates per iteration: the FLOPs of one iteration, what a device
of a given sustained FLOP rate would need for it (a projection, not a measurement: memory traffic,
launch overheads and the env are left out). Each update is compiled on its own because XLA counts a
loop's body once, whatever its trip count; the acting part loops over ``unroll_length`` steps, so
its count is multiplied by it.
"""

from __future__ import annotations

import argparse
import json
import time

import jax

import tasks
from parallel_skills import Skill, TrainConfig, learners
from parallel_skills.config import describe_schedule, dotted_names, from_dict, learner_schedule, resolve
from parallel_skills.train import make_evaluation, make_trainer, run_learner
from tasks.manipulation import scripted
from training import skill_library


def best_of(fn, *args, repeats: int = 5) -> float:
    """Seconds of the fastest of ``repeats`` calls (after one call that compiles)."""
    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best


def breakdown(env, skills, cfg, fill: int = 4, eval_every: int = 8, repeats: int = 5, report=None) -> dict:
    """Seconds per iteration of each part at the resolved config ``cfg``, on a state whose replay
    ``fill`` iterations filled: ``{"acting + insert", "scheduler updates" (when the method learns
    it), "new-skill updates", "evaluation / <eval_every>", "whole iteration"}``. ``report(parts)``,
    if given, is called after each part with the parts measured so far."""
    trainer = make_trainer(env, skills, cfg)
    sc, nc = cfg.scheduler, cfg.new_skill
    replay = trainer.replay
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    step = jax.jit(lambda s: trainer.collect_insert(s, s.key)[0].replace(key=jax.random.fold_in(s.key, 1)))
    for _ in range(fill):
        state = step(state)

    def sched(ts, key):
        return run_learner(learners.scheduler_learner_update,
                           lambda k: replay.sample_scheduler(ts.replay, ts.normalizer, k), sc, ts.scheduler, key,
                           trainer.scheduler_updates, True)[0]

    def new(ts, key):
        return run_learner(learners.new_skill_learner_update,
                           lambda k: replay.sample_new_skill(ts.replay, ts.normalizer, k), nc, ts.new_skill, key,
                           trainer.new_skill_updates, True)[0]

    key = jax.random.PRNGKey(1)
    measures = [("acting + insert", lambda: best_of(jax.jit(lambda s: trainer.collect_insert(s, key)[0]), state,
                                                    repeats=repeats))]
    if trainer.scheduler_updates:
        measures.append(("scheduler updates", lambda: best_of(jax.jit(sched), state, key, repeats=repeats)))
    measures.append(("new-skill updates", lambda: best_of(jax.jit(new), state, key, repeats=repeats)))
    evaluate = make_evaluation(env, trainer, int(env.episode_length), 0)
    measures.append((f"evaluation / {eval_every}", lambda: best_of(lambda s: evaluate(s, 0), state, repeats=2) / eval_every))
    measures.append(("whole iteration", lambda: best_of(jax.jit(lambda s: trainer.iteration(s)[0]), state,
                                                        repeats=repeats)))
    parts = {}
    for name, measure in measures:
        parts[name] = measure()
        if report is not None:
            report(dict(parts))
    return parts


def flops_of(fn, *args) -> float:
    """XLA's FLOP count of ``fn(*args)`` compiled (``learner_scaling.compiled_flops``)."""
    from learner_scaling import compiled_flops

    return compiled_flops(jax.jit(fn).lower(*args).compile())


def iteration_flops(env, skills, cfg, fill: int = 2) -> dict:
    """FLOPs of one iteration at the resolved config ``cfg``: ``{"acting + insert", "scheduler
    update", "new-skill update", "scheduler updates", "new-skill updates", "whole iteration"}`` (the
    plural rows: one update's count times the updates per iteration; acting: the unrolled step's
    count times ``unroll_length``)."""
    trainer = make_trainer(env, skills, cfg)
    replay = trainer.replay
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    step = jax.jit(lambda s: trainer.collect_insert(s, s.key)[0].replace(key=jax.random.fold_in(s.key, 1)))
    for _ in range(fill):
        state = step(state)
    key = jax.random.PRNGKey(1)
    out = {"acting + insert": cfg.unroll_length * flops_of(lambda s: trainer.collect_insert(s, key)[0], state)}
    if trainer.scheduler_updates:
        out["scheduler update"] = flops_of(lambda ts, k: learners.scheduler_learner_update(
            ts.scheduler, replay.sample_scheduler(ts.replay, ts.normalizer, k), k, cfg.scheduler)[0], state, key)
        out["scheduler updates"] = out["scheduler update"] * trainer.scheduler_updates
    out["new-skill update"] = flops_of(lambda ts, k: learners.new_skill_learner_update(
        ts.new_skill, replay.sample_new_skill(ts.replay, ts.normalizer, k), k, cfg.new_skill)[0], state, key)
    out["new-skill updates"] = out["new-skill update"] * trainer.new_skill_updates
    out["whole iteration"] = out["acting + insert"] + out.get("scheduler updates", 0.0) + out["new-skill updates"]
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="lift")
    p.add_argument("--skills", default="useful")
    p.add_argument("--recipe", default=None, help="cpu, parallel or paper (default: the device's)")
    p.add_argument("--num_envs", type=int, default=None)
    p.add_argument("--config", default=None, help="JSON file of TrainConfig fields (as training.run --config)")
    p.add_argument("--eval_every", type=int, default=8, help="iterations per evaluation, to share its cost")
    p.add_argument("--fill", type=int, default=4, help="iterations run first to fill the replay")
    p.add_argument("--flops", action="store_true", help="count each part's FLOPs (XLA's cost analysis) instead of "
                   "timing it, and project the iteration's time at --tflops")
    p.add_argument("--tflops", default="10,30,60", help="with --flops: sustained TFLOP/s to project at")
    args = p.parse_args()

    env = tasks.make(args.task)
    names = skill_library.skill_names(args.task, args.skills)
    skills = [Skill.from_fn(n, scripted.get(n)) for n in names]
    cfg, data = TrainConfig(recipe=args.recipe, num_envs=args.num_envs), {}
    if args.config:
        with open(args.config) as f:
            data = json.load(f)
        cfg = from_dict(cfg, data, args.config)
    cfg, _ = resolve(cfg, given=dotted_names(data))
    if args.flops:
        counts = iteration_flops(env, skills, cfg, min(args.fill, 2))
        print(f"{args.task}, recipe {cfg.recipe}, {cfg.num_envs} envs, {cfg.steps_per_iteration:,} env steps per "
              f"iteration; FLOPs by XLA's cost analysis ({jax.default_backend()})")
        print(describe_schedule(learner_schedule(cfg)))
        for name, flops in counts.items():
            print(f"{name:<22} {flops / 1e9:12.2f} GFLOP")
        whole = counts["whole iteration"]
        for rate in (float(x) for x in args.tflops.split(",")):
            t = whole / (rate * 1e12)
            print(f"projection at {rate:g} TFLOP/s sustained: {1e3 * t:.1f} ms per iteration, "
                  f"{cfg.steps_per_iteration / t:,.0f} env steps/s (learners and acting's FLOPs only)")
        return
    parts = breakdown(env, skills, cfg, args.fill, args.eval_every)
    whole = parts.pop("whole iteration")
    total = sum(parts.values())
    print(f"{args.task}, recipe {cfg.recipe}, {cfg.num_envs} envs, backend {jax.default_backend()} "
          f"({jax.device_count()} device(s))")
    print(describe_schedule(learner_schedule(cfg)))
    print(f"{'part':<22} {'ms / iteration':>15} {'share':>7}")
    for name, sec in parts.items():
        print(f"{name:<22} {1e3 * sec:15.1f} {sec / total:7.1%}")
    print(f"{'sum of the parts':<22} {1e3 * total:15.1f}   -> {cfg.steps_per_iteration / total:,.0f} env steps/s")
    print(f"{'one whole iteration':<22} {1e3 * whole:15.1f}   (acting + both learners in one jitted call)")


if __name__ == "__main__":
    main()
