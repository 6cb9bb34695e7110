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
