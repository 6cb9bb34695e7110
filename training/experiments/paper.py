"""The paper's experiment matrix in one command (its Fig. 3-style comparisons): every (task, variant,
seed) trained by ``training.run`` in its own run directory — finished runs skipped, cut runs
resumed — then learning-curve plots and a table of success at fixed budgets.

    python -m training.experiments.paper --tasks lift,stack \\
        --methods skills,scratch,finetune,rhpo,kl_reg,dagger --seeds 0,1,2 --out runs/paper --jobs 2

A variant is a method (``training.run --method``), or a method with config settings in brackets,
e.g. ``kl_reg[new_skill.mpo_epsilon=1,new_skill.mpo_alpha=0]`` (a baseline's sweep setting), or a
named ablation of SkillS (``ABLATIONS``: k1, fixed100, no_augmentation, new_skill_mpo,
no_new_skill_choice), or SkillS with another skill set (``SKILL_SETS``, the paper's Fig. 5:
useful_distractors, distractors, library_useful, many_useful; the last two load the neural skill
library, ``many_useful`` three seeds of each useful skill), or one of the defaults as a user gets them
(``DEFAULT_NAMES``: ``default``, ``default-library``, ``parallel-4096``: the accelerator recipe at its
env count and replay size).

Layout: ``OUT/<task>/<variant>/s<seed>/`` (a ``training.run`` directory, its log next to it as
``s<seed>.log``), ``OUT/<task>_new_skill.png`` (new skill alone, mean ± 1 std over seeds, each
method at its best setting among the variants run, as the paper reports its baselines),
``OUT/<task>_ablations.png`` (SkillS and its ablations, when any ran), ``OUT/<task>_skill_sets.png``
(SkillS and its skill sets, when any ran), ``OUT/results.md`` (every
variant: success at fixed fractions of the budget, wall time per run and in total).
``--budgets task=N,...`` sets env steps per task (``BUDGETS`` otherwise). ``--jobs J`` runs J
trainings at once, each pinned to its own CPU core. ``--dry_run`` prints the plan only;
``--report_only`` writes the plots and table from the runs on disk (of ``--seeds``) and trains
nothing (e.g. sweep settings run on fewer seeds than the defaults). ``--archive DIR`` copies every
run's records without machine paths (``training.archive``) to ``DIR/<task>/<variant>/s<seed>/``
(the repository keeps them in ``docs/results/paper_runs``): each run as soon as it finishes, the
plan's other runs with metrics (finished before, or cut) at the end.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
import time
from typing import Optional

from training.cli import Parser, UsageError, main_guard

# Env steps per task on a CPU with the cpu recipe (README "Results" states them).
BUDGETS = {"lift": 300_000, "stack": 1_200_000, "pyramid": 2_000_000, "triple_stack": 3_000_000}
# Named SkillS ablations (paper App. C / PAPER_EXPERIMENTS): (method, config).
ABLATIONS = {
    "k1": ("skills", {"scheduler": {"skill_lengths": [1]}}),  # a new choice at every step
    "fixed100": ("skills", {"scheduler": {"skill_lengths": [100]}}),  # one fixed skill length
    "no_augmentation": ("skills", {"scheduler": {"augmentation": False}}),
    "new_skill_mpo": ("skills", {"new_skill": {"mpo_alpha": 0.0}}),  # MPO instead of CRR for the new skill
    "no_new_skill_choice": ("skills", {"scheduler": {"new_skill_choice": False}}),  # Fig. 6a
}
# Skill-set ablations (paper Fig. 5, App. C's skill sets): SkillS with these ``training.run`` flags
# instead of the default (``--skills useful`` from the scripted controllers).
SKILL_SETS = {
    "useful_distractors": ("--skills", "useful+distractors"),
    "distractors": ("--skills", "distractors"),
    "library_useful": ("--skills", "useful", "--skill_source", "library"),  # many_useful's reference
    "many_useful": ("--skills", "many_useful", "--skill_source", "library"),  # 3 seeds of each useful skill
}
# The defaults as a user gets them, no setting beyond task / skills / seed: SkillS with the scripted
# useful skills and with the library's, and the accelerator recipe as a GPU runs it (its env count
# and replay size) on whatever this is (kind "default"; ``default_variants``).
DEFAULT_NAMES = ("default", "default-library", "parallel-4096")
FRACTIONS = (0.25, 0.5, 1.0)  # of the budget, for the table
KEY = "eval/new_skill_success"  # what the table and the choice of a method's best setting read
_VARIANT = re.compile(r"^(?P<name>[a-z0-9_]+(?:-[a-z0-9_]+)*)(\[(?P<settings>.*)\])?$")


def split_outside_brackets(text: str, sep: str = ",") -> list:
    """``text`` split at each ``sep`` outside brackets, parts stripped, empty ones dropped:
    ``"skills[a.b=1,c.d=[2,3]],k1"`` -> ``["skills[a.b=1,c.d=[2,3]]", "k1"]``."""
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        depth += (ch == "[") - (ch == "]")
        if ch == sep and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [p.strip() for p in parts if p.strip()]


@dataclasses.dataclass(frozen=True)
class Variant:
    name: str  # directory name
    method: str
    config: dict  # nested TrainConfig fields ({} for the defaults)
    run_args: tuple = ()  # extra training.run flags (a skill set)
    kind: str = "method"  # "method" (a method or one of its settings), "ablation", "skill_set" or "default"

    @property
    def is_reference(self) -> bool:
        """Whether this is SkillS with its defaults: the curve the ablations and skill sets are drawn against."""
        from parallel_skills import methods

        return (self.kind in ("method", "default") and methods.get(self.method) is methods.SKILLS
                and not self.config and not self.run_args)


def default_variants() -> dict:
    """``DEFAULT_NAMES`` -> (method, config, training.run flags)."""
    from parallel_skills.config import RECIPE_SIZES

    envs, replay = RECIPE_SIZES[("parallel", False)]  # what an accelerator gets
    return {"default": ("skills", {}, ()),
            "default-library": ("skills", {}, SKILL_SETS["library_useful"]),
            "parallel-4096": ("skills", {"recipe": "parallel", "num_envs": envs, "replay_size": replay}, ())}


def setting_label(key: str) -> str:
    """A setting's part of a variant's directory name: the field's name (``new_skill.mpo_alpha`` ->
    ``mpo_alpha``), or ``section_field`` for a field both learners have (``scheduler.n_step`` ->
    ``scheduler_n_step``), so that the name says which learner it sets."""
    from parallel_skills.config import NewSkillConfig, SchedulerConfig

    *path, field = key.split(".")
    shared = {f.name for f in dataclasses.fields(SchedulerConfig)} & {f.name for f in dataclasses.fields(NewSkillConfig)}
    return "_".join(path + [field]) if path and field in shared else field


def parse_variant(text: str, methods) -> Variant:
    """``NAME`` or ``NAME[a.b=v,...]`` (NAME a method or an ablation); UsageError otherwise."""
    m = _VARIANT.match(text.strip())
    if not m:
        raise UsageError(f"bad variant {text!r}: use METHOD or METHOD[section.field=value,...]")
    name = m.group("name")
    run_args, kind = (), "method"
    if name in DEFAULT_NAMES:
        (method, config, run_args), kind = default_variants()[name], "default"
    elif name in ABLATIONS:
        (method, config), kind = ABLATIONS[name], "ablation"
    elif name in SKILL_SETS:
        method, config, run_args, kind = "skills", {}, SKILL_SETS[name], "skill_set"
    elif name in methods:
        method, config = name, {}
    else:
        valid = list(methods) + list(ABLATIONS) + list(SKILL_SETS) + list(DEFAULT_NAMES)
        raise UsageError(f"unknown method, ablation or skill set {name!r}; valid: {', '.join(valid)}")
    config = json.loads(json.dumps(config))
    parts = []
    for item in split_outside_brackets(m.group("settings") or ""):
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UsageError(f"bad setting {item!r} in {text!r}: use section.field=value")
        try:
            parsed = json.loads(value)
        except ValueError:
            parsed = value
        node = config
        *path, last = key.split(".")
        for p in path:
            node = node.setdefault(p, {})
        node[last] = parsed
        label = ",".join(map(str, parsed)) if isinstance(parsed, list) else value  # (no brackets in paths)
        parts.append(f"{setting_label(key)}={label}")
    return Variant(name="-".join([name] + parts), method=method, config=config, run_args=run_args, kind=kind)


def run_status(run_dir: str, budget: int) -> str:
    """"done" (finished at ≥ budget), "resume" (a checkpoint to continue from), "restart" (started,
    but cut before its first checkpoint) or "new"."""
    from training import rundir

    if not os.path.isdir(run_dir):
        return "new"
    try:
        exported = rundir.exported_budget(run_dir)
    except UsageError:
        exported = None
    if exported is not None and exported >= budget:
        return "done"
    ckpt = os.path.join(run_dir, "checkpoints")
    if os.path.isdir(ckpt) and any(d.isdigit() for d in os.listdir(ckpt)):
        return "resume"
    return "restart"


def train_command(task: str, variant: Variant, seed: int, budget: int, run_dir: str, status: str,
                  config_path: Optional[str]) -> list:
    cmd = [sys.executable, "-m", "training.run"]
    if status == "resume":
        return cmd + ["--resume", "--out", run_dir, "--num_timesteps", str(budget)]
    cmd += ["--task", task, "--method", variant.method, "--seed", str(seed), "--num_timesteps", str(budget),
            "--out", run_dir, *variant.run_args]
    return cmd + (["--config", config_path] if config_path else [])


def _pin(core: Optional[int]):
    if core is None or not hasattr(os, "sched_setaffinity"):
        return None
    return lambda: os.sched_setaffinity(0, {core})


def run_jobs(jobs: list, parallel: int, on_finish=None) -> list:
    """Run (command, log path) jobs, ``parallel`` at a time, each pinned to its own core when
    parallel > 1; ``on_finish(index, exit code)`` as each ends. Returns the exit codes in job order."""
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else list(range(parallel))
    pending, running, codes = list(enumerate(jobs)), {}, [None] * len(jobs)
    while pending or running:
        while pending and len(running) < parallel:
            idx, (cmd, log) = pending.pop(0)
            free = [c for c in cores if c not in {core for _, core in running.values()}]
            core = free[0] if parallel > 1 and free else None
            with open(log, "ab") as f:
                f.write(f"$ {' '.join(cmd)}\n".encode())
                f.flush()
                proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, preexec_fn=_pin(core))
            running[idx] = (proc, core)
            print(f"started {' '.join(cmd[2:])}" + (f" (core {core})" if core is not None else ""), flush=True)
        time.sleep(1.0)
        for idx, (proc, _) in list(running.items()):
            if proc.poll() is not None:
                codes[idx] = proc.returncode
                del running[idx]
                print(f"{'finished' if proc.returncode == 0 else f'FAILED (exit {proc.returncode})'}: "
                      f"{jobs[idx][1]}", flush=True)
                if on_finish is not None:
                    on_finish(idx, proc.returncode)
    return codes


def success_at(rows: list, steps: float, key: str = "eval/new_skill_success") -> Optional[float]:
    """The last evaluation at or before ``steps`` env steps (None if none)."""
    before = [r for r in rows if isinstance(r.get(key), float) and r["env_steps"] <= steps]
    return before[-1][key] if before else None


def variant_runs(out: str, task: str, variant: Variant, seeds: list):
    """(run dirs, their metrics rows) of the variant's seeds that have evaluations."""
    from training.logging_utils import read_metrics

    dirs = [os.path.join(out, task, variant.name, f"s{s}") for s in seeds]
    dirs = [d for d in dirs if os.path.isfile(os.path.join(d, "metrics.csv"))]
    pairs = [(d, [r for r in read_metrics(os.path.join(d, "metrics.csv")) if isinstance(r.get("env_steps"), float)])
             for d in dirs]
    pairs = [(d, r) for d, r in pairs if r]
    return [d for d, _ in pairs], [r for _, r in pairs]


def score(rows: list, budget: int):
    """A variant's success at the budget, mean over its seeds (their last evaluation at or before
    it), then its mean success over all evaluations (ties: the faster learner)."""
    import numpy as np

    final = [success_at(r, budget, KEY) for r in rows]
    final = [x for x in final if x is not None]
    curve = [np.mean([x[KEY] for x in r if isinstance(x.get(KEY), float)] or [0.0]) for r in rows]
    return (float(np.mean(final)) if final else 0.0, float(np.mean(curve)) if curve else 0.0)


def best_settings(variants: list, scores: dict) -> dict:
    """{method: its best variant} over the non-ablation variants with runs (``scores``: name ->
    ``score``): the paper reports each baseline at its best sweep setting. Ties keep the order
    the variants were given in."""
    best = {}
    for v in variants:
        if v.kind != "method" or v.name not in scores:
            continue
        if v.method not in best or scores[v.name] > scores[best[v.method].name]:
            best[v.method] = v
    return best


def _label(v: Variant, runs: int) -> str:
    settings = v.name[len(v.method) + 1:] if v.name != v.method else ""
    return f"{v.method}" + (f" ({settings.replace('-', ', ')})" if settings else "") + \
        (f", {runs} seeds" if runs > 1 else ", 1 seed")


def write_results(out: str, tasks: list, variants: list, seeds: list, budgets: dict) -> list:
    """Per task: OUT/<task>_new_skill.png (each method at its best setting, ``best_settings``),
    OUT/<task>_ablations.png / OUT/<task>_skill_sets.png when ablations / skill sets ran (SkillS and
    them); OUT/results.md (every variant). Returns the files written."""
    import numpy as np

    from training.experiments.results import mean_std
    from training.plot import Run, plot_curves

    lines = ["# Experiment matrix: the new skill alone (success over the evaluation episodes)", "",
             f"Seeds {', '.join(map(str, seeds))}; mean ± sample std (n − 1) over the seeds that reached the budget "
             "fraction (one seed: its value).", ""]
    written, total_seconds = [], 0.0
    for task in tasks:
        budget = budgets[task]
        header = [f"{int(f * budget):,}" for f in FRACTIONS]
        lines += [f"## {task} (budget {budget:,} env steps)", "",
                  "| variant | " + " | ".join(header) + " | seeds | wall time per run (min) |",
                  "| --- | " + " | ".join("---" for _ in header) + " | --- | --- |"]
        found, scores = {}, {}
        for v in variants:
            dirs, rows = variant_runs(out, task, v, seeds)
            if not rows:
                lines.append(f"| {v.name} | " + " | ".join("–" for _ in header) + " | 0 | – |")
                continue
            found[v.name] = (dirs, rows)
            scores[v.name] = score(rows, budget)
            cells = []
            for f in FRACTIONS:
                vals = [success_at(r, f * budget) for r in rows if r[-1]["env_steps"] >= f * budget]
                vals = [x for x in vals if x is not None]
                cells.append(mean_std(vals) if vals else "–")
            walls = [r[-1]["wall_time"] / 60 for r in rows if isinstance(r[-1].get("wall_time"), float)]
            total_seconds += 60 * sum(walls)
            wall = f"{np.mean(walls):.1f}" if walls else "–"
            lines.append(f"| {v.name} | " + " | ".join(cells) + f" | {len(rows)} | {wall} |")
        lines.append("")
        best = best_settings(variants, scores)
        if best:
            lines.append("Plotted (each method at its best setting: success at the budget, then over the run): "
                         + "; ".join(f"{m}: {v.name}" for m, v in best.items()) + ".")
            lines.append("")
            groups = [(_label(v, len(found[v.name][0])), [Run(d) for d in found[v.name][0]]) for v in best.values()]
            written.append(plot_curves(groups, os.path.join(out, f"{task}_new_skill.png")))
        base = [v for v in variants if v.is_reference and v.name in found]
        for kind, suffix in (("ablation", "ablations"), ("skill_set", "skill_sets")):
            others = [v for v in variants if v.kind == kind and v.name in found]
            if not others:
                continue
            groups = [(_label(v, len(found[v.name][0])) if v.is_reference else
                       f"{v.name}, {len(found[v.name][0])} seed{'s' if len(found[v.name][0]) > 1 else ''}",
                       [Run(d) for d in found[v.name][0]]) for v in base + others]
            written.append(plot_curves(groups, os.path.join(out, f"{task}_{suffix}.png")))
    lines.append(f"Total training wall time of the runs above: {total_seconds / 3600:.2f} h (summed over runs; "
                 "runs in parallel overlap).")
    grid = selection_table(out, tasks, variants, seeds, budgets)
    if grid:
        lines += [""] + grid
        print("\n".join(grid))
    path = os.path.join(out, "results.md")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return written + [path]


def grid_cell(variant: Variant) -> Optional[tuple]:
    """(setting, skill source) of a SkillS variant in the selection grid (``selection_table``), or
    None for a baseline or an ablation: the setting is the variant's bracketed part ("defaults" for
    none; ``parallel-4096`` its own), the source "scripted" (the useful controllers), "library" (the
    library's useful set) or another skill set's name."""
    from parallel_skills import methods

    if methods.get(variant.method) is not methods.SKILLS or variant.kind == "ablation":
        return None
    if variant.kind == "default":
        return ("defaults", "library") if variant.name == "default-library" else (
            ("defaults", "scripted") if variant.name == "default" else (variant.name, "scripted"))
    base = variant.name.split("-")[0]
    setting = variant.name[len(base) + 1:] or "defaults"
    return setting, ("scripted" if base == "skills" else "library" if base == "library_useful" else base)


def selection_table(out: str, tasks: list, variants: list, seeds: list, budgets: dict) -> list:
    """The selection grid as markdown lines: one row per setting, one column per task and skill
    source, each cell the new skill alone at the task's budget (its last evaluation at or before
    it): mean ± std over the seeds that reached the budget, then the lowest seed's value in
    brackets, and how many seeds. Settings are compared on the same tasks, sources and seeds."""
    from training.experiments.results import mean_std

    cells, columns, rows = {}, [], []
    for task in tasks:
        for v in variants:
            where = grid_cell(v)
            if where is None:
                continue
            setting, source = where
            _, runs = variant_runs(out, task, v, seeds)
            finals = [success_at(r, budgets[task], KEY) for r in runs if r[-1]["env_steps"] >= budgets[task]]
            finals = [x for x in finals if x is not None]
            column = f"{task} · {source}"
            if column not in columns:
                columns.append(column)
            if setting not in rows:
                rows.append(setting)
            cells[setting, column] = (f"{mean_std(finals)} (min {min(finals):.2f}, {len(finals)} seeds)"
                                      if finals else "–")
    if not columns:
        return []
    lines = ["## Selection grid: the new skill alone at each task's budget", "",
             "Mean ± sample std over the seeds that reached the budget (min: the lowest seed).", "",
             "| setting | " + " | ".join(columns) + " |", "| --- | " + " | ".join("---" for _ in columns) + " |"]
    for setting in rows:
        lines.append(f"| {setting} | " + " | ".join(cells.get((setting, c), "") for c in columns) + " |")
    return lines + [""]


def archive_runs(out: str, archive: str, tasks: list, variants: list, seeds: list, done=frozenset()) -> list:
    """``training.archive`` of every run of the plan that has metrics, into
    ``archive/<task>/<variant>/s<seed>/`` (paths under ``out`` recorded as ``runs/paper/...``);
    ``done``: run directories archived already (as they finished), skipped."""
    from training.archive import archive_run

    written = []
    for task in tasks:
        for v in variants:
            for seed in seeds:
                run_dir = os.path.join(out, task, v.name, f"s{seed}")
                if run_dir not in done and os.path.isfile(os.path.join(run_dir, "metrics.csv")):
                    written += archive_run(run_dir, os.path.join(archive, task, v.name, f"s{seed}"), root=out)
    return written


def main(argv=None):
    from parallel_skills import methods as method_registry

    argv = list(sys.argv[1:] if argv is None else argv)
    p = Parser(prog="python -m training.experiments.paper", description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default="lift")
    p.add_argument("--methods", default="skills,scratch,finetune,rhpo,kl_reg,dagger",
                   help="variants: methods, ablations, METHOD[section.field=value,...] (semicolon-separated if "
                        "settings contain commas)")
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--budgets", default=None, help="task=env_steps,... (default: BUDGETS)")
    p.add_argument("--out", required=True)
    p.add_argument("--jobs", type=int, default=1, help="trainings at once, one core each")
    p.add_argument("--dry_run", action="store_true")
    p.add_argument("--report_only", action="store_true",
                   help="write the plots and results.md from the runs of --seeds on disk; train nothing")
    p.add_argument("--archive", default=None,
                   help="also copy each run's metrics.csv, config.json and export.json (machine paths taken out: "
                        "training.archive) to ARCHIVE/<task>/<variant>/s<seed>/, e.g. docs/results/paper_runs")
    p.add_argument("--results", default=None,
                   help="with --archive: rewrite RESULTS/<task>.md from the whole archive of each task "
                        "(training.experiments.results), e.g. docs/results")
    args = p.parse_args(argv)

    def plan():
        import tasks as task_registry

        task_list = [t.strip() for t in args.tasks.split(",") if t.strip()]
        for t in task_list:
            if t not in task_registry.names():
                raise UsageError(f"unknown task {t!r}; valid: {', '.join(task_registry.names())}")
        items = split_outside_brackets(args.methods, ";" if ";" in args.methods else ",")
        variants = [parse_variant(x, method_registry.names()) for x in items]
        if len({v.name for v in variants}) != len(variants):
            raise UsageError("a variant is listed twice")
        try:
            seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
        except ValueError:
            raise UsageError(f"--seeds must be integers separated by commas, got {args.seeds!r}") from None
        if not seeds or min(seeds) < 0:
            raise UsageError(f"--seeds needs non-negative integers, got {args.seeds!r}")
        budgets = dict(BUDGETS)
        for item in filter(None, (args.budgets or "").split(",")):
            task, sep, value = item.partition("=")
            if not sep or not value.isdigit() or int(value) < 1:
                raise UsageError(f"bad --budgets item {item!r}: use task=env_steps (a positive integer)")
            budgets[task] = int(value)
        missing = [t for t in task_list if t not in budgets]
        if missing:
            raise UsageError(f"no budget for {', '.join(missing)}: give --budgets {missing[0]}=N")
        if args.jobs < 1:
            raise UsageError(f"--jobs must be a positive integer, got {args.jobs}")
        if args.results and not args.archive:
            raise UsageError("--results needs --archive: the tables are rebuilt from the archived runs")
        return task_list, variants, seeds, budgets

    task_list, variants, seeds, budgets = main_guard(plan)
    jobs, job_archives = [], []  # job_archives: (run dir, its archive folder) or None, per job
    for task in task_list:
        for v in variants:
            config_path = None
            if v.config and not (args.dry_run or args.report_only):
                os.makedirs(os.path.join(args.out, "configs"), exist_ok=True)
                config_path = os.path.abspath(os.path.join(args.out, "configs", f"{v.name}.json"))
                with open(config_path, "w") as f:
                    json.dump(v.config, f, indent=2, sort_keys=True)
            for seed in seeds:
                run_dir = os.path.join(args.out, task, v.name, f"s{seed}")
                status = run_status(run_dir, budgets[task])
                print(f"{task:<13} {v.name:<40} s{seed}: {status}")
                if status == "done" or args.dry_run or args.report_only:
                    continue
                if status == "restart":  # cut before any checkpoint: keep it aside, start again
                    aside = f"{run_dir}.cut-{time.strftime('%Y%m%d-%H%M%S')}"
                    shutil.move(run_dir, aside)
                    print(f"  (moved to {aside}: no checkpoint to resume from)")
                os.makedirs(os.path.dirname(run_dir), exist_ok=True)
                jobs.append((train_command(task, v, seed, budgets[task], run_dir, status, config_path),
                             f"{run_dir}.log"))
                job_archives.append((run_dir, os.path.join(args.archive, task, v.name, f"s{seed}"))
                                    if args.archive else None)
    if args.dry_run:
        return
    archived = set()  # run directories archived as they finished

    def archive_finished(idx: int, code: int):
        """A run that finished is archived at once, not only when the whole plan ends (a session
        cut between seeds keeps what finished)."""
        if code == 0 and job_archives[idx] is not None:
            from training.archive import archive_run

            for path in archive_run(*job_archives[idx], root=args.out):
                print(f"archived: {path}", flush=True)
            archived.add(job_archives[idx][0])

    codes = run_jobs(jobs, args.jobs, on_finish=archive_finished)
    failed = [log for (_, log), c in zip(jobs, codes) if c != 0]
    for path in write_results(args.out, task_list, variants, seeds, budgets):
        print(f"written: {path}")
    if args.archive:
        for path in archive_runs(args.out, args.archive, task_list, variants, seeds, done=archived):
            print(f"archived: {path}")
    if args.results:
        from training.experiments.results import write_tables

        for path in write_tables(args.archive, args.results, task_list):
            print(f"written: {path}")
    if failed:
        print(f"{len(failed)} run(s) failed; their logs: {', '.join(failed)}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
