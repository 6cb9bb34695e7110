"""training/experiments/schedules.py: the schedule grammar, one-line errors (exit code 2), and a few
hand-computable rollouts on kinematic lift (4 envs, short episodes) with the JSON file they write."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from training.cli import UsageError, main_guard
from training.experiments import schedules as S
from training.rundir import new_skill_min_std
from cli_checks import one_line_error

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _fails(argv, capsys, *needles):
    """The command on ``argv`` exits with code 2 and one stderr line starting ``error:``."""
    return one_line_error(lambda: main_guard(lambda: S.main(argv)), capsys, *needles)


def test_parse_schedule():
    s = S.parse_schedule("stack_yellow_on_blue:150,stack_green_on_yellow")
    assert s.steps == (S.Step("stack_yellow_on_blue", 150), S.Step("stack_green_on_yellow")) and not s.is_random
    s = S.parse_schedule("reach_green:until+20,lift_green:until,lift_arm_open")
    assert s.steps == (S.Step("reach_green", "until", 20), S.Step("lift_green", "until"), S.Step("lift_arm_open"))
    assert S.parse_schedule("lift_green").steps == (S.Step("lift_green"),)
    assert S.parse_schedule("random").lengths == tuple(range(10, 101, 10))
    assert S.parse_schedule("random:20-40").lengths == (20, 30, 40)
    assert S.parse_schedule("random:7-7").lengths == (7,)
    for bad in ("reach_green,lift_arm_closed", "reach_green:60,lift_arm_closed:10", "reach_green:0,x",
                "reach_green:-3,x", "reach_green:until+,x", "reach_green:soon,x", ":10,x", "a:10,,b",
                "random:5-100", "random:100-10", "random:0-10", "random:abc", "random:10", "a:10,random"):
        with pytest.raises(UsageError, match="bad schedule .*valid forms: NAME:K"):
            S.parse_schedule(bad)


def test_success_tests():
    assert S.success_test("reach_green.s1") is S.success_test("reach_green")  # a library seed: its base's
    with pytest.raises(UsageError, match="no success test of its own"):
        S.success_test("wave_hello")


def test_bad_input_is_one_line(capsys, tmp_path):
    _fails(["reach_green,lift_arm_closed"], capsys, "needs a hold", "valid forms")
    _fails(["random:5-100"], capsys, "multiple of 10")
    _fails(["reach_purple:10,lift_arm_closed"], capsys, "no scripted controller 'reach_purple'")
    _fails(["--task", "nope", "lift_green"], capsys, "unknown manipulation task 'nope'", "triple_stack")
    _fails(["--task", "reach_green", "random"], capsys, "no skill table", "triple_stack")
    _fails(["--physics", "bullet", "lift_green"], capsys, "unknown physics 'bullet'")
    _fails(["--skill_source", "library", "--task", "stack", "stack_green_on_blue"], capsys,
           "not in the kinematic skill library")
    _fails(["--seeds", "0,a", "lift_green"], capsys, "--seeds")
    _fails(["--noise", "-1", "lift_green"], capsys, "--noise")
    _fails(["--episodes", "0", "lift_green"], capsys, "--episodes")
    _fails(["lift_green", "lift_green"], capsys, "twice")
    _fails(["--start_states", "tower", "lift_green"], capsys, "start_states must be one of table, mixed")
    _fails(["--physics", "mujoco", "--start_states", "mixed", "lift_green"], capsys, "kinematic physics only")
    _fails(["--skill_dir", str(tmp_path / "none"), "lift_green"], capsys, "does not exist")
    (tmp_path / "plain").write_text("x")
    _fails(["--json", str(tmp_path / "plain" / "out.json"), "lift_green"], capsys, "not a directory")


def test_command_line_error_exit_code():
    r = subprocess.run([sys.executable, "-m", "training.experiments.schedules", "reach_green:until+x,lift_green"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.startswith("error: bad schedule") and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_lift_schedules_and_json(tmp_path, capsys):
    """Lift green, 4 envs, 200 steps, seeds 0 and 1. Open fingers' test holds at the start (the
    fingers start open), so ``open_fingers:until`` hands over at once (never reached); then reach
    green for 60 steps and lift the arm closed: green lifted in most episodes. ``random:200-200``
    runs one skill of lift's useful set for the whole episode, and neither alone lifts green
    (reach green never closes; the arm closes high above the cubes): success and return 0."""
    out = tmp_path / "sub" / "schedules.json"
    S.main(["--task", "lift", "--episodes", "4", "--seeds", "0,1", "--steps", "200", "--json", str(out),
            "open_fingers:until,reach_green:60,lift_arm_closed", "random:200-200"])
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 + 2 * 3, lines  # header, then 2 seeds + a summary per schedule
    rec = json.loads(out.read_text())
    assert rec["task"] == "lift" and rec["steps"] == 200 and rec["seeds"] == [0, 1] and rec["noise"] == 0.0
    seq = rec["results"]["open_fingers:until,reach_green:60,lift_arm_closed"]
    assert seq["skills"] == ["open_fingers", "reach_green", "lift_arm_closed"]
    assert seq["success_mean"] >= 0.75 and seq["return_mean"] > 0
    for r in seq["per_seed"]:
        assert r["reached"] == [0.0, 1.0, 1.0] and r["start_step"] == [None, 0.0, 60.0], r
    rnd = rec["results"]["random:200-200"]
    assert rnd["skills"] == ["reach_green", "lift_arm_closed"]
    assert rnd["success_mean"] == 0.0 and rnd["return_mean"] == 0.0 and "reached" not in rnd["per_seed"][0]


def test_probes_report_where_a_schedule_gets_to(tmp_path, capsys):
    """``--probes``: reach green holds once the 60 reaching steps are done, so its probe is 1 in
    every episode; lift green's probe is the task's own success (lift's sparse test)."""
    out = tmp_path / "p.json"
    S.main(["--task", "lift", "--episodes", "4", "--seeds", "0", "--steps", "200", "--json", str(out),
            "--probes", "reach_green,lift_green", "reach_green:60,lift_arm_closed"])
    rec = json.loads(out.read_text())["results"]["reach_green:60,lift_arm_closed"]
    probes = rec["per_seed"][0]["probes"]
    assert list(probes) == ["reach_green", "lift_green"] and probes["reach_green"] == 1.0
    assert probes["lift_green"] == rec["per_seed"][0]["success"] and rec["probes_mean"] == probes
    assert "probes reach_green 1.00" in capsys.readouterr().out


def test_a_trained_new_skill_runs_as_step_new(tmp_path, capsys):
    """``--new_skill`` (a saved Gaussian-MLP skill, here untrained) is the step ``new``; without it,
    or with it but no schedule running it, one line."""
    import jax
    import jax.numpy as jnp

    import tasks
    from parallel_skills import networks
    from parallel_skills.skills import Skill

    env = tasks.make("lift")
    net = networks.GaussianPolicy(action_size=env.action_size, hidden=(8,))
    params = {"policy": net.init(jax.random.PRNGKey(0), jnp.zeros((1, env.observation_size))),
              "obs_mean": jnp.zeros((env.observation_size,)), "obs_std": jnp.ones((env.observation_size,))}
    Skill.gaussian_mlp("lift_new_skill", params, env.action_size, (8,)).save(str(tmp_path / "new_skill.npz"))
    out = tmp_path / "n.json"
    S.main(["--task", "lift", "--episodes", "2", "--seeds", "0", "--steps", "20", "--new_skill", str(tmp_path),
            "--json", str(out), "reach_green:10,new"])
    rec = json.loads(out.read_text())["results"]["reach_green:10,new"]
    assert rec["skills"] == ["reach_green", "new"] and rec["per_seed"][0]["reached"] == [1.0, 1.0]
    capsys.readouterr()
    _fails(["--task", "lift", "new"], capsys, "--new_skill is not given")
    _fails(["--task", "lift", "--new_skill", str(tmp_path), "lift_green"], capsys, "no schedule runs it")
    _fails(["--task", "lift", "--new_skill", str(tmp_path / "nope.npz"), "new"], capsys, "--new_skill")
    _fails(["--task", "lift", "--probes", "wave_hello", "lift_green"], capsys, "no success test of its own")


def test_new_skill_sampled_actions_draw_from_its_gaussian(tmp_path):
    """``--new_skill_actions sampled``: the new skill acts with clip(mean + std·ε), its std floor
    the run's ``new_skill.min_std`` (config.json beside the file, else the default); ``mean``
    ignores the key."""
    import jax
    import jax.numpy as jnp

    import tasks
    from parallel_skills import networks
    from parallel_skills.config import NewSkillConfig
    from parallel_skills.skills import Skill

    env = tasks.make("lift")
    net = networks.GaussianPolicy(action_size=env.action_size, hidden=(8,), min_std=0.2)
    params = {"policy": net.init(jax.random.PRNGKey(0), jnp.zeros((1, env.observation_size))),
              "obs_mean": jnp.zeros((env.observation_size,)), "obs_std": jnp.ones((env.observation_size,))}
    Skill.gaussian_mlp("lift_new_skill", params, env.action_size, (8,)).save(str(tmp_path / "new_skill.npz"))
    assert new_skill_min_std(str(tmp_path)) == NewSkillConfig.min_std  # no config.json: the default
    (tmp_path / "config.json").write_text(json.dumps({"train_config": {"new_skill": {"min_std": 0.2}}}))
    assert new_skill_min_std(str(tmp_path)) == 0.2
    obs = jax.random.normal(jax.random.PRNGKey(1), (env.observation_size,))
    k1, k2 = jax.random.PRNGKey(2), jax.random.PRNGKey(3)
    mean_skill = S.load_new_skill(str(tmp_path), env, "mean")
    sampled = S.load_new_skill(str(tmp_path), env, "sampled")
    assert np.array_equal(mean_skill.apply(mean_skill.params, obs, k1), mean_skill.apply(mean_skill.params, obs, k2))
    mean, std = net.apply(params["policy"], jnp.clip(obs, -10.0, 10.0))
    np.testing.assert_allclose(sampled.apply(sampled.params, obs, k1), networks.sample_action(mean, std, k1), atol=1e-6)
    assert not np.allclose(sampled.apply(sampled.params, obs, k1), sampled.apply(sampled.params, obs, k2))
    # --new_skill_std_scale: the same Gaussian with its std scaled (0: the mean action).
    tenth = S.load_new_skill(str(tmp_path), env, "sampled", std_scale=0.1)
    np.testing.assert_allclose(tenth.apply(tenth.params, obs, k1), networks.sample_action(mean, 0.1 * std, k1),
                               atol=1e-6)
    zero = S.load_new_skill(str(tmp_path), env, "sampled", std_scale=0.0)
    np.testing.assert_allclose(zero.apply(zero.params, obs, k1), jnp.clip(mean, -1.0, 1.0), atol=1e-6)
    # Beside a skill of the same network acting with its mean (a library skill), the sampled one
    # still samples: SkillSet stacks only skills of equal arch, which the two no longer share.
    from parallel_skills.skills import SkillSet

    both = SkillSet([mean_skill, sampled])
    assert both.vmapped_groups == []
    acts = both.frozen_actions(jnp.stack([obs, obs]), k1)
    assert np.allclose(acts[0, 0], jnp.clip(mean, -1.0, 1.0), atol=1e-6) and not np.allclose(acts[1, 0], acts[0, 0])
    assert SkillSet([mean_skill, S.load_new_skill(str(tmp_path), env, "mean")]).vmapped_groups == [[0, 1]]
    with pytest.raises(UsageError, match="--new_skill_actions"):
        S.load_new_skill(str(tmp_path), env, "greedy")


def test_new_skill_std_scale_bad_input_is_one_line(capsys):
    _fails(["--task", "lift", "--new_skill_std_scale", "-0.5", "lift_green"], capsys, "--new_skill_std_scale",
           "≥ 0")
    _fails(["--task", "lift", "--new_skill_std_scale", "nan", "lift_green"], capsys, "--new_skill_std_scale")
    _fails(["--task", "lift", "--new_skill_std_scale", "0.3", "lift_green"], capsys, "--new_skill_actions sampled")


def test_mixed_start_states_begin_some_episodes_stacked(tmp_path):
    """``--start_states mixed``: yellow already rests on blue at the start of some episodes (a
    probe that holds at step 0), never with the paper's resets."""
    out = {}
    for start in ("table", "mixed"):
        path = tmp_path / f"{start}.json"
        S.main(["--task", "stack", "--episodes", "128", "--seeds", "0", "--steps", "2", "--start_states", start,
                "--probes", "stack_yellow_on_blue", "--json", str(path), "open_fingers"])
        rec = json.loads(path.read_text())
        assert rec["start_states"] == start
        out[start] = rec["results"]["open_fingers"]["per_seed"][0]["probes"]["stack_yellow_on_blue"]
    assert out["table"] == 0.0 and 0.0 < out["mixed"] < 0.2, out
