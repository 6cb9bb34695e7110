"""The repository's results are its archived runs: every docs/results/<task>.md rebuilds exactly from
docs/results/paper_runs/<task>/ (training.experiments.results), each number of a README "Results"
table that names a docs/results file is in that file, and nothing under docs/results/ holds a path
of the machine that produced it."""

import json
import os
import re
import shutil

import pytest

from parallel_skills import config
from training.experiments import results

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCS = os.path.join(ROOT, "docs", "results")
ARCHIVE = os.path.join(DOCS, "paper_runs")
TASKS = results.archived_tasks(ARCHIVE)
NUMBER = re.compile(r"(?<![\w.])\d+(?:\.\d+)?[kM]?(?![\w])")
LINK = re.compile(r"docs/results/([\w\-]+\.md)")
ABSOLUTE = re.compile(r"(?<![\w.~])/(?:home|root|tmp|work|Users|mnt|scratch|private|var/folders)/")


def _rebuild(task, archive=ARCHIVE):
    return results.task_table(archive, task)


@pytest.mark.parametrize("task", TASKS)
def test_each_task_table_rebuilds_from_the_archive(task):
    path = os.path.join(DOCS, f"{task}.md")
    assert os.path.isfile(path), f"{path} missing: python -m training.experiments.results"
    assert open(path, encoding="utf-8").read() == _rebuild(task), \
        f"{path} differs from its rebuild: python -m training.experiments.results"


def test_a_value_changed_by_hand_in_the_archive_is_caught(tmp_path):
    archive = tmp_path / "paper_runs"
    shutil.copytree(os.path.join(ARCHIVE, "stack", "skills"), archive / "stack" / "skills")
    out = tmp_path / "out"
    results.write_tables(str(archive), str(out), ["stack"])
    assert results.stale(str(archive), str(out), ["stack"]) == []
    metrics = archive / "stack" / "skills" / "s1" / "metrics.csv"
    lines = metrics.read_text().splitlines()
    head, last = lines[0].split(","), lines[-1].split(",")
    col = head.index(results.NEW_SKILL)
    last[col] = f"{float(last[col]) + 0.25:.4f}"  # seed 1's final new-skill success, 0.4375 -> 0.6875
    metrics.write_text("\n".join(lines[:-1] + [",".join(last)]) + "\n")
    assert results.stale(str(archive), str(out), ["stack"]) == [str(out / "stack.md")]
    assert results.main(["--archive", str(archive), "--out", str(out), "--check"]) == 1


def _readme_tables():
    """(the docs/results file it names, the table's lines) for each table in README's Results section
    whose preceding paragraph links a docs/results/*.md file."""
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    section = text.split("\n## Results", 1)[1].split("\n## ", 1)[0].splitlines()
    tables, i = [], 0
    while i < len(section):
        if section[i].startswith("|") and i + 1 < len(section) and section[i + 1].startswith("| ---"):
            j = i
            while j < len(section) and section[j].startswith("|"):
                j += 1
            before = "\n".join(section[max(0, i - 4):i])
            for name in LINK.findall(before):
                tables.append((name, section[i + 2:j]))
            i = j
        else:
            i += 1
    return tables


def test_readme_result_tables_quote_their_docs_results_files():
    tables = _readme_tables()
    assert tables, "README Results names no docs/results/*.md file before a table"
    for name, rows in tables:
        source = open(os.path.join(DOCS, name), encoding="utf-8").read()
        have = set(NUMBER.findall(source))
        for row in rows:
            cells = row.strip("|").split("|")[1:]  # the first cell names the row
            missing = [n for n in NUMBER.findall("|".join(cells)) if n not in have]
            assert not missing, f"README row {row!r}: {missing} not in docs/results/{name}"


def test_no_file_under_docs_results_holds_a_machine_path():
    offenders = []
    for base, _, files in os.walk(DOCS):
        for f in files:
            if f.endswith((".csv", ".json", ".md")):
                path = os.path.join(base, f)
                if ABSOLUTE.search(open(path, encoding="utf-8", errors="replace").read()):
                    offenders.append(os.path.relpath(path, ROOT))
    assert not offenders, f"absolute paths in {offenders}"


def test_results_cli_bad_input_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        results.main(["--archive", str(tmp_path / "none")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a directory" in err[0]


# A shipped config that the docs recommend -> the archived runs whose results they quote for it.
SHIPPED_CONFIGS = {
    "stack_learned_skills.json": "stack/library_useful-replay_size=100000-td_target_action=mean-"
                                 "new_skill_collects=mean-n_step_returns=own-greedy_env_fraction=0.125",
}


@pytest.mark.parametrize("name", sorted(SHIPPED_CONFIGS))
def test_a_shipped_config_is_the_setting_of_the_runs_behind_it(name):
    """Every field the shipped file sets has the same value in each archived run's train config."""
    path = os.path.join(ROOT, "training", "configs", name)
    data = json.load(open(path, encoding="utf-8"))
    shipped = config.from_dict(config.TrainConfig(), data, path)  # read as --config reads it
    variant = os.path.join(ARCHIVE, SHIPPED_CONFIGS[name])
    seeds = sorted(d for d in os.listdir(variant) if d.startswith("s"))
    assert len(seeds) >= 3, f"{variant}: {seeds}"
    for seed in seeds:
        where = os.path.join(variant, seed, "config.json")
        run = config.from_dict(config.TrainConfig(), json.load(open(where, encoding="utf-8"))["train_config"], where)
        for field in config.dotted_names(data):
            want, got = config.dotted_value(shipped, field), config.dotted_value(run, field)
            assert got == want, f"{name}: {field}={want!r}, run {seed} has {got!r}"
