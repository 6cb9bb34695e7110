"""Any Brax-API env trains: a MuJoCo Playground DM-Control env (CartpoleBalance, impl jax) with
scripted skills, time-limited by brax's EpisodeWrapper (Playground is an optional dependency)."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig
from parallel_skills.train import make_trainer

registry = pytest.importorskip("mujoco_playground").registry


@pytest.mark.timeout(600)
def test_playground_cartpole_trains_a_few_iterations():
    pinned = hasattr(os, "sched_setaffinity")
    if pinned:  # MJX-jax on 2 CPU cores can deadlock unpinned (STACK.md); restored below
        saved = os.sched_getaffinity(0)
        os.sched_setaffinity(0, {sorted(saved)[0]})
    try:
        _train_cartpole()
    finally:
        if pinned:
            os.sched_setaffinity(0, saved)


def _train_cartpole():
    from brax.envs.wrappers.training import EpisodeWrapper

    env = EpisodeWrapper(registry.load("CartpoleBalance", config_overrides={"impl": "jax"}), 20, 1)
    skills = [
        Skill.from_fn("push_left", lambda obs, key: -jnp.ones((1,))),
        Skill.from_fn("push_right", lambda obs, key: jnp.ones((1,))),
    ]
    cfg = TrainConfig(
        num_envs=4, unroll_length=10, replay_size=1000,
        scheduler=SchedulerConfig(skill_lengths=(2, 4), hidden=(16,), critic_head_hidden=(16,), batch_size=8,
                                  min_replay_size=10, samples_per_insert=2.0),
        new_skill=NewSkillConfig(hidden=(16,), batch_size=8, min_replay_size=10, samples_per_insert=2.0),
    )
    trainer = make_trainer(env, skills, cfg)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    it = jax.jit(trainer.iteration)
    episodes = 0.0
    for _ in range(3):
        state, m = it(state)
        episodes += float(m["episodes"])
    m = jax.device_get(m)
    assert int(state.env_steps) == 3 * 4 * 10
    assert np.isfinite(m["scheduler/critic_loss"]) and np.isfinite(m["new_skill/critic_loss"])
    assert m["reward_mean"] > 0  # cartpole balance pays reward while upright
    assert episodes == 4  # 20-step episodes: one per env ended within the 30 steps
    assert np.sum(m["skill_histogram"]) > 0
