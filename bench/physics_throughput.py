"""Throughput of the physics manipulation domain on CPU, every backend measured in the same run.

Prints agent env-steps/s (one agent step = 50 ms = ``substeps`` physics steps) for
``mjx`` (MJX impl jax), ``warp`` (MJX impl warp) and ``mujoco`` (the ``pure_callback`` env) at
several batch sizes, each as a ratio to classic MuJoCo stepping the same model with
``mujoco.rollout`` on 2 threads (``bare``: no JAX, no observation code). Also the first-call time
of ``jit(scan(vmap(step)))`` (compile) and the warm start (same call in a fresh process with the
persistent compilation cache filled).

Each (backend, batch) runs in its own subprocess; MJX-jax subprocesses are pinned to one core (it
can deadlock on a 2-core CPU otherwise: shared/STACK.md).

    python bench/physics_throughput.py                        # 16, 256, 1024 envs, all backends
    python bench/physics_throughput.py --num-envs 256 --backends bare mujoco mjx
    python bench/physics_throughput.py --variant tuned        # physics options (see VARIANTS)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

# Physics option sets compared by --variant (physics_np.load_model overrides).
VARIANTS = {
    "default": {},
    "iter2": {"iterations": 2, "ls_iterations": 4},
    "iter1": {"iterations": 1, "ls_iterations": 4},
    "nopalm": {"palm_collision": False},
    "pairs6": {"max_geom_pairs": 6},
    "pairs6_nopalm": {"max_geom_pairs": 6, "palm_collision": False},
    "pyramidal": {"cone": 0},
    "cg": {"solver": 1},  # conjugate gradient: no per-iteration Cholesky of the Hessian
    "cheap": {"cone": 0, "iterations": 2, "ls_iterations": 4, "palm_collision": False},
    # Bound, not a candidate: no contacts at all (nothing can be grasped). What the step costs without
    # any collision detection or contact constraint: no collision tuning can be faster than this.
    # (pyramidal: MJX 3.x fails on elliptic cones with no contact rows.)
    "nocontact": {"contacts": False, "cone": 0},
    "nocontact_cg": {"contacts": False, "cone": 0, "solver": 1},
}


def _worker(backend: str, num_envs: int, steps: int, variant: str, cache_dir: str) -> dict:
    import numpy as np

    overrides = VARIANTS[variant]
    if backend == "bare":
        import mujoco  # noqa: F401
        from tasks.manipulation import physics_np as P

        stepper = P.Stepper(num_threads=2, **overrides)
        states = P.init_states(np.arange(num_envs))
        rng = np.random.default_rng(0)
        ctrl = P.action_to_ctrl(rng.uniform(-1, 1, (num_envs, 1, 5)), np)
        out = np.empty((num_envs, stepper.substeps * steps, P.STATE_SIZE))
        stepper.pool.rollout(stepper.model, stepper.datas, states, ctrl, nstep=stepper.substeps, state=out[:, : stepper.substeps])
        t0 = time.perf_counter()
        stepper.pool.rollout(stepper.model, stepper.datas, states, ctrl, nstep=stepper.substeps * steps, state=out)
        run = time.perf_counter() - t0
        return {"steps_per_s": num_envs * steps / run, "run_s": run}

    import jax

    jax.config.update("jax_compilation_cache_dir", cache_dir)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    if backend == "mujoco":
        from tasks.manipulation.mujoco_env import make_mujoco_env

        env = make_mujoco_env("lift_green", num_threads=2, **overrides)
    else:
        from tasks.manipulation.mjx_env import make_mjx_env

        extra = {"max_envs": num_envs} if backend == "warp" else {}  # warp: contact buffer for the batch
        env = make_mjx_env("lift_green", impl="jax" if backend == "mjx" else "warp", **extra, **overrides)

    @jax.jit
    def run(key):
        k0, k1 = jax.random.split(key)
        s = jax.vmap(env.reset)(jax.random.split(k0, num_envs))

        def body(s, k):
            a = jax.random.uniform(k, (num_envs, 5), minval=-1.0, maxval=1.0)
            s = jax.vmap(env.step)(s, a)
            return s, s.reward

        s, r = jax.lax.scan(body, s, jax.random.split(k1, steps))
        return r

    t0 = time.perf_counter()
    jax.block_until_ready(run(jax.random.PRNGKey(0)))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(run(jax.random.PRNGKey(1)))
    run_s = time.perf_counter() - t0
    return {"steps_per_s": num_envs * steps / run_s, "run_s": run_s, "first_call_s": first}


def _spawn(backend, num_envs, steps, variant, cache_dir, timeout):
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", backend, "--num-envs", str(num_envs),
           "--steps", str(steps), "--variant", variant, "--cache-dir", cache_dir]
    if backend == "mjx" and hasattr(os, "sched_getaffinity"):
        cmd = ["taskset", "-c", str(min(os.sched_getaffinity(0)))] + cmd
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout after {timeout}s"}
    for line in reversed(out.stdout.splitlines()):
        if line.startswith("RESULT "):
            return json.loads(line[len("RESULT "):])
    return {"error": (out.stderr or out.stdout)[-400:]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--num-envs", type=int, nargs="+", default=[16, 256, 1024])
    ap.add_argument("--backends", nargs="+", default=["bare", "mujoco", "mjx", "warp"])
    ap.add_argument("--steps", type=int, default=0, help="agent steps per measurement (0: ~4096 env-steps, at least 8)")
    ap.add_argument("--variant", default="default", choices=sorted(VARIANTS))
    ap.add_argument("--cache-dir", default=os.path.join(os.path.expanduser("~"), ".cache", "parallel_skills_bench"))
    ap.add_argument("--timeout", type=int, default=900)
    ap.add_argument("--no-warm", action="store_true", help="skip the warm-start (persistent cache) rerun")
    ap.add_argument("--worker", default=None)
    args = ap.parse_args()

    if args.worker:
        res = _worker(args.worker, args.num_envs[0], args.steps, args.variant, args.cache_dir)
        print("RESULT " + json.dumps(res), flush=True)
        return

    import shutil

    print(f"variant {args.variant}: {VARIANTS[args.variant] or 'scene defaults'}; CPU cores {os.cpu_count()}")
    print(f"{'envs':>6} {'backend':>8} {'steps/s':>10} {'x bare':>7} {'first call s':>13} {'warm start s':>13}")
    for n in args.num_envs:
        steps = args.steps or max(8, 4096 // n)
        bare = None
        for backend in args.backends:
            cache = os.path.join(args.cache_dir, f"{backend}_{n}_{args.variant}")
            if backend != "bare":
                shutil.rmtree(cache, ignore_errors=True)  # a true first compile
            res = _spawn(backend, n, steps, args.variant, cache, args.timeout)
            if "error" in res:
                print(f"{n:>6} {backend:>8}  error: {res['error']}", flush=True)
                continue
            if backend == "bare":
                bare = res["steps_per_s"]
            warm = ""
            if backend != "bare" and not args.no_warm:
                w = _spawn(backend, n, steps, args.variant, cache, args.timeout)
                warm = f"{w['first_call_s']:.1f}" if "first_call_s" in w else "error"
            ratio = f"{res['steps_per_s'] / bare:.2f}" if bare else "-"
            first = f"{res['first_call_s']:.1f}" if "first_call_s" in res else ""
            print(f"{n:>6} {backend:>8} {res['steps_per_s']:>10.0f} {ratio:>7} {first:>13} {warm:>13}", flush=True)


if __name__ == "__main__":
    main()
