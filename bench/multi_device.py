"""Data parallelism over devices: env steps/s, learner updates/s and whole iterations for 1 vs D
devices at the same global num_envs and learner batches, measured in one run of this script (each
device count in its own subprocess: XLA fixes the device count when it starts).

    python bench/multi_device.py                        # 1 vs 2 forced host devices, cpu recipe, lift
    python bench/multi_device.py --devices 2 --num_envs 256 --recipe parallel

On a CPU the devices are forced host devices (``--xla_force_host_platform_device_count``) sharing
the machine's cores: expect a ratio near 1 (or below: the partitioned program adds collectives). The
bench is for accelerators, where each device brings its own compute: run it there with
``--real_devices`` (the host's own devices, no forcing; D = all of them).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def worker(args) -> dict:
    """Timings on this process's devices (all of them), printed as JSON."""
    sys.path.insert(0, ROOT)
    import jax

    from iteration_breakdown import best_of  # (bench/ is this script's directory)

    import tasks
    from parallel_skills import Skill, TrainConfig, sharding
    from parallel_skills.config import resolve
    from parallel_skills.train import compile_trainer, make_trainer
    from tasks.manipulation import scripted
    from training import skill_library

    env = tasks.make(args.task)
    skills = [Skill.from_fn(n, scripted.get(n)) for n in skill_library.skill_names(args.task, "useful")]
    cfg, _ = resolve(TrainConfig(recipe=args.recipe, num_envs=args.num_envs))
    mesh = sharding.make_mesh() if jax.device_count() > 1 else None
    trainer = make_trainer(env, skills, cfg, mesh)
    init, iteration, _ = compile_trainer(trainer, mesh, seed_axis=False)
    state = init(jax.random.PRNGKey(0))
    for _ in range(args.fill):  # the replay above both learners' minimum
        state, _ = iteration(state)
    key = jax.random.PRNGKey(1)
    if mesh is None:
        def jit(fn, state_out=False):
            return jax.jit(fn)
    else:
        shard = sharding.state_shardings(jax.eval_shape(lambda s: s, state), mesh, cfg.num_envs)

        def jit(fn, state_out=False):
            """Jitted on the mesh: the state in, a state (``state_out``) or replicated values out."""
            return jax.jit(fn, in_shardings=(shard,), out_shardings=shard if state_out else sharding.replicated(mesh))

    acting = jit(lambda s: trainer.collect_insert(s, key)[0], state_out=True)
    learning = jit(lambda s: trainer.learn(s, key)[:2])
    whole = jit(lambda s: trainer.iteration(s)[0], state_out=True)
    t_act, t_learn, t_whole = best_of(acting, state), best_of(learning, state), best_of(whole, state)
    updates = trainer.scheduler_updates + trainer.new_skill_updates
    return {"devices": jax.device_count(), "backend": jax.default_backend(), "num_envs": cfg.num_envs,
            "recipe": cfg.recipe, "scheduler_batch": cfg.scheduler.batch_size,
            "new_skill_batch": cfg.new_skill.batch_size, "updates": updates,
            "env_steps_per_s": cfg.steps_per_iteration / t_act, "learner_updates_per_s": updates / t_learn,
            "iteration_env_steps_per_s": cfg.steps_per_iteration / t_whole}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="lift")
    p.add_argument("--recipe", default="cpu")
    p.add_argument("--num_envs", type=int, default=64)
    p.add_argument("--devices", type=int, default=2, help="forced host devices to compare with 1")
    p.add_argument("--real_devices", action="store_true", help="all of the host's own devices vs the first one")
    p.add_argument("--fill", type=int, default=20, help="iterations run first to fill the replay")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.worker:
        print(json.dumps(worker(args)))
        return
    base = [sys.executable, os.path.abspath(__file__), "--worker", "--task", args.task, "--recipe", args.recipe,
            "--num_envs", str(args.num_envs), "--fill", str(args.fill)]
    results = []
    for d in (1, None if args.real_devices else args.devices):
        env = dict(os.environ, PYTHONPATH=ROOT)
        if args.real_devices:
            if d == 1:  # the first device alone
                env["CUDA_VISIBLE_DEVICES"] = env.get("CUDA_VISIBLE_DEVICES", "0").split(",")[0]
        else:
            env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={d}").strip()
        proc = subprocess.run(base, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(f"worker with {d or 'all'} device(s) failed:\n{proc.stderr[-2000:]}")
        results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    one, many = results
    print(f"{args.task}, recipe {one['recipe']}, {one['num_envs']} envs (global), learner batches "
          f"{one['scheduler_batch']} / {one['new_skill_batch']} (global), {one['updates']} updates per iteration, "
          f"backend {one['backend']}")
    devices = f"{many['devices']} devices"
    print(f"{'':<34} {'1 device':>12} {devices:>12} {'ratio':>7}")
    for key, name in (("env_steps_per_s", "acting: env steps/s"), ("learner_updates_per_s", "learners: updates/s"),
                      ("iteration_env_steps_per_s", "whole iteration: env steps/s")):
        print(f"{name:<34} {one[key]:12,.1f} {many[key]:12,.1f} {many[key] / one[key]:7.2f}")


if __name__ == "__main__":
    main()
