"""Result tables rebuilt from the archived runs: one Markdown file per task, ``docs/results/<task>.md``,
computed from ``docs/results/paper_runs/<task>/<variant>/s<seed>/metrics.csv`` and nothing else.
README "Results" quotes these files; ``tests/test_results.py`` rebuilds them and fails on any difference.

    python -m training.experiments.results                 # (re)write docs/results/<task>.md, every archived task
    python -m training.experiments.results --check         # exit 1, naming each file that differs from its rebuild
    python -m training.experiments.results --archive DIR --out DIR --tasks stack,triple_stack

Per variant (a directory under the task; its seeds: the ``s<seed>`` directories holding a metrics.csv),
with the variant's budget = the most env steps any of its seeds reached:

* the new skill alone (``eval/new_skill_success``, its mean action) at the last evaluation at or
  before ¼, ½ and all of the budget (the columns name those evaluations' env steps: real evaluation
  points, not the fractions), as mean ± sample standard deviation (n − 1) over the n seeds, each
  seed's value at the budget, each seed's best evaluation and its first evaluation ≥ 0.8;
* the scheduler alone (greedy; at ½ and all of the budget), and at the budget: greedy with the new
  skill's sampled actions, as it collects (sampled), and the new skill with sampled actions, each where
  the run recorded it; the
  share of the env steps the scheduler gave the new skill in the last evaluation interval, wall
  time per run (minutes, as the run's last row records it) and resident memory (first → largest
  ``rss_mb``), per seed.

Each variant has a status (``variant_status``), read from its seeds' config.json: **default** (its
train config is what today's defaults resolve to for its method, ablation or skill set: the row
marked in each table), **current** (today's defaults plus the settings its name says) or
**history** (an earlier recipe or skill library, a setting since removed, or runs without a
config.json): history variants go in a section of their own below the others.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
from typing import Optional, Sequence

from training.cli import Parser, UsageError, main_guard

ARCHIVE = os.path.join("docs", "results", "paper_runs")
OUT = os.path.join("docs", "results")
FRACTIONS = (0.25, 0.5, 1.0)
NEW_SKILL, SCHEDULER, SAMPLED = "eval/new_skill_success", "eval/scheduler_success", "eval/new_skill_sampled_success"
# The scheduler as it collects (sampled decisions, collection noise, the new skill sampled), and
# greedy with the new skill's sampled actions (runs since 2026-12-06; older ones: "–").
SCHEDULER_SAMPLED, SCHEDULER_NEW_SAMPLED = "eval/scheduler_sampled_success", "eval/scheduler_new_skill_sampled_success"
METHOD_ORDER = ("skills", "scratch", "finetune", "rhpo", "kl_reg", "dagger")
# Variant names that future runs of today's defaults use: their rows are marked default as they are.
DEFAULT_NAMES = ("default", "default-library", "parallel-4096")
BASE_ALIASES = {"quickstart": "skills"}  # ``python -m training.run`` with no arguments: SkillS
EVALUATION_FIELDS = ("eval_every", "eval_episodes")  # how often and how long a run evaluates: no training change
HEADER = ("<!-- Written by `python -m training.experiments.results` from docs/results/paper_runs/{task}/; "
          "edit the runs, not this file (tests/test_results.py rebuilds it). -->")


def steps_label(steps: float) -> str:
    """Env steps as the tables write them: ``1200000 -> 1.2M``, ``60800 -> 60.8k``, ``512 -> 512``."""
    if steps >= 1e6:
        return f"{steps / 1e6:.3g}M"
    if steps >= 1e3:
        return f"{steps / 1e3:.4g}k"
    return f"{int(steps)}"


def mean_std(values: Sequence[float]) -> str:
    """``0.71 ± 0.24`` (sample standard deviation, n − 1), or the single value for one seed."""
    if len(values) == 1:
        return f"{values[0]:.2f}"
    mean = sum(values) / len(values)
    std = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))
    return f"{mean:.2f} ± {std:.2f}"


def per_seed(values: Sequence[Optional[str]]) -> str:
    return " / ".join("–" if v is None else v for v in values)


class SeedRun:
    """One archived seed: its evaluation rows (``read_metrics`` rows with an env_steps value) and
    its config.json record (a dict; None for runs archived without one)."""

    def __init__(self, seed: int, rows: list, record: Optional[dict] = None):
        self.seed, self.rows, self.record = seed, rows, record

    @property
    def last_steps(self) -> float:
        return self.rows[-1]["env_steps"]

    def evaluations(self, key: str) -> list:
        return [r for r in self.rows if isinstance(r.get(key), float)]

    def at(self, steps: float, key: str = NEW_SKILL) -> Optional[dict]:
        """The last row with ``key`` at or before ``steps`` env steps (None if none)."""
        before = [r for r in self.evaluations(key) if r["env_steps"] <= steps]
        return before[-1] if before else None

    def first_at_least(self, level: float, key: str = NEW_SKILL) -> Optional[float]:
        hit = [r["env_steps"] for r in self.evaluations(key) if r[key] >= level]
        return hit[0] if hit else None

    def best(self, key: str = NEW_SKILL) -> Optional[float]:
        vals = [r[key] for r in self.evaluations(key)]
        return max(vals) if vals else None

    def new_skill_share(self) -> Optional[float]:
        """The new skill's share of the env steps in the last evaluation interval (``skill_steps``'s last entry)."""
        steps = self.rows[-1].get("skill_steps")
        if not isinstance(steps, list) or not sum(steps):
            return None
        return steps[-1] / sum(steps)

    def rss(self) -> Optional[str]:
        vals = [r["rss_mb"] for r in self.rows if isinstance(r.get("rss_mb"), float)]
        return f"{vals[0]:.0f} → {max(vals):.0f}" if vals else None


def read_variant(path: str) -> list:
    """The seeds of one variant directory, in seed order (``SeedRun``; those with evaluations)."""
    from training.logging_utils import read_metrics

    runs = []
    for name in os.listdir(path):
        metrics = os.path.join(path, name, "metrics.csv")
        if name.startswith("s") and name[1:].isdigit() and os.path.isfile(metrics):
            rows = [r for r in read_metrics(metrics) if isinstance(r.get("env_steps"), float)]
            record = os.path.join(path, name, "config.json")
            if rows:
                runs.append(SeedRun(int(name[1:]), rows, json.load(open(record, encoding="utf-8"))
                                    if os.path.isfile(record) else None))
    return sorted(runs, key=lambda r: r.seed)


def variant_kind(name: str) -> str:
    """"method", "ablation" or "skill set" of an archived variant directory's name."""
    from training.experiments.paper import ABLATIONS, SKILL_SETS

    base = name.split("-")[0]
    return "ablation" if base in ABLATIONS else "skill set" if base in SKILL_SETS else "method"


def variant_order(name: str) -> tuple:
    kinds = ("method", "ablation", "skill set")
    base = name.split("-")[0]
    rank = METHOD_ORDER.index(BASE_ALIASES.get(base, base)) if BASE_ALIASES.get(base, base) in METHOD_ORDER \
        else len(METHOD_ORDER)
    return kinds.index(variant_kind(name)), rank, name != base, name


def known_fields(cls, data: dict) -> dict:
    """The JSON object ``data`` of config class ``cls`` without the fields ``cls`` no longer has (a
    recorded setting since removed: the variant's name says it where it was not the neutral value)."""
    names = {f.name for f in dataclasses.fields(cls)}
    out = {}
    for key, value in data.items():
        if key in names:
            sub = getattr(cls(), key)
            out[key] = known_fields(type(sub), value) if dataclasses.is_dataclass(sub) and isinstance(value, dict) \
                else value
    return out


def setting_labels(field: str) -> set:
    """The names a variant may give the dotted config field ``field`` (``training.experiments.paper``'s
    label, or the field dotted with underscores: ``new_skill.crr_mode`` -> crr_mode, new_skill_crr_mode)."""
    from training.experiments.paper import setting_label

    return {setting_label(field), field.replace(".", "_")}


def config_differences(a, b, prefix: str = "") -> list:
    """The dotted fields two configs differ in (the evaluation-only fields ignored)."""
    out = []
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if dataclasses.is_dataclass(x):
            out += config_differences(x, y, f"{prefix}{f.name}.")
        elif x != y and f.name not in EVALUATION_FIELDS:
            out.append(prefix + f.name)
    return out


def default_config(base: str, recipe: str):
    """The TrainConfig today's ``training.run`` resolves for variant ``base`` (a method, an ablation or
    a skill set of ``training.experiments.paper``) on the device kind of ``recipe`` ("cpu": a CPU,
    else an accelerator); None for a base that names none of them."""
    from parallel_skills import config, methods
    from training.experiments.paper import parse_variant
    from training.run import BASE_CONFIG

    try:
        variant = parse_variant(BASE_ALIASES.get(base, base), methods.names())
    except UsageError:
        return None
    cfg = config.from_dict(dataclasses.replace(BASE_CONFIG, method=variant.method), variant.config, base)
    given = ["method"] + config.dotted_names(variant.config)
    return config.resolve(cfg, backend="cpu" if recipe == "cpu" else "gpu", given=given)[0]


def variant_status(name: str, runs: list) -> str:
    """"default", "current" or "history" of an archived variant (module docstring), from its name
    and its seeds' config.json records: history when a seed has no record, the name says
    ``archived`` or a setting today's configs lack, the skills came from a ``--skill_dir``, or the
    train config differs from today's defaults in a field the name does not set; default when it
    differs in none and the name holds settings only; current otherwise."""
    from parallel_skills import config
    from training import rundir

    if name in DEFAULT_NAMES:
        return "default"
    base, *parts = name.split("-")
    records = [r.record for r in runs]
    if any(r is None for r in records) or any(p.startswith("archived") for p in parts) \
            or any(r.get("skill_dir") for r in records):
        return "history"
    live = set(f.name for f in dataclasses.fields(rundir.RunRecord))
    for field in config.dotted_names(dataclasses.asdict(config.TrainConfig())):
        live |= setting_labels(field)
    named = {p.split("=", 1)[0] for p in parts if "=" in p}
    if named - live:
        return "history"
    differing = set()
    for record in records:
        expected = default_config(base, record["train_config"].get("recipe"))
        if expected is None:
            return "history"
        data = known_fields(config.TrainConfig, rundir.recorded_train_config(record["train_config"]))
        differing |= set(config_differences(expected, config.from_dict(config.TrainConfig(), data, name)))
    if any(not setting_labels(f) & named for f in differing):
        return "history"
    return "default" if not differing and all("=" in p for p in parts) else "current"


def shown_name(name: str, status: str) -> str:
    return f"**{name}** (default)" if status == "default" else name


def new_skill_row(name: str, runs: list, status: str = "current") -> str:
    budget = max(r.last_steps for r in runs)
    cells, points = [], []
    for f in FRACTIONS:
        hits = [r.at(f * budget) for r in runs]
        vals = [h[NEW_SKILL] for h in hits if h is not None]
        steps = sorted({h["env_steps"] for h in hits if h is not None})
        points.append("–" if not steps else steps_label(steps[0]) if len(steps) == 1
                      else f"{steps_label(steps[0])}–{steps_label(steps[-1])}")
        cells.append(mean_std(vals) if vals else "–")
    final = [r.at(budget) for r in runs]
    seeds = per_seed([None if h is None else f"{h[NEW_SKILL]:.2f}" for h in final])
    best = per_seed([None if r.best() is None else f"{r.best():.2f}" for r in runs])
    first = per_seed([None if r.first_at_least(0.8) is None else steps_label(r.first_at_least(0.8)) for r in runs])
    return (f"| {shown_name(name, status)} | {per_seed([str(r.seed) for r in runs])} | {steps_label(budget)} | {' / '.join(points)} | "
            + " | ".join(cells) + f" | {seeds} | {best} | {first} |")


def cost_row(name: str, runs: list, status: str = "current") -> str:
    budget = max(r.last_steps for r in runs)

    def final(key):
        return per_seed([None if r.at(budget, key) is None else f"{r.at(budget, key)[key]:.2f}" for r in runs])

    def half(key):
        return per_seed([None if r.at(budget / 2, key) is None else f"{r.at(budget / 2, key)[key]:.2f}" for r in runs])

    scheduled = any(r.evaluations(SCHEDULER) for r in runs)  # scratch & co. have no scheduler: no share either
    share = per_seed([None if not scheduled or r.new_skill_share() is None else f"{r.new_skill_share():.2f}"
                      for r in runs])
    wall = per_seed([f"{r.rows[-1]['wall_time'] / 60:.1f}" if isinstance(r.rows[-1].get("wall_time"), float)
                     else None for r in runs])
    return (f"| {shown_name(name, status)} | {half(SCHEDULER)} | {final(SCHEDULER)} | {final(SCHEDULER_NEW_SAMPLED)} | "
            f"{final(SCHEDULER_SAMPLED)} | {final(SAMPLED)} | {share} | {wall} | {per_seed([r.rss() for r in runs])} |")


def task_table(archive: str, task: str) -> str:
    """The Markdown of ``<archive>/<task>/`` (module docstring). UsageError if it holds no runs."""
    root = os.path.join(archive, task)
    variants = {}
    if os.path.isdir(root):
        for name in os.listdir(root):
            if os.path.isdir(os.path.join(root, name)):
                runs = read_variant(os.path.join(root, name))
                if runs:
                    variants[name] = runs
    if not variants:
        raise UsageError(f"no archived runs under {root} (expected {root}/<variant>/s<seed>/metrics.csv)")
    names = sorted(variants, key=variant_order)
    status = {n: variant_status(n, variants[n]) for n in names}
    names = sorted(names, key=lambda n: (variant_order(n)[:2], status[n] != "default", variant_order(n)[2:]))
    lines = [HEADER.format(task=task), "", f"# {task}: archived runs", "",
             "Each variant's budget is the most env steps any of its seeds reached; the columns are the last "
             "evaluation at or before ¼, ½ and all of it (their env steps named). Mean ± sample standard "
             "deviation (n − 1) over the seeds listed; one seed: its value. Evaluations: the runs' own "
             "(32 episodes unless the run's config.json says otherwise).", "",
             "**(default)** marks the variants whose train config is what today's defaults resolve to for "
             "their method, ablation or skill set; the other rows above History are today's defaults with the "
             "settings their names say. History: earlier recipes and skill libraries, settings since removed, "
             "and runs archived without a config.json.", ""]
    current = [n for n in names if status[n] != "history"]
    history = [n for n in names if status[n] == "history"]
    lines += _section(current, variants, status, "##")
    if history:
        lines += ["## History", ""] + _section(history, variants, status, "###")
    return "\n".join(lines)


def _section(names: list, variants: dict, status: dict, level: str) -> list:
    """The new-skill tables (one per kind) and the cost table of ``names``."""
    lines = []
    for kind in ("method", "ablation", "skill set"):
        group = [n for n in names if variant_kind(n) == kind]
        if not group:
            continue
        lines += [f"{level} New skill alone: {kind}s" if kind != "skill set" else f"{level} New skill alone: skill sets",
                  "",
                  "| variant | seeds | budget | evaluations at | ¼ | ½ | budget | per seed at the budget | best evaluation "
                  "per seed | first ≥ 0.8 per seed |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        lines += [new_skill_row(n, variants[n], status[n]) for n in group] + [""]
    if names:
        lines += [f"{level} Scheduler alone, sampled new skill, usage and cost (per seed, at the budget)", "",
                  "| variant | scheduler alone at ½ | scheduler alone | scheduler alone, the new skill's actions sampled | "
                  "scheduler as it collects (sampled) | new skill, sampled actions | new skill's share of the "
                  "last interval's env steps | wall time per run (min) | rss_mb first → max |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        lines += [cost_row(n, variants[n], status[n]) for n in names] + [""]
    return lines


def archived_tasks(archive: str) -> list:
    return sorted(d for d in os.listdir(archive) if os.path.isdir(os.path.join(archive, d))) if os.path.isdir(archive) else []


def stale(archive: str, out: str, tasks: Sequence[str]) -> list:
    """The ``<out>/<task>.md`` files missing or different from their rebuild."""
    bad = []
    for task in tasks:
        path = os.path.join(out, f"{task}.md")
        text = open(path, encoding="utf-8").read() if os.path.isfile(path) else None
        if text != task_table(archive, task):
            bad.append(path)
    return bad


def write_tables(archive: str, out: str, tasks: Sequence[str]) -> list:
    """Write ``<out>/<task>.md`` for each task; returns the paths."""
    os.makedirs(out, exist_ok=True)
    written = []
    for task in tasks:
        text = task_table(archive, task)
        path = os.path.join(out, f"{task}.md")
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
        written.append(path)
    return written


def main(argv=None) -> int:
    p = Parser(prog="python -m training.experiments.results", description=__doc__.splitlines()[0])
    p.add_argument("--archive", default=ARCHIVE, help="the archived runs: ARCHIVE/<task>/<variant>/s<seed>/")
    p.add_argument("--out", default=OUT, help="where <task>.md go")
    p.add_argument("--tasks", default=None, help="comma-separated (default: every task under --archive)")
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if a file differs from its rebuild")
    args = p.parse_args(argv)

    def run() -> int:
        if not os.path.isdir(args.archive):
            raise UsageError(f"--archive {args.archive}: not a directory")
        tasks = args.tasks.split(",") if args.tasks else archived_tasks(args.archive)
        if args.check:
            bad = stale(args.archive, args.out, tasks)
            for path in bad:
                print(f"stale: {path} differs from its rebuild (python -m training.experiments.results)")
            return 1 if bad else 0
        for path in write_tables(args.archive, args.out, tasks):
            print(path)
        return 0

    return main_guard(run)


if __name__ == "__main__":
    sys.exit(main())
