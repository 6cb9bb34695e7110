"""bench/peers.py: Brax's PPO and SAC on the project's tasks. The smoke run writes every run's files;
the shaped reward's terms on hand-built states; the report's time-to-threshold and ratio arithmetic."""

import csv
import importlib.util
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _load():
    spec = importlib.util.spec_from_file_location("bench_peers", os.path.join(ROOT, "bench", "peers.py"))
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # (its dataclass looks its module up)
    spec.loader.exec_module(module)
    return module


peers = _load()


@pytest.mark.timeout(300)
def test_smoke_trains_evaluates_writes_and_skips_finished_runs(tmp_path, monkeypatch, capsys):
    out = tmp_path / "peers"
    r = subprocess.run([sys.executable, "bench/peers.py", "--smoke", "--out", str(out)], cwd=ROOT,
                       capture_output=True, text=True, timeout=280)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert {a for a, _ in peers.SMOKE_LEARNERS} == set(peers.ALGOS)  # both learners
    assert {w for _, w in peers.SMOKE_LEARNERS} == set(peers.REWARDS)  # and both rewards
    for algo, reward in peers.SMOKE_LEARNERS:
        run = out / "lift" / f"{algo}-{reward}" / "s0"
        with open(run / "config.json") as f:
            config = json.load(f)
        assert (config["task"], config["algo"], config["reward"], config["seed"]) == ("lift", algo, reward, 0)
        assert config["num_timesteps"] == peers.SMOKE_BUDGET and config["eval_episodes"] == peers.SMOKE_EVAL_EPISODES
        assert {"jax", "brax"} <= set(config["versions"])
        hp = config["hyperparameters"]
        assert hp["num_envs"] == peers.SMOKE[algo]["num_envs"] and hp["seed"] == 0
        assert hp["discounting"] == peers.PLAYGROUND[algo]["discounting"]  # Playground's, unchanged
        assert list(config["reward_weights"]) == (peers.shaped_terms_names("lift") if reward == "shaped" else ["task"])
        assert not any(str(v).startswith("/") for v in hp.values())  # no machine paths
        with open(run / "metrics.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        assert list(rows[0]) == peers.METRICS and len(rows) == peers.SMOKE_EVALS
        values = [[float(v) for v in row.values()] for row in rows]
        assert all(math.isfinite(v) for row in values for v in row)
        steps = [row[0] for row in values]
        assert steps == sorted(steps) and steps[-1] >= peers.SMOKE_BUDGET
        assert all(0.0 <= row[2] <= 1.0 and 0.0 <= row[4] <= 1.0 for row in values)
    assert "| lift | ppo-shaped | 0/1 |" in r.stdout and "| lift | sac-sparse | 0/1 |" in r.stdout
    # Again (in this process): every run reached its budget, so nothing trains.
    monkeypatch.setenv("JAX_DISABLE_MOST_OPTIMIZATIONS", "1")  # (--smoke sets it; restored after the test)
    peers.main(["--smoke", "--out", str(out)])
    printed = capsys.readouterr().out
    assert printed.count(": done") == 2 and "env_steps=" not in printed and "| lift | ppo-shaped |" in printed


def _inputs(pinch, aperture, grasp, green, yellow=(0.1, 0.1, 0.02), blue=(-0.1, 0.1, 0.02)):
    from tasks.manipulation.task_defs import Inputs

    return Inputs(np.array(pinch, np.float32), np.float32(aperture), np.float32(grasp),
                  np.array([green, yellow, blue], np.float32))


def _tanh_shaped(scaled, margin_scaled):  # 1 - tanh²(d·ε), ε: 0.1 at the margin
    return 1.0 - math.tanh(scaled * math.atanh(math.sqrt(0.9)) / margin_scaled) ** 2


def test_shaped_lift_terms_on_hand_built_states():
    # Green held halfway up (z = 0.10 m), centred: reach, centre and grasp 1, lift (0.10 - 0.02) / 0.16.
    held = peers.shaped_terms("lift", _inputs((0, 0, 0.10), 0.04, 1.0, (0, 0, 0.10)))
    assert list(held) == peers.shaped_terms_names("lift") == ["reach", "centre", "grasp", "lift", "task"]
    np.testing.assert_allclose([float(v) for v in held.values()], [1.0, 1.0, 1.0, 0.5, 0.0], rtol=1e-6)
    at_top = _inputs((0, 0, 0.18), 0.04, 1.0, (0, 0, 0.18))
    assert float(peers.shaped_reward("lift", at_top)) == pytest.approx(1 + 1 + 1 + 1 + 5)
    # The gripper 0.2 m away, holding another cube: reach and centre shaped, no grasp or lift term.
    away = peers.shaped_terms("lift", _inputs((0.2, 0.0, 0.10), 0.04, 1.0, (0, 0, 0.10)))
    assert float(away["reach"]) == pytest.approx(_tanh_shaped(0.2 / 0.055, 0.3 / 0.055), rel=1e-5)
    assert float(away["centre"]) == pytest.approx(_tanh_shaped(0.2 / 0.01, 0.1 / 0.01), rel=1e-3)
    assert float(away["grasp"]) == 0.0 and float(away["lift"]) == 0.0
    # Fingers closed 3.5 cm beside green on the table: reach in full, centre not, nothing for the fingers.
    beside = peers.shaped_terms("lift", _inputs((0.035, 0, 0.02), 0.0, 0.0, (0, 0, 0.02)))
    np.testing.assert_allclose([float(v) for v in beside.values()], [1.0, _tanh_shaped(3.5, 10.0), 0.0, 0.0, 0.0],
                               rtol=1e-5)


def test_shaped_stack_terms_and_the_wrapped_env():
    # Green released on yellow, the gripper 5 cm above it: hover 1, the task's reward 1, no grasp term.
    stacked = peers.shaped_terms("stack", _inputs((0.1, 0.1, 0.11), 0.085, 0.0, (0.1, 0.1, 0.06)))
    assert list(stacked) == ["reach", "centre", "grasp", "hover", "task"]
    assert [float(stacked[k]) for k in ("grasp", "hover", "task")] == [0.0, 1.0, 1.0]
    assert 0.5 < float(stacked["reach"]) < 1.0
    with pytest.raises(ValueError, match="no shaped reward"):
        peers.task_cubes("pyramid")
    # The wrapper pays the shaped reward of the observation (the same as of the state it shows) and
    # leaves time limits to Brax: an env step that ends the episode comes out with done 0.
    import jax
    import jax.numpy as jnp
    from brax.envs.base import Wrapper

    import tasks
    from tasks.manipulation.kinematic import observe, task_inputs

    env = tasks.make("stack")
    start = env.reset(jax.random.PRNGKey(0))
    held = start.pipeline_state.replace(held=jnp.asarray(2, jnp.int32))  # (blue held: the grasp sensor on)
    start = start.replace(pipeline_state=held, obs=observe(held))

    class Ended(Wrapper):  # the env's last step: done 1, its own (sparse) reward
        def step(self, state, action):
            return state.replace(done=jnp.ones(()), reward=jnp.zeros(()))

    for reward in peers.REWARDS:
        out = peers._wrappers()[0](Ended(env), "stack", reward).step(start, jnp.zeros(5))
        assert float(out.done) == 0.0
    assert float(out.reward) == pytest.approx(float(peers.shaped_reward("stack", task_inputs(start.pipeline_state))),
                                              rel=1e-6)
    for a, b in zip(peers.observation_inputs(start.obs), task_inputs(start.pipeline_state)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)


def test_device_put_replicated_shim(monkeypatch):
    import jax

    monkeypatch.delattr(jax, "device_put_replicated", raising=False)
    assert peers.install_device_put_replicated()
    x = jax.device_put_replicated({"a": np.arange(3, dtype=np.float32), "b": np.uint32(7)}, jax.local_devices())
    n = len(jax.local_devices())
    assert x["a"].shape == (n, 3) and x["b"].shape == (n,) and x["b"].dtype == np.uint32
    np.testing.assert_array_equal(np.asarray(jax.pmap(lambda t: t["a"] * 2)(x))[0], [0.0, 2.0, 4.0])
    assert not peers.install_device_put_replicated()  # defined now: left alone


def _metrics(path, key, rows):
    os.makedirs(path, exist_ok=True)
    with open(os.path.join(path, "metrics.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["env_steps", "wall_time", key])
        w.writerows(rows)


def test_time_to_threshold_and_ratios(tmp_path):
    rows = lambda pairs: [{"env_steps": s, "wall_time": w, "eval/success": v} for s, w, v in pairs]  # noqa: E731
    fast = rows([(100, 10.0, 0.5), (200, 20.0, 0.9)])
    slow = rows([(100, 10.0, 0.1), (400, 50.0, 0.85)])
    never = rows([(100, 10.0, 0.1), (1000, 90.0, 0.6)])
    both = peers.time_to_threshold([fast, slow], 0.8, "eval/success")
    assert (both.steps, both.wall, both.reached, both.seeds, both.lower_bound) == (300.0, 35.0, 2, 2, False)
    assert both.best == pytest.approx(0.875)
    cut = peers.time_to_threshold([fast, never, []], 0.8, "eval/success")  # (a seed without rows is left out)
    assert (cut.steps, cut.wall, cut.reached, cut.seeds, cut.lower_bound) == (600.0, 55.0, 1, 2, True)
    assert peers.time_to_threshold([[], []], 0.8, "eval/success") is None
    skills = peers.Reach(steps=100.0, wall=70.0, reached=2, seeds=2, best=1.0)
    assert peers.ratio(both, skills, "steps") == (3.0, "")
    assert peers.ratio(both, skills, "wall") == (0.5, "")
    assert peers.ratio(cut, skills, "steps") == (6.0, "≥")
    unreached = peers.Reach(steps=1000.0, wall=100.0, reached=0, seeds=1, best=0.2)
    assert peers.ratio(both, unreached, "steps") == (0.3, "≤")
    assert peers.ratio(cut, unreached, "steps") is None
    # The table reads SkillS's archive layout and the peers' run directories.
    _metrics(tmp_path / "skills" / "lift" / "skills" / "s0", "eval/new_skill_success", [(100, 70.0, 0.9)])
    _metrics(tmp_path / "out" / "lift" / "ppo-shaped" / "s0", "eval/success", [(100, 10.0, 0.5), (300, 35.0, 0.8)])
    table = peers.report(str(tmp_path / "out"), ["lift"], [("ppo", "shaped"), ("sac", "shaped")], [0],
                         str(tmp_path / "skills"), "skills", 0.8)
    assert "| lift | SkillS (skills) | 1/1 | 0.1k | 70 | 0.90 | – | – |" in table
    assert "| lift | ppo-shaped | 1/1 | 0.3k | 35 | 0.80 | 3.0x | 0.5x |" in table
    assert "| lift | sac-shaped | no runs |" in table


@pytest.mark.parametrize("args, message", [
    (["--algos", "ppo,td3"], "error: --algos: unknown td3; valid: ppo, sac"),
    (["--tasks", "pyramid"], "error: --tasks: task 'pyramid' has no shaped reward here"),
    (["--num_timesteps", "lift=0"], "error: bad --num_timesteps item 'lift=0'"),
    (["--tasks", "stack_green_on_blue"], "error: no budget for stack_green_on_blue"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as e:
        peers.main(args + ["--out", str(tmp_path / "x"), "--dry_run"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(message), err
    assert not (tmp_path / "x").exists()
