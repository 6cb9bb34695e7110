"""Host memory and speed with glibc's dynamic mmap threshold against a fixed one
(``MALLOC_MMAP_THRESHOLD_=1048576``): the same lift run twice, each in a fresh process, one after the
other, printing env steps/s after the first evaluation, resident memory at it and at most, and the
ratios. glibc raises its threshold, up to 32 MiB, whenever an mmapped block is freed; host buffers
of a few MiB (a 100k-row replay's columns, their checkpoint copies) then come from the heap and
fragment it, so resident memory creeps up (docs/research/scaling.md, "Stack memory").

    python bench/mmap_threshold.py                           # lift, 100k replay, 120k env steps
    python bench/mmap_threshold.py --replay_size 300000 --num_timesteps 300000

Pin it to one core (``taskset -c N``) for a ratio that another process does not disturb. The run
here writes no checkpoints (``training.run`` copies the replay to the host for each), so it measures
the speed cost of the fixed threshold more than the memory it saves (docs/research/scaling.md, "Memory with
a smaller replay").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
THRESHOLD = 1 << 20  # the fixed threshold measured (bytes)

# One run in this process: train, and report speed and resident memory at every evaluation.
_RUN = """
import json, os, sys, time
from training.logging_utils import release_free_memory, resident_mb
fixed = "MALLOC_MMAP_THRESHOLD_" in os.environ
import tasks
from parallel_skills import Skill, TrainConfig, train
from tasks.manipulation import scripted
from training import skill_library
env = tasks.make("lift")
skills = [Skill.from_fn(n, scripted.get(n)) for n in skill_library.skill_names("lift")]
rss, t = [], {}
def progress(steps, m):
    release_free_memory()
    rss.append(resident_mb())
    t.setdefault("first", (time.perf_counter(), steps))
train(env, skills, num_timesteps=int(sys.argv[2]), seed=0, config=TrainConfig(replay_size=int(sys.argv[3])),
      progress_fn=progress)
t1, s0 = t["first"]
print(json.dumps({"fixed": fixed, "steps_per_s": (int(sys.argv[2]) - s0) / (time.perf_counter() - t1),
                  "rss_first_mb": rss[0], "rss_max_mb": max(rss)}))
"""


def run(mode: str, num_timesteps: int, replay_size: int) -> dict:
    env = dict(os.environ, PYTHONPATH=ROOT)
    env.pop("MALLOC_MMAP_THRESHOLD_", None)
    if mode == "fixed":
        env["MALLOC_MMAP_THRESHOLD_"] = str(THRESHOLD)
    r = subprocess.run([sys.executable, "-c", _RUN, mode, str(num_timesteps), str(replay_size)], env=env,
                       capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--num_timesteps", type=int, default=120_000)
    p.add_argument("--replay_size", type=int, default=100_000)
    p.add_argument("--json", default=None, help="also write the results here")
    args = p.parse_args(argv)
    out = {mode: run(mode, args.num_timesteps, args.replay_size) for mode in ("dynamic", "fixed")}
    for mode, r in out.items():
        print(f"{mode:8s} threshold: {r['steps_per_s']:7.0f} env steps/s after the first evaluation, resident "
              f"{r['rss_first_mb']:.0f} MiB at it, {r['rss_max_mb']:.0f} at most")
    d, f = out["dynamic"], out["fixed"]
    out["ratios"] = {"speed_fixed_over_dynamic": f["steps_per_s"] / d["steps_per_s"],
                     "growth_dynamic_mb": d["rss_max_mb"] - d["rss_first_mb"],
                     "growth_fixed_mb": f["rss_max_mb"] - f["rss_first_mb"]}
    print(f"speed fixed / dynamic: {out['ratios']['speed_fixed_over_dynamic']:.3f}; resident growth: dynamic "
          f"{out['ratios']['growth_dynamic_mb']:+.0f} MiB, fixed {out['ratios']['growth_fixed_mb']:+.0f} MiB")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
