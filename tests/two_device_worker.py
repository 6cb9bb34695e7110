"""Run by tests/test_sharding.py in a subprocess with two forced host devices
(``XLA_FLAGS=--xla_force_host_platform_device_count=2``, set before JAX starts): the same run on one
device and data parallel on a 2-device mesh, and a checkpoint taken on the mesh restored onto it.
Prints one JSON object on its last line."""

from __future__ import annotations

import json
import os
import sys
import tempfile

import jax
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import tasks  # noqa: E402
from parallel_skills import NewSkillConfig, SchedulerConfig, Skill, TrainConfig, sharding  # noqa: E402
from parallel_skills.train import compile_trainer, make_trainer  # noqa: E402
from tasks.manipulation import scripted  # noqa: E402
from training.checkpointing import Checkpointer  # noqa: E402

CONFIG = TrainConfig(
    num_envs=4, unroll_length=5, replay_size=200, eval_episodes=2, eval_every=1,
    scheduler=SchedulerConfig(skill_lengths=(2, 3), hidden=(16,), critic_head_hidden=(8,), batch_size=8,
                              min_replay_size=10, samples_per_insert=2.0),
    new_skill=NewSkillConfig(hidden=(16,), batch_size=8, min_replay_size=10, samples_per_insert=2.0, n_step=3),
)
ITERATIONS = 3


_COMPILED = {}


def run(mesh, iterations, state=None):
    if mesh not in _COMPILED:  # (one trainer and one compile per mesh)
        _COMPILED[mesh] = compile_trainer(make_trainer(ENV, SKILLS, CONFIG, mesh), mesh, seed_axis=False)
    init, iteration, place = _COMPILED[mesh]
    state = init(jax.random.PRNGKey(0)) if state is None else place(state)
    metrics = []
    for _ in range(iterations):
        state, m = iteration(state)
        metrics.append({k: np.asarray(v, np.float64).tolist() for k, v in jax.device_get(m).items()})
    return state, metrics


def max_diff(a, b):
    return max(float(np.max(np.abs(np.asarray(x, np.float64) - np.asarray(y, np.float64)))) if np.size(x) else 0.0
               for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


def main():
    global ENV, SKILLS
    ENV = tasks.make("lift", episode_length=7)
    SKILLS = [Skill.from_fn(n, scripted.get(n)) for n in ("reach_green", "lift_arm_closed")]
    assert jax.device_count() == 2, jax.devices()
    mesh = sharding.make_mesh()
    one_state, one = run(None, ITERATIONS)
    two_state, two = run(mesh, ITERATIONS)
    out = {
        "devices": jax.device_count(),
        "metric_keys": sorted(one[-1]),
        "metrics_max_abs_diff": max(max_diff(list(a.values()), list(b.values())) for a, b in zip(one, two)),
        "metrics_bitwise": one == two,
        "params_max_abs_diff": max_diff(jax.device_get(one_state.new_skill), jax.device_get(two_state.new_skill)),
        "scheduler_max_abs_diff": max_diff(jax.device_get(one_state.scheduler), jax.device_get(two_state.scheduler)),
        "actor_sharding": str(two_state.actor.c.sharding.spec),
        "pending_sharding": str(two_state.pending.reward.sharding.spec),
        "params_sharding": str(jax.tree.leaves(two_state.new_skill.policy_params)[0].sharding.spec),
    }
    # A checkpoint taken on the mesh (after 2 iterations) restored onto it continues the run exactly.
    from training.checkpointing import abstract_training_state

    with tempfile.TemporaryDirectory() as tmp:
        state, first = run(mesh, ITERATIONS - 1)
        ckpt = Checkpointer(tmp)
        ckpt.save(state, {"iteration": ITERATIONS - 1})
        abstract, fresh = abstract_training_state(ENV, SKILLS, CONFIG, 0)
        shardings = sharding.state_shardings(abstract, mesh, CONFIG.num_envs)
        restored, _ = ckpt.restore(abstract, fresh, shardings=shardings)
        ckpt.close()
        out["restored_actor_sharding"] = str(restored.actor.c.sharding.spec)
        out["restored_on_mesh"] = all(leaf.sharding.mesh.shape == mesh.shape for leaf in jax.tree.leaves(restored)
                                      if hasattr(leaf, "sharding") and hasattr(leaf.sharding, "mesh"))
        resumed_state, resumed = run(mesh, 1, state=restored)
        out["resume_bitwise"] = (first + resumed) == two
        out["resume_params_max_abs_diff"] = max_diff(jax.device_get(resumed_state.new_skill),
                                                     jax.device_get(two_state.new_skill))
        # The same checkpoint restored onto one device (no shardings given) continues there.
        ckpt = Checkpointer(tmp)
        single, _ = ckpt.restore(abstract, fresh)
        ckpt.close()
        single_state, single_last = run(None, 1, state=single)
        out["one_device_resume_metrics_max_abs_diff"] = max_diff(list(single_last[0].values()),
                                                                 list(two[-1].values()))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
