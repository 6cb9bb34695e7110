"""Beyond one device (parallel_skills.sharding): the data-parallel iteration on 2 forced host devices
matches the one-device run, a checkpoint taken on the mesh restores onto it (and onto one device), two processes on
loopback (jax.distributed, gloo) train together with process 0 alone writing the run directory,
and bad mesh inputs are one line with exit code 2.

Device counts are fixed when JAX starts, so these run in subprocesses
(``XLA_FLAGS=--xla_force_host_platform_device_count=2``)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import pytest

from training.run import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY = {"num_envs": 4, "unroll_length": 5, "replay_size": 200, "eval_episodes": 2,
        "scheduler": {"skill_lengths": [2, 3], "hidden": [16], "critic_head_hidden": [8], "batch_size": 8,
                      "min_replay_size": 10, "samples_per_insert": 2.0},
        "new_skill": {"hidden": [16], "batch_size": 8, "min_replay_size": 10, "samples_per_insert": 2.0}}
# The one-device run and the 2-device run compute the same float32 program except that each
# gradient is the sum of two per-device partial sums (the cross-device all-reduce) instead of one
# sum over the batch: float summation order, a few ulps per update. Measured after 3 iterations:
# metrics within 5e-7, parameters within 1.2e-7.
TOLERANCE = 1e-5


def _env(devices: int = 1, **extra) -> dict:
    import jax

    env = dict(os.environ, PYTHONPATH=ROOT, JAX_COMPILATION_CACHE_DIR=jax.config.jax_compilation_cache_dir, **extra)
    if devices > 1:
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={devices}").strip()
    env.pop("JAX_PLATFORMS", None)
    return env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.timeout(900)
def test_two_devices_match_one_device_and_resume_on_the_mesh():
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "tests", "two_device_worker.py")], cwd=ROOT,
                          env=_env(2), capture_output=True, text=True, timeout=880)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["devices"] == 2
    assert "scheduler/critic_loss" in out["metric_keys"] and "new_skill/critic_loss" in out["metric_keys"]
    assert out["metrics_max_abs_diff"] < TOLERANCE, out
    assert out["params_max_abs_diff"] < TOLERANCE and out["scheduler_max_abs_diff"] < TOLERANCE, out
    # The env batch is split over the devices (the n-step window along its env axis), the
    # parameters are replicated.
    assert out["actor_sharding"] == "P('data',)", out
    assert out["pending_sharding"] == "P(None, 'data')", out
    assert out["params_sharding"] == "P()", out
    # Saved on 2 devices, restored onto them: the continuation is the uninterrupted run, bit for bit.
    assert out["restored_actor_sharding"] == "P('data',)" and out["restored_on_mesh"], out
    assert out["resume_bitwise"] and out["resume_params_max_abs_diff"] == 0.0, out
    # ... and restored onto one device (another mesh), it continues as the 2-device run does.
    assert out["one_device_resume_metrics_max_abs_diff"] < TOLERANCE, out


@pytest.mark.timeout(900)
def test_two_processes_train_together_and_process_0_alone_writes(tmp_path):
    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps(TINY))
    out = tmp_path / "run"
    port = _free_port()
    procs, cwds = [], []
    for i in (0, 1):
        cwd = tmp_path / f"cwd{i}"  # each process's own working directory: nothing may land there
        cwd.mkdir()
        cwds.append(cwd)
        args = ["--config", str(cfg), "--num_timesteps", "60", "--eval_every", "1", "--out", str(out),
                "--coordinator", f"127.0.0.1:{port}", "--num_processes", "2", "--process_id", str(i),
                "--coordinator_timeout", "120"]
        # The two processes' wall clocks disagree about whether a checkpoint is due (process 0: at
        # every evaluation; process 1: only at the end), as they may on a loaded machine: the
        # checkpoints are collectives, so the processes must take process 0's decision.
        spacing = 0.0 if i == 0 else 1e9
        cmd = [sys.executable, "-c", "import sys; import training.run_files as f; "
               f"f.CHECKPOINT_MIN_SECONDS = {spacing}; import training.run as r; sys.exit(r.main({args!r}))"]
        procs.append(subprocess.Popen(cmd, cwd=str(cwd), env=_env(1), stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True))
    results = [p.communicate(timeout=840) for p in procs]
    for p, (stdout, stderr) in zip(procs, results):
        assert p.returncode == 0, stderr[-3000:]
    digests = [[line for line in stdout.splitlines() if "parameters sha256" in line] for stdout, _ in results]
    assert [len(d) for d in digests] == [1, 1], digests
    assert digests[0][0].split()[-1] == digests[1][0].split()[-1], digests  # the replicas agree
    assert "devices: 2 in 2 processes" in results[0][0]
    # Process 1 prints its digest and nothing of the run's progress or outputs (gloo's own
    # connection line aside).
    assert [line for line in results[1][0].splitlines()
            if "parameters sha256" not in line and not line.startswith("[Gloo]")] == []
    assert all(not any(c.iterdir()) for c in cwds)
    with open(out / "metrics.csv") as f:
        assert len(f.read().strip().splitlines()) == 1 + 3  # header + 3 evaluations, written once
    for name in ("config.json", "export.json", "new_skill.npz", "checkpoints"):
        assert (out / name).exists(), name
    assert len(list(out.glob("events.out.tfevents.*"))) == 1  # one TensorBoard writer


def test_process_id_out_of_range_is_one_line(tmp_path, capsys):
    argv = ["--out", str(tmp_path / "run"), "--coordinator", "127.0.0.1:1", "--num_processes", "2"]
    for pid in ("2", "5"):
        with pytest.raises(SystemExit) as e:
            main(argv + ["--process_id", pid])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"process_id {pid} is out of range: use 0 .. 1" in err[0], err
    for bad, needle in ((["--out", "x", "--coordinator", "nohostport", "--num_processes", "2", "--process_id", "0"],
                         "must be HOST:PORT"),
                        (["--out", "x", "--coordinator", "127.0.0.1:1"], "needs --num_processes and --process_id"),
                        (["--out", "x", "--num_processes", "2", "--process_id", "0"], "need --coordinator"),
                        (["--coordinator", "127.0.0.1:1", "--num_processes", "2", "--process_id", "0"],
                         "needs --out DIR")):
        with pytest.raises(SystemExit) as e:
            main(bad)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0], (bad, err)
    assert not (tmp_path / "run").exists() and not os.path.exists("x")


def _cli(args, cwd, devices=1, timeout=120):
    return subprocess.run([sys.executable, "-m", "training.run", *args], cwd=str(cwd), env=_env(devices),
                          capture_output=True, text=True, timeout=timeout)


def test_num_envs_not_dividing_by_the_devices_is_one_line(tmp_path):
    proc = _cli(["--num_envs", "3", "--num_timesteps", "60", "--out", str(tmp_path / "run")], tmp_path, devices=2)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1, proc.stderr
    assert "num_envs 3 does not divide by the 2 devices" in err[0], err
    assert not (tmp_path / "run").exists()


def test_unreachable_coordinator_times_out_in_one_line(tmp_path):
    port = _free_port()  # nobody listens there
    proc = _cli(["--out", str(tmp_path / "run"), "--coordinator", f"127.0.0.1:{port}", "--num_processes", "2",
                 "--process_id", "1", "--coordinator_timeout", "2"], tmp_path)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1, proc.stderr
    assert f"coordinator 127.0.0.1:{port} unreachable: no answer within 2 s" in err[0], err
    assert not (tmp_path / "run").exists()


def test_distributed_without_a_cluster_is_one_line(tmp_path):
    env_keys = [k for k in os.environ if k.startswith(("SLURM_", "OMPI_", "PMI_"))]
    if env_keys:
        pytest.skip(f"running inside a cluster job ({env_keys[0]} is set)")
    proc = _cli(["--out", str(tmp_path / "run"), "--distributed"], tmp_path)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1, proc.stderr
    assert "--distributed found no cluster in the environment" in err[0], err
    assert not (tmp_path / "run").exists()
