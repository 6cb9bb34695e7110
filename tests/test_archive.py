"""training.archive: a run directory's records copied without machine paths."""

import json
import os
import subprocess
import sys

from training.archive import archive_run, portable_path


def test_archive_takes_the_machine_paths_out(tmp_path):
    root = tmp_path / "paper"
    run = root / "lift" / "skills" / "s0"
    (run / "checkpoints").mkdir(parents=True)
    (run / "metrics.csv").write_text("env_steps,eval/new_skill_success\n100,0.5\n")
    record = {"command": f"python -m training.run --out {run} --config {root}/configs/x.json --seed 0",
              "skill_dir": "/somewhere/else/skills", "seed": 0, "nested": {"paths": [str(run / "a.npz")]}}
    (run / "config.json").write_text(json.dumps(record))
    dest = tmp_path / "archive" / "s0"
    written = archive_run(str(run), str(dest), root=str(root))
    assert sorted(os.path.basename(w) for w in written) == ["config.json", "metrics.csv"]
    got = json.loads((dest / "config.json").read_text())
    assert got["command"] == ("python -m training.run --out runs/paper/lift/skills/s0 "
                              "--config runs/paper/configs/x.json --seed 0")
    assert got["skill_dir"] == "skills" and got["seed"] == 0
    assert got["nested"]["paths"] == ["runs/paper/lift/skills/s0/a.npz"]
    assert str(tmp_path) not in (dest / "config.json").read_text()
    assert (dest / "metrics.csv").read_text() == (run / "metrics.csv").read_text()
    assert not (dest / "checkpoints").exists()
    assert portable_path("relative/x", "/r", "L") == "relative/x"


def test_archive_of_a_directory_without_metrics_is_one_line(tmp_path):
    r = subprocess.run([sys.executable, "-m", "training.archive", str(tmp_path), str(tmp_path / "d")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.startswith("error:") and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "d").exists()


def test_archive_with_the_new_skill_copies_it_and_its_portable_sidecar(tmp_path):
    run = tmp_path / "paper" / "s0"
    run.mkdir(parents=True)
    (run / "metrics.csv").write_text("env_steps\n1\n")
    (run / "new_skill.npz").write_bytes(b"\x00weights")
    (run / "new_skill.json").write_text(json.dumps({"command": f"python -m training.run --out {run}", "seed": 0}))
    written = archive_run(str(run), str(tmp_path / "a"), root=str(tmp_path / "paper"), new_skill=True)
    assert sorted(os.path.basename(w) for w in written) == ["metrics.csv", "new_skill.json", "new_skill.npz"]
    assert (tmp_path / "a" / "new_skill.npz").read_bytes() == b"\x00weights"
    assert json.loads((tmp_path / "a" / "new_skill.json").read_text())["command"] == \
        "python -m training.run --out runs/paper/s0"
    (run / "new_skill.npz").unlink()  # an unfinished run: refused in one line, nothing written
    r = subprocess.run([sys.executable, "-m", "training.archive", str(run), str(tmp_path / "b"), "--new_skill"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.startswith("error:") and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "b").exists()
