"""Collection noise (TrainConfig.skill_noise_std) lands on the frozen skills that take it
(Skill.collection_noise), never on a skill that opts out or on the new skill, and never when greedy."""

import jax
import jax.numpy as jnp
import numpy as np

from parallel_skills.acting import Actor
from parallel_skills.skills import Skill, SkillSet


def _actor(noise_std=0.3):
    skills = [Skill.from_fn("noisy", lambda obs, key: jnp.full(3, 0.1)),
              Skill.from_fn("stateful", lambda obs, key: jnp.full(3, 0.2), collection_noise=False)]
    return Actor(env=None, skill_set=SkillSet(skills), scheduler_apply=None,
                 new_skill_apply=lambda p, obs: (jnp.full(obs.shape[:-1] + (3,), 0.3), jnp.full(obs.shape[:-1] + (3,), 1e-9)),
                 skill_lengths=(1,), num_envs=6, skill_noise_std=noise_std)


def test_noise_only_on_skills_that_take_it():
    actor = _actor()
    np.testing.assert_array_equal(actor.skill_set.collection_noise, [True, False, False])
    obs = jnp.zeros((6, 2))
    i = jnp.array([0, 1, 2, 0, 1, 2])
    ka, ks = jax.random.split(jax.random.PRNGKey(0))
    a = np.asarray(jax.jit(lambda: actor.actions(obs, obs, None, i, ka, ks, greedy=False))())
    assert np.all(np.abs(a[[0, 3]] - 0.1) > 1e-4)  # noisy skill: perturbed (std 0.3)
    np.testing.assert_allclose(a[[1, 4]], 0.2)  # opted out: exact
    np.testing.assert_allclose(a[[2, 5]], 0.3, atol=1e-6)  # the new skill: its own (here ~deterministic) sample
    g = np.asarray(actor.actions(obs, obs, None, i, ka, ks, greedy=True))
    np.testing.assert_allclose(g, np.array([0.1, 0.2, 0.3] * 2)[:, None].repeat(3, 1), atol=1e-6)


def test_zero_std_means_no_noise():
    actor = _actor(noise_std=0.0)
    obs = jnp.zeros((6, 2))
    a = np.asarray(actor.actions(obs, obs, None, jnp.array([0, 1, 2, 0, 1, 2]), jax.random.PRNGKey(1),
                                 jax.random.PRNGKey(2), greedy=False))
    np.testing.assert_allclose(a[[0, 3]], 0.1)


def test_greedy_with_the_new_skill_sampled_keeps_the_frozen_skills_noise_free():
    """``eval/scheduler_new_skill_sampled_*``: greedy acting, the new skill's action sampled."""
    skills = [Skill.from_fn("noisy", lambda obs, key: jnp.full(3, 0.1))]
    actor = Actor(env=None, skill_set=SkillSet(skills), scheduler_apply=None,
                  new_skill_apply=lambda p, obs: (jnp.full(obs.shape[:-1] + (3,), 0.3),
                                                  jnp.full(obs.shape[:-1] + (3,), 0.5)),
                  skill_lengths=(1,), num_envs=4, skill_noise_std=0.3)
    obs, i = jnp.zeros((4, 2)), jnp.array([0, 1, 0, 1])
    ka, ks = jax.random.split(jax.random.PRNGKey(0))
    mean = np.asarray(actor.actions(obs, obs, None, i, ka, ks, greedy=True))
    sampled = np.asarray(actor.actions(obs, obs, None, i, ka, ks, greedy=True, new_skill_sampled=True))
    collect = np.asarray(actor.actions(obs, obs, None, i, ka, ks, greedy=False))
    np.testing.assert_allclose(mean[[0, 2]], 0.1)
    np.testing.assert_allclose(sampled[[0, 2]], 0.1)  # frozen skill: no collection noise
    np.testing.assert_allclose(mean[[1, 3]], 0.3, atol=1e-6)  # the new skill's mean
    assert np.all(np.abs(sampled[[1, 3]] - 0.3) > 1e-4)  # its sample (std 0.5) ...
    np.testing.assert_allclose(sampled[[1, 3]], collect[[1, 3]])  # ... the one collection draws


def test_greedy_envs_collect_as_the_greedy_evaluation_acts():
    """``TrainConfig.greedy_env_fraction``: the first ``greedy_envs`` of the batch take argmax
    decisions, the new skill's mean and no collection noise while collecting; the others explore
    exactly as with none (same keys, same draws)."""
    skills = [Skill.from_fn("noisy", lambda obs, key: jnp.full(3, 0.1))]
    apply = lambda p, obs: (jnp.full(obs.shape[:-1] + (3,), 0.3), jnp.full(obs.shape[:-1] + (3,), 0.5))  # noqa: E731
    make = lambda n: Actor(env=None, skill_set=SkillSet(skills), scheduler_apply=None, new_skill_apply=apply,  # noqa: E731
                           skill_lengths=(1, 2, 3), num_envs=8, skill_noise_std=0.3, greedy_envs=n)
    obs, i = jnp.zeros((8, 2)), jnp.array([0, 1] * 4)
    ka, ks = jax.random.split(jax.random.PRNGKey(0))
    mixed = np.asarray(make(4).actions(obs, obs, None, i, ka, ks, greedy=False))
    explore = np.asarray(make(0).actions(obs, obs, None, i, ka, ks, greedy=False))
    np.testing.assert_allclose(mixed[[0, 2]], 0.1)  # greedy envs: the frozen skill noise-free
    np.testing.assert_allclose(mixed[[1, 3]], 0.3, atol=1e-6)  # ... and the new skill's mean
    np.testing.assert_array_equal(mixed[4:], explore[4:])  # the others: as with no greedy envs
    assert np.all(np.abs(explore[[0, 2]] - 0.1) > 1e-4) and np.all(np.abs(explore[[1, 3]] - 0.3) > 1e-4)
    # Decisions: argmax where greedy, the categorical's draw elsewhere.
    from parallel_skills.acting import ActorState

    state = ActorState(env_state=None, c=jnp.zeros(8, jnp.int32), i=jnp.zeros(8, jnp.int32),
                       k_idx=jnp.zeros(8, jnp.int32), first=jnp.ones(8, bool), ep_return=jnp.zeros(8),
                       ep_success=jnp.zeros(8))
    logits_i = jnp.tile(jnp.array([0.0, 0.1]), (8, 1))  # argmax: the new skill (1); samples: both
    logits_k = jnp.tile(jnp.array([0.2, 0.0, 0.0]), (8, 1))  # argmax: length index 0
    k_i, k_k = jax.random.split(jax.random.PRNGKey(3))
    _, i_m, k_m, _ = make(4).decide(state, logits_i, logits_k, k_i, k_k, greedy=False)
    _, i_e, k_e, _ = make(0).decide(state, logits_i, logits_k, k_i, k_k, greedy=False)
    np.testing.assert_array_equal(i_m[:4], 1)
    np.testing.assert_array_equal(k_m[:4], 0)
    np.testing.assert_array_equal(i_m[4:], i_e[4:])
    np.testing.assert_array_equal(k_m[4:], k_e[4:])
    assert set(np.asarray(i_e).tolist()) == {0, 1}  # the explorers draw both skills here


def test_greedy_env_count_and_the_config_field():
    """The training actor takes round(f · num_envs) greedy envs; the evaluations' actors none."""
    import tasks
    from parallel_skills.config import FieldError, TrainConfig
    from parallel_skills.train import greedy_env_count, make_actor

    assert [greedy_env_count(f, 32) for f in (0.0, 0.25, 1.0)] == [0, 8, 32]
    env, config = tasks.make("lift"), TrainConfig(greedy_env_fraction=0.25)
    assert make_actor(env, [], config, 32, collecting=True).greedy_envs == 8
    assert make_actor(env, [], config, 32).greedy_envs == 0
    try:
        TrainConfig(greedy_env_fraction=1.5)
    except FieldError as e:
        assert e.name == "greedy_env_fraction"
    else:
        raise AssertionError("greedy_env_fraction 1.5 accepted")


def test_new_skill_collects_its_mean():
    """``TrainConfig.new_skill_collects`` "mean": the new skill acts with its mean while collecting
    (every env, every actor of the run, so the scheduler-as-it-collects read-out too); the frozen
    skills keep their collection noise; the read-out with the new skill sampled still samples."""
    import pytest

    import tasks
    from parallel_skills.config import FieldError, TrainConfig
    from parallel_skills.train import make_actor

    skills = [Skill.from_fn("noisy", lambda obs, key: jnp.full(3, 0.1))]
    apply = lambda p, obs: (jnp.full(obs.shape[:-1] + (3,), 0.3), jnp.full(obs.shape[:-1] + (3,), 0.5))  # noqa: E731
    make = lambda m: Actor(env=None, skill_set=SkillSet(skills), scheduler_apply=None, new_skill_apply=apply,  # noqa: E731
                           skill_lengths=(1,), num_envs=4, skill_noise_std=0.3, new_skill_collects_mean=m)
    obs, i = jnp.zeros((4, 2)), jnp.array([0, 1, 0, 1])
    ka, ks = jax.random.split(jax.random.PRNGKey(0))
    mean = np.asarray(make(True).actions(obs, obs, None, i, ka, ks, greedy=False))
    sampled = np.asarray(make(False).actions(obs, obs, None, i, ka, ks, greedy=False))
    np.testing.assert_allclose(mean[[1, 3]], 0.3, atol=1e-6)  # the new skill's mean
    assert np.all(np.abs(sampled[[1, 3]] - 0.3) > 1e-4)  # (the paper: its sample)
    np.testing.assert_array_equal(mean[[0, 2]], sampled[[0, 2]])  # frozen: the same noisy draws
    assert np.all(np.abs(mean[[0, 2]] - 0.1) > 1e-4)
    forced = np.asarray(make(True).actions(obs, obs, None, i, ka, ks, greedy=True, new_skill_sampled=True))
    assert np.all(np.abs(forced[[1, 3]] - 0.3) > 1e-4)
    env = tasks.make("lift")
    config = TrainConfig(new_skill_collects="mean")
    assert make_actor(env, [], config, 8, collecting=True).new_skill_collects_mean
    assert make_actor(env, [], config, 8).new_skill_collects_mean
    assert not make_actor(env, [], TrainConfig(), 8, collecting=True).new_skill_collects_mean
    with pytest.raises(FieldError, match="new_skill_collects"):
        TrainConfig(new_skill_collects="greedy")
    with pytest.raises(ValueError, match="scheduler acts"):
        TrainConfig(new_skill_collects="mean", method="scratch")
