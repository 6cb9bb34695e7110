"""Archive a ``training.run`` directory for the repository: what a reader needs to recompute its
results, without checkpoints and without machine paths.

    python -m training.archive RUN_DIR DEST_DIR [--root ROOT --label runs/paper]

Copies ``metrics.csv``, ``config.json`` and, when the run exported, ``export.json`` into
``DEST_DIR`` (created; files there are replaced); with ``--new_skill`` also the final new skill
(``new_skill.npz`` and its sidecar ``new_skill.json``, ≈ 0.3 MB: what a later evaluation of the run's
result needs, e.g. ``training.experiments.schedules --new_skill``). In ``config.json`` (and the
sidecars) every absolute path (the recorded command's ``--out`` / ``--config`` values,
``skill_dir``) is rewritten: a path under ``ROOT`` becomes ``LABEL/<its path below ROOT>``, any
other one its file name. ``ROOT`` defaults to
the run directory itself (``LABEL`` then stands for it). The paper runner archives with its
``--out`` as ROOT and ``runs/paper`` as LABEL (``training.experiments.paper --archive``).
"""

from __future__ import annotations

import json
import os
import shutil
import sys

from training.cli import Parser, UsageError, main_guard, write_json_atomic

FILES = ("metrics.csv", "config.json", "export.json")
NEW_SKILL_FILES = ("new_skill.npz", "new_skill.json")


def portable_path(path: str, root: str, label: str) -> str:
    """``path`` without this machine in it: ``label/<relative>`` under ``root``, else its name."""
    if not os.path.isabs(path):
        return path
    rel = os.path.relpath(os.path.abspath(path), os.path.abspath(root))
    if rel == ".":
        return label
    if not rel.startswith(".."):
        return f"{label}/{rel}"
    return os.path.basename(path.rstrip("/"))


def portable_record(record, root: str, label: str):
    """A JSON value with every absolute path in it (whole strings, or tokens of a command line)
    made portable (``portable_path``)."""
    if isinstance(record, dict):
        return {k: portable_record(v, root, label) for k, v in record.items()}
    if isinstance(record, list):
        return [portable_record(v, root, label) for v in record]
    if isinstance(record, str) and "/" in record:
        if " " in record:  # a command line
            return " ".join(portable_path(t, root, label) for t in record.split(" "))
        return portable_path(record, root, label)
    return record


def archive_run(run_dir: str, dest: str, root: str | None = None, label: str = "runs/paper",
                new_skill: bool = False) -> list[str]:
    """Copy the run's metrics / config / export record (and with ``new_skill`` its final new skill)
    into ``dest`` (the JSON files with portable paths). Returns the files written. UsageError when
    ``run_dir`` has no metrics.csv, or with ``new_skill`` no new_skill.npz."""
    if not os.path.isfile(os.path.join(run_dir, "metrics.csv")):
        raise UsageError(f"{run_dir} is not a training.run directory with metrics (no metrics.csv)")
    if new_skill and not os.path.isfile(os.path.join(run_dir, "new_skill.npz")):
        raise UsageError(f"{run_dir} has no new_skill.npz (the run did not finish): archive it without --new_skill")
    root = run_dir if root is None else root
    os.makedirs(dest, exist_ok=True)
    written = []
    for name in FILES + (NEW_SKILL_FILES if new_skill else ()):
        src = os.path.join(run_dir, name)
        if not os.path.isfile(src):
            continue
        out = os.path.join(dest, name)
        if name.endswith(".json"):
            with open(src) as f:
                write_json_atomic(out, portable_record(json.load(f), root, label), indent=1)
        else:
            shutil.copyfile(src, out)
        written.append(out)
    return written


def main(argv=None):
    p = Parser(prog="python -m training.archive", description=__doc__.splitlines()[0])
    p.add_argument("run_dir")
    p.add_argument("dest")
    p.add_argument("--root", default=None, help="paths under it are written LABEL/...; default the run directory")
    p.add_argument("--label", default="runs/paper")
    p.add_argument("--new_skill", action="store_true", help="also new_skill.npz and new_skill.json")
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    for path in main_guard(lambda: archive_run(args.run_dir, args.dest, args.root, args.label, args.new_skill)):
        print(f"written: {path}")


if __name__ == "__main__":
    main()
