"""The paper's baselines as methods (App. B): scratch with the MPO mix, finetune, kl_reg, dagger.
Each runs 3 iterations of the jitted trainer; the losses themselves are in test_baseline_losses."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import tasks
from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig
from parallel_skills import normalization as obs_norm
from parallel_skills.config import resolve
from parallel_skills.methods import MIX_ALPHA
from parallel_skills.replay import Transition
from parallel_skills.train import finetune_source, make_trainer
from tasks.manipulation import scripted
from training import skill_library

SMALL = TrainConfig(
    num_envs=4, unroll_length=5, replay_size=2000, eval_episodes=2, eval_every=1,
    scheduler=SchedulerConfig(skill_lengths=(2, 3), hidden=(16,), critic_head_hidden=(8,), batch_size=16,
                              min_replay_size=10, samples_per_insert=4.0),
    new_skill=NewSkillConfig(hidden=(32, 32), batch_size=16, min_replay_size=10, samples_per_insert=4.0,
                             mpo_num_samples=4),
)


def _skills():
    return [Skill.from_fn(n, scripted.get(n)) for n in ("reach_green", "lift_arm_closed")]


def _run(config, skills, iterations=3, seed=0):
    env = tasks.make("lift", episode_length=7)
    config, _ = resolve(config)
    trainer = make_trainer(env, skills, config)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(seed))
    iteration = jax.jit(trainer.iteration)
    history = []
    for _ in range(iterations):
        state, metrics = iteration(state)
        history.append(jax.device_get(metrics))
    return trainer, state, history


def _finite(m):
    return all(np.all(np.isfinite(np.asarray(v))) for k, v in m.items() if not k.startswith("episode_"))


@pytest.mark.parametrize("method,extra", [("kl_reg", "new_skill/kl_reg_ess"),
                                          ("dagger", "new_skill/dagger_cross_entropy")])
def test_teacher_methods_run_three_iterations(method, extra):
    trainer, state, history = _run(dataclasses.replace(SMALL, method=method), _skills())
    cfg = trainer.config.new_skill
    assert cfg.baseline == method and cfg.mpo_alpha == MIX_ALPHA  # set by resolve
    assert trainer.scheduler_updates == 0 and trainer.new_skill_updates > 0
    last = history[-1]
    assert _finite(last) and last["new_skill/critic_loss"] > 0 and extra in last
    assert float(last["new_skill_selection_rate"]) == 1.0  # the new skill acts alone
    assert int(state.new_skill.steps) > 0


def test_kl_reg_weights_use_the_prior_samples():
    """Effective sample size of the kl_reg E-step weights: between 1 and the number of samples."""
    _, _, history = _run(dataclasses.replace(SMALL, method="kl_reg"), _skills())
    ess = float(history[-1]["new_skill/kl_reg_ess"])
    assert 1.0 <= ess <= SMALL.new_skill.mpo_num_samples


def test_dagger_alone_moves_the_new_skill_towards_the_skills():
    """α = 0 (no CRR), α_D = 1: pure DAGGER. Its cross-entropy to the skill mixture falls."""
    cfg = dataclasses.replace(SMALL, method="dagger",
                              new_skill=dataclasses.replace(SMALL.new_skill, mpo_alpha=0.0, learning_rate=3e-3))
    _, _, history = _run(cfg, _skills(), iterations=8)
    ce = [float(m["new_skill/dagger_cross_entropy"]) for m in history]
    assert ce[-1] < ce[0] - 0.5, ce


def test_rhpo_runs_three_iterations_and_trains_categorical_and_component():
    trainer, state, history = _run(dataclasses.replace(SMALL, method="rhpo"), _skills())
    assert trainer.config.scheduler.skill_lengths == (1,) and trainer.config.new_skill.mpo_alpha == 0.5
    last = history[-1]
    assert _finite(last) and last["new_skill/critic_loss"] > 0
    assert {"new_skill/rhpo_kl_cat", "new_skill/rhpo_new_component_prob", "new_skill/rhpo_temperature"} <= set(last)
    # The categorical chooses at every step among the 2 skills and the component.
    hist = np.sum([m["skill_histogram"] for m in history], axis=0)
    assert hist.shape == (3,) and hist.sum() == 3 * trainer.steps_per_iteration and (hist > 0).sum() >= 2
    init = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    moved = lambda a, b: not all(np.allclose(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))  # noqa: E731
    assert moved(state.scheduler.policy_params, init.scheduler.policy_params)  # the categorical learnt
    assert moved(state.new_skill.policy_params, init.new_skill.policy_params)  # the component learnt
    assert not moved(state.scheduler.critic_params, init.scheduler.critic_params)  # HCMPO's critic unused


def test_scratch_with_the_mpo_mix_runs():
    cfg = dataclasses.replace(SMALL, method="scratch", new_skill=dataclasses.replace(SMALL.new_skill, mpo_alpha=0.5))
    trainer, _, history = _run(cfg, _skills())
    assert trainer.skills == () and _finite(history[-1]) and "new_skill/mpo_kl_mean" in history[-1]


def test_finetune_starts_from_the_library_skill_and_keeps_its_statistics():
    env = tasks.make("lift", episode_length=7)
    skill = skill_library.load_skills(["reach_green"], "kinematic", "library", env.observation_size,
                                      env.action_size)[0]
    cfg = dataclasses.replace(SMALL, method="finetune",
                              new_skill=dataclasses.replace(SMALL.new_skill, hidden=tuple(skill.metadata["hidden"])))
    trainer, state, history = _run(cfg, [skill])
    assert trainer.skills == () and trainer.scheduler_updates == 0 and _finite(history[-1])
    # The observation statistics are the skill's, unchanged by 3 iterations of data.
    np.testing.assert_allclose(state.normalizer.mean, skill.params.obs_mean, rtol=1e-6)
    np.testing.assert_allclose(obs_norm.std(state.normalizer), skill.params.obs_std, rtol=1e-6)
    # At the start the new skill is the skill: same mean action on the same observations.
    init = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    obs = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(3), 5)).obs
    apply = trainer.actor.new_skill_apply
    mean, _ = apply(init.new_skill.policy_params, obs_norm.normalize(init.normalizer, obs))
    expected = jax.vmap(skill.apply, in_axes=(None, 0, None))(skill.params, obs, jax.random.PRNGKey(0))
    np.testing.assert_allclose(mean, expected, rtol=1e-5, atol=1e-6)
    # ... and training moves it.
    assert not np.allclose(state.new_skill.policy_params["params"]["head"]["kernel"],
                           init.new_skill.policy_params["params"]["head"]["kernel"])


def test_finetune_needs_one_network_skill_of_the_new_skill_sizes():
    cfg = dataclasses.replace(SMALL, method="finetune")
    with pytest.raises(ValueError, match="exactly one skill"):
        finetune_source(_skills(), cfg)
    with pytest.raises(ValueError, match="no network parameters"):
        finetune_source(_skills()[:1], cfg)
    env = tasks.make("lift")
    skill = skill_library.load_skills(["reach_green"], "kinematic", "library", env.observation_size,
                                      env.action_size)
    with pytest.raises(ValueError, match="hidden sizes"):
        finetune_source(skill, cfg)


def test_teacher_method_config():
    given, _ = resolve(dataclasses.replace(SMALL, method="dagger"), given=["new_skill.mpo_alpha"])
    assert given.new_skill.baseline == "dagger" and given.new_skill.mpo_alpha == SMALL.new_skill.mpo_alpha
    with pytest.raises(ValueError, match="needs method 'kl_reg'"):
        TrainConfig(new_skill=NewSkillConfig(baseline="kl_reg"))
    with pytest.raises(ValueError, match="baseline must be one of"):
        NewSkillConfig(baseline="bc")
    with pytest.raises(ValueError, match=r"dagger_alpha must be a number in \[0, 1\]"):
        NewSkillConfig(dagger_alpha=2.0)
    with pytest.raises(ValueError, match="method must be one of"):
        TrainConfig(method="rl")
    with pytest.raises(ValueError, match="skill_lengths must be"):
        resolve(TrainConfig(method="rhpo"), given=["scheduler.skill_lengths"])
    # The learner refuses a teacher baseline without the skills' actions.
    from parallel_skills import learners

    cfg = NewSkillConfig(hidden=(8,), baseline="dagger", mpo_alpha=0.5)
    state = learners.new_skill_learner_init(jax.random.PRNGKey(0), 3, 2, cfg)
    batch = Transition.zeros(3, 2, (4,))
    with pytest.raises(ValueError, match="needs the skills' actions"):
        learners.new_skill_learner_update(state, batch, jax.random.PRNGKey(1), cfg)
