"""Env steps and wall time until the new skill alone first succeeds at a threshold, for several runs,
as ratios to a reference run (the first): how recipes compare in sample efficiency and wall clock.

    python -m training.experiments.time_to_success runs/lift-cpu-s0 runs/lift-parallel-s0 --threshold 0.8

Reads each run's metrics.csv (one row per evaluation). ``--consecutive N``: the threshold must hold at
N evaluations in a row (the first of them counts). ``--budget_seconds S``: also each run's wall time
as a ratio to a time budget S (≤ 1: within it), e.g. 300 for "≤ 5 minutes". A run that never reaches it is reported with its
last row ("not reached by …") and no ratio. Wall time is the training time metrics.csv records
(compilation included, evaluations included).
"""

from __future__ import annotations

import os
import sys

from training.cli import Parser, UsageError, main_guard
from training.logging_utils import read_metrics


def first_success(rows: list[dict], threshold: float, consecutive: int = 1, key: str = "eval/new_skill_success"):
    """The first row from which ``key`` ≥ ``threshold`` holds for ``consecutive`` rows, or None."""
    for n in range(len(rows) - consecutive + 1):
        window = rows[n:n + consecutive]
        if all(isinstance(r.get(key), (int, float)) and r[key] >= threshold for r in window):
            return rows[n]
    return None


def main(argv=None):
    p = Parser(prog="python -m training.experiments.time_to_success", description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", help="run directories (the first is the reference)")
    p.add_argument("--threshold", type=float, default=0.8)
    p.add_argument("--consecutive", type=int, default=1)
    p.add_argument("--key", default="eval/new_skill_success", help="metrics.csv column")
    p.add_argument("--budget_seconds", type=float, default=None,
                   help="also print each run's wall time to success / this budget (<= 1: within it)")
    args = p.parse_args(sys.argv[1:] if argv is None else argv)

    def run():
        if not 0.0 <= args.threshold <= 1.0:
            raise UsageError(f"--threshold must be in [0, 1], got {args.threshold}")
        if args.consecutive < 1:
            raise UsageError(f"--consecutive must be a positive integer, got {args.consecutive}")
        if args.budget_seconds is not None and not args.budget_seconds > 0:
            raise UsageError(f"--budget_seconds must be a positive number of seconds, got {args.budget_seconds}")
        results = []
        for d in args.runs:
            path = os.path.join(d, "metrics.csv")
            if not os.path.isfile(path):
                raise UsageError(f"{d} has no metrics.csv (not a training.run directory)")
            rows = read_metrics(path)
            if not rows:
                raise UsageError(f"{path} has no evaluation rows yet")
            results.append((d, first_success(rows, args.threshold, args.consecutive, args.key), rows[-1]))
        ref = results[0][1]
        print(f"{args.key} >= {args.threshold:g}" + (f" ({args.consecutive} evaluations in a row)"
                                                         if args.consecutive > 1 else ""))
        budget = args.budget_seconds
        print(f"{'run':<40} {'env steps':>11} {'wall s':>8} {'steps ratio':>12} {'time ratio':>11}"
              + (f" {'/ budget':>9}" if budget else ""))
        for d, hit, last in results:
            if hit is None:
                print(f"{d:<40} not reached by {int(last['env_steps']):,} env steps ({last['wall_time']:.0f} s; "
                      f"last {args.key} {last.get(args.key)})")
                continue
            steps, wall = int(hit["env_steps"]), float(hit["wall_time"])
            ratios = ("", "") if ref is None else (f"{steps / int(ref['env_steps']):.2f}",
                                                   f"{wall / float(ref['wall_time']):.2f}")
            print(f"{d:<40} {steps:>11,} {wall:>8.0f} {ratios[0]:>12} {ratios[1]:>11}"
                  + (f" {wall / budget:>9.2f}" if budget else ""))
        if budget:
            print(f"budget {budget:g} s: / budget = wall time to success / budget (<= 1: within it)")

    main_guard(run)


if __name__ == "__main__":
    main()
