"""Run outputs of issue 5 items 2 and 5: per-skill consecutive-run counting, metrics.csv plots,
TensorBoard events (with the resume purge), the progress display and videos."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from training.logging_utils import Progress, TensorBoardLogger, event_files, format_row, read_scalars

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# ----------------------------------------------------------------------------- skill_runs

def _run_ends(i, dec, done):
    """skill_run_ends over a sequence [T, B] from a fresh reset; returns per-step counts [T, B, N]."""
    from parallel_skills.acting import skill_run_ends

    T, B = i.shape
    i_prev, first_prev, out = jnp.zeros(B, jnp.int32), jnp.ones(B, bool), []
    for t in range(T):
        out.append(np.asarray(skill_run_ends(i_prev, first_prev, jnp.asarray(i[t]), jnp.asarray(dec[t]),
                                             jnp.asarray(done[t]), 3)))
        i_prev, first_prev = jnp.asarray(i[t]), jnp.asarray(done[t])
    return np.stack(out)


def test_skill_runs_hand_computed():
    # env 0: skill 0 for 3 steps (a decision at t=2 picks it again: one run), skill 1 until the
    # episode ends at t=4, skill 1 again in the new episode (a new run), then skill 2 (still running).
    # env 1: skill 2, then 2 again at a decision, episode end at t=2, then 0, 1, 1, 0, 0, 0.
    i = np.array([[0, 2], [0, 2], [0, 2], [1, 0], [1, 1], [1, 1], [2, 0], [2, 0], [2, 0]], np.int32)
    dec = np.array([[1, 1], [0, 1], [1, 0], [1, 1], [0, 1], [1, 0], [1, 1], [1, 0], [0, 1]], bool)
    done = np.zeros_like(dec)
    done[4, 0] = done[2, 1] = True
    ends = _run_ends(i, dec, done)
    expected = np.zeros((9, 2, 3))
    expected[3, 0, 0] = 1  # env 0: the run of skill 0 (t=0..2) ends when skill 1 is chosen at t=3
    expected[4, 0, 1] = 1  # episode end: the run of skill 1 (t=3..4)
    expected[6, 0, 1] = 1  # the new episode's run of skill 1 (t=5) ends at the switch at t=6
    expected[2, 1, 2] = 1  # env 1: skill 2 (t=0..2, re-chosen at t=1) ends with the episode
    expected[4, 1, 0] = 1  # skill 0 (t=3) ends at the switch to 1 at t=4
    expected[6, 1, 1] = 1  # skill 1 (t=4..5) ends at the switch to 0 at t=6; 0 (t=6..8) runs on
    np.testing.assert_array_equal(ends, expected)
    steps = np.stack([np.bincount(i[:, b], minlength=3) for b in range(2)]).sum(0)
    np.testing.assert_array_equal(steps, [7, 5, 6])
    np.testing.assert_array_equal(ends.sum(axis=(0, 1)), [2, 3, 1])


def _reference_run_ends(i, done):
    """Independent count per skill of the maximal runs closed within a window that starts at a
    reset: a run is closed by its episode's end or by the next step acting with another skill."""
    T, B = i.shape
    n = np.zeros(3)
    for b in range(B):
        for t in range(T):
            if done[t, b] or (t + 1 < T and i[t + 1, b] != i[t, b]):
                n[i[t, b]] += 1
    return n


class _ToyEnv:
    """A tiny Brax-API env (episodes of 4 steps, random observations): cheap to compile."""

    observation_size, action_size, episode_length = 2, 1, 4

    def reset(self, rng):
        from brax.envs.base import State

        z = jnp.zeros(())
        return State(pipeline_state=None, obs=jax.random.normal(rng, (2,)), reward=z, done=z,
                     metrics={}, info={"steps": jnp.zeros((), jnp.int32), "truncation": z})

    def step(self, state, action):
        steps = state.info["steps"] + 1
        done = (steps >= self.episode_length).astype(jnp.float32)
        obs = jnp.stack([jnp.sin(state.obs[0] * 3.0 + action[0]), jnp.cos(state.obs[1] * 5.0 + steps)])
        return state.replace(obs=obs, reward=jnp.sum(obs), done=done, info={"steps": steps, "truncation": done})


def test_acting_step_counts_skill_runs():
    """The trainer's acting step reports skill_runs consistent with the skills that acted."""
    from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig
    from parallel_skills import learners
    from parallel_skills import normalization
    from parallel_skills.train import make_trainer

    cfg = TrainConfig(num_envs=3, unroll_length=2, replay_size=64, eval_episodes=1,
                      scheduler=SchedulerConfig(skill_lengths=(1, 2), hidden=(8,), critic_head_hidden=(4,), batch_size=4,
                                                initial_max_length_prob=0.5),
                      new_skill=NewSkillConfig(hidden=(8,), batch_size=4))
    skills = [Skill.from_fn(n, lambda obs, key: jnp.zeros(1)) for n in ("a", "b")]
    trainer = make_trainer(_ToyEnv(), skills, cfg)
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(0), 3)
    sched = learners.scheduler_networks(3, cfg.scheduler)[0].init(k1, jnp.zeros((1, 2)))
    new = learners.new_skill_networks(1, cfg.new_skill)[0].init(k2, jnp.zeros((1, 2)))

    def unroll(key):
        def body(a, k):
            a, tr, st = trainer.actor.step(a, sched, new, normalization.init(2), k)
            return a, (tr.skill, st.done, st.skill_runs)

        return jax.lax.scan(body, trainer.actor.reset(k3), jax.random.split(key, 12))[1]

    i, done, runs = (np.asarray(x) for x in jax.jit(unroll)(jax.random.PRNGKey(1)))
    assert runs.shape == (12, 3, 3) and done.any() and len(np.unique(i)) == 3
    np.testing.assert_array_equal(runs.sum(axis=(0, 1)), _reference_run_ends(i, done))


# ----------------------------------------------------------------------------- metrics.csv and plots

def _write_csv(run_dir, rows, fields=None):
    """metrics.csv exactly as training.run writes it (same header and row formatting)."""
    from training.run_files import CSV_FIELDS

    fields = fields or CSV_FIELDS
    os.makedirs(run_dir, exist_ok=True)
    with open(os.path.join(run_dir, "metrics.csv"), "wb") as f:
        for row in [fields] + [format_row(m, fields) for m in rows]:
            buf = io.StringIO()
            csv.writer(buf).writerow(row)
            f.write(buf.getvalue().encode())


def _synthetic_run(run_dir, seed, method="skills", skills=("reach_green", "lift_arm_closed")):
    rng = np.random.default_rng(seed)
    names = list(skills) if method == "skills" else []
    n = len(names) + 1
    rows = []
    for e in range(1, 6):
        steps = rng.integers(50, 100, n).astype(float)
        runs = np.maximum(1.0, np.round(steps / (2 + e * np.arange(1, n + 1))))
        m = {"env_steps": 1000 * e, "wall_time": 1.5 * e, "eval/new_skill_success": min(1.0, 0.2 * e + 0.05 * seed),
             "eval/new_skill_return": 10.0 * e, "episode_success": 0.5, "episode_return": 3.0,
             "new_skill_selection_rate": 0.3, "scheduler/critic_loss": 0.1, "new_skill/critic_loss": 0.2,
             "scheduler/policy_entropy_i": 1.0, "skill_histogram": [1.0] * n, "length_histogram": [2.0, 3.0],
             "skill_steps": steps.tolist(), "skill_runs": runs.tolist()}
        if method == "skills":
            m.update({"eval/scheduler_success": 0.5 + 0.1 * seed, "eval/scheduler_return": 20.0 + e})
        rows.append(m)
    _write_csv(run_dir, rows)
    with open(os.path.join(run_dir, "config.json"), "w") as f:
        json.dump({"task": "lift", "physics": "kinematic", "skill_set": "useful", "skills": names, "seed": seed,
                   "train_config": {"method": method}}, f)
    return rows


def _is_png(path):
    with open(path, "rb") as f:
        head = f.read(8)
    return head == PNG_MAGIC and os.path.getsize(path) > 5000


def test_plots_from_synthetic_metrics_csv(tmp_path, capsys):
    from training import plot

    rows = {s: _synthetic_run(str(tmp_path / f"skills_s{s}"), s) for s in (0, 1)}
    _synthetic_run(str(tmp_path / "scratch_s0"), 0, method="scratch")
    dirs = [str(tmp_path / d) for d in ("skills_s0", "skills_s1", "scratch_s0")]

    # Reading back: the format round-trips, groups are per config, mean ± std over seeds.
    runs = [plot.Run(d) for d in dirs]
    groups = plot.group_runs(runs)
    assert [(label, len(members)) for label, members in groups] == [("SkillS (useful skills), 2 seeds", 2), ("from scratch", 1)]
    steps, mean, std, count = plot.aggregate([r.series("eval/new_skill_success") for r in runs[:2]])
    a = np.array([m["eval/new_skill_success"] for m in rows[0]])
    b = np.array([m["eval/new_skill_success"] for m in rows[1]])
    np.testing.assert_array_equal(steps, [1000, 2000, 3000, 4000, 5000])
    np.testing.assert_allclose(mean, (a + b) / 2)
    np.testing.assert_allclose(std, np.abs(a - b) / 2)
    np.testing.assert_array_equal(count, 2)
    u_steps, avg, share, labels = plot.usage_series(runs[0])
    assert labels == ["reach_green", "lift_arm_closed", "new_skill"]
    np.testing.assert_allclose(avg, [np.divide(m["skill_steps"], m["skill_runs"]) for m in rows[0]])
    np.testing.assert_allclose(share.sum(axis=1), 1.0)

    out = str(tmp_path / "cmp.png")
    plot.main([*dirs, "--out", out])
    assert _is_png(out) and _is_png(str(tmp_path / "cmp_skill_usage.png"))
    printed = capsys.readouterr().out
    assert "cmp.png" in printed and "cmp_skill_usage.png" in printed

    # One run, as training.run writes at the end.
    curves, usage = plot.write_run_plots(dirs[0])
    assert curves.endswith("curves.png") and usage.endswith("skill_usage.png")
    assert _is_png(curves) and _is_png(usage)


def test_plots_of_a_run_without_skill_runs_or_config(tmp_path):
    """A metrics.csv of a run from before skill_runs was logged (and no config.json) still plots."""
    from training import plot
    from training.run_files import CSV_FIELDS

    old = [f for f in CSV_FIELDS if f != "skill_runs"]
    _write_csv(str(tmp_path / "old"), [{"env_steps": 100 * e, "eval/new_skill_success": 0.1 * e,
                                        "eval/new_skill_return": 1.0, "skill_steps": [5.0, 5.0]} for e in (1, 2)], old)
    assert plot.usage_series(plot.Run(str(tmp_path / "old"))) is None
    curves, usage = plot.write_run_plots(str(tmp_path / "old"))
    assert _is_png(curves) and _is_png(usage)


def test_usage_over_episode_shares_per_start_kind(tmp_path):
    """training.evaluate --usage_plot: the share of episodes running each skill at each step, one
    panel per start kind (hand-computed)."""
    from training.plot import plot_usage_over_episode, usage_shares

    timeline = [[0, 0, 1, 2], [1, 0, 1, 1], [1, 1, 1, 1]]  # [T 3, B 4]: skill index per step and episode
    groups = [0, 0, 1, 1]
    shares = usage_shares(timeline, 3, groups)
    np.testing.assert_allclose(shares[0], [[1, 0.5, 0], [0, 0.5, 1], [0, 0, 0]])
    np.testing.assert_allclose(shares[1], [[0, 0, 0], [0.5, 1, 1], [0.5, 0, 0]])
    np.testing.assert_allclose(usage_shares(timeline, 3)[0][1], [0.25, 0.75, 1.0])
    out = plot_usage_over_episode(timeline, ["a", "b", "new_skill"], str(tmp_path / "u.png"), 0.025,
                                  groups=groups, group_names={0: "standing", 1: "prone"})
    assert os.path.getsize(out) > 0


def test_plot_cli_bad_input(tmp_path, capsys):
    from training import plot

    (tmp_path / "empty").mkdir()
    for argv, needle in [([str(tmp_path / "nope"), "--out", "x.png"], "does not exist"),
                         ([str(tmp_path / "empty")], "no metrics.csv")]:
        with pytest.raises(SystemExit) as e:
            plot.main(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and needle in err[0], err


# ----------------------------------------------------------------------------- TensorBoard and progress

def _metrics(step, value):
    return {"env_steps": step, "eval/new_skill_success": value, "eval/scheduler_success": 1 - value,
            "skill_steps": [4.0, 6.0], "skill_runs": [2.0, 0.0], "length_histogram": [1.0, 3.0], "note": "text"}


def test_tensorboard_events_read_back_and_resume_purge(tmp_path):
    tb = TensorBoardLogger(str(tmp_path), ["reach_green"], [10, 20])
    for step, v in [(10, 0.1), (20, 0.2), (30, 0.3)]:
        tb.log(step, dict(_metrics(step, v), episode_success=math.nan if step == 20 else v))
    tb.close()
    s = read_scalars(str(tmp_path))
    # No episode ended in the interval of step 20: a gap, not a NaN point (metrics.csv keeps the nan).
    assert [p for p, _ in s["episode_success"]] == [10, 30]
    assert s["eval/new_skill_success"] == [(10, pytest.approx(0.1)), (20, pytest.approx(0.2)), (30, pytest.approx(0.3))]
    assert s["skill_steps/reach_green"][0] == (10, 4.0) and s["skill_runs/new_skill"][0] == (10, 0.0)
    assert s["skill_avg_consecutive/reach_green"][0] == (10, 2.0)
    assert "skill_avg_consecutive/new_skill" not in s  # no completed run: no average
    assert s["length_histogram/k20"][0] == (10, 3.0) and "note" not in s

    # A resume from a checkpoint at step 20: a new event file whose purge step hides step 30 of
    # the first file (logged after the checkpoint, recomputed by the resumed run).
    tb = TensorBoardLogger(str(tmp_path), ["reach_green"], [10, 20], purge_step=21)
    for step, v in [(30, 0.35), (40, 0.4)]:
        tb.log(step, _metrics(step, v))
    tb.close()
    assert len(event_files(str(tmp_path))) == 2
    s = read_scalars(str(tmp_path))
    assert [p for p, _ in s["eval/new_skill_success"]] == [10, 20, 30, 40]
    assert s["eval/new_skill_success"][2][1] == pytest.approx(0.35)


def test_progress_plain_lines_without_a_terminal_and_a_bar_with_one():
    m = {"eval/new_skill_success": 0.25, "eval/new_skill_return": 3.0, "episode_success": 0.5,
         "new_skill_selection_rate": 0.4}
    err, out = io.StringIO(), io.StringIO()
    p = Progress(1000, stream=err, out=out)  # StringIO is no terminal
    p.update(500, m)
    p.close()
    assert err.getvalue() == "" and out.getvalue().count("\n") == 1
    assert "new_skill success=0.25" in out.getvalue() and "500 steps" in out.getvalue()

    err, out = io.StringIO(), io.StringIO()
    p = Progress(1000, stream=err, out=out, tty=True)
    p.update(500, m)
    p.close()
    bar = err.getvalue()
    assert "\r" in bar and "50% |" in bar and "500/1,000 env steps" in bar and "new_skill success 0.25" in bar
    assert "steps/s" in bar and bar.endswith("\n") and out.getvalue().count("\n") == 1

    # Iterations between evaluations move the bar (no line printed).
    err, out = io.StringIO(), io.StringIO()
    p = Progress(1000, stream=err, out=out, tty=True, tick=0)
    p.advance(250)
    assert "25% |" in p.bar() and "250/1,000 env steps" in p.bar() and "steps/s" in p.bar()
    p.close()
    assert out.getvalue() == ""


# ----------------------------------------------------------------------------- video

def _kinematic_observations():
    """A few observations of distinct kinematic states (no jit: eager JAX)."""
    from tasks.manipulation import kinematic as K

    s = K.sample_initial_state(jax.random.PRNGKey(3))
    states = [s, s.replace(pinch=jnp.array([0.03, -0.02, 0.05]), yaw=jnp.asarray(0.7), aperture=jnp.asarray(0.04)),
              s.replace(yaw=jnp.asarray(-2.5), aperture=jnp.asarray(0.0))]
    return np.stack([np.asarray(K.observe(x)) for x in states])


def test_qpos_from_observations_matches_the_scene_layout():
    """The scene at the qpos built from an observation observes the same poses."""
    from tasks.manipulation import layout as L
    from tasks.manipulation import physics_np as P
    from training.video import qpos_from_observations

    obs = _kinematic_observations()
    qpos = qpos_from_observations(obs)
    again = P.observe(qpos, np.zeros(qpos.shape[:-1] + (P.NV,)), np.zeros(qpos.shape[:-1] + (P.NU,)))
    for name in ["joint_pos", "finger_angle"] + [f"{c}_pose" for c in L.CUBE_NAMES]:
        a, b = obs[:, L.OBS_SLICES[name]], again[:, L.OBS_SLICES[name]]
        if name.endswith("_pose"):  # quaternions up to sign
            b = b * np.where(np.sum(a[:, 3:] * b[:, 3:], -1, keepdims=True) < 0, [1, 1, 1, -1, -1, -1, -1], 1)
        np.testing.assert_allclose(a, b, atol=2e-6, err_msg=name)
    for c in L.CUBE_NAMES:
        np.testing.assert_allclose(obs[:, L.cube_rel_pos(c)], again[:, L.cube_rel_pos(c)], atol=2e-6)


@pytest.mark.parametrize("fmt", ["gif", "mp4"])
def test_video_writes_a_file(tmp_path, fmt):
    from training.video import VideoError, ffmpeg_available, qpos_from_observations, write_video

    if fmt == "mp4" and not ffmpeg_available():
        pytest.skip("mp4 needs imageio + imageio-ffmpeg (the [video] extra); GIF is the fallback")
    qpos = qpos_from_observations(np.repeat(_kinematic_observations(), 2, axis=0))
    try:
        path = write_video(qpos, str(tmp_path / "clip"), fps=20, size=(160, 120), fmt=fmt)
    except VideoError as e:
        if e.gl:
            pytest.skip(f"no headless OpenGL backend (egl, osmesa) works on this machine: {e}")
        raise
    assert path == str(tmp_path / f"clip.{fmt}") and os.path.getsize(path) > 500
    assert sorted(os.listdir(tmp_path)) == [f"clip.{fmt}"]  # no temporary left behind
    if fmt == "gif":
        from PIL import Image

        with Image.open(path) as im:
            assert im.size == (160, 120) and im.n_frames >= 3  # 20 fps kept every 2nd frame


# ----------------------------------------------------------------------------- a whole run

# tests/test_resume.py's tiny run (same config and flags: the compiled functions are shared
# through the persistent compilation cache).
TINY = {"num_envs": 4, "unroll_length": 5, "replay_size": 2000, "eval_episodes": 2,
        "scheduler": {"skill_lengths": [2, 3], "hidden": [32, 32], "critic_head_hidden": [16], "batch_size": 16,
                      "min_replay_size": 10, "samples_per_insert": 4.0},
        "new_skill": {"hidden": [32, 32], "batch_size": 16, "min_replay_size": 10, "samples_per_insert": 4.0}}


def test_run_writes_logs_plots_and_video(tmp_path, capsys):
    from training.run import main
    from training.run_files import CSV_FIELDS

    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps(TINY))
    out = str(tmp_path / "run")
    main(["--task", "lift", "--config", str(cfg), "--num_timesteps", "240", "--episode_length", "20",
          "--eval_every", "3", "--seed", "1", "--out", out, "--video"])
    printed = capsys.readouterr()
    assert printed.out.strip().splitlines()[-1].startswith("success=")
    assert printed.out.count(" steps ") >= 4 and "\r" not in printed.err  # no terminal: plain lines only

    with open(os.path.join(out, "metrics.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == CSV_FIELDS and [int(r["env_steps"]) for r in rows] == [60, 120, 180, 240]
    for r in rows:
        steps, runs = json.loads(r["skill_steps"]), json.loads(r["skill_runs"])
        assert len(steps) == len(runs) == 3 and sum(steps) == 60  # every env step of the interval
        assert 0 < sum(runs) <= sum(steps)
        assert 100 < float(r["rss_mb"]) < 100_000  # the process's resident memory (a JAX process: > 100 MiB)

    scalars = read_scalars(out)
    assert [s for s, _ in scalars["eval/new_skill_success"]] == [60, 120, 180, 240]
    assert {"skill_steps/reach_green", "skill_runs/new_skill", "scheduler/critic_loss"} <= set(scalars)
    assert _is_png(os.path.join(out, "curves.png")) and _is_png(os.path.join(out, "skill_usage.png"))
    videos = [f for f in os.listdir(out) if f.startswith("new_skill.") and f.endswith((".mp4", ".gif"))]
    if not videos:
        assert "video skipped: no headless OpenGL backend" in printed.err, printed.err
        pytest.skip(f"no headless OpenGL backend: {printed.err.strip().splitlines()[-1]}")
    assert os.path.getsize(os.path.join(out, videos[0])) > 500


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc_trim: Linux only")
def test_release_free_memory_returns_freed_heap_pages_to_the_os():
    """Blocks of 32 KiB come from the heap (below glibc's mmap threshold); freeing every other one
    leaves ~64 MiB free inside the heap, which glibc keeps resident until ``malloc_trim``."""
    from training.logging_utils import release_free_memory, resident_mb

    blocks = [bytearray(32 * 1024) for _ in range(4000)]  # 125 MiB, touched
    for i in range(0, len(blocks) - 1, 2):
        blocks[i] = None
    before = resident_mb()
    assert release_free_memory()
    after = resident_mb()
    assert before - after > 30, (before, after)
    del blocks
