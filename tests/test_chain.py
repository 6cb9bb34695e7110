"""training.chain (issue 4): lift green -> stack end to end on tiny shapes, the new skill of one stage
joining the next stage's skills via ``--skill_dir``; rerunning continues (skips finished stages);
bad input. Also ``load_skills(skill_dir=...)`` on its own."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY = {"num_envs": 4, "unroll_length": 5, "replay_size": 200, "eval_episodes": 1,
        "scheduler": {"skill_lengths": [2, 3], "hidden": [16], "critic_head_hidden": [8], "batch_size": 8,
                      "min_replay_size": 10, "samples_per_insert": 2.0},
        "new_skill": {"hidden": [16], "batch_size": 8, "min_replay_size": 10, "samples_per_insert": 2.0}}


def _chain(argv, cwd):
    env = dict(os.environ, PYTHONPATH=ROOT, JAX_COMPILATION_CACHE_DIR=jax.config.jax_compilation_cache_dir)
    return subprocess.run([sys.executable, "-m", "training.chain", *argv], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=1200)


def test_chain_lift_then_stack_feeds_the_new_skill_forward_and_continues(tmp_path, capsys):
    with open(tmp_path / "tiny.json", "w") as f:
        json.dump(TINY, f)
    argv = ["--out", "chain", "--stages", "lift_green,stack", "--lift_timesteps", "40", "--stack_timesteps", "40",
            "--config", "tiny.json", "--eval_episodes", "2"]
    r = _chain(argv, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    record = json.load(open(tmp_path / "chain" / "chain.json"))
    assert list(record["stages"]) == ["lift_green", "stack"]
    for stage in record["stages"].values():  # training time summed over resumes, from the run's metrics.csv
        assert 0 < stage["training_wall_time_s"] and 0 < stage["wall_time_s"]
    # The lift stage's new skill is published with its sidecar and loads for the lift task's sizes.
    from parallel_skills import Skill
    import tasks

    env = tasks.make("stack")
    side = json.load(open(tmp_path / "chain" / "skills" / "lift_green.json"))
    assert side["chain_stage"] == "lift_green" and side["eval_episodes"] == 2
    assert side["command"].startswith("python -m training.chain") and "--skill_dir chain/skills" in side["stage_command"]
    assert 0.0 <= side["success"] <= 1.0
    skill = Skill.load(str(tmp_path / "chain" / "skills" / "lift_green.npz"), obs_size=env.observation_size,
                       action_size=env.action_size)
    assert skill.name == "lift_green"
    # ... and the stack stage trained with it, taken from the chain's skill directory.
    stack_run = json.load(open(tmp_path / "chain" / "stack" / "config.json"))
    assert "lift_green" in stack_run["skills"]
    assert os.path.samefile(stack_run["skill_dir"], tmp_path / "chain" / "skills")
    assert json.load(open(tmp_path / "chain" / "skills" / "stack.json"))["trained_with"] == stack_run["skills"]
    # Its export records where each skill came from, so that ':scheduler' evaluations run the same ones.
    sources = json.load(open(tmp_path / "chain" / "stack" / "export.json"))["metadata"]["skill_sources"]
    by_name = {e["name"]: e for e in sources}
    assert by_name["lift_green"]["source"] == "skill_dir" and by_name["reach_green"]["source"] == "scripted"
    assert os.path.samefile(by_name["lift_green"]["path"], tmp_path / "chain" / "skills" / "lift_green.npz")
    # Rerunning the same command continues the chain: nothing left to train.
    before = {p: os.path.getmtime(tmp_path / "chain" / "skills" / p) for p in ("lift_green.npz", "stack.npz")}
    r2 = _chain(argv, tmp_path)
    assert r2.returncode == 0, r2.stderr[-2000:]
    assert r2.stdout.count("skipped") == 2
    assert before == {p: os.path.getmtime(tmp_path / "chain" / "skills" / p) for p in before}
    # Another command on the same directory is refused, one line, exit 2.
    err = _refused(argv[:-2] + ["--eval_episodes", "3"], tmp_path, capsys)
    assert err[0].startswith("error:") and len(err) == 1
    _check_raised_budgets(tmp_path, argv, capsys)
    _check_ship(tmp_path, capsys)


def _refused(argv, cwd, capsys) -> list:
    """``training.chain``'s refusal of ``argv`` in ``cwd`` (in this process: a refusal trains nothing):
    exit code 2; the lines it printed to stderr."""
    from training.chain import main

    capsys.readouterr()
    here = os.getcwd()
    os.chdir(cwd)
    try:
        with pytest.raises(SystemExit) as e:
            main(argv)
    finally:
        os.chdir(here)
    assert e.value.code == 2, argv
    return capsys.readouterr().err.strip().splitlines()


def _check_raised_budgets(tmp_path, argv, capsys):
    """A rerun may raise a stage's budget: that stage is extended (its shorter run's outputs kept)
    and published again; lowering a budget, or extending a stage whose skill a later stage trained
    with, is refused in one line."""
    chain = tmp_path / "chain"
    for extra, needle in [(["--timesteps", "lift_green=80"], "stage stack was trained with the skill of lift_green"),
                          (["--stack_timesteps", "20"], "can be raised, not lowered"),
                          (["--timesteps", "reach_blue=80"], "--timesteps names reach_blue, not a stage"),
                          (["--timesteps", "stack=8x"], "is not STAGE=N")]:
        lines = _refused(argv + extra, tmp_path, capsys)
        assert len(lines) == 1 and needle in lines[0], (extra, lines)
    before = json.load(open(chain / "chain.json"))
    r = _chain(argv + ["--timesteps", "stack=80"], tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "[chain] lift_green: done" in r.stdout and "--resume --out chain/stack --num_timesteps 80" in r.stdout
    record = json.load(open(chain / "chain.json"))
    assert record["stages"]["lift_green"] == before["stages"]["lift_green"]
    assert record["stages"]["stack"]["num_timesteps"] == 80 and record["commands"][-1] == record["command"]
    assert record["command"].endswith("--timesteps stack=80") and len(record["commands"]) == 2
    assert json.load(open(chain / "stack" / "export.json"))["env_steps"] == 80
    assert json.load(open(chain / "stack" / "before_extension_40" / "export.json"))["env_steps"] == 40
    assert json.load(open(chain / "skills" / "stack.json"))["command"] == record["command"]


def _check_ship(tmp_path, capsys):
    """training.ship: a finished stage's skill goes into a library byte for byte, with the library
    sidecar; below the bar, unfinished stages and existing files are refused in one line."""
    from training.export import file_sha256
    from training.ship import main

    lib = tmp_path / "lib"
    base = ["--chain", "chain", "--root", str(lib), "--episodes", "2"]
    r = subprocess.run([sys.executable, "-m", "training.ship", *base, "--stage", "lift_green"], cwd=tmp_path,
                       env=dict(os.environ, PYTHONPATH=ROOT), capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and "below the kinematic library's bar 0.8; not shipped" in r.stderr  # tiny skill
    assert len(r.stderr.strip().splitlines()) == 1 and not lib.exists()
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        main(base + ["--stage", "lift_green", "--min_success", "0"])
        main(base + ["--stage", "stack", "--min_success", "0"])  # the library's name: stack_green_on_yellow
        # A ship killed between its two renames (the .npz in place, no sidecar) is finished by a rerun.
        os.remove(lib / "kinematic" / "stack_green_on_yellow.json")
        main(base + ["--stage", "stack", "--min_success", "0"])
        assert "shipped stack as stack_green_on_yellow" in capsys.readouterr().out
        main(base + ["--stage", "stack", "--min_success", "0", "--as_seed", "2"])  # the chain's seed 0 as .s2
        assert "shipped stack as stack_green_on_yellow.s2:" in capsys.readouterr().out
        side_s2 = json.load(open(lib / "kinematic" / "stack_green_on_yellow.s2.json"))
        assert side_s2["seed"] == 0 and side_s2["library_seed"] == 2
        for argv, needle in [(base + ["--stage", "lift_green", "--min_success", "0"], "already exists"),
                             (base + ["--stage", "lift_blue"], "has not finished in chain; finished stages: "
                                                               "lift_green, stack"),
                             (base + ["--stage", "lift_yellow", "--min_success", "2"], "--min_success must be in")]:
            with pytest.raises(SystemExit) as e:
                main(argv)
            err = capsys.readouterr().err.strip().splitlines()
            assert e.value.code == 2 and len(err) == 1 and needle in err[0], (argv, err)
    finally:
        os.chdir(cwd)
    shipped = lib / "kinematic" / "lift_green.npz"
    assert file_sha256(str(shipped)) == file_sha256(str(tmp_path / "chain" / "skills" / "lift_green.npz"))
    side = json.load(open(lib / "kinematic" / "lift_green.json"))
    assert side["trained_with"] == "skills" and side["sha256"] == file_sha256(str(shipped))
    assert side["command"] == json.load(open(tmp_path / "chain" / "chain.json"))["command"]
    assert side["training"]["chain_stage"] == "lift_green" and side["success_episodes"] == 2
    assert side["eval_command"] == (f"python -m training.evaluate --task lift_green --physics kinematic --policy "
                                    f"{shipped} --episodes 2 --seed 0")
    assert side["wall_time_s"] > 0 and side["min_std"] == 0.05
    stack = json.load(open(lib / "kinematic" / "stack_green_on_yellow.json"))
    assert stack["name"] == stack["task"] == "stack_green_on_yellow" and stack["training"]["chain_stage"] == "stack"
    assert "--task stack_green_on_yellow " in stack["eval_command"] and not (lib / "kinematic" / "stack.npz").exists()


@pytest.mark.parametrize("argv, message", [
    (["--out", "c", "--stages", "lift_green,fly"], "unknown task 'fly'"),
    (["--out", "c", "--stages", "reach_green"], "has no skill table"),
    (["--out", "c", "--stages", "lift_green,lift_green"], "repeats a task"),
    (["--out", "c", "--physics", "bullet"], "unknown physics"),
    (["--out", "c", "--config", "missing.json"], "does not exist"),
    (["--out", "c", "--start_states", "tower"], "start_states must be one of table, mixed"),
    (["--out", "c", "--physics", "mujoco", "--start_states", "mixed"], "kinematic physics only"),
])
def test_chain_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, argv, message):
    err = _refused(argv, tmp_path, capsys)
    assert len(err) == 1 and err[0].startswith("error:") and message in err[0]
    assert os.listdir(tmp_path) == []


def test_load_skills_prefers_the_skill_dir(tmp_path):
    from parallel_skills import Skill
    from parallel_skills.networks import GaussianPolicy
    from training import skill_library

    obs, act = 60, 5
    net = GaussianPolicy(action_size=act, hidden=(8,))
    params = {"policy": net.init(jax.random.PRNGKey(0), np.zeros((1, obs), np.float32)),
              "obs_mean": np.zeros(obs, np.float32), "obs_std": np.ones(obs, np.float32)}
    Skill.gaussian_mlp("mine", params, act, (8,)).save(str(tmp_path / "reach_green.npz"), obs_size=obs)
    skills = skill_library.load_skills(["reach_green", "lift_arm_closed"], "kinematic", "scripted", obs, act,
                                    skill_dir=str(tmp_path))
    assert [s.name for s in skills] == ["reach_green", "lift_arm_closed"]
    assert skills[0].metadata["source"] == "skill_dir" and skills[1].metadata["source"] == "scripted"
    with pytest.raises(ValueError, match="obs"):  # sizes are checked against the task
        skill_library.load_skills(["reach_green"], "kinematic", "scripted", obs + 1, act, skill_dir=str(tmp_path))
    with pytest.raises(ValueError, match="does not exist"):
        skill_library.load_skills(["reach_green"], "kinematic", "scripted", obs, act, skill_dir=str(tmp_path / "nope"))


def test_total_training_wall_time_reads_runs_recorded_without_it(tmp_path):
    """Stages recorded before ``training_wall_time_s`` existed: their run's metrics.csv has the time
    summed over resumes (the record's ``wall_time_s`` is only the last call's)."""
    from training.chain import total_training_wall_time

    old = tmp_path / "lift_green"
    old.mkdir()
    (old / "metrics.csv").write_text("env_steps,wall_time\n100,50.5\n200,3688.25\n")
    record = {"stages": {
        "lift_green": {"run_dir": str(old), "wall_time_s": 3601.4},
        "lift_yellow": {"run_dir": str(tmp_path / "gone"), "wall_time_s": 2592.8, "training_wall_time_s": 2593.0},
        "stack": {"run_dir": str(tmp_path / "gone"), "wall_time_s": 10.0}}}
    assert total_training_wall_time(record) == pytest.approx(3688.2 + 2593.0 + 10.0)


def test_stage_argv_passes_start_states_on():
    """--start_states reaches every new stage's training.run (a resume reads it from the record)."""
    from training.chain import build_parser, stage_argv

    args = build_parser().parse_args(["--out", "c", "--start_states", "mixed"])
    argv = stage_argv("stack_green_on_yellow", args, "c/skills", "c/stack_green_on_yellow", resume=False)
    assert argv[argv.index("--start_states") + 1] == "mixed"
    assert "--start_states" not in stage_argv("lift_green", build_parser().parse_args(["--out", "c"]), "s", "r", False)
    assert "--start_states" not in stage_argv("lift_green", args, "s", "r", resume=True)


def test_publish_best_selects_on_its_own_seed_and_keeps_the_last_on_ties(tmp_path, monkeypatch):
    """``--publish best``: the final or the best evaluated new skill, by their success on the
    selection seed's episodes (ties and a missing best file: the final one)."""
    import training.evaluate
    from training.chain import SELECTION_SEED, build_parser, select_skill

    run = tmp_path / "run"
    run.mkdir()
    (run / "new_skill.npz").write_bytes(b"")
    args = build_parser().parse_args(["--out", "c", "--publish", "best", "--eval_episodes", "4"])
    path, sel = select_skill("stack", args, str(run))
    assert path == str(run / "new_skill.npz") and sel["published"] == "last" and "missing" in sel["why"]
    (run / "best_new_skill.npz").write_bytes(b"")
    (run / "best_new_skill.json").write_text(json.dumps({"success": 0.9, "env_steps": 1200}))
    seen = []

    def fake(scores):
        def evaluate_policy(task, physics, path, episodes, seed, start_states="table"):
            seen.append((os.path.basename(path), episodes, seed))
            return {"success": np.asarray(scores[os.path.basename(path)])}
        return evaluate_policy

    monkeypatch.setattr(training.evaluate, "evaluate_policy", fake({"new_skill.npz": [1, 0, 0, 1],
                                                                    "best_new_skill.npz": [1, 1, 0, 1]}))
    path, sel = select_skill("stack", args, str(run))
    assert path == str(run / "best_new_skill.npz") and sel["published"] == "best"
    assert (sel["success_last"], sel["success_best"], sel["best_env_steps"]) == (0.5, 0.75, 1200)
    assert {s for _, _, s in seen} == {SELECTION_SEED} and {e for _, e, _ in seen} == {4}
    monkeypatch.setattr(training.evaluate, "evaluate_policy", fake({"new_skill.npz": [1, 0], "best_new_skill.npz": [0, 1]}))
    path, sel = select_skill("stack", args, str(run))
    assert path == str(run / "new_skill.npz") and sel["published"] == "last"
