"""training.run on bad input: one line on stderr naming what is wrong and what is allowed, exit
code 2, no traceback, no file written or clobbered (issue 5, item 6). In-process (``main(argv)``),
plus a few subprocess runs for the real stderr."""

from __future__ import annotations

import dataclasses
import gc
import hashlib
import json
import os
import subprocess
import sys

import pytest

from training.run import main
from cli_checks import one_line_error

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY = {"num_envs": 4, "unroll_length": 5, "replay_size": 200, "eval_episodes": 2,
        "scheduler": {"skill_lengths": [2, 3], "hidden": [16], "critic_head_hidden": [8], "batch_size": 8,
                      "min_replay_size": 10, "samples_per_insert": 2.0},
        "new_skill": {"hidden": [16], "batch_size": 8, "min_replay_size": 10, "samples_per_insert": 2.0}}


def _snapshot(root):
    out = {}
    for d, _, files in os.walk(root):
        out[d] = None
        for f in files:
            p = os.path.join(d, f)
            with open(p, "rb") as fh:
                out[p] = (os.stat(p).st_mtime_ns, hashlib.sha256(fh.read()).hexdigest())
    return out


def _fails(argv, capsys, *needles):
    """main(argv) exits with code 2 and one stderr line containing every needle."""
    return one_line_error(lambda: main(argv), capsys, *needles)


@pytest.fixture
def ws(tmp_path):
    """A workspace with a pre-existing run dir holding files, a config file and a plain file."""
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "metrics.csv").write_text("env_steps\n1\n")
    (existing / "config.json").write_text("{not json")
    (tmp_path / "tiny.json").write_text(json.dumps(TINY))
    (tmp_path / "plain_file").write_text("x")
    return tmp_path


def _new(ws):
    return str(ws / "new_run")


BAD_NUMBERS = [
    (["--num_envs", "-1"], "--num_envs", "positive integer"),
    (["--num_envs", "0"], "--num_envs", "positive integer"),
    (["--num_envs", "2.5"], "--num_envs", "positive integer"),
    (["--num_envs", "many"], "--num_envs", "positive integer"),
    (["--num_timesteps", "0"], "--num_timesteps", "positive integer"),
    (["--num_timesteps", "-100"], "--num_timesteps", "positive integer"),
    (["--num_timesteps", "1e9.5"], "--num_timesteps", "positive integer"),
    (["--seed", "-1"], "--seed", "non-negative integer"),
    (["--seed", "0.5"], "--seed", "non-negative integer"),
    (["--episode_length", "0"], "--episode_length", "positive integer"),
    (["--eval_every", "0"], "--eval_every", "positive integer"),
    (["--eval_episodes", "-3"], "--eval_episodes", "positive integer"),
    (["--checkpoint_every", "0"], "--checkpoint_every", "positive integer"),
    (["--checkpoint_every", "ten"], "--checkpoint_every", "positive integer"),
]


UNKNOWN_NAMES = [
    (["--task", "juggle"], "unknown task 'juggle'", "lift"),
    (["--physics", "bullet"], "unknown physics 'bullet'", "kinematic"),
    (["--skills", "everything"], "unknown skill set 'everything'", "useful+distractors"),
    (["--method", "magic"], "--method", "scratch"),
    (["--recipe", "fast"], "--recipe", "parallel"),
    (["--task", "reach_green"], "no skill table for task 'reach_green'", "lift"),  # a dense task has no skill set
    (["--finetune_from", "reach_green"], "--finetune_from is for --method finetune", "not skills"),
    (["--method", "finetune", "--skill_source", "scripted"], "starts from a network skill", "--skill_source library"),
    (["--method", "finetune", "--finetune_from", "fly"], "fly", "checkpoints"),
]


@pytest.mark.parametrize("args,what,allowed", BAD_NUMBERS + UNKNOWN_NAMES)
def test_bad_numbers_and_unknown_names(ws, capsys, args, what, allowed):
    before = _snapshot(ws)
    _fails(args + ["--out", _new(ws)], capsys, what, allowed)
    assert _snapshot(ws) == before


BAD_CONFIGS = [
    ("missing", None, "does not exist"),
    ("syntax", "{unroll_length: 5", "cannot read config file"),
    ("list", "[1, 2]", "must hold a JSON object"),
    ("unknown", {"unrol_length": 5}, "unknown config field 'unrol_length'"),
    ("unknown_nested", {"scheduler": {"bach_size": 5}}, "unknown scheduler config field"),
    ("nested_not_object", {"new_skill": 3}, "new_skill must be a JSON object"),
    ("zero", {"unroll_length": 0}, "unroll_length must be a positive integer"),
    ("negative_envs", {"num_envs": -2}, "num_envs must be a positive integer or null"),
    ("fraction", {"unroll_length": 2.5}, "unroll_length must be a positive integer"),
    ("string", {"scheduler": {"batch_size": "big"}}, "scheduler.batch_size must be a positive integer"),
    ("bool", {"scheduler": {"augmentation": "yes"}}, "scheduler.augmentation must be true or false"),
    ("nan_like", {"new_skill": {"learning_rate": "fast"}}, "new_skill.learning_rate must be a finite number"),
    ("lengths", {"scheduler": {"skill_lengths": [3, 2]}}, "skill_lengths must be positive, unique and ascending"),
    ("lengths_type", {"scheduler": {"skill_lengths": 3}}, "skill_lengths must be a non-empty list"),
    ("crr_mode", {"new_skill": {"crr_mode": "bogus"}}, "crr_mode must be 'exp' or 'indicator'"),
    ("method", {"method": "magic"}, "method must be one of skills, scratch, finetune, kl_reg, dagger, rhpo"),
    ("baseline", {"new_skill": {"baseline": "bc"}}, "baseline must be one of mpo, kl_reg, dagger"),
    ("rhpo_lengths", {"method": "rhpo", "scheduler": {"skill_lengths": [2, 3]}}, "skill_lengths must be [1]"),
    ("recipe", {"recipe": "fast"}, "recipe must be one of cpu, parallel, paper or null"),
]


@pytest.mark.parametrize("name,content,what", BAD_CONFIGS, ids=[c[0] for c in BAD_CONFIGS])
def test_bad_config_files(ws, capsys, name, content, what):
    path = ws / f"{name}.json"
    if content is not None:
        path.write_text(content if isinstance(content, str) else json.dumps(content))
    before = _snapshot(ws)
    _fails(["--config", str(path), "--out", _new(ws)], capsys, what, str(path))
    assert _snapshot(ws) == before


def test_config_file_is_a_directory(ws, capsys):
    before = _snapshot(ws)
    _fails(["--config", str(ws / "existing"), "--out", _new(ws)], capsys, "is a directory")
    assert _snapshot(ws) == before


def test_unwritable_output(ws, capsys):
    before = _snapshot(ws)
    _fails(["--out", str(ws / "plain_file" / "run")], capsys, "cannot create the run directory", "not a directory")
    assert _snapshot(ws) == before


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write into read-only directories")
def test_read_only_parent(ws, capsys):
    ro = ws / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        _fails(["--out", str(ro / "run")], capsys, "not writable")
        assert not (ro / "run").exists()
    finally:
        ro.chmod(0o755)


def test_existing_run_dir_is_never_written_into(ws, capsys):
    before = _snapshot(ws)
    _fails(["--out", str(ws / "existing")], capsys, "already exists", "--resume")
    _fails(["--out", str(ws / "plain_file")], capsys, "already exists")
    assert _snapshot(ws) == before


def test_resume_errors(ws, capsys):
    before = _snapshot(ws)
    _fails(["--resume"], capsys, "--resume needs --out")
    _fails(["--resume", "--out", str(ws / "nope")], capsys, "does not exist")
    _fails(["--resume", "--out", str(ws / "plain_file")], capsys, "not a directory")
    _fails(["--resume", "--out", str(ws / "existing")], capsys, "config.json", "invalid")
    empty = ws / "empty"
    empty.mkdir()
    _fails(["--resume", "--out", str(empty)], capsys, "no config.json")
    assert not (ws / "nope").exists()
    before[str(empty)] = None
    assert _snapshot(ws) == before


@pytest.fixture
def fresh_run(ws):
    """A run dir as training.run creates it, before its first checkpoint (config.json only)."""
    from training.run import build_parser, prepare_new

    out = ws / "run"
    argv = ["--config", str(ws / "tiny.json"), "--num_timesteps", "100", "--seed", "3", "--out", str(out)]
    prepare_new(build_parser().parse_args(argv), argv)
    return out


def test_config_file_fields_and_the_cpu_recipe(ws):
    """A config file that sets one learner field keeps the CPU recipe for the others (config.json)."""
    from training.run import build_parser, prepare_new

    (ws / "nstep.json").write_text(json.dumps({"unroll_length": 5, "new_skill": {"n_step": 2}}))
    out = ws / "nstep_run"
    argv = ["--config", str(ws / "nstep.json"), "--num_timesteps", "100", "--out", str(out)]
    prepare_new(build_parser().parse_args(argv), argv)
    with open(out / "config.json") as f:
        record = json.load(f)
    new_skill = record["train_config"]["new_skill"]
    assert new_skill["n_step"] == 2 and new_skill["samples_per_insert"] == 16.0 and new_skill["crr_mode"] == "exp"
    assert record["train_config"]["recipe"] == "cpu"
    # The learners' batches and updates per iteration are recorded: 32 envs x 5 steps = 160 per iteration.
    assert record["learners"]["env_steps_per_iteration"] == 160
    assert record["learners"]["new_skill"] == {"batch_size": 256, "updates_per_iteration": 10,
                                               "samples_per_env_step": 16.0}
    # And what same-seed numbers depend on besides the config: the CPU cores this process may run on.
    assert record["host"]["cpu_cores"] == len(os.sched_getaffinity(0)) and record["host"]["backend"] == "cpu"


def test_a_runs_config_json_as_config_file(ws):
    """``--config RUN/config.json``: the run's whole resolved TrainConfig, so a new run trains as that
    one did (here with the recipe's earlier indicator weights), whatever the recipe is now."""
    from training.run import build_parser, prepare_new

    first = ws / "recorded_run"
    argv = ["--new_skill.crr_mode", "indicator", "--scheduler.n_step", "3", "--num_timesteps", "100", "--out", str(first)]
    prepare_new(build_parser().parse_args(argv), argv)
    again = ws / "from_record"
    argv = ["--config", str(first / "config.json"), "--num_timesteps", "100", "--out", str(again)]
    prepare_new(build_parser().parse_args(argv), argv)
    recorded, rebuilt = (json.loads((d / "config.json").read_text())["train_config"] for d in (first, again))
    assert rebuilt == recorded and rebuilt["new_skill"]["crr_mode"] == "indicator"


def test_resume_without_checkpoint_and_conflicting_flags(ws, fresh_run, capsys):
    changed = ws / "changed.json"
    changed.write_text(json.dumps({"unroll_length": 7}))
    before = _snapshot(ws)
    out = ["--resume", "--out", str(fresh_run)]
    _fails(out, capsys, "holds no checkpoint")
    _fails(out + ["--seed", "4"], capsys, "--seed 4 conflicts with", "seed=3", "drop the flag")
    _fails(out + ["--num_timesteps", "50"], capsys, "--num_timesteps 50 is below the budget", "num_timesteps=100",
           "not shorten")
    _fails(out + ["--num_timesteps", "200"], capsys, "holds no checkpoint")  # (a larger budget extends)
    _fails(out + ["--task", "stack"], capsys, "--task stack conflicts", '"lift"')
    _fails(out + ["--method", "scratch"], capsys, "--method scratch conflicts")
    _fails(out + ["--recipe", "paper"], capsys, "--recipe paper conflicts", '"cpu"')
    _fails(out + ["--no-replay-checkpoint"], capsys, "--no-replay-checkpoint conflicts")
    # Generated flags too: nested fields (the recipe's value is the run's) and the RunConfig ones.
    _fails(out + ["--new_skill.n_step", "3"], capsys, "--new_skill.n_step 3 conflicts with", "new_skill.n_step=10")
    _fails(out + ["--scheduler.skill_lengths", "2,4"], capsys, "--scheduler.skill_lengths 2,4 conflicts",
           "scheduler.skill_lengths=[2, 3]")
    _fails(out + ["--checkpoint_every", "7"], capsys, "--checkpoint_every 7 conflicts", "checkpoint_every=null")
    _fails(out + ["--new_skill.n_step", "10", "--scheduler.skill_lengths", "2,3"], capsys, "holds no checkpoint")
    _fails(out + ["--config", str(changed)], capsys, "sets unroll_length=7", "has 5")
    _fails(out + ["--config", str(ws / "missing.json")], capsys, "does not exist")
    # Flags equal to the run's own config are not conflicts (the error is the missing checkpoint).
    _fails(out + ["--seed", "3", "--config", str(ws / "tiny.json")], capsys, "holds no checkpoint")
    assert _snapshot(ws) == before


def test_resume_of_complete_run_and_of_mismatched_checkpoint(ws, fresh_run, capsys):
    import jax
    import jax.numpy as jnp

    import tasks
    from parallel_skills import TrainConfig
    from training.checkpointing import Checkpointer, abstract_training_state
    from training.run import apply_config

    # A checkpoint of a differently sized network (hidden 8 instead of 16): cannot be restored.
    cfg = apply_config(TrainConfig(), dict(TINY, new_skill=dict(TINY["new_skill"], hidden=[8])), "test")
    abstract, _ = abstract_training_state(tasks.make("lift"), [], dataclasses.replace(cfg, method="scratch"), 0)
    zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), abstract)
    ckpt = Checkpointer(str(fresh_run))
    ckpt.save(zeros, {"iteration": 0, "csv_bytes": 0, "csv_rows": 0})
    ckpt.close()
    before = _snapshot(ws)
    _fails(["--resume", "--out", str(fresh_run)], capsys, "does not match this run's training state")
    assert _snapshot(ws) == before
    # orbax leaves the failed restore's read coroutines behind; they print to stderr when collected.
    gc.collect()
    capsys.readouterr()
    (fresh_run / "export.json").write_text("{}")
    _fails(["--resume", "--out", str(fresh_run)], capsys, "export.json is unreadable")
    (fresh_run / "export.json").write_text(json.dumps({"env_steps": 100, "metadata": {"num_timesteps": 100}}))
    _fails(["--resume", "--out", str(fresh_run)], capsys, "is complete", "--num_timesteps N, N > 100")
    _fails(["--resume", "--out", str(fresh_run), "--num_timesteps", "100"], capsys, "is complete")


@pytest.mark.parametrize("argv,needle", [
    (["--num_envs", "-4"], "argument --num_envs: expected a positive integer, got '-4'"),
    (["--task", "juggle"], "unknown task 'juggle'; valid tasks:"),
    (["--resume", "--out", "/nonexistent/run"], "cannot resume: run directory /nonexistent/run does not exist"),
    (["--skill_dir", "/nonexistent/skills"], "skill directory /nonexistent/skills does not exist"),
])
def test_real_stderr_of_a_subprocess(ws, argv, needle):
    env = dict(os.environ, PYTHONPATH=ROOT)
    r = subprocess.run([sys.executable, "-m", "training.run", *argv, *([] if "--out" in argv else ["--out", _new(ws)])],
                       capture_output=True, text=True, cwd=str(ws), env=env, timeout=120)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], r.stderr
    assert "Traceback" not in r.stderr and r.stdout == ""
    assert not os.path.exists(_new(ws))
