"""The method seam (parallel_skills.methods): a method is one object the trainer, the config and
the command line read. A toy method defined here alone trains 3 iterations."""

import dataclasses

import numpy as np
import pytest

import tasks
from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig, methods
from parallel_skills.config import learner_schedule, resolve
from parallel_skills.train import train
from tasks.manipulation import scripted

SMALL = TrainConfig(
    num_envs=4, unroll_length=5, replay_size=2000, eval_episodes=2, eval_every=1,
    scheduler=SchedulerConfig(skill_lengths=(2, 3), hidden=(16,), critic_head_hidden=(8,), batch_size=16,
                              min_replay_size=10, samples_per_insert=4.0),
    new_skill=NewSkillConfig(hidden=(32, 32), batch_size=16, min_replay_size=10, samples_per_insert=4.0,
                             mpo_num_samples=4),
)

# The scheduler acts (with its initial, untrained policy) and only the new skill learns, with the
# CRR mix α = 0.8 unless given: no file but this one knows it.
TOY = methods.Method("toy_fixed_scheduler", "the untrained scheduler acts, the new skill learns",
                     scheduler_acts=True, mix_alpha=0.8)


@pytest.fixture
def toy():
    methods.register(TOY)
    yield TOY
    methods.unregister(TOY.name)


def test_the_paper_methods_are_registered():
    assert methods.names() == ("skills", "scratch", "finetune", "kl_reg", "dagger", "rhpo")
    for m in methods.all_methods():
        assert m.help and methods.get(m.name) is m
    with pytest.raises(ValueError, match="method must be one of skills, scratch"):
        methods.get("nope")
    with pytest.raises(ValueError, match="registered already"):
        methods.register(methods.SKILLS)


def test_a_toy_method_defined_in_this_file_trains_three_iterations(toy):
    cfg, notes = resolve(dataclasses.replace(SMALL, method=toy.name))
    assert cfg.new_skill.mpo_alpha == 0.8 and any(toy.name in n for n in notes)
    assert learner_schedule(cfg)["scheduler"]["updates_per_iteration"] == 0  # it does not learn the scheduler
    env = tasks.make("lift", episode_length=7)
    skills = [Skill.from_fn(n, scripted.get(n)) for n in ("reach_green", "lift_arm_closed")]
    seen = []
    make_policy, params, metrics = train(env, skills, num_timesteps=3 * cfg.steps_per_iteration, seed=0, config=cfg,
                                         progress_fn=lambda steps, m: seen.append(steps), auto_config=False)
    assert seen == [20, 40, 60]
    assert "eval/scheduler_success" in metrics  # the scheduler acts: it is evaluated
    assert "eval/scheduler_sampled_success" not in metrics  # (it has no learnt critic to read)
    assert metrics["new_skill/critic_loss"] > 0 and metrics["scheduler/critic_loss"] == 0.0
    assert np.isfinite(metrics["eval/new_skill_return"])
    assert metrics["new_skill_selection_rate"] < 1.0  # the frozen skills act too
    action = make_policy(params)(np.zeros(env.observation_size, np.float32), None)
    assert action.shape == (env.action_size,)


def test_an_unregistered_method_is_a_config_error():
    with pytest.raises(ValueError, match="got 'toy_fixed_scheduler'"):
        TrainConfig(method=TOY.name)
