"""Exact resumption (issue 5, item 3): a training.run killed with SIGKILL after a checkpoint and
resumed with --resume ends identical to an uninterrupted run of the same seed (metrics.csv,
exported params, the whole final training state); --no-replay-checkpoint resumes with an empty
replay buffer."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

from training.checkpointing import CHECKPOINT_SUBDIR, Checkpointer
from training.run import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY = {"num_envs": 4, "unroll_length": 5, "replay_size": 2000, "eval_episodes": 2,
        "scheduler": {"skill_lengths": [2, 3], "hidden": [32, 32], "critic_head_hidden": [16], "batch_size": 16,
                      "min_replay_size": 10, "samples_per_insert": 4.0},
        # n_step 2: the checkpoint also holds the collector's pending steps (parallel_skills.nstep); a
        # 1-step run's state is the same tree without them.
        "new_skill": {"hidden": [32, 32], "batch_size": 16, "min_replay_size": 10, "samples_per_insert": 4.0,
                      "n_step": 2}}
ITERATIONS = 12  # 20 env steps each; evaluations at 3, 6, 9, 12; checkpoints every 2 iterations


def _args(tmp, out, *extra, iterations=ITERATIONS):
    cfg = os.path.join(tmp, "tiny.json")
    if not os.path.exists(cfg):
        with open(cfg, "w") as f:
            json.dump(TINY, f)
    return ["--task", "lift", "--config", cfg, "--num_timesteps", str(20 * iterations), "--episode_length", "20",
            "--eval_every", "3", "--checkpoint_every", "40", "--seed", "1", *extra, "--out", out]


def _rows(run):
    with open(os.path.join(run, "metrics.csv"), newline="") as f:
        rows = list(csv.reader(f))
    machine = [rows[0].index(c) for c in ("wall_time", "rss_mb") if c in rows[0]]
    return [[x for n, x in enumerate(r) if n not in machine] for r in rows]  # all but wall clock and memory


def _npz(path):
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def _assert_same_arrays(a, b):
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def _final_state(run):
    """The latest checkpoint's state leaves and host state (wall time and csv position aside)."""
    ck = Checkpointer(run)
    import orbax.checkpoint as ocp

    step = ck.latest_step()
    r = ck.manager().restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(),
                                                        replay=ocp.args.StandardRestore(),
                                                        host=ocp.args.JsonRestore()))
    host = dict(r.host)
    for k in ("wall_time", "csv_bytes"):
        host.pop(k)
    host["metrics"].pop("wall_time")
    ck.close()
    return step, jax.tree.leaves((r.state, r.replay)), host


def _run_and_kill_after_first_checkpoint(argv, cwd, env):
    """Start ``training.run argv`` in a subprocess, SIGKILL it as soon as its first checkpoint is
    complete; return the latest checkpoint's iteration."""
    run = argv[argv.index("--out") + 1]
    ckpt = Checkpointer(run)
    proc = subprocess.Popen([sys.executable, "-m", "training.run", *argv], cwd=cwd, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 240
    try:
        while time.time() < deadline and proc.poll() is None:
            # orbax renames the finished checkpoint into place: a digit-named dir is complete.
            if os.path.isdir(ckpt.directory) and any(s.isdigit() for s in os.listdir(ckpt.directory)):
                os.kill(proc.pid, signal.SIGKILL)
                break
            time.sleep(0.01)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode in (0, -signal.SIGKILL), proc.returncode
    step = ckpt.latest_step()
    assert step is not None, "no checkpoint was written"
    return step


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    tmp = str(tmp_path_factory.mktemp("resume"))
    run = os.path.join(tmp, "a")
    main(_args(tmp, run))
    return tmp, run


def test_sigkill_then_resume_matches_uninterrupted_run(uninterrupted):
    tmp, run_a = uninterrupted
    env = dict(os.environ, PYTHONPATH=ROOT, JAX_COMPILATION_CACHE_DIR=jax.config.jax_compilation_cache_dir)
    for attempt in range(3):  # a retry only if the run outran the kill (finished before it)
        run_b = os.path.join(tmp, f"b{attempt}")
        killed_at = _run_and_kill_after_first_checkpoint(_args(tmp, run_b), tmp, env)
        if killed_at < ITERATIONS:
            break
    assert killed_at < ITERATIONS, f"killed too late (checkpoint {killed_at})"
    assert not os.path.exists(os.path.join(run_b, "export.json"))
    # A row written after the last checkpoint (as a run killed between its evaluation and its
    # next checkpoint leaves): the resume must drop it.
    with open(os.path.join(run_b, "metrics.csv"), "a") as f:
        f.write("999999,0,0,0,0,0,0,0,0,0,0,0,[],[],[]\n")

    main(["--resume", "--out", run_b])

    rows = _rows(run_a)
    assert len(rows) == 1 + ITERATIONS // 3 and [int(r[0]) for r in rows[1:]] == [60, 120, 180, 240]
    assert _rows(run_b) == rows
    _assert_same_arrays(_npz(os.path.join(run_a, "new_skill.npz")), _npz(os.path.join(run_b, "new_skill.npz")))
    _assert_same_arrays(_npz(os.path.join(run_a, "export.npz")), _npz(os.path.join(run_b, "export.npz")))
    # The best evaluated new skill: the last evaluation of the highest success, the same after a resume.
    _assert_same_arrays(_npz(os.path.join(run_a, "best_new_skill.npz")),
                        _npz(os.path.join(run_b, "best_new_skill.npz")))
    with open(os.path.join(run_a, "metrics.csv")) as f:
        evals = [(float(r["eval/new_skill_success"]), int(r["env_steps"])) for r in csv.DictReader(f)]
    with open(os.path.join(run_a, "best_new_skill.json")) as f:
        best = json.load(f)
    top = max(e[0] for e in evals)
    assert (best["success"], best["env_steps"]) == (top, max(e[1] for e in evals if e[0] == top))
    with open(os.path.join(run_a, "export.json")) as fa, open(os.path.join(run_b, "export.json")) as fb:
        ja, jb = json.load(fa), json.load(fb)
    assert ja["metadata"].pop("command") != jb["metadata"].pop("command") and ja == jb  # (different --out)
    step_a, leaves_a, host_a = _final_state(run_a)
    step_b, leaves_b, host_b = _final_state(run_b)
    assert step_a == step_b == ITERATIONS and host_a == host_b
    for x, y in zip(leaves_a, leaves_b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert len(Checkpointer(run_b).steps()) == 2  # the latest 2 are kept


def test_resume_without_replay_checkpoint(uninterrupted):
    tmp, run_a = uninterrupted
    run_c = os.path.join(tmp, "c")
    main(_args(tmp, run_c, "--no-replay-checkpoint"))
    ck = Checkpointer(run_c)
    steps = ck.steps()
    assert steps == [ITERATIONS - 2, ITERATIONS]
    assert not os.path.exists(os.path.join(ck.directory, str(steps[-1]), "replay"))
    assert _rows(run_c) == _rows(run_a)  # checkpointing does not change the run
    # Roll back to the earlier checkpoint, as if the run had been killed before its last one.
    shutil.rmtree(os.path.join(ck.directory, str(ITERATIONS)))
    for name in ("export.npz", "export.json"):
        os.remove(os.path.join(run_c, name))
    main(["--resume", "--out", run_c])
    rows = _rows(run_c)
    # No duplicate or lost rows: the rows the checkpoint covers are kept, the rest recomputed.
    assert [int(r[0]) for r in rows[1:]] == [60, 120, 180, 240]
    assert rows[:-1] == _rows(run_a)[:-1]
    ckpt_dir = os.path.join(run_c, CHECKPOINT_SUBDIR)
    assert sorted(int(s) for s in os.listdir(ckpt_dir) if s.isdigit()) == [ITERATIONS - 2, ITERATIONS]


def test_extending_a_finished_run_matches_a_run_of_the_larger_budget(uninterrupted):
    """``--resume --num_timesteps N`` continues a finished run to N env steps: the final state and
    every evaluation of a run started with N (evaluations leave the training state unchanged), the
    shorter run's outputs kept in before_extension_<budget>/. Its final evaluation (iteration 5, not
    an evaluation iteration of the longer run) stays in metrics.csv as an extra row; the training
    statistics of the next row start after it."""
    tmp, run_a = uninterrupted
    run_e = os.path.join(tmp, "e")
    short_iterations = 5
    main(_args(tmp, run_e, iterations=short_iterations))
    short = {n: _npz(os.path.join(run_e, n)) for n in ("new_skill.npz", "export.npz")}
    main(["--resume", "--out", run_e, "--num_timesteps", str(20 * ITERATIONS)])

    kept = os.path.join(run_e, f"before_extension_{20 * short_iterations}")
    for name, arrays in short.items():
        _assert_same_arrays(_npz(os.path.join(kept, name)), arrays)
    assert sorted(os.listdir(kept)) == ["curves.png", "export.json", "export.npz", "new_skill.json",
                                        "new_skill.npz", "skill_usage.png"]
    rows_a, rows_e = _rows(run_a), _rows(run_e)
    extra = [r[0] for r in rows_e].index(str(20 * short_iterations))
    assert [int(r[0]) for r in rows_e[1:]] == [60, 100, 120, 180, 240]
    header = rows_a[0]
    evals = [i for i, h in enumerate(header) if h == "env_steps" or h.startswith("eval/")]
    rows_e = rows_e[:extra] + rows_e[extra + 1:]
    assert [[r[i] for i in evals] for r in rows_e] == [[r[i] for i in evals] for r in rows_a]
    assert rows_e[:extra] == rows_a[:extra] and rows_e[extra + 1:] == rows_a[extra + 1:]
    _assert_same_arrays(_npz(os.path.join(run_a, "export.npz")), _npz(os.path.join(run_e, "export.npz")))
    step_a, leaves_a, host_a = _final_state(run_a)
    step_e, leaves_e, host_e = _final_state(run_e)
    assert host_e.pop("csv_rows") == host_a.pop("csv_rows") + 1  # the extra row
    assert step_a == step_e == ITERATIONS and host_a == host_e
    for x, y in zip(leaves_a, leaves_e):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    with open(os.path.join(run_e, "config.json")) as f:
        cfg = json.load(f)
    assert cfg["num_timesteps"] == 20 * ITERATIONS
    assert cfg["extensions"] == [{"from": 20 * short_iterations, "to": 20 * ITERATIONS,
                                  "command": f"python -m training.run --resume --out {run_e} "
                                             f"--num_timesteps {20 * ITERATIONS}"}]
    with open(os.path.join(run_e, "export.json")) as f:
        assert json.load(f)["metadata"]["extensions"] == cfg["extensions"]


def test_a_run_in_use_by_another_process_is_refused(uninterrupted, capsys):
    """Two training.run processes on one directory would interleave checkpoints and metrics: the
    second is refused (one line, exit 2) while the first holds DIR's lock, and nothing is changed."""
    tmp, run_a = uninterrupted
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from training.rundir import lock; lock(sys.argv[1]); "
                               "print('locked', flush=True); time.sleep(120)", run_a],
        cwd=ROOT, env=dict(os.environ, PYTHONPATH=ROOT), stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with open(os.path.join(run_a, "config.json")) as f:
            config = f.read()
        capsys.readouterr()
        with pytest.raises(SystemExit) as e:
            main(["--resume", "--out", run_a, "--num_timesteps", str(40 * ITERATIONS)])
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and len(err) == 1 and "is in use by another training.run process" in err[0], err
        with open(os.path.join(run_a, "config.json")) as f:
            assert f.read() == config
        assert os.path.exists(os.path.join(run_a, "export.json"))
    finally:
        holder.kill()
        holder.wait()


def _tree_bytes(root):
    """{relative path: bytes} of every file and directory under ``root`` (a byte-identical check)."""
    out = {}
    for d, _, files in os.walk(root):
        out[os.path.relpath(d, root) + "/"] = None
        for n in files:
            p = os.path.join(d, n)
            with open(p, "rb") as f:
                out[os.path.relpath(p, root)] = f.read()
    return out


def _truncate_files(root, only_data: bool = False):
    """Cut every file under ``root`` (``only_data``: the array data of its items, under d/) to half."""
    cut = 0
    for d, _, files in os.walk(root):
        if only_data and os.path.basename(d) != "d":
            continue
        for n in files:
            p = os.path.join(d, n)
            with open(p, "r+b") as f:
                f.truncate(os.path.getsize(p) // 2)
            cut += 1
    assert cut, root


def _killed_before_export(tmp, run_a, name):
    """A copy of the finished run as a run killed after its last checkpoint, before its export."""
    run = os.path.join(tmp, name)
    shutil.copytree(run_a, run)
    for n in ("export.npz", "export.json"):
        os.remove(os.path.join(run, n))
    return run


def test_resume_past_a_truncated_latest_checkpoint(uninterrupted, capsys):
    """The latest checkpoint's files truncated: --resume says so in one line, continues from the
    previous one and ends as the uninterrupted run (issue 31, item 6); the unreadable checkpoint is
    kept aside, not deleted."""
    tmp, run_a = uninterrupted
    run_t = _killed_before_export(tmp, run_a, "t")
    ckpt_dir = os.path.join(run_t, CHECKPOINT_SUBDIR)
    _truncate_files(os.path.join(ckpt_dir, str(ITERATIONS)))
    capsys.readouterr()
    main(["--resume", "--out", run_t])
    captured = capsys.readouterr()
    warnings = [line for line in captured.err.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "does not restore" in warnings[0], captured.err
    assert f"from its checkpoint at iteration {ITERATIONS - 2}" in captured.out
    assert _rows(run_t) == _rows(run_a)
    _assert_same_arrays(_npz(os.path.join(run_a, "export.npz")), _npz(os.path.join(run_t, "export.npz")))
    assert Checkpointer(run_t).steps() == [ITERATIONS - 2, ITERATIONS]
    assert os.listdir(os.path.join(run_t, "unrestorable_checkpoints")) == [str(ITERATIONS)]


def test_resume_with_every_checkpoint_corrupt_is_refused_and_changes_nothing(uninterrupted, capsys):
    """No checkpoint restores: one line, exit 2, the run directory byte-identical."""
    import gc

    from cli_checks import one_line_error

    tmp, run_a = uninterrupted
    run_x = _killed_before_export(tmp, run_a, "x")
    ckpt_dir = os.path.join(run_x, CHECKPOINT_SUBDIR)
    _truncate_files(os.path.join(ckpt_dir, str(ITERATIONS)))  # (host JSON and all)
    _truncate_files(os.path.join(ckpt_dir, str(ITERATIONS - 2)), only_data=True)  # (the arrays alone)
    before = _tree_bytes(run_x)
    gc.collect()
    capsys.readouterr()
    line = one_line_error(lambda: main(["--resume", "--out", run_x]), capsys, "cannot resume",
                          "restores", f"{ITERATIONS - 2}")
    assert "does not match" not in line, line
    assert _tree_bytes(run_x) == before


def test_load_checkpointed_run_reads_a_named_or_the_latest_checkpoint(uninterrupted):
    """training.run_files.load_checkpointed_run: the run rebuilt from config.json and a checkpoint
    (the latest by default, or a named step), read only; a step that is not there is one line."""
    from training.cli import UsageError
    from training.run_files import load_checkpointed_run

    _, run = uninterrupted
    before = _tree_bytes(run)
    steps = Checkpointer(run).steps()
    latest = load_checkpointed_run(run)
    assert latest.record.task == "lift" and latest.host["env_steps"] == 20 * ITERATIONS
    first = load_checkpointed_run(run, min(steps))
    assert first.host["env_steps"] < latest.host["env_steps"]
    assert int(first.state.iteration) < int(latest.state.iteration)
    with pytest.raises(UsageError) as e:
        load_checkpointed_run(run, max(steps) + 1)
    assert f"no checkpoint at iteration {max(steps) + 1}" in str(e.value), e.value
    assert len(str(e.value).splitlines()) == 1
    assert _tree_bytes(run) == before


def test_readouts_of_a_checkpoint(uninterrupted, tmp_path, capsys):
    """research.readouts: the new skill of the run's latest checkpoint read out as its
    mean, sampled and critic-weighted policy on the same resets; the same numbers twice; bad input
    is one line and exit 2, the run untouched."""
    from research import readouts

    _, run = uninterrupted
    before = sorted(os.listdir(run))
    out = str(tmp_path / "r.json")
    first = readouts.main([run, "--episodes", "4", "--batch", "2", "--json", out])
    assert list(first) == list(readouts.READOUTS)
    for r in first.values():
        assert 0.0 <= r["success"] <= 1.0 and r["episodes"] == 4 and np.isfinite(r["return"])
    saved = json.load(open(out))
    assert saved["env_steps"] == 20 * ITERATIONS and saved["readouts"] == first
    assert readouts.main([run, "--episodes", "4", "--batch", "2"]) == first
    # Noise on every action dimension is the sampled read-out itself (the same keys, the same actions).
    dims = readouts.main([run, "--episodes", "4", "--batch", "2", "--noise_dims", "0,1,2,3,4", "--noise_dims", "4"])
    assert dims["sampled_dims_0_1_2_3_4"] == first["sampled"] and 0.0 <= dims["sampled_dims_4"]["success"] <= 1.0
    capsys.readouterr()
    for argv, words in (([run, "--episodes", "3", "--batch", "2"], "multiple of --batch"),
                        ([run, "--episodes", "2", "--batch", "2", "--noise_dims", "4,5"], "indices in 0..4"),
                        ([str(tmp_path / "none")], "does not exist"),
                        ([str(tmp_path)], "cannot read the run")):
        with pytest.raises(SystemExit) as e:
            readouts.main(argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    assert sorted(os.listdir(run)) == before


def test_action_trace_of_a_checkpoint(uninterrupted, tmp_path, capsys):
    """research.action_trace: the checkpoint's new skill with its mean action, one action
    dimension's mean and std and the named observation entries per step; its first step is the
    policy's mean (and its critic's values) at the reset observation, computed here apart; bad input is
    one line."""
    import jax

    from parallel_skills import learners
    from parallel_skills import normalization as obs_norm
    from tasks.manipulation import layout as L
    from research import action_trace
    from training.run_files import load_checkpointed_run

    _, run = uninterrupted
    out = action_trace.main([run, "--episodes", "2", "--every", "200", "--obs", "finger_angle,green_pose",
                             "--json", str(tmp_path / "t.json")])
    length = out["mean"].shape[0]
    assert out["mean"].shape == out["std"].shape == (length, 2) and out["green_pose"].shape == (length, 2, 3)
    loaded = load_checkpointed_run(run)
    env, trainer, state = loaded.env, loaded.trainer(), loaded.state
    obs = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 2)).obs
    mean, std = learners.make_new_skill_apply(int(env.action_size), trainer.config.new_skill)(
        state.new_skill.policy_params, obs_norm.normalize(state.normalizer, obs))
    np.testing.assert_allclose(out["mean"][0], np.asarray(mean)[:, 4], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(out["std"][0], np.asarray(std)[:, 4], rtol=1e-5, atol=1e-6)
    _, critic = learners.new_skill_networks(int(env.action_size), trainer.config.new_skill)
    q = lambda a: np.min(np.asarray(learners.critic_values(  # noqa: E731
        critic, state.new_skill.critic_params, obs_norm.normalize(state.normalizer, obs), a)), axis=-1)
    np.testing.assert_allclose(out["q_mean"][0], q(mean), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(out["q_up"][0], q(mean.at[:, 4].set(1.0)), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(out["q_down"][0], q(mean.at[:, 4].set(-1.0)), rtol=1e-4, atol=1e-5)
    assert out["v"].shape == (length, 2) and np.all(np.isfinite(out["v"]))
    np.testing.assert_allclose(out["finger_angle"][0, :, 0], np.asarray(obs)[:, L.FINGER])
    np.testing.assert_allclose(out["green_pose"][0], np.asarray(obs)[:, L.cube_pos("green")])
    saved = json.load(open(tmp_path / "t.json"))
    assert saved["dim"] == 4 and len(saved["mean"]) == length
    capsys.readouterr()
    summary = action_trace.main([run, "--episodes", "2", "--every", "600", "--over", "green,yellow",
                                 "--summary_json", str(tmp_path / "s.json")])["summary"]
    assert summary == {k: v for k, v in json.load(open(tmp_path / "s.json")).items()
                       if k not in ("run", "env_steps", "dim", "seed")}
    assert summary["episodes"] == 2 and len(summary["per_episode"]) == 2
    assert summary["steps_over"] == sum(e["steps_over"] for e in summary["per_episode"])
    for e in summary["per_episode"]:  # the means are over the steps held over, None without any
        assert all((v is None) == (e["steps_over"] == 0) for k, v in e.items() if k not in ("success", "steps_over"))
    capsys.readouterr()
    for argv, words in (([run, "--dim", "5"], "action index in 0..4"), ([run, "--obs", "nose"], "unknown entry 'nose'"),
                        ([run, "--over", "green,green"], "two different cube names"),
                        ([run, "--summary_json", "x.json"], "needs --over")):
        with pytest.raises(SystemExit) as e:
            action_trace.main(argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and len(err.strip().splitlines()) == 1 and words in err, err


def test_over_target_summary_counts_the_steps_held_over_the_target():
    """action_trace --over: the steps where TOP is held within 0.03 m horizontally and > 0.03 m above
    BOTTOM, and the means over them, on a hand-made two-episode trace."""
    from research.action_trace import over_target_summary

    t, e = 4, 2
    top = np.zeros((t, e, 3))
    top[:, 0] = [[0.0, 0.0, 0.10], [0.01, 0.0, 0.10], [0.05, 0.0, 0.10], [0.0, 0.0, 0.02]]  # over at t 0, 1
    top[:, 1] = [[0.0, 0.0, 0.10]] * 4  # over, but held only at t 3
    grasp = np.ones((t, e, 1))
    grasp[:3, 1] = 0.0
    ramp = np.arange(t * e, dtype=float).reshape(t, e)
    out = {"grasp": grasp, "green_pose": top, "yellow_pose": np.zeros((t, e, 3)), "success": np.array([1.0, 0.0]),
           "mean": ramp, "std": ramp + 1, "q_mean": ramp, "q_up": ramp + 2, "q_down": ramp - 1, "v": np.ones((t, e))}
    s = over_target_summary(out, "green", "yellow")
    assert s["steps_over"] == 3 and s["episodes_ever_over"] == 2 and s["episodes_success"] == 1
    first, second = s["per_episode"]
    assert (first["steps_over"], first["first_step_over"], first["mean"]) == (2, 0, 1.0)  # mean of ramp[0:2, 0] = 0, 2
    assert (second["steps_over"], second["first_step_over"], second["mean"]) == (1, 3, 7.0)
    assert first["q_up_minus_v"] == 2.0 and first["q_down_minus_v"] == -1.0
    assert s["over_step_means"]["mean"] == (0 + 2 + 7) / 3


def test_replay_census_counts_the_stored_rows_by_sign_and_skill(uninterrupted, monkeypatch, capsys):
    """research.replay_census: the held-over test on hand-made observations; on the
    checkpoint's replay (every stored row taken as "over"), the up / down parts and their per-skill
    rows and CRR weights add up; bad input is one line."""
    from tasks.manipulation import layout as L
    from research import replay_census
    from training.run_files import load_checkpointed_run

    obs = np.zeros((3, L.OBS_SIZE), np.float32)
    obs[:, L.GRASP] = [1.0, 0.0, 1.0]
    obs[:, L.cube_pos("green")] = [[0.01, 0.0, 0.10], [0.0, 0.0, 0.10], [0.05, 0.0, 0.10]]
    np.testing.assert_array_equal(replay_census.over_rows(obs, "green", "yellow"), [True, False, False])

    _, run = uninterrupted
    monkeypatch.setattr(replay_census, "over_rows", lambda o, top, bottom: np.ones(len(o), bool))
    out = replay_census.census(load_checkpointed_run(run), "green", "yellow", 4)
    assert out["rows_over"] > 0 and out["up"]["rows"] + out["down"]["rows"] == out["rows_over"] <= out["replay_rows"]
    for part in (out["up"], out["down"]):
        assert sum(s["rows"] for s in part["by_skill"].values()) == part["rows"]
        assert abs(sum(s["crr_weight_sum"] for s in part["by_skill"].values()) - part["crr_weight_sum"]) < 0.01 * len(
            part["by_skill"]) + 1e-6
    assert -1.0 <= out["crr_weighted_mean_of_dim"] <= 1.0 and out["crr"]["mode"] == "exp"
    monkeypatch.undo()
    capsys.readouterr()
    for argv, words in (([run, "--over", "green"], "two different cube names"), ([run, "--dim", "9"], "0..4")):
        with pytest.raises(SystemExit) as e:
            replay_census.main(argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
