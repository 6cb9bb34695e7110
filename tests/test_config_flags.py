"""training.run's flags generated from the config dataclasses (training.config_flags): one per
dotted field, help from the field's comment, values checked by the dataclasses alone, the same
config as the JSON overrides, and the recipe filling only what no flag sets."""

from __future__ import annotations

import ast
import dataclasses
import json
import os

import pytest

from cli_checks import one_line_error
from parallel_skills.config import NewSkillConfig, RunConfig, SchedulerConfig, TrainConfig
from training import config_flags
from training.run import BASE_CONFIG, build_parser, main, prepare_new

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _record(tmp_path, argv):
    """The config.json record training.run would write for ``argv`` (nothing is written)."""
    argv = argv + ["--out", str(tmp_path / "run")]
    _, run, resolved, _ = prepare_new(build_parser().parse_args(argv), argv, write=False)
    return run, resolved


def test_every_config_field_is_a_flag():
    flags = set(vars(build_parser().parse_args([])))
    names = config_flags.flag_names(TrainConfig) + config_flags.flag_names(RunConfig)
    assert "scheduler.n_step" in names and "new_skill.samples_per_insert" in names and "num_envs" in names
    assert set(names) <= flags
    count = lambda cls: len(dataclasses.fields(cls))  # noqa: E731
    assert len(names) == count(TrainConfig) - 2 + count(SchedulerConfig) + count(NewSkillConfig) + count(RunConfig)


def test_run_writes_out_only_the_flags_that_are_no_config_field():
    """training/run.py's own add_argument calls name no config field (those are generated)."""
    with open(os.path.join(ROOT, "training", "run.py")) as f:
        tree = ast.parse(f.read())
    written = [call.args[0].value for call in ast.walk(tree) if isinstance(call, ast.Call)
               and getattr(call.func, "attr", None) == "add_argument"]
    fields = set(config_flags.flag_names(TrainConfig) + config_flags.flag_names(RunConfig))
    assert written and not {w.lstrip("-") for w in written} & fields, written


def test_help_is_the_field_comment():
    comments = config_flags.field_comments(SchedulerConfig)
    assert comments["n_step"].startswith("n-step targets for the critic within skill executions")
    assert comments["epsilon"] == "E-step KL bound (temperature dual)."  # (a comment at the line's end)
    assert "init_log_alpha" not in comments  # (no comment of its own)
    text = build_parser().format_help()
    assert "--new_skill.samples_per_insert" in text and "clipped double Q" in text


def test_flags_set_nested_fields_and_the_recipe_fills_the_rest(tmp_path):
    run, cfg = _record(tmp_path, ["--scheduler.n_step", "10", "--new_skill.samples_per_insert", "32",
                                  "--num_envs", "64", "--seed", "3", "--scheduler.skill_lengths", "5,10",
                                  "--scheduler.augmentation", "false"])
    assert cfg.scheduler.n_step == 10 and cfg.new_skill.samples_per_insert == 32.0 and cfg.num_envs == 64
    assert cfg.scheduler.skill_lengths == (5, 10) and cfg.scheduler.augmentation is False
    assert isinstance(cfg.new_skill.samples_per_insert, float)
    assert cfg.new_skill.n_step == 10 and cfg.new_skill.crr_mode == "exp"  # the CPU recipe's, not given
    assert cfg.scheduler.samples_per_insert == 8.0
    assert run.seed == 3 and run.train_config["new_skill"]["samples_per_insert"] == 32.0
    assert any("samples_per_insert=8" in n for n in run.auto) and not any("=32" in n for n in run.auto)


def test_a_flag_and_a_config_file_make_the_same_config_and_the_flag_wins(tmp_path):
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"unroll_length": 5, "new_skill": {"n_step": 3, "learning_rate": 1e-3}}))
    _, from_file = _record(tmp_path, ["--config", str(path)])
    _, from_flags = _record(tmp_path, ["--unroll_length", "5", "--new_skill.n_step", "3",
                                       "--new_skill.learning_rate", "1e-3"])
    assert from_file == from_flags
    _, both = _record(tmp_path, ["--config", str(path), "--new_skill.n_step", "4"])
    assert both.new_skill.n_step == 4 and both.new_skill.learning_rate == 1e-3 and both.unroll_length == 5


def test_defaults_are_the_runs():
    args = build_parser().parse_args([])
    assert config_flags.given(args, config_flags.flag_names(TrainConfig)) == {}  # nothing given
    assert BASE_CONFIG.eval_episodes == 32 and RunConfig().seed == 0


def test_start_states_is_recorded_and_rebuilds_the_runs_env(tmp_path):
    """--start_states mixed: in config.json, and the env a resume or a read-out builds from the
    record has it; "table" (the default, and records from before the field) adds no override."""
    from training.rundir import RunRecord

    run, _ = _record(tmp_path, ["--task", "stack", "--start_states", "mixed"])
    assert run.start_states == "mixed" and run.to_json()["start_states"] == "mixed"
    assert RunRecord.from_json(run.to_json()).env_overrides() == {"episode_length": 600, "start_states": "mixed"}
    old = {k: v for k, v in run.to_json().items() if k != "start_states"}
    assert RunRecord.from_json(old).start_states == "table"
    assert RunRecord.from_json(old).env_overrides() == {"episode_length": 600}


@pytest.mark.parametrize("argv,needle", [
    (["--start_states", "tower"], "start_states must be one of table, mixed, or TOP_on_BOTTOM"),
    (["--physics", "mujoco", "--start_states", "mixed"], "kinematic physics only"),
    (["--scheduler.n_step", "0"], "argument --scheduler.n_step: expected a positive integer, got '0'"),
    (["--new_skill.crr_mode", "bogus"], "argument --new_skill.crr_mode: expected 'exp' or 'indicator', got 'bogus'"),
    (["--scheduler.skill_lengths", "3,2"], "expected positive, unique and ascending integers, got '3,2'"),
    (["--scheduler.skill_lengths", "a,b"], "expected a non-empty list of positive integers"),
    (["--scheduler.augmentation", "yes"], "argument --scheduler.augmentation: expected true or false"),
    (["--new_skill.mpo_alpha", "1.5"], "argument --new_skill.mpo_alpha: expected a number in [0, 1], got '1.5'"),
    (["--skill_noise_std", "inf"], "argument --skill_noise_std: expected a finite number"),
    (["--new_skill.baseline", "dagger"], "new_skill.baseline 'dagger' reads the skills' actions: it needs method"),
    (["--method", "rhpo", "--scheduler.skill_lengths", "2,3"], "skill_lengths must be [1]"),
])
def test_bad_generated_flags_are_one_line(tmp_path, capsys, argv, needle):
    one_line_error(lambda: main(argv + ["--out", str(tmp_path / "run")]), capsys, needle)
    assert not (tmp_path / "run").exists()


def test_a_rule_relating_fields_is_judged_on_the_whole_config(tmp_path):
    """initial_max_length_prob 1 is allowed with one skill length: not refused flag by flag."""
    _, cfg = _record(tmp_path, ["--scheduler.skill_lengths", "5", "--scheduler.initial_max_length_prob", "1.0"])
    assert cfg.scheduler.skill_lengths == (5,) and cfg.scheduler.initial_max_length_prob == 1.0
