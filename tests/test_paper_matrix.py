"""training.experiments.paper: variants, run states, the plan and the results table (no training here:
each run is a training.run, tested on its own)."""

import csv
import json
import os

import pytest

from training.experiments import paper
from training.experiments.paper import ABLATIONS, Variant, parse_variant, run_status, success_at, train_command

METHODS = ("skills", "scratch", "kl_reg")


def test_variants():
    assert parse_variant("skills", METHODS) == Variant("skills", "skills", {})
    v = parse_variant("kl_reg[new_skill.mpo_epsilon=1,new_skill.mpo_alpha=0]", METHODS)
    assert v.method == "kl_reg" and v.name == "kl_reg-mpo_epsilon=1-mpo_alpha=0"
    # A field both learners have is named with its learner.
    both = parse_variant("skills[scheduler.n_step=10,new_skill.n_step=50]", METHODS)
    assert both.name == "skills-scheduler_n_step=10-new_skill_n_step=50"
    assert both.config == {"scheduler": {"n_step": 10}, "new_skill": {"n_step": 50}}
    assert v.config == {"new_skill": {"mpo_epsilon": 1, "mpo_alpha": 0}}
    k1 = parse_variant("k1", METHODS)
    assert k1.method == "skills" and k1.config == ABLATIONS["k1"][1]
    many = parse_variant("many_useful", METHODS)
    assert (many.method, many.config, many.kind) == ("skills", {}, "skill_set")
    assert many.run_args == ("--skills", "many_useful", "--skill_source", "library")
    assert parse_variant("distractors", METHODS).run_args == ("--skills", "distractors")
    # The defaults as a user gets them: nothing set but the skills (and the accelerator's sizes).
    assert parse_variant("default", METHODS) == Variant("default", "skills", {}, (), "default")
    assert parse_variant("default", METHODS).is_reference
    lib = parse_variant("default-library", METHODS)
    assert lib.config == {} and lib.run_args == ("--skills", "useful", "--skill_source", "library")
    from parallel_skills.config import RECIPE_SIZES
    envs, replay = RECIPE_SIZES[("parallel", False)]
    assert parse_variant("parallel-4096", METHODS).config == {"recipe": "parallel", "num_envs": envs,
                                                              "replay_size": replay} and envs == 4096
    with pytest.raises(Exception, match="unknown method, ablation or skill set 'bc'"):
        parse_variant("bc", METHODS)
    with pytest.raises(Exception, match="bad setting"):
        parse_variant("kl_reg[epsilon]", METHODS)
    # A list value (brackets and commas inside the brackets), named without brackets.
    lengths = parse_variant("skills[scheduler.skill_lengths=[50,100],replay_size=1000]", METHODS)
    assert lengths.config == {"scheduler": {"skill_lengths": [50, 100]}, "replay_size": 1000}
    assert lengths.name == "skills-skill_lengths=50,100-replay_size=1000"
    assert paper.split_outside_brackets("skills[scheduler.skill_lengths=[100]],k1, scratch") == [
        "skills[scheduler.skill_lengths=[100]]", "k1", "scratch"]


def _metrics(d, rows, export_budget=None):
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "metrics.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["env_steps", "wall_time", "eval/new_skill_success", "eval/new_skill_return"])
        w.writerows(rows)
    if export_budget is not None:
        with open(os.path.join(d, "export.json"), "w") as f:
            json.dump({"env_steps": export_budget, "metadata": {"num_timesteps": export_budget}}, f)


def test_run_status_and_commands(tmp_path):
    d = str(tmp_path / "lift" / "skills" / "s0")
    assert run_status(d, 1000) == "new"
    _metrics(d, [(500, 10.0, 0.1, 1.0)])
    assert run_status(d, 1000) == "restart"  # no checkpoint yet
    os.makedirs(os.path.join(d, "checkpoints", "12"))
    assert run_status(d, 1000) == "resume"
    cmd = train_command("lift", Variant("skills", "skills", {}), 0, 1000, d, "resume", None)
    assert cmd[-5:] == ["--resume", "--out", d, "--num_timesteps", "1000"]
    _metrics(d, [(1000, 20.0, 0.5, 1.0)], export_budget=1000)
    assert run_status(d, 1000) == "done" and run_status(d, 2000) == "resume"  # extended to a larger budget
    cmd = train_command("stack", Variant("kl_reg-x", "kl_reg", {"a": 1}), 2, 5000, d, "new", "/c.json")
    assert cmd[2:] == ["training.run", "--task", "stack", "--method", "kl_reg", "--seed", "2", "--num_timesteps",
                       "5000", "--out", d, "--config", "/c.json"]
    # A skill set is SkillS with training.run's skill flags; a resume takes them from the run's record.
    cmd = train_command("stack", parse_variant("useful_distractors", METHODS), 1, 5000, d, "new", None)
    assert cmd[2:] == ["training.run", "--task", "stack", "--method", "skills", "--seed", "1", "--num_timesteps",
                       "5000", "--out", d, "--skills", "useful+distractors"]
    assert "--skills" not in train_command("stack", parse_variant("distractors", METHODS), 1, 5000, d, "resume", None)


def test_success_at_budget_fractions_and_results(tmp_path):
    rows = [{"env_steps": s, "eval/new_skill_success": v} for s, v in ((100.0, 0.1), (200.0, 0.5), (300.0, 0.9))]
    assert success_at(rows, 250) == 0.5 and success_at(rows, 50) is None
    out = str(tmp_path)
    for seed, final in ((0, 0.9), (1, 0.7)):
        _metrics(os.path.join(out, "lift", "skills", f"s{seed}"),
                 [(100, 5.0, 0.1, 1.0), (200, 10.0, 0.3, 2.0), (400, 20.0, final, 3.0)])
    variants = [Variant("skills", "skills", {}), Variant("scratch", "scratch", {})]
    paths = paper.write_results(out, ["lift"], variants, [0, 1], {"lift": 400})
    table = open(os.path.join(out, "results.md")).read()
    assert "| skills | 0.10 ± 0.00 | 0.30 ± 0.00 | 0.80 ± 0.14 | 2 |" in table
    assert "| scratch | – | – | – | 0 | – |" in table
    assert any(p.endswith("lift_new_skill.png") for p in paths)


def test_dry_run_prints_the_plan(tmp_path, capsys):
    _metrics(str(tmp_path / "lift" / "scratch" / "s0"), [(300000, 100.0, 0.0, 0.0)], export_budget=300000)
    paper.main(["--tasks", "lift", "--methods", "skills,scratch", "--seeds", "0", "--out", str(tmp_path),
                "--dry_run"])
    out = capsys.readouterr().out
    assert "skills" in out and "s0: new" in out and "s0: done" in out
    paper.main(["--tasks", "lift", "--methods", "default,default-library,skills[replay_size=1000,greedy_env_fraction=0.5]",
                "--seeds", "0", "--out", str(tmp_path), "--dry_run"])
    out = capsys.readouterr().out
    assert all(f"lift          {name}" in out for name in ("default ", "default-library ",
                                                           "skills-replay_size=1000-greedy_env_fraction=0.5 "))


def test_bad_arguments(tmp_path, capsys):
    for argv, msg in ((["--tasks", "lifft"], "unknown task"), (["--seeds", "a"], "--seeds must be integers"),
                      (["--budgets", "lift=x"], "bad --budgets item"), (["--methods", "skills,skills"], "listed twice"),
                      (["--jobs", "0"], "--jobs must be")):
        with pytest.raises(SystemExit) as e:
            paper.main(argv + ["--out", str(tmp_path / "m")])
        assert e.value.code == 2 and msg in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "m")  # nothing written on bad input


def test_plots_each_method_at_its_best_setting_and_the_ablations(tmp_path, capsys):
    out = str(tmp_path)
    curves = {"skills": (0.5, 0.9), "scratch": (0.0, 0.1), "scratch-mpo_alpha=0": (0.2, 0.3),
              "scratch-mpo_alpha=0.5": (0.0, 0.3), "k1": (0.0, 0.2), "distractors": (0.95, 0.95)}
    for name, (mid, final) in curves.items():
        for seed in ((0, 1) if name in ("skills", "scratch") else (0,)):
            _metrics(os.path.join(out, "lift", name, f"s{seed}"), [(200, 5.0, mid, 1.0), (400, 10.0, final, 2.0)])
    variants = [parse_variant(x, ("skills", "scratch")) for x in
                ("skills", "scratch", "scratch[new_skill.mpo_alpha=0]", "scratch[new_skill.mpo_alpha=0.5]", "k1",
                 "distractors")]
    scores = {v.name: paper.score(paper.variant_runs(out, "lift", v, [0, 1])[1], 400) for v in variants}
    best = paper.best_settings(variants, scores)
    # Ties at the budget (0.3) go to the better curve; ablations and skill sets (distractors, above
    # SkillS here) are never a method's best setting.
    assert {m: v.name for m, v in best.items()} == {"skills": "skills", "scratch": "scratch-mpo_alpha=0"}
    paths = paper.write_results(out, ["lift"], variants, [0, 1], {"lift": 400})
    assert {os.path.basename(p) for p in paths} == {"lift_new_skill.png", "lift_ablations.png", "lift_skill_sets.png",
                                                     "results.md"}
    table = open(os.path.join(out, "results.md")).read()
    assert "scratch: scratch-mpo_alpha=0" in table and "| scratch-mpo_alpha=0.5 |" in table
    # --report_only: the same files from the runs on disk, nothing trained, nothing moved aside.
    os.remove(os.path.join(out, "results.md"))
    paper.main(["--tasks", "lift", "--methods", "skills;scratch;scratch[new_skill.mpo_alpha=0];k1", "--seeds", "0,1",
                "--budgets", "lift=400", "--out", out, "--report_only"])
    printed = capsys.readouterr().out
    assert "started" not in printed and os.path.isfile(os.path.join(out, "results.md"))
    assert sorted(os.listdir(os.path.join(out, "lift", "k1"))) == ["s0"]


def test_selection_grid_puts_each_setting_against_tasks_and_skill_sources(tmp_path):
    """One row per setting, one column per task and skill source; the cell: the new skill at the
    budget, mean ± std over the seeds that reached it and the lowest seed. Baselines and ablations
    are not candidates; the defaults' named variants are the "defaults" row."""
    out = str(tmp_path)
    finals = {("lift", "default"): (0.9, 0.7), ("lift", "default-library"): (0.8, 1.0),
              ("lift", "skills-replay_size=100000"): (1.0, 1.0),
              ("stack", "library_useful-replay_size=100000"): (0.5, 0.3), ("lift", "scratch"): (0.0, 0.0),
              ("lift", "k1"): (0.1, 0.1)}
    for (task, name), values in finals.items():
        for seed, final in enumerate(values):
            _metrics(os.path.join(out, task, name, f"s{seed}"), [(200, 5.0, 0.0, 1.0), (400, 10.0, final, 2.0)])
    variants = [parse_variant(x, METHODS) for x in ("default", "default-library", "skills[replay_size=100000]",
                                                    "library_useful[replay_size=100000]", "scratch", "k1")]
    lines = paper.selection_table(out, ["lift", "stack"], variants, [0, 1], {"lift": 400, "stack": 400})
    assert "| setting | lift · scripted | lift · library | stack · scripted | stack · library |" in lines
    assert "| defaults | 0.80 ± 0.14 (min 0.70, 2 seeds) | 0.90 ± 0.14 (min 0.80, 2 seeds) | – | – |" in lines
    assert "| replay_size=100000 | 1.00 ± 0.00 (min 1.00, 2 seeds) | – | – | 0.40 ± 0.14 (min 0.30, 2 seeds) |" in lines
    assert not any(line.startswith(("| scratch", "| k1")) for line in lines)
    assert "| defaults | – | – |" in paper.selection_table(out, ["lift"], variants, [0, 1], {"lift": 800})


def test_run_jobs_reports_each_job_as_it_finishes(tmp_path, capsys):
    """``run_jobs``'s ``on_finish(index, exit code)`` comes as each job ends (what lets ``--archive``
    keep a run that finished before the plan was cut), with the job's own code."""
    import sys

    from training.experiments.paper import run_jobs

    seen = []
    jobs = [([sys.executable, "-c", "import sys; sys.exit(0)"], str(tmp_path / "a.log")),
            ([sys.executable, "-c", "import sys; sys.exit(3)"], str(tmp_path / "b.log"))]
    codes = run_jobs(jobs, 1, on_finish=lambda idx, code: seen.append((idx, code)))
    assert codes == [0, 3] and seen == [(0, 0), (1, 3)]
    assert "FAILED (exit 3)" in capsys.readouterr().out
