"""Checkpoint layout: n-step runs keep their collector's pending steps; 1-step runs keep the on-disk
tree of checkpoints written before the ``pending`` field existed (those runs must still resume)."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest
from flax import struct

import tasks
from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig
from parallel_skills.train import make_trainer
from tasks.manipulation import scripted
from training.checkpointing import Checkpointer, abstract_training_state

CFG = TrainConfig(num_envs=2, unroll_length=3, replay_size=100,
                  scheduler=SchedulerConfig(skill_lengths=(2, 3), hidden=(8,), critic_head_hidden=(8,)),
                  new_skill=NewSkillConfig(hidden=(8,)))


@struct.dataclass
class _TrainingStateBeforeNStep:
    """parallel_skills.train.TrainingState as it was before ``pending`` (field order kept)."""

    scheduler: Any
    new_skill: Any
    replay: Any
    actor: Any
    normalizer: Any
    key: Any
    env_steps: Any
    iteration: Any


def _setup(n_step):
    env = tasks.make("lift", episode_length=5)
    skills = [Skill.from_fn("reach_green", scripted.get("reach_green"))]
    cfg = dataclasses.replace(CFG, new_skill=dataclasses.replace(CFG.new_skill, n_step=n_step))
    trainer = make_trainer(env, skills, cfg)
    state, _, _ = jax.jit(trainer.collect_insert)(jax.jit(trainer.init)(jax.random.PRNGKey(0)), jax.random.PRNGKey(1))
    state = state.replace(iteration=state.iteration + 1)
    return env, skills, cfg, state


def _assert_same(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    assert jax.tree.structure(a) == jax.tree.structure(b) and len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.mark.parametrize("n_step", [1, 3])
def test_save_restore_round_trip(tmp_path, n_step):
    env, skills, cfg, state = _setup(n_step)
    assert (state.pending is None) == (n_step == 1)
    ck = Checkpointer(str(tmp_path))
    ck.save(state, {"iteration": 1})
    restored, host = ck.restore(abstract_training_state(env, skills, cfg, 0)[0])
    ck.close()
    assert host["iteration"] == 1
    _assert_same(restored, state)


def test_checkpoint_written_before_the_pending_field_restores(tmp_path):
    env, skills, cfg, state = _setup(1)
    old = _TrainingStateBeforeNStep(**{f.name: getattr(state, f.name)
                                       for f in dataclasses.fields(_TrainingStateBeforeNStep)})
    ck = Checkpointer(str(tmp_path))
    ck.manager().save(1, args=ocp.args.Composite(  # what Checkpointer.save wrote then
        state=ocp.args.StandardSave(old.replace(replay=None)), replay=ocp.args.StandardSave(state.replay),
        host=ocp.args.JsonSave({"iteration": 1, "replay_saved": True})))
    ck.manager().wait_until_finished()
    restored, _ = ck.restore(abstract_training_state(env, skills, cfg, 0)[0])
    ck.close()
    _assert_same(restored, state)


def test_checkpoint_with_dict_duals_restores(tmp_path):
    """Checkpoints written while the MPO duals were dicts ({"log_temperature", ...}) restore into
    the typed duals (learners.SchedulerDuals / NewSkillDuals): orbax names the leaves alike."""
    from parallel_skills.learners import NewSkillDuals, SchedulerDuals

    env, skills, cfg, state = _setup(1)
    typed = lambda x: isinstance(x, (SchedulerDuals, NewSkillDuals))  # noqa: E731
    as_dicts = lambda tree: jax.tree.map(  # noqa: E731
        lambda x: {f.name: getattr(x, f.name) for f in dataclasses.fields(x)} if typed(x) else x, tree, is_leaf=typed)
    old = state.replace(**{name: getattr(state, name).replace(dual_params=as_dicts(getattr(state, name).dual_params),
                                                               dual_opt_state=as_dicts(getattr(state, name).dual_opt_state))
                           for name in ("scheduler", "new_skill")})
    assert isinstance(old.scheduler.dual_params, dict) and isinstance(old.new_skill.dual_opt_state[0].mu, dict)
    ck = Checkpointer(str(tmp_path))
    ck.save(old, {"iteration": 1})
    restored, _ = ck.restore(abstract_training_state(env, skills, cfg, 0)[0])
    ck.close()
    assert isinstance(restored.scheduler.dual_params, SchedulerDuals)
    _assert_same(restored, state)
