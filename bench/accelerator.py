"""The accelerator run: one command that answers, on one accelerator and within 8 minutes wall,
what docs/research/scaling.md so far only projects from CPU measurements.

Parts (each in its own process under its own time cap, so that one slow compile or one slow
learner cannot eat the window; a part stopped at its cap keeps what it measured until then):

* ``env``        kinematic lift env steps/s at 4,096 / 16,384 / 65,536 envs: the env alone
                 (``jit(vmap(step))`` in ``lax.scan``) and the acting step with both networks
                 (scheduler + frozen skills + new skill + replay insert, ``Trainer.collect_insert``).
* ``iteration``  the parallel recipe's iteration split into acting, each learner and the
                 evaluation's share, at 4,096 and 16,384 envs (``iteration_breakdown.breakdown``).
* ``lift``       kinematic lift trained with the accelerator defaults (parallel recipe, 4,096 envs)
                 until the new skill alone reaches 0.8: env steps and wall time from the start, the
                 compile time apart.
* ``stack``      stack with the same defaults for a fixed 3-minute budget: the best and last success
                 reached and the env steps done.
* ``mjx``        MJX (impl jax) lift at 4,096 envs: compile time and env steps/s.

Every part records the device's peak memory (``memory_stats``; none on a CPU). The figures print
as they come and are written to ``OUT/accelerator.json`` (``OUT/<part>.json`` per part).

    python bench/accelerator.py --out /tmp/accel            # on the accelerator
    python bench/accelerator.py --smoke --out /tmp/accel    # every part at tiny sizes on a CPU (< 3 min)
    python bench/accelerator.py --parts env,lift --cap lift=300 --out /tmp/accel

On the lent machine (it lacks mujoco, mujoco-mjx, brax and flashbax; ``bench/device_wheels.py``
downloads them as wheels into the git-ignored ``.whl/``): docs/research/scaling.md "The accelerator run".
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import signal
import subprocess
import sys
import time

sys.path.insert(1, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # the checkout, uninstalled

PARTS = ("env", "iteration", "lift", "stack", "mjx")

# Sizes and caps (seconds, the part's whole process: start-up and compiles included) of the full run:
# 8 minutes in all. The smoke run's are below it.
FULL = {
    "env": dict(num_envs=[4096, 16384, 65536], steps=100, acting_steps=16, cap=45),
    "iteration": dict(num_envs=[4096, 16384], fill=4, repeats=5, cap=60),
    "lift": dict(num_envs=4096, target=0.8, max_env_steps=20_000_000, cap=120),
    "stack": dict(num_envs=4096, budget_s=180, cap=195),
    "mjx": dict(num_envs=4096, steps=20, cap=60),
}
SMOKE = {
    "env": dict(num_envs=[8], steps=4, acting_steps=2, cap=150),
    "iteration": dict(num_envs=[8], fill=2, repeats=1, cap=150),
    "lift": dict(num_envs=8, target=0.8, max_env_steps=16, cap=150),
    "stack": dict(num_envs=8, budget_s=5, cap=150),
    "mjx": dict(num_envs=2, steps=2, cap=150),
}


# ----------------------------------------------------------------------------- the parts (child process)

def device_memory() -> dict:
    """The first local device's peak and current bytes in use (None where it keeps no statistics)."""
    import jax

    stats = jax.local_devices()[0].memory_stats() or {}
    return {"peak_bytes": stats.get("peak_bytes_in_use"), "bytes_in_use": stats.get("bytes_in_use")}


class CompileClock:
    """Seconds JAX spent tracing, lowering and compiling since it was made (JAX's monitoring
    events ``/jax/core/compile/*``)."""

    def __init__(self):
        import jax

        self.seconds = 0.0

        def listen(event, duration, **_):
            if event.startswith("/jax/core/compile/"):
                self.seconds += duration

        jax.monitoring.register_event_duration_secs_listener(listen)


def useful_skills(task: str):
    """The task's useful set of scripted skills (training.run's default)."""
    from parallel_skills import Skill
    from tasks.manipulation import scripted
    from training import skill_library

    return [Skill.from_fn(n, scripted.get(n)) for n in skill_library.skill_names(task, "useful")]


def parallel_config(num_envs: int, **fields):
    """The accelerator default (the parallel recipe) at ``num_envs``, resolved as training.run does."""
    from parallel_skills import TrainConfig
    from parallel_skills.config import resolve

    return resolve(TrainConfig(recipe="parallel", num_envs=num_envs, **fields))[0]


def part_env(p: dict, record) -> None:
    import jax

    import tasks
    from kinematic_throughput import measure
    from parallel_skills.train import make_trainer

    env = tasks.make("lift", physics="kinematic")
    skills = useful_skills("lift")
    for n in p["num_envs"]:
        state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n))
        sps, compile_s = measure(env.step, state, n, p["steps"], env.action_size)
        del state
        row = {"num_envs": n, "env_steps_per_s": sps, "env_compile_s": compile_s}
        record(f"env{n}", row)
        T = p["acting_steps"]
        cfg = parallel_config(n, unroll_length=T, replay_size=max(2 * n * T, 100_000))
        trainer = make_trainer(env, skills, cfg)
        ts = jax.jit(trainer.init)(jax.random.PRNGKey(0))
        act = jax.jit(lambda s, k: trainer.collect_insert(s, k)[0], donate_argnums=0)
        t0 = time.perf_counter()
        ts = jax.block_until_ready(act(ts, jax.random.PRNGKey(1)))
        row["acting_compile_s"] = time.perf_counter() - t0
        best = float("inf")
        for r in range(3):
            t0 = time.perf_counter()
            ts = jax.block_until_ready(act(ts, jax.random.PRNGKey(2 + r)))
            best = min(best, time.perf_counter() - t0)
        del ts
        row.update(acting_steps_per_s=n * T / best, acting_unroll=T, acting_over_env=n * T / best / sps)
        record(f"env{n}", row)


def part_iteration(p: dict, record) -> None:
    import tasks
    from iteration_breakdown import breakdown

    env = tasks.make("lift", physics="kinematic")
    skills = useful_skills("lift")
    for n in p["num_envs"]:
        cfg = parallel_config(n)
        row = {"num_envs": n, "steps_per_iteration": cfg.steps_per_iteration, "scheduler_batch": cfg.scheduler.batch_size,
               "new_skill_batch": cfg.new_skill.batch_size}

        def report(parts, row=row, name=f"iteration{n}"):
            row["ms"] = {k: 1e3 * v for k, v in parts.items()}
            if "whole iteration" in parts:
                row["env_steps_per_s"] = row["steps_per_iteration"] / parts["whole iteration"]
            record(name, row)

        breakdown(env, skills, cfg, fill=p["fill"], eval_every=cfg.eval_every, repeats=p["repeats"], report=report)


class Stop(Exception):
    """Raised from train()'s callbacks to end a measured run."""


def train_part(task: str, p: dict, record, reached) -> None:
    """Train ``task`` with the parallel recipe at ``p["num_envs"]``; ``reached(row)`` True ends it.
    Records every evaluation: env steps, wall time from the start, compile time so far."""
    import tasks
    from parallel_skills.train import train

    env = tasks.make(task, physics="kinematic")
    skills = useful_skills(task)
    cfg = parallel_config(p["num_envs"])
    clock, t0 = CompileClock(), time.perf_counter()
    evals, out = [], {"num_envs": cfg.num_envs, "recipe": cfg.recipe, "eval_every_env_steps": cfg.eval_every *
                      cfg.steps_per_iteration}

    def progress(env_steps, metrics):
        wall = time.perf_counter() - t0
        row = {"env_steps": int(env_steps), "wall_s": wall, "compile_s": clock.seconds,
               "wall_minus_compile_s": wall - clock.seconds,
               "new_skill_success": metrics.get("eval/new_skill_success"),
               "scheduler_success": metrics.get("eval/scheduler_success")}
        evals.append(row)
        out.update(evaluations=evals, last=row,
                   best_new_skill_success=max(e["new_skill_success"] or 0.0 for e in evals))
        record(task, out)
        if reached(row):
            raise Stop

    def step(env_steps):
        out["env_steps_done"] = int(env_steps)
        if "budget_s" in p and time.perf_counter() - t0 >= p["budget_s"]:
            raise Stop

    try:
        train(env, skills, num_timesteps=p.get("max_env_steps", 10**9), seed=0, config=cfg,
              progress_fn=progress, step_fn=step, auto_config=False)
    except Stop:
        pass
    out["stopped_at_wall_s"] = time.perf_counter() - t0
    record(task, out)


def part_lift(p: dict, record) -> None:
    def reached(row):
        if (row["new_skill_success"] or 0.0) >= p["target"]:
            row["reached_target"] = p["target"]
            return True
        return False

    train_part("lift", p, record, reached)


def part_stack(p: dict, record) -> None:
    train_part("stack", p, record, lambda row: False)


def part_mjx(p: dict, record) -> None:
    import jax

    import tasks
    from kinematic_throughput import measure

    clock = CompileClock()
    t0 = time.perf_counter()
    env = tasks.make("lift", physics="mjx")
    reset = jax.jit(jax.vmap(env.reset))
    state = jax.block_until_ready(reset(jax.random.split(jax.random.PRNGKey(0), p["num_envs"])))
    row = {"num_envs": p["num_envs"], "reset_wall_s": time.perf_counter() - t0}
    record("mjx", row)
    sps, compile_s = measure(env.step, state, p["num_envs"], p["steps"], env.action_size)
    row.update(env_steps_per_s=sps, step_first_call_s=compile_s, compile_s=clock.seconds)
    record("mjx", row)


PART_FUNCTIONS = {"env": part_env, "iteration": part_iteration, "lift": part_lift, "stack": part_stack,
                  "mjx": part_mjx}


def run_child(part: str, params: dict, path: str) -> None:
    """One part in this process; its results rewritten to ``path`` after every measurement."""
    import jax

    result = {"part": part, "params": params, "backend": jax.default_backend(),
              "device": str(jax.devices()[0].device_kind), "device_count": jax.device_count(),
              "jax": jax.__version__, "results": {}}

    def record(name, row):
        result["results"][name] = row
        result["memory"] = device_memory()
        with open(path + ".tmp", "w") as f:
            json.dump(result, f, indent=1)
        os.replace(path + ".tmp", path)
        print(f"[{part}] {name}: {json.dumps(row)[:400]}", flush=True)

    PART_FUNCTIONS[part](params, record)
    record("done", True)


# ----------------------------------------------------------------------------- the parent

class PartProcess:
    """One part running in a child process under ``params["cap"]`` seconds (its own session, so
    that the cap kills its whole process group)."""

    def __init__(self, part: str, params: dict, out: str, env: dict):
        self.part, self.params, self.path = part, params, os.path.join(out, f"{part}.json")
        if os.path.exists(self.path):
            os.remove(self.path)
        cmd = [sys.executable, os.path.abspath(__file__), "--child", part, "--params", json.dumps(params), "--out", out]
        self.log = open(os.path.join(out, f"{part}.log"), "w+")
        self.shown = 0  # how much of the log has been echoed
        self.started = time.perf_counter()
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT, text=True,
                                     start_new_session=True, env=env)
        self.status = None

    def echo(self) -> None:
        """Print the figures the child has written to its log since the last call."""
        self.log.flush()
        with open(self.log.name) as f:
            f.seek(self.shown)
            text = f.read()
        complete = text[:text.rfind("\n") + 1]
        self.shown += len(complete.encode())
        for line in complete.splitlines():
            if line.startswith(f"[{self.part}]"):
                print(line, flush=True)

    def poll(self) -> bool:
        """True once the part has ended, by itself or at its cap (then killed)."""
        if self.status is None:
            if self.proc.poll() is not None:
                self.status = "ok"
            elif time.perf_counter() - self.started > self.params["cap"]:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
                self.status = "timed out"
        return self.status is not None

    def result(self) -> dict:
        """What the part recorded, with its status ("ok"; "timed out" at its cap; "failed", with the
        output's last line as the error) and wall time."""
        self.log.seek(0)
        lines = self.log.read().splitlines()
        self.log.close()
        result = {}
        if os.path.exists(self.path):
            with open(self.path) as f:
                result = json.load(f)
        status = self.status
        if status == "ok" and (self.proc.returncode != 0 or not result.get("results", {}).get("done")):
            status = "failed"
            result["error"] = next((ln for ln in reversed(lines) if ln.strip()), f"exit {self.proc.returncode}")
            result["output_tail"] = lines[-30:]
        result.update(status=status, wall_s=time.perf_counter() - self.started, cap_s=self.params["cap"])
        return result


def run_parts(names, sizes: dict, caps: dict, out: str, jobs: int, on_result) -> None:
    """Run the parts ``names``, ``jobs`` at a time (1 on an accelerator: they share it), calling
    ``on_result(name, result)`` as each ends. Children print their figures as they measure."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    if sizes is SMOKE:  # compile fast: the smoke run checks the script, its figures mean nothing
        env["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "1"
    waiting, running = list(names), []
    while waiting or running:
        while waiting and len(running) < jobs:
            name = waiting.pop(0)
            params = dict(sizes[name], cap=caps.get(name, sizes[name]["cap"]))
            print(f"--- {name} (cap {params['cap']} s)", flush=True)
            running.append(PartProcess(name, params, out, env))
        time.sleep(0.2)
        for proc in list(running):
            proc.echo()
            if not proc.poll():
                continue
            proc.echo()
            running.remove(proc)
            on_result(proc.part, proc.result())


def summary(parts: dict) -> list:
    """The figures of docs/research/scaling.md's accelerator table, one line each."""
    lines = []
    for name, r in parts.items():
        res, head = r.get("results", {}), f"{name:<10} {r['status']:<9} {r['wall_s']:6.1f} s of {r['cap_s']} s"
        mem = (r.get("memory") or {}).get("peak_bytes")
        head += f", peak device memory {mem / 2**30:.2f} GiB" if mem else ""
        lines.append(head)
        if r["status"] == "failed":
            lines.append(f"  error: {r.get('error')}")
        for key, row in res.items():
            if key == "done":
                continue
            if name == "env":
                text = f"  {row['num_envs']:>6} envs: env {row['env_steps_per_s']:,.0f} steps/s"
                if "acting_steps_per_s" in row:
                    text += f", acting {row['acting_steps_per_s']:,.0f} steps/s ({row['acting_over_env']:.2f} of the env)"
            elif name == "iteration":
                text = f"  {row['num_envs']:>6} envs: " + ", ".join(f"{k} {v:.1f} ms" for k, v in row.get("ms", {}).items())
                if "env_steps_per_s" in row:
                    text += f" -> {row['env_steps_per_s']:,.0f} env steps/s"
            elif name in ("lift", "stack"):
                last = row.get("last") or {}
                text = (f"  {row.get('env_steps_done', 0):,} env steps; best new skill {row.get('best_new_skill_success', 0):.2f}; "
                        f"last eval at {last.get('env_steps', 0):,} steps, {last.get('wall_s', 0):.1f} s "
                        f"({last.get('compile_s', 0):.1f} s compiling): new skill {last.get('new_skill_success')}, "
                        f"scheduler {last.get('scheduler_success')}")
                if last.get("reached_target"):
                    text += f"  REACHED {last['reached_target']}"
            else:
                text = "  " + ", ".join(f"{k} {v:,.1f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items())
            lines.append(text)
    return lines


def parse_caps(text: str) -> dict:
    caps = {}
    for item in filter(None, text.split(",")):
        name, sep, value = item.partition("=")
        if not sep or name not in PARTS or not value.isdigit() or int(value) < 1:
            raise ValueError(f"--cap {item!r}: use PART=SECONDS, PART one of {', '.join(PARTS)}")
        caps[name] = int(value)
    return caps


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="directory for accelerator.json and each part's JSON")
    p.add_argument("--smoke", action="store_true", help="every part at tiny sizes (a CPU check of the script)")
    p.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated, of {', '.join(PARTS)}")
    p.add_argument("--cap", default="", help="PART=SECONDS,... replacing the parts' time caps")
    p.add_argument("--jobs", type=int, default=None,
                   help="parts at once (default 1; 2 with --smoke: a CPU's compiles overlap)")
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)
    p.add_argument("--params", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    if args.child:
        run_child(args.child, json.loads(args.params), os.path.join(args.out, f"{args.child}.json"))
        return 0
    names = [n for n in args.parts.split(",") if n]
    bad = [n for n in names if n not in PARTS]
    if bad:
        print(f"error: --parts: unknown part(s) {', '.join(bad)}; valid: {', '.join(PARTS)}", file=sys.stderr)
        return 2
    sizes = SMOKE if args.smoke else FULL
    try:
        caps = parse_caps(args.cap)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    started = time.perf_counter()
    report = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "smoke": args.smoke, "command": " ".join(["python", "bench/accelerator.py"] + (argv or sys.argv[1:])),
              "parts": {}}

    def write():
        with open(os.path.join(args.out, "accelerator.json"), "w") as f:
            json.dump(report, f, indent=1)

    def on_result(name, result):
        report["parts"][name] = result
        report["wall_s"] = time.perf_counter() - started
        write()  # after every part: a run cut short keeps what it measured
        print(f"--- {name}: {result['status']} after {result['wall_s']:.1f} s" +
              (f" ({result.get('error')})" if result["status"] == "failed" else ""), flush=True)

    run_parts(names, sizes, caps, args.out, args.jobs or (2 if args.smoke else 1), on_result)
    report["parts"] = {n: report["parts"][n] for n in names}  # parts finish out of order with --jobs 2
    write()
    first = next((r for r in report["parts"].values() if r.get("device")), {})
    print(f"\n{first.get('device', '?')} ({first.get('backend', '?')}), jax {first.get('jax', '?')}; "
          f"{report['wall_s']:.0f} s in all")
    print("\n".join(summary(report["parts"])))
    return 0 if all(r["status"] == "ok" for r in report["parts"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
