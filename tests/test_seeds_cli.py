"""training.run --seeds: several seeds in one vmapped process, one run directory each; a seed's
metrics match a single run of it; the group resumes and extends together."""

import csv
import json
import os

import numpy as np
import pytest

from training.run import main

TINY = {"num_envs": 4, "unroll_length": 5, "replay_size": 200, "eval_episodes": 2,
        "scheduler": {"skill_lengths": [2, 3], "hidden": [16], "critic_head_hidden": [8], "batch_size": 8,
                      "min_replay_size": 10, "samples_per_insert": 2.0},
        "new_skill": {"hidden": [16], "batch_size": 8, "min_replay_size": 10, "samples_per_insert": 2.0}}
STEPS = 60  # 3 iterations of 4 envs x 5 steps


def _rows(d):
    with open(os.path.join(d, "metrics.csv"), newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def group(tmp_path_factory):
    ws = tmp_path_factory.mktemp("seeds")
    cfg = ws / "tiny.json"
    cfg.write_text(json.dumps(TINY))
    out = str(ws / "group")
    main(["--seeds", "0,1", "--config", str(cfg), "--num_timesteps", str(STEPS), "--eval_every", "1", "--out", out])
    return ws, cfg, out


def test_each_seed_writes_its_own_run_directory(group):
    _, _, out = group
    assert json.load(open(os.path.join(out, "seeds.json")))["runs"] == ["s0", "s1"]
    for s in (0, 1):
        d = os.path.join(out, f"s{s}")
        record = json.load(open(os.path.join(d, "config.json")))
        assert record["seed"] == s and "--seeds 0,1" in record["command"]
        assert len(_rows(d)) == 3
        for name in ("export.json", "new_skill.npz", "checkpoints"):
            assert os.path.exists(os.path.join(d, name)), name


def test_a_seed_matches_its_single_run(group):
    ws, cfg, out = group
    single = str(ws / "single1")
    main(["--seed", "1", "--config", str(cfg), "--num_timesteps", str(STEPS), "--eval_every", "1", "--out", single])
    got, want = _rows(os.path.join(out, "s1")), _rows(single)
    assert len(got) == len(want) == 3
    for g, w in zip(got, want):
        for k in ("env_steps", "eval/new_skill_success", "eval/new_skill_return", "eval/scheduler_success",
                  "eval/scheduler_return", "scheduler/critic_loss", "new_skill/critic_loss", "new_skill/q_mean"):
            np.testing.assert_allclose(float(g[k]), float(w[k]), rtol=1e-4, atol=1e-6, err_msg=k)


def test_the_group_resumes_and_extends_together(group, capsys):
    _, _, out = group
    main(["--resume", "--out", out, "--num_timesteps", str(2 * STEPS)])
    for s in (0, 1):
        d = os.path.join(out, f"s{s}")
        rows = _rows(d)
        assert len(rows) == 6 and float(rows[-1]["env_steps"]) == 2 * STEPS
        assert json.load(open(os.path.join(d, "config.json")))["num_timesteps"] == 2 * STEPS
        assert os.path.isdir(os.path.join(d, f"before_extension_{STEPS}"))


@pytest.mark.parametrize("argv,needle", [
    (["--seeds", "0,1", "--seed", "2"], "--seed and --seeds"),
    (["--seeds", "0,0"], "distinct"),
    (["--seeds", "a"], "--seeds must be"),
])
def test_bad_seeds(tmp_path, capsys, argv, needle):
    with pytest.raises(SystemExit) as e:
        main(argv + ["--out", str(tmp_path / "g")])
    assert e.value.code == 2 and needle in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "g")
