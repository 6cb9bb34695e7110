"""OP3 locomotion on the CPU fast path (``physics="mujoco"``): env steps/s next to bare
``mujoco.rollout`` of the same scene from the same start states, measured in one run.

One agent step = 25 ms = ``substeps`` (5) physics steps of 5 ms. Rows, per batch B and host
threads N (ratios are agent steps/s over the ``mujoco.rollout`` row of the same B and N):

* ``mujoco.rollout``: the bare C rollout (no JAX, no observation code), B trajectories of
  T·substeps physics steps, N threads (one MjData per thread);
* ``host stepper``: the env's ``_HostStepper.step`` called T times from Python (what the env's
  host callback does: per env ``mj_setState``, ``substeps`` × ``mj_step``, ``mj_getState``, checks);
* ``env``: ``jit(scan(vmap(env.step)))`` over T agent steps (``tasks.make("getup_and_walk",
  physics="mujoco", num_threads=N)``); compile time of that function in its own column;
* ``env, 0 substeps``: the same compiled function with the host stepper doing no physics step: the
  cost of everything but the physics (JAX observation / reward / start sampling, the callback, the
  stepper's per-env Python loop).

The methods take turns for ``--repeats`` rounds and each keeps its best time, so that a change in
the load of a shared machine hits all rows of a (B, N) block alike.

Start states: ``vmap(env.reset)`` (2/3 prone). The env's action is constant per env, its reset
filter state, so the joint targets are constant (≈ the held start pose): the rollout gets those
controls and both simulate the same trajectories (the script prints the final qpos difference).
Also, for information: a Python loop of ``mujoco.mj_step`` on one MjData.

    taskset -c 1 python bench/op3_throughput.py                 # B 32 256, threads 1 2, T 100
    python bench/op3_throughput.py --batch 256 --threads 2 --repeats 1

Measured 2026-12-02, 2-core CPU, shared (other jobs busy on both cores, one of them on core 1 too),
mujoco 4.0.0, jax 0.10.2, 8.5 min wall:

    $ taskset -c 1 python bench/op3_throughput.py
    note: 2 threads on 1 core(s): the multi-thread rows time-share
    method                               batch threads env steps/s physics steps/s x rollout compile s
    mujoco.rollout                          32       1       1,882           9,409      1.00
    host stepper (Python loop, no JAX)      32       1       1,485           7,423      0.79
    env jit(scan(vmap(step)))               32       1       1,307           6,535      0.69      19.2
    env, 0 substeps (all but physics)       32       1      11,592               -      6.16
    mujoco.rollout                          32       2       1,765           8,825      1.00
    host stepper (Python loop, no JAX)      32       2       1,489           7,445      0.84
    env jit(scan(vmap(step)))               32       2       1,161           5,803      0.66      22.2
    env, 0 substeps (all but physics)       32       2       8,040               -      4.56
    mujoco.rollout                         256       1       1,679           8,396      1.00
    host stepper (Python loop, no JAX)     256       1       1,495           7,474      0.89
    env jit(scan(vmap(step)))              256       1       1,334           6,669      0.79      23.6
    env, 0 substeps (all but physics)      256       1      16,847               -     10.03
    mujoco.rollout                         256       2       2,719          13,595      1.00
    host stepper (Python loop, no JAX)     256       2       2,466          12,328      0.91
    env jit(scan(vmap(step)))              256       2       2,245          11,224      0.83      22.5
    env, 0 substeps (all but physics)      256       2      30,162               -     11.09
    mj_step Python loop (1 MjData)           1       1       2,908          14,540         -
    final qpos max |env - rollout| 2.1e-08 in all four blocks, no NaN resets

The other job on core 1 eased during the last block (B 256, 2 threads) and the mj_step loop:
compare rows within a block, not across blocks. On one core the env runs at 0.66-0.79 of bare
rollout (0.79 at B 256); a second thread on the same core changes nothing. Per env step at B 256:
rollout 596 µs, env 750 µs, of which ≈ 60 µs is not physics (the ``0 substeps`` row; ≈ 35 µs of it the
host stepper's per-env Python loop, timed apart, the rest the JAX observation / reward / start sampling code and
the callback); at B 32 the non-physics part is 86-124 µs (per-call costs amortised over fewer envs).
The rest of the gap is physics running slower in the stepper than in the rollout (host stepper row),
within this shared machine's noise (±15 % between rounds).

Both cores (``taskset -c 0,1``, each also running another job), 1.5 min wall:

    $ taskset -c 0,1 python bench/op3_throughput.py --batch 256 --threads 2 --repeats 2
    mujoco.rollout                         256       2       4,017          20,083      1.00
    host stepper (Python loop, no JAX)     256       2       3,062          15,310      0.76
    env jit(scan(vmap(step)))              256       2       3,413          17,063      0.85       8.6
    env, 0 substeps (all but physics)      256       2      33,546               -      8.35
    mj_step Python loop (1 MjData)           1       1       3,149          15,746         -

Two threads on the two contended cores give the rollout 1.3× a single-thread mj_step loop and the
env 0.85 of that rollout (``mj_step`` releases the GIL, so the env's thread pool does run in parallel).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import mujoco
import numpy as np
from mujoco import rollout

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import tasks  # noqa: E402
from tasks.locomotion.env import STATE_SPEC  # noqa: E402

FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def rollout_inputs(model, env_states):
    """Env physics states [B, size] (STATE_SPEC) -> rollout initial states [B, nfull] and warm
    starts [B, nv]."""
    data = mujoco.MjData(model)
    full = np.empty((len(env_states), mujoco.mj_stateSize(model, FULL)))
    warm = np.empty((len(env_states), model.nv))
    for b, s in enumerate(env_states):
        mujoco.mj_setState(model, data, s, STATE_SPEC)
        mujoco.mj_getState(model, data, full[b], FULL)
        warm[b] = data.qacc_warmstart
    return full, warm


def starts(env, batch, seed):
    """Env states after ``vmap(env.reset)``, the constant action [B, NU] (the reset filter state),
    its joint targets ``ctrl`` [B, NU] (float64) and the physics states [B, size] (float64)."""
    s0 = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(seed), batch))
    action = s0.info["a_filt"]
    ctrl = np.asarray(jax.vmap(env.ctrl_of)(action), np.float64)
    return s0, action, ctrl, env.physics_states(s0)


def measure(env, batch, steps, repeats, seed):
    """Rows (method, env steps/s, physics steps/s or None, compile s or None) for one env (its
    ``num_threads``) at batch ``batch``, T = ``steps`` agent steps; the final qpos difference env vs
    rollout and the env's NaN resets. The methods take turns, ``repeats`` rounds, best time of each
    (the cores are shared: load changes during the run)."""
    model, sub, threads = env.mj_model, env.substeps, env.stepper.num_threads
    s0, action, ctrl, states0 = starts(env, batch, seed)

    # Bare rollout: [B, T·substeps, nfull] states out, constant controls [B, 1, NU] (tiled).
    full, warm = rollout_inputs(model, states0)
    datas = [mujoco.MjData(model) for _ in range(threads)]
    out = np.empty((batch, steps * sub, full.shape[1]))

    def bare():
        rollout.rollout(model, datas, full, ctrl[:, None], nstep=steps * sub, initial_warmstart=warm, state=out,
                        persistent_pool=True)

    def stepper():  # the env's host stepper alone, from Python: T calls on [B, size] states
        s = states0
        for _ in range(steps):
            s, _ = env.stepper.step(s, ctrl, states0[:, 1:1 + model.nq])

    # The env: jit(scan(vmap(step))) over T steps, final state out.
    def scan(s):
        return jax.lax.scan(lambda s, _: (jax.vmap(env.step)(s, action), None), s, None, length=steps)[0]

    t0 = time.perf_counter()
    run = jax.jit(scan).lower(s0).compile()
    compile_s = time.perf_counter() - t0
    final = {}

    def env_run():
        final["s"] = jax.block_until_ready(run(s0))

    def env_no_physics():  # substeps is read by the host stepper at run time: same compiled function
        env.stepper.substeps = 0
        try:
            jax.block_until_ready(run(s0))
        finally:
            env.stepper.substeps = sub

    methods = {"mujoco.rollout": bare, "host stepper (Python loop, no JAX)": stepper,
               "env jit(scan(vmap(step)))": env_run, "env, 0 substeps (all but physics)": env_no_physics}
    best = dict.fromkeys(methods, float("inf"))
    for _ in range(repeats):
        for name, fn in methods.items():
            t0 = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - t0)
    rows = [(name, batch * steps / t, None if "0 substeps" in name else batch * steps * sub / t,
             compile_s if name.startswith("env jit") else None) for name, t in best.items()]

    q_env = env.physics_states(final["s"])[:, 1:1 + model.nq]
    q_bare = out[:, -1, 1:1 + model.nq]
    resets = float(np.sum(final["s"].metrics["nan_resets"]))
    return rows, float(np.abs(q_env - q_bare).max()), resets


def mj_step_loop(model, states, ctrl, nstep):
    """Physics steps/s of a Python loop of ``mj_step`` on one MjData, from each start state [n, size]
    with its controls [n, NU]."""
    data = mujoco.MjData(model)
    t = 0.0
    for s, c in zip(states, ctrl):
        mujoco.mj_setState(model, data, s, STATE_SPEC)
        data.ctrl[:] = c
        t0 = time.perf_counter()
        for _ in range(nstep):
            mujoco.mj_step(model, data)
        t += time.perf_counter() - t0
    return len(states) * nstep / t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, nargs="+", default=[32, 256])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--steps", type=int, default=100, help="agent steps T per measured call")
    ap.add_argument("--repeats", type=int, default=3, help="rounds of all methods; best time of each")
    ap.add_argument("--task", default="getup_and_walk")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    envs = {n: tasks.make(args.task, physics="mujoco", num_threads=n) for n in args.threads}
    env = envs[args.threads[0]]
    print(f"{args.task}, physics mujoco, T = {args.steps} agent steps × {env.substeps} substeps, "
          f"mujoco {mujoco.__version__}, jax {jax.__version__}; {cores} of {os.cpu_count()} cores usable")
    if max(args.threads) > cores:
        print(f"note: {max(args.threads)} threads on {cores} core(s): the multi-thread rows time-share")

    head = f"{'method':<36} {'batch':>5} {'threads':>7} {'env steps/s':>11} {'physics steps/s':>15} {'x rollout':>9} {'compile s':>9}"
    print(head)
    notes = []
    for b in args.batch:
        for n in args.threads:
            rows, dq, resets = measure(envs[n], b, args.steps, args.repeats, args.seed)
            bare = rows[0][1]
            for name, sps, phys, comp in rows:
                phys_s = f"{phys:>15,.0f}" if phys else f"{'-':>15}"
                comp_s = f"{comp:>9.1f}" if comp else f"{'':>9}"
                print(f"{name:<36} {b:>5} {n:>7} {sps:>11,.0f} {phys_s} {sps / bare:>9.2f} {comp_s}", flush=True)
            notes.append(f"B {b} threads {n}: final qpos max |env - rollout| {dq:.2g}, env nan resets {resets:.0f}")

    _, _, ctrl, states0 = starts(env, min(args.batch), args.seed)
    phys = mj_step_loop(env.mj_model, states0[:8], ctrl[:8], args.steps * env.substeps)
    print(f"{'mj_step Python loop (1 MjData)':<36} {1:>5} {1:>7} {phys / env.substeps:>11,.0f} {phys:>15,.0f} "
          f"{'-':>9} {'':>9}")
    for line in notes:
        print(line)


if __name__ == "__main__":
    main()
