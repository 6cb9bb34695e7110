"""Plots of training runs (PNG, matplotlib's Agg canvas; no display needed).

    python -m training.plot RUN_DIR [RUN_DIR ...] --out FILE.png [--usage USAGE.png]

* ``--out``: learning curves vs env steps of the new skill alone and of the scheduler alone
  (evaluation success and return, paper App. C.3). Runs that differ only in their seed form one
  group (from each run's config.json: task, physics, method, skill set), drawn as the mean over
  its runs with a ± 1 std band.
* ``--usage`` (default ``<FILE>_skill_usage.png``): skill usage over training, one column per
  group: the average *consecutive* execution per skill in env steps, per evaluation interval
  (paper Fig. 4c: ``skill_steps / skill_runs``, a run going on across decisions that choose the
  same skill again), and each skill's share of the env steps.

With a single RUN_DIR and no ``--out`` it writes ``RUN_DIR/curves.png`` and
``RUN_DIR/skill_usage.png``, as ``training.run`` does at the end of a run.
"""

from __future__ import annotations

import json
import os
import sys
from typing import Optional, Sequence

import numpy as np

from training.cli import Parser, UsageError, main_guard
from training.logging_utils import read_metrics, skill_labels

GROUP_KEYS = ("task", "physics", "method", "skill_set")
METHOD_LABELS = {"skills": "SkillS", "scratch": "from scratch", "finetune": "fine-tuning", "kl_reg": "KL-reg. to mixture",
                 "dagger": "DAGGER", "rhpo": "RHPO"}


class Run:
    """One run directory: its config.json (or None) and its metrics.csv rows."""

    def __init__(self, path: str):
        self.path = path
        if not os.path.isdir(path):
            raise UsageError(f"run directory {path} does not exist" if not os.path.exists(path)
                             else f"{path} is not a run directory")
        csv_path = os.path.join(path, "metrics.csv")
        if not os.path.isfile(csv_path):
            raise UsageError(f"{path} has no metrics.csv (not a training.run directory)")
        try:
            self.rows = read_metrics(csv_path)
        except (OSError, ValueError) as e:
            raise UsageError(f"cannot read {csv_path}: {str(e).splitlines()[0]}") from None
        self.rows = [r for r in self.rows if isinstance(r.get("env_steps"), float)]
        if not self.rows:
            raise UsageError(f"{csv_path} holds no evaluation rows yet")
        self.config = None
        cfg = os.path.join(path, "config.json")
        if os.path.isfile(cfg):
            try:
                with open(cfg) as f:
                    self.config = json.load(f)
            except (OSError, ValueError):
                self.config = None
        if not isinstance(self.config, dict):
            self.config = None

    @property
    def method(self) -> Optional[str]:
        if self.config is None:
            return None
        return (self.config.get("train_config") or {}).get("method", self.config.get("method"))

    def key(self) -> tuple:
        if self.config is None:
            return ("dir", os.path.abspath(self.path))
        return tuple((k, self.method if k == "method" else self.config.get(k)) for k in GROUP_KEYS)

    def series(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(env steps, values) of a numeric column, rows without a value left out."""
        pts = [(r["env_steps"], r[name]) for r in self.rows if isinstance(r.get(name), float)]
        if not pts:
            return np.zeros(0), np.zeros(0)
        s, v = zip(*pts)
        return np.asarray(s), np.asarray(v)

    def skill_names(self) -> Optional[list]:
        return list(self.config.get("skills") or []) if self.config else None


def group_runs(runs: Sequence[Run]) -> list[tuple[str, list[Run]]]:
    """Runs grouped by config (everything but the seed), labelled by what differs across groups."""
    groups: dict[tuple, list[Run]] = {}
    for r in runs:
        groups.setdefault(r.key(), []).append(r)
    keys = list(groups)
    configured = [dict(key) for key in keys if key[0] != "dir"]
    varying = [k for k in GROUP_KEYS if len({d.get(k) for d in configured}) > 1]
    out = []
    for key in keys:
        members = groups[key]
        if key[0] == "dir":
            label = os.path.basename(os.path.normpath(members[0].path))
        else:
            d = dict(key)
            d["method"] = METHOD_LABELS.get(d.get("method"), d.get("method"))
            shown = varying or ["task", "method"]
            label = " ".join(str(d[k]) for k in shown if d.get(k) is not None)
            if d["method"] == "SkillS" and "skill_set" not in shown and d.get("skill_set"):
                label += f" ({d['skill_set']} skills)"
        seeds = len(members)
        out.append((f"{label}, {seeds} seeds" if seeds > 1 else label, members))
    return out


def aggregate(series: Sequence[tuple[np.ndarray, np.ndarray]]):
    """Mean and std (over the runs that have a value there) at every env step of any run."""
    steps = np.unique(np.concatenate([s for s, _ in series])) if series else np.zeros(0)
    mean, std, count = [], [], []
    for x in steps:
        vals = np.asarray([v[s == x][0] for s, v in series if np.any(s == x)], np.float64)
        vals = vals[np.isfinite(vals)]
        mean.append(vals.mean() if vals.size else np.nan)
        std.append(vals.std() if vals.size else np.nan)
        count.append(vals.size)
    return steps, np.asarray(mean), np.asarray(std), np.asarray(count)


def _save(fig, out: str):
    d = os.path.dirname(os.path.abspath(out))
    if not os.path.isdir(d):
        raise UsageError(f"cannot write {out}: {d} is not a directory")
    base, ext = os.path.splitext(out)
    tmp = f"{base}.tmp-{os.getpid()}{ext}"  # keep the extension: it names the format
    try:
        fig.savefig(tmp, dpi=110)
        os.replace(tmp, out)
    except PermissionError:
        raise UsageError(f"cannot write {out}: permission denied") from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return out


def _figure(w: float, h: float):
    from matplotlib.figure import Figure  # the Agg canvas: no pyplot, no display

    return Figure(figsize=(w, h), layout="constrained")


def plot_curves(groups, out: str) -> str:
    """Learning curves of the new skill alone and the scheduler alone (module docstring)."""
    fig = _figure(11, 7)
    axes = fig.subplots(2, 2, sharex=True)
    panels = [("new_skill", "new skill alone"), ("scheduler", "scheduler alone")]
    for col, (who, title) in enumerate(panels):
        for row, what in enumerate(("success", "return")):
            ax = axes[row, col]
            drawn = 0
            for idx, (label, runs) in enumerate(groups):
                series = [r.series(f"eval/{who}_{what}") for r in runs]
                series = [s for s in series if s[0].size]
                if not series:
                    continue
                steps, mean, std, n = aggregate(series)
                color = f"C{idx % 10}"
                ax.plot(steps, mean, color=color, label=label, marker="o" if steps.size < 12 else None, ms=3)
                band = n > 1
                if band.any():
                    ax.fill_between(steps, np.where(band, mean - std, np.nan), np.where(band, mean + std, np.nan),
                                    color=color, alpha=0.2, linewidth=0)
                drawn += 1
            if not drawn:
                ax.text(0.5, 0.5, "no evaluations\n(from-scratch runs have no scheduler)" if who == "scheduler"
                        else "no evaluations", ha="center", va="center", transform=ax.transAxes, color="0.4")
            if what == "success":
                ax.set_ylim(-0.03, 1.03)
                ax.set_title(title)
            ax.set_ylabel(f"evaluation {what}")
            ax.grid(alpha=0.3)
            if row == 1:
                ax.set_xlabel("env steps")
            if drawn and row == 0:
                ax.legend(fontsize=8, loc="best")
    if any(len(runs) > 1 for _, runs in groups):
        fig.suptitle("mean ± 1 std over seeds", fontsize=9)
    return _save(fig, out)


def usage_series(run: Run):
    """(env steps [R], average consecutive execution [R, N+1], share of env steps [R, N+1], labels)
    of one run; None if its metrics.csv has no skill_runs column (runs before it was logged)."""
    rows = [r for r in run.rows if isinstance(r.get("skill_steps"), list) and isinstance(r.get("skill_runs"), list)]
    if not rows:
        return None
    steps = np.asarray([r["env_steps"] for r in rows])
    s = np.asarray([r["skill_steps"] for r in rows], np.float64)
    n = np.asarray([r["skill_runs"] for r in rows], np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        avg = np.where(n > 0, s / np.maximum(n, 1), np.nan)
        share = s / np.maximum(s.sum(axis=1, keepdims=True), 1)
    return steps, avg, share, skill_labels(s.shape[1], run.skill_names())


def plot_usage(groups, out: str) -> str:
    """Skill usage over training per group (module docstring)."""
    fig = _figure(max(6.0, 5.5 * len(groups)), 7)
    axes = fig.subplots(2, len(groups), sharex="col", squeeze=False)
    for col, (label, runs) in enumerate(groups):
        per_run = [u for u in (usage_series(r) for r in runs) if u is not None]
        top, bottom = axes[0, col], axes[1, col]
        top.set_title(label)
        if not per_run:
            top.text(0.5, 0.5, "no skill_runs in metrics.csv\n(a run from before they were logged)",
                     ha="center", va="center", transform=top.transAxes, color="0.4")
            continue
        labels = per_run[0][3]
        per_run = [u for u in per_run if u[1].shape[1] == len(labels)]
        for j, name in enumerate(labels):
            color = "black" if name == "new_skill" else f"C{j % 10}"
            steps, mean, _, _ = aggregate([(u[0], u[1][:, j]) for u in per_run])
            top.plot(steps, mean, color=color, label=name, lw=2.2 if name == "new_skill" else 1.4,
                     marker="o" if steps.size < 12 else None, ms=3)
        steps, _, _, _ = aggregate([(u[0], u[2][:, 0]) for u in per_run])
        shares = np.stack([aggregate([(u[0], u[2][:, j]) for u in per_run])[1] for j in range(len(labels))])
        colors = ["black" if n == "new_skill" else f"C{j % 10}" for j, n in enumerate(labels)]
        bottom.stackplot(steps, np.nan_to_num(shares), colors=colors, alpha=0.75, labels=labels)
        top.set_ylabel("average consecutive execution (env steps)")
        top.grid(alpha=0.3)
        top.legend(fontsize=7, loc="best")
        bottom.set_ylabel("share of env steps")
        bottom.set_ylim(0, 1)
        bottom.set_xlabel("env steps")
        bottom.grid(alpha=0.3)
    fig.suptitle("skill usage per evaluation interval" + (" (mean over seeds)" if any(len(r) > 1 for _, r in groups)
                                                          else ""), fontsize=10)
    return _save(fig, out)


def usage_shares(timeline, num_skills: int, groups=None) -> dict:
    """{group value: share of that group's episodes running each skill at each step [N+1, T]} from
    ``timeline`` [T, B] (skill index per episode and step) and ``groups`` [B] (None: one group 0)."""
    idx = np.asarray(timeline, np.int64)
    groups = np.zeros(idx.shape[1], np.int64) if groups is None else np.asarray(groups)
    return {v: np.stack([(idx[:, groups == v] == j).mean(axis=1) for j in range(num_skills)])
            for v in sorted(set(groups.tolist()))}


def plot_usage_over_episode(timeline, names, out: str, step_seconds: float | None = None, title: str = "",
                            groups=None, group_names: dict | None = None) -> str:
    """Which skill the scheduler runs at each step of an episode: ``timeline`` [T, B] = the skill index
    each of B episodes (started together) runs at step t (``ScheduledPolicy.timeline``), drawn as the
    share of episodes per skill over episode time (``step_seconds``: seconds per step for the x axis).
    ``groups`` [B] (e.g. the env's start kind): one panel per group value, titled by ``group_names``."""
    _require_matplotlib()
    shares = usage_shares(timeline, len(names), groups)
    values = list(shares)
    counts = {v: int(np.sum(np.asarray(groups) == v)) if groups is not None else np.asarray(timeline).shape[1]
              for v in values}
    t = np.arange(np.asarray(timeline).shape[0]) * (step_seconds or 1.0)
    fig = _figure(7, 2.2 + 1.6 * len(values))
    axes = np.atleast_1d(fig.subplots(len(values), 1, sharex=True, squeeze=False)[:, 0])
    colors = ["black" if n.endswith("new_skill") else f"C{j % 10}" for j, n in enumerate(names)]
    for ax, v in zip(axes, values):
        ax.stackplot(t, shares[v], colors=colors, alpha=0.75, labels=list(names))
        label = (group_names or {}).get(v, "" if len(values) == 1 else f"group {v}")
        ax.set_title(f"{label} ({counts[v]} episodes)" if label else f"{counts[v]} episodes", fontsize=9)
        ax.set_ylabel("share of episodes")
        ax.set_ylim(0, 1)
        ax.set_xlim(t[0], t[-1] if t.size > 1 else 1)
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("time in episode (s)" if step_seconds else "step of episode")
    fig.suptitle(title or "skill the scheduler runs over the episode", fontsize=10)
    return _save(fig, out)


def _require_matplotlib():
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise UsageError("plots need matplotlib: pip install 'parallel-skills[plots]'") from None


def write_run_plots(run_dir: str) -> tuple[str, str]:
    """``RUN_DIR/curves.png`` and ``RUN_DIR/skill_usage.png`` of one run (``training.run`` calls it)."""
    groups = group_runs([Run(run_dir)])
    return (plot_curves(groups, os.path.join(run_dir, "curves.png")),
            plot_usage(groups, os.path.join(run_dir, "skill_usage.png")))


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    p = Parser(prog="python -m training.plot", description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="training.run directories (seeds of one config are averaged)")
    p.add_argument("--out", default=None, help="learning-curves image (default RUN_DIR/curves.png with one RUN_DIR)")
    p.add_argument("--usage", default=None, help="skill-usage image (default: <--out without .png>_skill_usage.png, "
                   "or RUN_DIR/skill_usage.png)")
    args = p.parse_args(argv)

    def run():
        _require_matplotlib()
        runs = [Run(d) for d in args.runs]
        if args.out is None and len(runs) > 1:
            raise UsageError("several RUN_DIRs need --out FILE.png")
        out = args.out or os.path.join(args.runs[0], "curves.png")
        usage = args.usage or (os.path.join(args.runs[0], "skill_usage.png") if args.out is None
                               else os.path.splitext(out)[0] + "_skill_usage.png")
        groups = group_runs(runs)
        return plot_curves(groups, out), plot_usage(groups, usage)

    curves, usage = main_guard(run)
    print(f"learning curves: {curves}")
    print(f"skill usage: {usage}")


if __name__ == "__main__":
    main()
