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


def _readme_result_rows(text: str):
    """(the docs/results file, the row's cells that quote it) for each row of a table in the
    "## Results" section of ``text`` (a README): a row that links a docs/results/*.md file quotes
    it in every cell but the first two (task, method) and the link's own; a row that links none
    quotes the file its table's preceding paragraph links, in every cell but the first."""
    section = text.split("\n## Results", 1)[1].split("\n## ", 1)[0].splitlines()
    rows, i = [], 0
    while i < len(section):
        if section[i].startswith("|") and i + 1 < len(section) and section[i + 1].startswith("| ---"):
            j = i
            while j < len(section) and section[j].startswith("|"):
                j += 1
            before = LINK.findall("\n".join(section[max(0, i - 4):i]))
            for row in section[i + 2:j]:
                cells = row.strip().strip("|").split("|")
                linked = [c for c in cells if LINK.search(c)]
                if linked:
                    quoted = [c for c in cells[2:] if not LINK.search(c)]
                    rows += [(name, row, quoted) for name in LINK.findall(linked[0])[:1]]
                else:
                    rows += [(name, row, cells[1:]) for name in before]
            i = j
        else:
            i += 1
    return rows


def test_readme_result_tables_quote_their_docs_results_files():
    rows = _readme_result_rows(open(os.path.join(ROOT, "README.md"), encoding="utf-8").read())
    assert rows, "README's Results section has no table row that names a docs/results/*.md file"
    for name, row, cells in rows:
        source = open(os.path.join(DOCS, name), encoding="utf-8").read()
        have = set(NUMBER.findall(source))
        missing = [n for n in NUMBER.findall("|".join(cells)) if n not in have]
        assert not missing, f"README row {row!r}: {missing} not in docs/results/{name}"


def test_a_readme_number_missing_from_its_file_is_caught():
    table = ("intro\n\n## Results\n\n| task | method | new skill | file |\n| --- | --- | --- | --- |\n"
             "| lift | skills | 0.94 ± 0.06 | [lift](docs/results/lift.md) |\n"
             "| lift | skills | 0.93 ± 0.999 | [lift](docs/results/lift.md) |\n\n## Next\n")
    rows = _readme_result_rows(table)
    assert [(name, cells) for name, _, cells in rows] == [("lift.md", [" 0.94 ± 0.06 "]), ("lift.md", [" 0.93 ± 0.999 "])]
    have = set(NUMBER.findall(open(os.path.join(DOCS, "lift.md"), encoding="utf-8").read()))
    assert all(n in have for n in NUMBER.findall(rows[0][2][0]))
    assert "0.999" not in have and "0.999" in NUMBER.findall(rows[1][2][0])


def _copy_variant(archive, task, variant, name):
    dest = archive / task / name
    shutil.copytree(os.path.join(ARCHIVE, task, variant), dest)
    return dest


def _status(path):
    return results.variant_status(os.path.basename(path), results.read_variant(str(path)))


def test_the_current_defaults_rows_are_found_by_their_config(tmp_path):
    """A variant whose runs' train config is today's default is marked default whatever its name;
    the same runs with a config field changed that the name does not set are history, and with
    the name setting it, current; runs without a config.json, or named archived, are history."""
    default = "skills-scheduler_n_step=10-crr_mode=exp"
    archive = tmp_path / "paper_runs"
    assert _status(os.path.join(ARCHIVE, "stack", default)) == "default"
    assert _status(_copy_variant(tmp_path / "renamed", "stack", default, "skills")) == "default"
    assert _status(_copy_variant(archive, "stack", default, "default")) == "default"
    assert _status(_copy_variant(archive, "stack", default, "skills-archived_x")) == "history"
    assert _status(os.path.join(ARCHIVE, "stack", "skills")) == "history"  # the recipe before (indicator weights)
    assert _status(os.path.join(ARCHIVE, "stack", "scratch")) == "history"  # no config.json
    for name, want in (("skills", "history"), ("skills-replay_size=1000", "current")):
        path = _copy_variant(archive, "stack", default, name)
        for seed in os.listdir(path):
            record = path / seed / "config.json"
            data = json.loads(record.read_text())
            data["train_config"]["replay_size"] = 1000
            record.write_text(json.dumps(data))
        assert _status(path) == want, name
    table = results.task_table(str(archive), "stack")
    head, history = table.split("\n## History\n")
    assert f"| **default** (default) |" in head and "| skills-replay_size=1000 |" in head
    assert "| skills-archived_x |" in history and "| skills |" in history


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
        # (Records from before docs/research/pruned.md hold the removed fields, at their off values.)
        recorded = results.known_fields(config.TrainConfig, json.load(open(where, encoding="utf-8"))["train_config"])
        run = config.from_dict(config.TrainConfig(), recorded, where)
        for field in config.dotted_names(data):
            want, got = config.dotted_value(shipped, field), config.dotted_value(run, field)
            assert got == want, f"{name}: {field}={want!r}, run {seed} has {got!r}"
