"""training.experiments.time_to_success: the first evaluation at a threshold, and ratios to a reference."""

import csv

import pytest

from training.experiments.time_to_success import first_success, main


def _run(tmp_path, name, rows):
    d = tmp_path / name
    d.mkdir()
    with open(d / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["env_steps", "wall_time", "eval/new_skill_success"])
        w.writerows(rows)
    return str(d)


def test_first_success_and_consecutive():
    rows = [{"env_steps": s, "eval/new_skill_success": v} for s, v in ((1, 0.1), (2, 0.9), (3, 0.5), (4, 0.8), (5, 0.85))]
    assert first_success(rows, 0.8)["env_steps"] == 2
    assert first_success(rows, 0.8, consecutive=2)["env_steps"] == 4
    assert first_success(rows, 0.95) is None


def test_ratios_to_the_reference(tmp_path, capsys):
    ref = _run(tmp_path, "ref", [(1000, 10.0, 0.2), (2000, 20.0, 0.81)])
    fast = _run(tmp_path, "fast", [(1000, 4.0, 0.85)])
    never = _run(tmp_path, "never", [(1000, 5.0, 0.1)])
    main([ref, fast, never])
    out = capsys.readouterr().out
    assert "0.50" in out.splitlines()[3] and "0.20" in out.splitlines()[3]  # half the env steps, a fifth of the time
    assert "not reached by 1,000 env steps" in out
    with pytest.raises(SystemExit):
        main([str(tmp_path / "missing")])


def test_budget_ratio_and_bad_budget(tmp_path, capsys):
    fast = _run(tmp_path, "fast", [(1000, 150.0, 0.2), (2000, 330.0, 0.81)])
    main([fast, "--budget_seconds", "300"])
    row = capsys.readouterr().out.splitlines()[2]
    assert row.split()[-1] == "1.10"  # 330 s against a 300 s budget: over it
    with pytest.raises(SystemExit) as e:
        main([fast, "--budget_seconds", "0"])
    assert e.value.code == 2 and "--budget_seconds must be a positive" in capsys.readouterr().err
