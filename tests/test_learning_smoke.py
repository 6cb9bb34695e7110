"""CI-sized learning smoke test: the scheduler's return rises over its first iterations.

Kinematic `lift_arm_closed` (the appendix's dense "lift arm with closed fingers" reward) with three
frozen scripted skills of which one is right: HCMPO must learn to pick it.
"""

import jax
import numpy as np

import tasks
from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig
from parallel_skills.train import make_evaluators, make_trainer
from tasks.manipulation import scripted

EPISODE = 100
CFG = TrainConfig(
    num_envs=16, unroll_length=20, replay_size=50_000, eval_episodes=16,
    scheduler=SchedulerConfig(skill_lengths=(10, 20), hidden=(64, 64), critic_head_hidden=(64,), batch_size=64,
                              min_replay_size=200, samples_per_insert=4.0),
    new_skill=NewSkillConfig(hidden=(32, 32), batch_size=32, min_replay_size=200, samples_per_insert=0.25),
)


def test_scheduler_return_rises():
    env = tasks.make("lift_arm_closed", episode_length=EPISODE)
    skills = [Skill.from_fn(n, scripted.get(n)) for n in ("reach_green", "lift_arm_open", "lift_arm_closed")]
    trainer = make_trainer(env, skills, CFG)
    eval_sched = make_evaluators(env, trainer, CFG.eval_episodes, EPISODE).scheduler
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    iteration = jax.jit(trainer.iteration)

    def greedy_return(s):
        r = eval_sched(s.scheduler.policy_params, s.new_skill.policy_params, s.normalizer, jax.random.PRNGKey(9))
        return float(np.mean(r["return"]))

    before = greedy_return(state)
    returns = []
    for _ in range(40):
        state, m = iteration(state)
        if float(m["episodes"]) > 0:
            returns.append(float(m["episode_return"]))
    after = greedy_return(state)
    # The sampled scheduler's training episodes and the greedy scheduler both improve.
    assert np.mean(returns[-2:]) > np.mean(returns[:2]) + 2.0, returns
    assert after > before + 5.0, (before, after)
