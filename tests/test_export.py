"""Export (``training.export``), its NumPy forward passes, and ``training.evaluate`` on exports:
JAX vs NumPy agreement, the scheduler's counters, a JAX-free evaluation subprocess, bad input."""

import hashlib
import json
import os
import subprocess
import sys
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig, learners
from parallel_skills import normalization as obs_norm
from parallel_skills.numpy_policy import NumpyGaussianPolicy, ScheduledPolicy, load_export
from parallel_skills.train import TrainedParams, make_policy_factory
from tasks.manipulation import layout as L
from training import evaluate
from training.export import ExportExistsError, write_export

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SKILLS = ["reach_green", "lift_arm_closed"]
CONFIG = TrainConfig(scheduler=SchedulerConfig(hidden=(16, 16), skill_lengths=(2, 3, 5)),
                     new_skill=NewSkillConfig(hidden=(16, 16)))


def _params(obs_size, action_size, num_frozen, config=CONFIG, seed=0):
    """What ``train`` returns, from freshly initialised (then perturbed) networks."""
    k = jax.random.split(jax.random.PRNGKey(seed), 5)
    obs = jnp.zeros((1, obs_size))
    new = learners.new_skill_networks(action_size, config.new_skill)[0].init(k[0], obs)
    sched = learners.scheduler_networks(num_frozen + 1, config.scheduler)[0].init(k[1], obs)

    def perturb(p, key):  # heads start at ~0: move every weight so outputs differ across observations
        leaves, tree = jax.tree.flatten(p)
        keys = jax.random.split(key, len(leaves))
        return jax.tree.unflatten(tree, [x + 1.0 * jax.random.normal(kk, x.shape) for x, kk in zip(leaves, keys)])

    stats = obs_norm.update(obs_norm.init(obs_size), jax.random.normal(k[4], (200, obs_size)) * 0.2 + 0.05)
    return TrainedParams(new_skill=perturb(new, k[2]), scheduler=perturb(sched, k[3]), normalizer=stats)


def _env(obs_size=L.OBS_SIZE, action_size=L.ACTION_SIZE):
    return types.SimpleNamespace(observation_size=obs_size, action_size=action_size)


def _digest(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture(scope="session")
def exported(tmp_path_factory):
    params = _params(L.OBS_SIZE, L.ACTION_SIZE, len(SKILLS))
    out = tmp_path_factory.mktemp("run")
    path = write_export(str(out), params, env=_env(), config=CONFIG, task="lift", physics="kinematic",
                        metadata={"skills": SKILLS, "seed": 3, "env_steps": 1234, "command": "test"})
    return path, params


def test_export_files_and_sidecar(exported):
    path, _ = exported
    out = os.path.dirname(path)
    assert sorted(os.listdir(out)) == ["export.json", "export.npz"]  # no temporary files left
    meta = json.load(open(os.path.join(out, "export.json")))
    assert (meta["task"], meta["physics"], meta["obs_size"], meta["action_size"]) == ("lift", "kinematic", 60, 5)
    assert (meta["seed"], meta["env_steps"], meta["metadata"]) == (3, 1234, {"command": "test"})
    assert meta["new_skill"]["hidden"] == [16, 16] and meta["scheduler"]["hidden"] == [16, 16]
    assert meta["scheduler"]["num_skills"] == 3 and meta["scheduler"]["skill_lengths"] == [2, 3, 5]
    assert meta["scheduler"]["skill_names"] == SKILLS + ["lift_new_skill"]
    with np.load(path) as data:
        assert "new_skill/obs_mean" in data.files and "scheduler/policy/params/head_i/kernel" in data.files


def test_jax_vs_numpy_forward(exported):
    path, params = exported
    export = load_export(path, obs_size=60, action_size=5)
    make_policy = make_policy_factory(5, CONFIG, len(SKILLS) + 1)
    stats = params.normalizer
    obs = stats.mean + obs_norm.std(stats) * 2.0 * jax.random.normal(jax.random.PRNGKey(7), (256, 60))
    obs = obs.at[:8].multiply(100.0)  # some observations beyond the ±10 clip
    keys = jax.random.split(jax.random.PRNGKey(8), 256)
    a_jax = np.asarray(jax.vmap(make_policy(params, "new_skill"))(obs, keys))
    z_jax = np.asarray(jax.vmap(make_policy(params, "scheduler"))(obs, keys))
    obs64 = np.asarray(obs, np.float64)
    diff = float(np.max(np.abs(export.new_skill(obs64) - a_jax)))
    print(f"JAX vs NumPy new-skill action max abs diff: {diff:.3g}")
    assert diff <= 1e-5
    assert np.std(a_jax) > 0.05  # not trivially constant
    z_np = export.scheduler(obs64)  # greedy (i, K[k])
    np.testing.assert_array_equal(z_np, z_jax)
    assert len(np.unique(z_np[:, 0])) > 1 and len(np.unique(z_np[:, 1])) > 1  # both heads vary
    # Logits too, against the learner's own apply.
    li, lk = learners.make_scheduler_apply(3, CONFIG.scheduler)(params.scheduler, obs_norm.normalize(stats, obs))
    li_np, lk_np = export.scheduler.logits(obs64)
    assert max(np.max(np.abs(li_np - li)), np.max(np.abs(lk_np - lk))) <= 1e-4


def test_sampled_scheduler_matches_probabilities(exported):
    export = load_export(exported[0])
    obs = np.repeat(export.new_skill.a["obs_mean"][None], 4000, axis=0)
    i, k = export.scheduler.choose(obs, np.random.default_rng(0))
    li, lk = export.scheduler.logits(obs[:1])
    for sample, logits in ((i, li[0]), (k, lk[0])):
        p = np.exp(logits - logits.max())
        p /= p.sum()
        freq = np.bincount(sample, minlength=len(p)) / len(sample)
        assert np.max(np.abs(freq - p)) < 0.03


def test_counters_run_skill_i_for_k_steps():
    """At a decision pick (i, k); skill i acts K[k] steps (docs/design.md "Scheduler and counters")."""

    class Alternating:
        calls = 0

        def choose(self, obs, rng):
            self.calls += 1
            b = obs.shape[0]
            return np.full(b, self.calls % 2), np.full(b, (self.calls - 1) % 2)  # i: 1, 0, 1, ...; k_idx: 0, 1, 0

    skills = lambda obs: np.stack([np.zeros((obs.shape[0], 1)), np.ones((obs.shape[0], 1))])  # noqa: E731
    policy = ScheduledPolicy(Alternating(), skills, skill_lengths=(2, 3))
    acted = [int(policy(np.zeros((2, 4)))[0, 0]) for _ in range(9)]
    assert acted == [1, 1, 0, 0, 0, 1, 1, 0, 0]
    assert policy.usage.tolist() == [10, 8]  # env steps per skill (2 envs)
    assert np.stack(policy.timeline).tolist() == [[a, a] for a in acted]  # the skill each env runs, per step
    policy.reset(2)
    assert policy.timeline == []
    policy.reset(2)  # a new episode is a decision whatever the counter (skill 0 had a step left)
    assert int(policy(np.zeros((2, 4)))[0, 0]) == 1 and policy.scheduler.calls == 5


def test_never_overwrites_and_validates(exported, tmp_path):
    path, params = exported
    out = os.path.dirname(path)
    before = {n: _digest(os.path.join(out, n)) for n in os.listdir(out)}
    with pytest.raises(ExportExistsError, match="already exists"):
        write_export(out, params, env=_env(), config=CONFIG, task="lift", physics="kinematic",
                     metadata={"skills": SKILLS, "seed": 0, "env_steps": 0})
    assert {n: _digest(os.path.join(out, n)) for n in os.listdir(out)} == before
    with pytest.raises(ValueError, match="lacks"):
        write_export(str(tmp_path), params, env=_env(), config=CONFIG, task="lift", physics="kinematic", metadata={})
    with pytest.raises(ValueError, match="names 1 frozen skills, but the scheduler chooses among 3"):
        write_export(str(tmp_path), params, env=_env(), config=CONFIG, task="lift", physics="kinematic",
                     metadata={"skills": SKILLS[:1], "seed": 0, "env_steps": 0})
    assert os.listdir(tmp_path) == []


def test_evaluate_mujoco_imports_no_jax(exported, tmp_path):
    """The export's new skill and a skill .npz on the classic-MuJoCo twin: NumPy only."""
    path, params = exported
    skill_path = str(tmp_path / "skill.npz")
    Skill.gaussian_mlp("s", params.new_skill_params(), 5, (16, 16), obs_size=60).save(skill_path)
    script = (
        "import sys\n"
        "from training.evaluate import main\n"
        f"for policy in ({path!r}, {skill_path!r}):\n"
        "    main(['--task', 'lift', '--physics', 'mujoco', '--policy', policy, '--episodes', '2'])\n"
        "assert 'jax' not in sys.modules, sorted(m for m in sys.modules if m.startswith('jax'))\n"
        "print('JAX-FREE')\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, PYTHONPATH=ROOT))
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[-1] == "JAX-FREE"
    assert sum(line.startswith("success=") for line in lines) == 2


def test_evaluate_scheduler_runs_scripted_skills(tmp_path, capsys):
    """``export.npz:scheduler`` whose scheduler always picks skill 0 = the scripted skill alone."""
    params = _params(L.OBS_SIZE, L.ACTION_SIZE, len(SKILLS))
    sched = jax.tree.map(lambda x: x, params.scheduler)
    head_i = sched["params"]["head_i"]
    sched["params"]["head_i"] = {"kernel": jnp.zeros_like(head_i["kernel"]),
                                 "bias": jnp.asarray([50.0, 0.0, 0.0])}
    params = params.replace(scheduler=sched)
    path = write_export(str(tmp_path), params, env=_env(), config=CONFIG, task="reach_green", physics="kinematic",
                        metadata={"skills": SKILLS, "seed": 0, "env_steps": 0})
    common = ["--task", "reach_green", "--physics", "kinematic", "--episodes", "3", "--episode_length", "20"]
    evaluate.main(common + ["--policy", path + ":scheduler", "--usage_plot", str(tmp_path / "usage.png")])
    out_sched = capsys.readouterr().out.strip().splitlines()
    assert out_sched.pop(-2) == f"usage plot: {tmp_path / 'usage.png'}" and (tmp_path / "usage.png").stat().st_size > 0
    evaluate.main(common + ["--policy", "scripted:reach_green"])
    out_scripted = capsys.readouterr().out.strip().splitlines()
    with pytest.raises(SystemExit) as e:
        evaluate.main(common + ["--policy", "scripted:reach_green", "--usage_plot", str(tmp_path / "u.png")])
    assert e.value.code == 2 and "--usage_plot needs a ':scheduler' policy" in capsys.readouterr().err
    assert out_sched[-2].startswith("skill usage") and "reach_green=1.000" in out_sched[-2]
    assert out_sched[-1] == out_scripted[-1]
    assert float(out_sched[-1].split("return=")[1]) > 0.0


def test_evaluate_scheduler_with_the_new_skills_sampled_actions(tmp_path, capsys):
    """``:scheduler --actions sampled`` samples the new skill's actions (its choices stay greedy): a
    scheduler that always picks the new skill then acts as the new skill's Gaussian, not its mean;
    a scripted policy still cannot be sampled (one line)."""
    params = _params(L.OBS_SIZE, L.ACTION_SIZE, len(SKILLS))
    sched = jax.tree.map(lambda x: x, params.scheduler)
    head_i = sched["params"]["head_i"]
    sched["params"]["head_i"] = {"kernel": jnp.zeros_like(head_i["kernel"]),
                                 "bias": jnp.asarray([0.0, 0.0, 50.0])}  # the new skill
    params = params.replace(scheduler=sched)
    path = write_export(str(tmp_path), params, env=_env(), config=CONFIG, task="reach_green", physics="kinematic",
                        metadata={"skills": SKILLS, "seed": 0, "env_steps": 0})
    common = ["--task", "reach_green", "--physics", "kinematic", "--episodes", "3", "--episode_length", "20",
              "--policy", path + ":scheduler"]
    out = {}
    for actions in ("mean", "sampled"):
        evaluate.main(common + ["--actions", actions])
        out[actions] = capsys.readouterr().out.strip().splitlines()
        assert "_new_skill=1.000" in out[actions][-2], out[actions]  # always the new skill
    assert out["sampled"][0].endswith("actions=sampled") and not out["mean"][0].endswith("actions=sampled")
    assert out["sampled"][-1] != out["mean"][-1]  # the Gaussian's noise changes the returns
    evaluate.main(common + ["--actions", "sampled"])
    assert capsys.readouterr().out.strip().splitlines()[-1] == out["sampled"][-1]  # seeded
    with pytest.raises(SystemExit) as e:
        evaluate.main(common[:-2] + ["--policy", "scripted:reach_green", "--actions", "sampled"])
    assert e.value.code == 2 and "--actions sampled needs a Gaussian-MLP policy" in capsys.readouterr().err


def test_evaluate_scheduler_sampled_decisions_and_collection_noise(tmp_path, capsys):
    """``:scheduler --decisions sampled`` draws the choices from the scheduler's heads (a uniform
    scheduler's argmax is always skill 0, its samples spread over every skill), ``--skill_noise``
    perturbs the frozen skills' actions (seeded); both only for a scheduler, one line each."""
    params = _params(L.OBS_SIZE, L.ACTION_SIZE, len(SKILLS))
    sched = jax.tree.map(lambda x: x, params.scheduler)
    for head in ("head_i", "head_k"):
        sched["params"][head] = jax.tree.map(jnp.zeros_like, sched["params"][head])  # uniform choices
    params = params.replace(scheduler=sched)
    path = write_export(str(tmp_path), params, env=_env(), config=CONFIG, task="reach_green", physics="kinematic",
                        metadata={"skills": SKILLS, "seed": 0, "env_steps": 0})
    common = ["--task", "reach_green", "--physics", "kinematic", "--episodes", "4", "--episode_length", "40",
              "--policy", path + ":scheduler"]

    def lines(extra):
        evaluate.main(common + extra)
        return capsys.readouterr().out.strip().splitlines()

    greedy, sampled = lines([]), lines(["--decisions", "sampled"])
    usage = lambda out: dict(kv.split("=") for kv in out[-2].split(": ")[1].split())  # noqa: E731
    assert usage(greedy)[SKILLS[0]] == "1.000"  # argmax of equal logits: the first skill
    assert all(float(v) > 0 for v in usage(sampled).values()), sampled[-2]  # every skill is chosen
    assert sampled[0].endswith("decisions=sampled") and lines(["--decisions", "sampled"]) == sampled  # seeded
    noisy = lines(["--skill_noise", "0.3"])
    assert noisy[0].endswith("skill_noise=0.3") and usage(noisy) == usage(greedy)
    assert noisy[-1] != greedy[-1] and lines(["--skill_noise", "0.3"]) == noisy  # perturbed, seeded
    assert "--decisions must be one of greedy, sampled, got 'soft'" in _bad(common + ["--decisions", "soft"], capsys)
    assert "--skill_noise must be a finite std >= 0" in _bad(common + ["--skill_noise", "-1"], capsys)
    assert "apply to a scheduler" in _bad(common[:-1] + [path, "--decisions", "sampled"], capsys)


def test_evaluate_scheduler_runs_library_and_skill_dir_skills(tmp_path, capsys):
    """An export of a run with neural skills (``--skill_source library`` / ``--skill_dir``) runs those
    files under ``:scheduler`` (NumPy, on the JAX-free twin here), not the scripted controllers of the
    same names; a skill file changed since the run is one error line."""
    import shutil

    from training import skill_library
    from training.run_files import skill_sources

    own = tmp_path / "skills"
    own.mkdir()
    for ext in ("npz", "json"):  # a user's lift_arm_closed: here the shipped reach_green's network
        shutil.copy(os.path.join(ROOT, "checkpoints", "kinematic", f"reach_green.{ext}"), own / f"lift_arm_closed.{ext}")
    skills = skill_library.load_skills(SKILLS, "kinematic", "library", L.OBS_SIZE, L.ACTION_SIZE, skill_dir=str(own))
    sources = skill_sources(skills, "kinematic")
    assert [e["source"] for e in sources] == ["library", "skill_dir"] and sources[0]["library"] == "kinematic"
    assert sources[1]["path"] == str(own / "lift_arm_closed.npz") and "path" not in sources[0]  # no machine path

    params = _params(L.OBS_SIZE, L.ACTION_SIZE, len(SKILLS))
    runs = {}
    for pick in (0, 1):  # a scheduler that always picks skill `pick`
        sched = jax.tree.map(lambda x: x, params.scheduler)
        head_i = sched["params"]["head_i"]
        sched["params"]["head_i"] = {"kernel": jnp.zeros_like(head_i["kernel"]),
                                     "bias": jnp.asarray([50.0 if j == pick else 0.0 for j in range(3)])}
        out = tmp_path / f"run{pick}"
        runs[pick] = write_export(str(out), params.replace(scheduler=sched), env=_env(), config=CONFIG,
                                  task="reach_green", physics="kinematic",
                                  metadata={"skills": SKILLS, "skill_sources": sources, "seed": 0, "env_steps": 0})
    common = ["--task", "reach_green", "--physics", "mujoco", "--episodes", "3", "--episode_length", "30"]
    results = []
    for pick in (0, 1):
        evaluate.main(common + ["--policy", runs[pick] + ":scheduler"])
        results.append(capsys.readouterr().out.strip().splitlines())
    evaluate.main(common + ["--policy", os.path.join(ROOT, "checkpoints", "kinematic", "reach_green.npz")])
    alone = capsys.readouterr().out.strip().splitlines()[-1]
    scripted = []
    for name in SKILLS:
        evaluate.main(common + ["--policy", f"scripted:{name}"])
        scripted.append(capsys.readouterr().out.strip().splitlines()[-1])
    # Both the library skill and the skill_dir file are reach_green's network: the same episodes,
    # not those of the scripted controllers of the same names.
    assert results[0][-1] == results[1][-1] == alone and alone not in scripted
    assert "reach_green=1.000" in results[0][-2] and "lift_arm_closed=1.000" in results[1][-2]

    with open(own / "lift_arm_closed.npz", "ab") as f:
        f.write(b"\0")
    err = _bad(common + ["--policy", runs[1] + ":scheduler"], capsys)
    assert "lift_arm_closed.npz changed since the run" in err


@pytest.fixture(scope="session")
def mismatched(tmp_path_factory):
    """An export for observations of size 7 (not the manipulation tasks' 60)."""
    out = tmp_path_factory.mktemp("mismatch")
    return write_export(str(out), _params(7, L.ACTION_SIZE, 0), env=_env(obs_size=7), config=CONFIG,
                        task="other", physics="kinematic", metadata={"skills": [], "seed": 0, "env_steps": 0})


def _bad(argv, capsys):
    with pytest.raises(SystemExit) as e:
        evaluate.main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert len(err.strip().splitlines()) == 1 and err.startswith("error: ") and "Traceback" not in err
    return err


@pytest.mark.parametrize("physics", ["mujoco", "kinematic"])
def test_evaluate_bad_input(exported, mismatched, tmp_path, capsys, physics):
    path, _ = exported
    truncated = tmp_path / "trunc"
    truncated.mkdir()
    for name in ("export.npz", "export.json"):
        (truncated / name).write_bytes(open(os.path.join(os.path.dirname(path), name), "rb").read())
    with open(truncated / "export.npz", "r+b") as f:
        f.truncate(200)
    files = [path, str(truncated / "export.npz"), mismatched]
    before = [_digest(f) for f in files]
    base = ["--task", "lift", "--physics", physics, "--episodes", "1", "--episode_length", "2", "--policy"]
    assert "does not exist" in _bad(base + [str(tmp_path / "missing" / "export.npz")], capsys)
    assert "corrupt or truncated" in _bad(base + [str(truncated / "export.npz")], capsys)
    assert "corrupt or truncated" in _bad(base + [str(truncated / "export.npz") + ":scheduler"], capsys)
    assert "expects observations of size 7, the task gives 60" in _bad(base + [mismatched], capsys)
    assert "expects observations of size 7" in _bad(base + [mismatched + ":scheduler"], capsys)
    err = _bad(base + [path + ":schedular"], capsys)
    assert "unknown --policy suffix ':schedular'" in err and ":scheduler" in err
    assert [_digest(f) for f in files] == before
    assert sorted(os.listdir(os.path.dirname(path))) == ["export.json", "export.npz"]


def test_numpy_skill_load_checks_sizes(exported, tmp_path):
    _, params = exported
    skill_path = str(tmp_path / "s.npz")
    Skill.gaussian_mlp("s", params.new_skill_params(), 5, (16, 16), obs_size=60).save(skill_path)
    with pytest.raises(ValueError, match="expects observations of size 60, the task gives 59"):
        NumpyGaussianPolicy.load(skill_path, obs_size=59)
    meta = json.load(open(tmp_path / "s.json"))
    json.dump(dict(meta, hidden=[16, 32]), open(tmp_path / "s.json", "w"))  # sidecar disagrees with the arrays
    with pytest.raises(ValueError, match="has shape"):
        NumpyGaussianPolicy.load(skill_path)


def test_evaluate_a_run_directory_and_a_library_skill(exported, tmp_path, capsys):
    """``--policy DIR`` (a training.run directory: its export, ``DIR:scheduler`` too) and
    ``--policy library:NAME`` (a shipped skill, found through the installed package)."""
    import json
    import shutil

    from training.rundir import RunRecord, create

    path, _ = exported
    run = tmp_path / "run"
    record = RunRecord(command="test", task="lift", physics="kinematic", skill_set="useful", skill_source="scripted",
                       skill_dir=None, skills=SKILLS, seed=0, num_timesteps=1, episode_length=None,
                       checkpoint_every=None, replay_checkpoint=True, video=False, train_config={})
    create(str(run), record)
    assert json.loads((run / "config.json").read_text())["skills"] == SKILLS
    base = ["--task", "lift", "--physics", "kinematic", "--episodes", "2", "--episode_length", "5", "--policy"]
    assert "has not finished" in _bad(base + [str(run)], capsys)
    for name in ("export.npz", "export.json"):
        shutil.copy(os.path.join(os.path.dirname(path), name), run / name)
    for suffix in ("", ":scheduler"):
        evaluate.main(base + [str(run) + suffix])
        by_dir = capsys.readouterr().out.strip().splitlines()[-1]
        evaluate.main(base + [path + suffix])
        assert capsys.readouterr().out.strip().splitlines()[-1] == by_dir
    evaluate.main(base + ["library:reach_green"])
    by_name = capsys.readouterr().out.strip().splitlines()[-1]
    evaluate.main(base + [os.path.join(ROOT, "checkpoints", "kinematic", "reach_green.npz")])
    assert capsys.readouterr().out.strip().splitlines()[-1] == by_name
    err = _bad(base + ["library:no_such_skill"], capsys)
    assert "no skill 'no_such_skill' in the kinematic library" in err and "reach_green" in err


@pytest.mark.parametrize("physics", ["mujoco", "kinematic"])
def test_evaluate_sampled_actions(exported, capsys, physics):
    """``--actions sampled``: the new skill acting with actions drawn from its Gaussian (as collected),
    the same numbers for the same seed, others than its mean action's; one-line errors for a scripted
    policy and for an unknown choice (``:scheduler``: its new skill's, the test below)."""
    path, _ = exported  # reach_green: a shaped reward, so returns tell the actions apart within 6 steps
    base = ["--task", "reach_green", "--physics", physics, "--episodes", "3", "--episode_length", "6", "--policy", path]

    def last_line(args):
        evaluate.main(base + args)
        return capsys.readouterr().out.strip().splitlines()[-1]

    mean = last_line([])
    sampled = last_line(["--actions", "sampled"])
    assert sampled == last_line(["--actions", "sampled"])
    assert sampled != mean and sampled.startswith("success=")
    assert last_line(["--actions", "sampled", "--seed", "1"]) != sampled
    assert "--actions must be one of mean, sampled, got 'noisy'" in _bad(base + ["--actions", "noisy"], capsys)
    assert "needs a Gaussian-MLP policy" in _bad(base[:-1] + ["scripted:lift_green", "--actions", "sampled"], capsys)


def test_evaluate_start_states(exported, capsys):
    """``--start_states mixed`` (kinematic): other resets, so other returns than the paper's; the
    MuJoCo twin and an unknown name are one line."""
    path, _ = exported
    base = ["--task", "reach_green", "--episodes", "4", "--episode_length", "6", "--policy", path]

    def last_line(args):
        evaluate.main(base + args)
        return capsys.readouterr().out.strip().splitlines()[-1]

    assert last_line(["--start_states", "mixed"]) != last_line([]) == last_line(["--start_states", "table"])
    err = _bad(base + ["--start_states", "tower"], capsys)
    assert "start_states must be one of table, mixed, or TOP_on_BOTTOM" in err and "got 'tower'" in err
    assert "MuJoCo twin resets with 'table' only" in _bad(base + ["--physics", "mujoco", "--start_states", "mixed"],
                                                          capsys)
