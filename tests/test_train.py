"""SkillS training loop: acting-step counters across resets, transfer guard, seeds, determinism."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import tasks
from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig
from parallel_skills.train import make_trainer
from tasks.manipulation import scripted

SMALL = TrainConfig(
    num_envs=4, unroll_length=5, replay_size=2000, eval_episodes=2, eval_every=1,
    scheduler=SchedulerConfig(skill_lengths=(2, 3), hidden=(32, 32), critic_head_hidden=(16,), batch_size=16,
                              min_replay_size=10, samples_per_insert=4.0),
    new_skill=NewSkillConfig(hidden=(32, 32), batch_size=16, min_replay_size=10, samples_per_insert=4.0),
)


def _skills():
    return [Skill.from_fn(n, scripted.get(n)) for n in ("reach_green", "lift_arm_closed")]


@pytest.fixture(scope="session")
def small_trainer():
    env = tasks.make("lift", episode_length=7)
    trainer = make_trainer(env, _skills(), SMALL)
    return env, trainer, jax.jit(trainer.init), jax.jit(trainer.iteration)


def test_acting_counters_across_auto_reset(small_trainer):
    env, trainer, init, _ = small_trainer
    state = init(jax.random.PRNGKey(0))
    act = jax.jit(trainer.actor.step)
    actor = state.actor
    lengths = np.array(SMALL.scheduler.skill_lengths)
    prev_c = np.zeros(4, int)
    prev_first = np.ones(4, bool)
    prev_i = prev_k = None
    for t in range(20):
        actor, tr, st = act(actor, state.scheduler.policy_params, state.new_skill.policy_params, state.normalizer,
                            jax.random.PRNGKey(t))
        c, dec, i, k = (np.asarray(x) for x in (tr.c, tr.is_decision, tr.skill, tr.k_idx))
        expected_dec = prev_first | (prev_c <= 1)
        np.testing.assert_array_equal(dec, expected_dec)
        np.testing.assert_array_equal(c[dec], lengths[k[dec]])  # a decision sets c = k
        if prev_i is not None:
            np.testing.assert_array_equal(c[~dec], prev_c[~dec] - 1)  # otherwise count down
            np.testing.assert_array_equal(i[~dec], prev_i[~dec])
            np.testing.assert_array_equal(k[~dec], prev_k[~dec])
        done = np.asarray(st.done)
        assert done.any() == ((t + 1) % 7 == 0)  # episode length 7, synchronous envs
        np.testing.assert_array_equal(np.asarray(actor.first), done)  # a reset forces a decision next
        # Truncation bootstraps: discount stays 1 at the time limit.
        np.testing.assert_array_equal(np.asarray(tr.discount), 1.0)
        prev_c, prev_first, prev_i, prev_k = c, np.asarray(actor.first), i, k


def test_iterations_under_transfer_guard(small_trainer):
    _, trainer, init, iteration = small_trainer
    state = init(jax.random.PRNGKey(1))
    state, _ = iteration(state)  # compile outside the guard
    with jax.transfer_guard("disallow"):
        for _ in range(3):
            state, metrics = iteration(state)
    assert int(state.env_steps) == 4 * trainer.steps_per_iteration
    # The learners ran (replay above its minimum) and produced finite losses.
    m = jax.device_get(metrics)
    assert m["new_skill/critic_loss"] > 0 and np.isfinite(m["new_skill/critic_loss"])
    assert m["scheduler/critic_loss"] > 0 and np.isfinite(m["scheduler/critic_loss"])


def test_same_seed_same_numbers_and_vmap_over_seeds(small_trainer):
    _, trainer, init, iteration = small_trainer

    def run(seed, n=2):
        s = init(jax.random.PRNGKey(seed))
        for _ in range(n):
            s, m = iteration(s)
        return s, m

    s_a, m_a = run(3)
    s_b, m_b = run(3)
    for k in m_a:
        np.testing.assert_array_equal(np.asarray(m_a[k]), np.asarray(m_b[k]))
    s_c, _ = run(4)

    keys = jnp.stack([jax.random.PRNGKey(3), jax.random.PRNGKey(4)])
    v_init, v_iter = jax.jit(jax.vmap(trainer.init)), jax.jit(jax.vmap(trainer.iteration))
    vs = v_init(keys)
    for _ in range(2):
        vs, vm = v_iter(vs)
    # Each vmapped seed matches its own single-seed run.
    for idx, single in ((0, s_a), (1, s_c)):
        np.testing.assert_allclose(
            np.asarray(vs.actor.env_state.obs[idx]), np.asarray(single.actor.env_state.obs), atol=1e-5)
        leaves_v = jax.tree.leaves(jax.tree.map(lambda x: x[idx], vs.new_skill.policy_params))
        leaves_s = jax.tree.leaves(single.new_skill.policy_params)
        for a, b in zip(leaves_v, leaves_s):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-4)
    assert not np.allclose(np.asarray(vs.actor.env_state.obs[0]), np.asarray(vs.actor.env_state.obs[1]))


def test_train_entry_point_returns_policies():
    from parallel_skills import train

    env = tasks.make("lift", episode_length=10)
    seen, steps, saved = [], [], []
    cfg = dataclasses.replace(SMALL, eval_every=2)
    make_policy, params, metrics = train(env, _skills(), num_timesteps=60, seed=0, config=cfg,
                                         progress_fn=lambda n, m: seen.append(n), step_fn=steps.append,
                                         checkpoint_fn=lambda s, h: saved.append(h["env_steps"]),
                                         checkpoint_min_seconds=3600.0)
    assert seen and seen[-1] == metrics["env_steps"] >= 60
    assert len(seen) > 1 and saved == [seen[-1]]  # evaluations within the hour: only the final checkpoint
    spi = SMALL.num_envs * SMALL.unroll_length  # step_fn: after every iteration
    assert steps == [spi * (i + 1) for i in range(len(steps))] and steps[-1] == metrics["env_steps"]
    assert set(seen) <= set(steps)
    obs = env.reset(jax.random.PRNGKey(0)).obs
    a = make_policy(params, "new_skill")(obs, jax.random.PRNGKey(1))
    assert a.shape == (5,) and np.all(np.abs(np.asarray(a)) <= 1)
    z = make_policy(params, "scheduler")(obs, jax.random.PRNGKey(1))
    assert int(z[0]) in (0, 1, 2) and int(z[1]) in SMALL.scheduler.skill_lengths
    for key in ("eval/new_skill_success", "eval/scheduler_success", "skill_histogram", "new_skill_selection_rate"):
        assert key in metrics
    with pytest.raises(ValueError, match="num_timesteps must be a positive integer"):
        train(env, _skills(), num_timesteps=0, config=cfg)


def test_nonfinite_transitions_are_masked():
    """A physics blow-up (NaN observation) resets that env and never reaches the learners."""
    from brax.envs.base import Wrapper

    class Exploding(Wrapper):
        def step(self, state, action):
            nxt = self.env.step(state, action)
            bad = nxt.info["steps"] == 3
            return nxt.replace(obs=jnp.where(bad, jnp.nan, nxt.obs), reward=jnp.where(bad, jnp.nan, nxt.reward))

    env = Exploding(tasks.make("lift", episode_length=7))
    trainer = make_trainer(env, _skills(), SMALL)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    it = jax.jit(trainer.iteration)
    for _ in range(3):
        state, m = it(state)
    exp = state.replay.experience
    n = int(state.replay.current_index)
    for key in ("obs", "next_obs", "reward"):
        assert np.all(np.isfinite(np.asarray(getattr(exp, key)[0, :n])))
    assert np.all(np.isfinite(np.asarray(state.normalizer.mean)))
    leaves = jax.tree.leaves(state.new_skill.policy_params) + jax.tree.leaves(state.scheduler.critic_params)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in leaves)
    # The blown-up transitions carry weight 0.
    w = np.asarray(exp.weight[0, :n])
    # Each env blows up at its 3rd step after every reset: global steps 3, 6, 9, 12, 15.
    assert (w == 0).sum() == 4 * 5


def test_nan_reset_steps_are_dropped_and_force_a_decision(small_trainer):
    """A physics backend that restarted a blown-up env in place (``info["nan_reset"]``, as the MuJoCo
    and MJX envs do) stored that step as weight 0 and makes the scheduler decide at the next one."""
    from brax.envs.base import Wrapper

    class Restarting(Wrapper):
        def reset(self, rng):
            state = self.env.reset(rng)
            return state.replace(info=dict(state.info, nan_reset=jnp.zeros(())))

        def step(self, state, action):
            nxt = self.env.step(state, action)
            return nxt.replace(info=dict(nxt.info, nan_reset=(nxt.info["steps"] == 3).astype(jnp.float32)))

    _, trainer, init, _ = small_trainer
    env = Restarting(tasks.make("lift", episode_length=7))
    actor = dataclasses.replace(trainer.actor, env=env)
    state = init(jax.random.PRNGKey(0))
    step = jax.jit(actor.step)
    a = actor.reset(jax.random.PRNGKey(1))
    for t in range(6):
        a, tr, st = step(a, state.scheduler.policy_params, state.new_skill.policy_params, state.normalizer,
                         jax.random.PRNGKey(t))
        restarted = t == 2  # the env's 3rd step
        np.testing.assert_array_equal(np.asarray(tr.weight), 0.0 if restarted else 1.0)
        np.testing.assert_array_equal(np.asarray(a.first), restarted)  # the next step decides
        if t == 3:
            assert np.asarray(tr.is_decision).all()
        assert not np.asarray(st.done).any()  # the episode goes on


def test_cpu_recipe_applies_only_to_learner_configs_left_at_paper_defaults():
    from parallel_skills.config import RECIPE_SIZES, recipe_values, resolve

    cpu = recipe_values("cpu", 32, 25)
    cfg, notes = resolve(TrainConfig(), backend="cpu")
    assert cfg.recipe == "cpu" and (cfg.num_envs, cfg.replay_size) == RECIPE_SIZES[("cpu", True)]
    for (learner, field), value in cpu.items():
        assert getattr(getattr(cfg, learner), field) == value, (learner, field)
    assert cfg.new_skill.n_step == 10 and cfg.new_skill.samples_per_insert == 16.0 and cfg.scheduler.n_step == 10
    assert len(notes) == 5  # every automatic choice is logged: recipe, 2 sizes, 2 learners
    mine = TrainConfig(num_envs=8, new_skill=NewSkillConfig(samples_per_insert=16.0))
    cfg, notes = resolve(mine, backend="cpu")
    assert cfg.num_envs == 8 and cfg.new_skill == mine.new_skill  # the user's choices stand
    assert cfg.scheduler.samples_per_insert == cpu[("scheduler", "samples_per_insert")]
    assert resolve(cfg, backend="cpu")[0] == cfg  # a resolved config is left as it is
    paper, _ = resolve(TrainConfig(recipe="paper"), backend="cpu")
    assert paper.scheduler == SchedulerConfig() and paper.new_skill == NewSkillConfig() and paper.num_envs == 32


def test_accelerator_default_is_the_parallel_recipe_with_at_most_32_updates_per_iteration():
    """The issue's bound: resolved for an accelerator, the defaults run ≤ 32 learner updates per
    iteration whatever the number of envs, with batches that grow with the envs."""
    from parallel_skills.config import learner_schedule, resolve

    gpu, notes = resolve(TrainConfig(), backend="gpu")
    assert gpu.recipe == "parallel" and gpu.num_envs == 4096 and gpu.unroll_length == 1
    assert "recipe=parallel" in notes
    for envs in (None, 1024, 4096, 16384, 65536):
        cfg, _ = resolve(TrainConfig(num_envs=envs), backend="gpu")
        s = learner_schedule(cfg)
        assert s["scheduler"]["updates_per_iteration"] + s["new_skill"]["updates_per_iteration"] <= 32
        assert s["scheduler"]["batch_size"] == cfg.num_envs * 25 // 8 and s["new_skill"]["batch_size"] == cfg.num_envs
        # Within 4x of the paper's samples per env step (scheduler 100, new skill 50).
        assert s["scheduler"]["samples_per_env_step"] == 25.0 and s["new_skill"]["samples_per_env_step"] == 24.0
        assert s["scheduler"]["updates_per_iteration"] == 8 and s["new_skill"]["updates_per_iteration"] == 24
        assert resolve(cfg, backend="gpu")[0] == cfg
    # Selectable on a CPU (1,024 envs by default there); the paper's settings stay reachable.
    par, _ = resolve(TrainConfig(recipe="parallel"), backend="cpu")
    assert par.num_envs == 1024 and learner_schedule(par)["new_skill"]["updates_per_iteration"] == 24
    assert par.new_skill.num_critics == 2 and gpu.new_skill.num_critics == 2  # clipped double Q (docs/research/scaling.md)
    assert resolve(TrainConfig(), backend="cpu")[0].new_skill.num_critics == 1  # the cpu recipe: one, as the paper
    paper, _ = resolve(TrainConfig(recipe="paper"), backend="gpu")
    assert learner_schedule(paper)["scheduler"]["updates_per_iteration"] == 80_000
    with pytest.raises(ValueError, match="recipe must be one of cpu, parallel, paper"):
        TrainConfig(recipe="fast")


def test_cpu_recipe_fills_the_fields_a_config_file_leaves():
    """training.run knows which fields its config file set (``given``): each recipe field it left
    takes the CPU recipe, whatever else the file set; what it set stands, paper values included."""
    from parallel_skills.config import resolve

    mine = TrainConfig(scheduler=SchedulerConfig(samples_per_insert=100.0), new_skill=NewSkillConfig(n_step=3))
    cfg, notes = resolve(mine, backend="cpu", given=["new_skill.n_step", "scheduler.samples_per_insert"])
    assert cfg.new_skill.n_step == 3 and cfg.new_skill.samples_per_insert == 16.0
    assert cfg.new_skill.crr_mode == "exp"  # the paper's, which the CPU recipe keeps
    assert cfg.scheduler.samples_per_insert == 100.0  # set (to the paper's value) in the file: kept
    assert cfg.scheduler.policy_warmup_updates == 1500
    assert "scheduler policy_warmup_updates=1500 (paper 0), n_step=10 (paper 1)" in notes
    assert "new-skill samples_per_insert=16 (paper 50)" in notes and "crr_mode" not in " ".join(notes)
    # Without ``given`` (a config built in code) a changed learner config is the user's: no recipe.
    assert resolve(mine, backend="cpu")[0].new_skill == mine.new_skill


def test_training_episode_stats_are_nan_when_no_episode_ended():
    """An evaluation interval shorter than an episode has no training episode to average: NaN (shown as
    n/a), not a success of 0."""
    from parallel_skills.train import EpisodeAccumulator
    from training.logging_utils import Progress

    m = {k: np.zeros(3) if k.endswith("histogram") or k.startswith("skill_") else np.float32(0.0)
         for k in EpisodeAccumulator.SUMMED + ("episode_return", "episode_success")}
    acc = EpisodeAccumulator()
    acc.add(m)
    out = acc.summary({"eval/new_skill_success": 0.5, "eval/new_skill_return": 1.0, "new_skill_selection_rate": 0.2})
    assert np.isnan(out["episode_success"]) and np.isnan(out["episode_return"])
    assert "train_success=n/a" in Progress.line(100, 1.0, out)
    acc.add(dict(m, episodes=np.float32(2.0), episode_success=np.float32(0.5)))
    assert acc.summary({})["episode_success"] == 0.5


def test_learner_schedule_of_the_cpu_recipe():
    """What training.run prints and records in config.json ("learners")."""
    from parallel_skills.config import describe_schedule, learner_schedule, resolve

    cfg, _ = resolve(TrainConfig(), backend="cpu")
    s = learner_schedule(cfg)
    assert s["env_steps_per_iteration"] == 32 * 25
    assert s["scheduler"] == {"batch_size": 128, "updates_per_iteration": 50, "samples_per_env_step": 8.0}
    assert s["new_skill"] == {"batch_size": 256, "updates_per_iteration": 50, "samples_per_env_step": 16.0}
    assert learner_schedule(dataclasses.replace(cfg, method="scratch"))["scheduler"]["updates_per_iteration"] == 0
    assert "scheduler batch 128 x 50 updates" in describe_schedule(s)


def test_vmapped_seeds_match_single_runs():
    """train_seeds([0, 1]) runs both seeds in one vmapped iteration; seed 1's metrics are those of
    train(seed=1) up to float reordering of the batched matrix products (rtol 1e-4; the evaluation
    episodes, keys and counts are identical)."""
    from parallel_skills.train import train, train_seeds

    env = tasks.make("lift", episode_length=7)
    cfg = dataclasses.replace(SMALL, eval_every=2)
    rows_v = {0: [], 1: []}
    _, params_v, metrics_v = train_seeds(
        env, _skills(), seeds=[0, 1], num_timesteps=3 * cfg.steps_per_iteration, config=cfg,
        progress_fns=[lambda s, m, i=i: rows_v[i].append(m) for i in (0, 1)])
    rows_1 = []
    _, params_1, metrics_1 = train(env, _skills(), seed=1, num_timesteps=3 * cfg.steps_per_iteration, config=cfg,
                                   progress_fn=lambda s, m: rows_1.append(m))
    assert len(rows_v[1]) == len(rows_1) == 2  # evaluations after iterations 2 and 3
    for got, want in zip(rows_v[1], rows_1):
        assert set(got) == set(want)
        for k in want:
            if k == "wall_time":
                continue
            np.testing.assert_allclose(np.asarray(got[k], np.float64), np.asarray(want[k], np.float64),
                                       rtol=1e-4, atol=1e-5, err_msg=k)
    for a, b in zip(jax.tree.leaves(params_v[1]), jax.tree.leaves(params_1)):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    # The two seeds differ.
    assert not np.allclose(params_v[0].new_skill["params"]["head"]["kernel"],
                           params_v[1].new_skill["params"]["head"]["kernel"])
    with pytest.raises(ValueError, match="distinct"):
        train_seeds(env, _skills(), seeds=[1, 1], num_timesteps=10, config=cfg)
