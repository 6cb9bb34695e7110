"""Start states a learnt skill leaves: ``start_states="after:NAME:K"`` (kinematic).

A chain's later skill starts where an earlier one ends: ``stack_green_on_yellow`` after the neural
``stack_yellow_on_blue``, with yellow a little off blue's centre, turned, perhaps still held, and the
gripper right beside it. The ``TOP_on_BOTTOM_loose`` resets draw an imitation of that state; these
draw the state itself. Half the resets are the paper's table resets; the other half are states of
a pool: ``POOL_SIZE`` table resets, each run for K env steps (``K`` one integer or a range
``KMIN-KMAX``, drawn per pool state) by the shipped library skill NAME
(``checkpoints/kinematic/NAME.npz``, its mean action, no noise: as ``training.experiments.schedules``
runs a frozen skill); the episode starts there, its step counter at 0.

The pool is rolled out once, when the env is built (from ``POOL_SEED``: the same pool in every
process), so a reset costs what a table reset costs. It must: under ``vmap`` (``training.run
--seeds``) the trainer's auto-reset ``lax.cond`` runs its reset branch at every step, and a
rollout inside the reset would run with it (7x the reset's cost per step at 2 x 32 envs). A run
records the string, so a resume rebuilds the same pool as long as the library skill is the same.
"""

from __future__ import annotations

import dataclasses
import os
import re

import jax
import jax.numpy as jnp

PREFIX = "after:"
FORM = "after:NAME:K or after:NAME:KMIN-KMAX (NAME a skill of the kinematic library, 1 ≤ KMIN ≤ KMAX ≤ 1000)"
MAX_STEPS = 1000
POOL_SIZE = 4096  # states rolled out once per env
POOL_SEED = 0
_SPEC = re.compile(r"^after:([A-Za-z0-9_.]+):(\d+)(?:-(\d+))?$")


@dataclasses.dataclass(frozen=True)
class AfterSkill:
    """``after:NAME:KMIN-KMAX``, parsed: library skill ``skill`` run for ``kmin``..``kmax`` env steps."""

    skill: str
    kmin: int
    kmax: int


def is_after(start_states: str) -> bool:
    return isinstance(start_states, str) and start_states.startswith(PREFIX)


def library_file(name: str) -> str:
    """``checkpoints/kinematic/<name>.npz`` of the installed library."""
    import checkpoints

    return os.path.join(checkpoints.library_root(), "kinematic", f"{name}.npz")


def parse(start_states: str) -> AfterSkill:
    """``after:NAME:K`` / ``after:NAME:KMIN-KMAX`` -> ``AfterSkill``; ValueError (one line) saying what is
    wrong and what is allowed, including a NAME the kinematic library does not have."""
    m = _SPEC.match(start_states)
    if m is None:
        raise ValueError(f"start_states {start_states!r} is not {FORM}")
    name, kmin = m[1], int(m[2])
    kmax = kmin if m[3] is None else int(m[3])
    if not 1 <= kmin <= kmax <= MAX_STEPS:
        raise ValueError(f"start_states {start_states!r}: the steps must satisfy 1 ≤ KMIN ≤ KMAX ≤ {MAX_STEPS}")
    path = library_file(name)
    if not (os.path.isfile(path) and os.path.isfile(path[:-4] + ".json")):
        have = sorted(f[:-4] for f in os.listdir(os.path.dirname(path)) if f.endswith(".npz"))
        raise ValueError(f"start_states {start_states!r}: no skill {name!r} in the kinematic library; "
                         f"valid: {', '.join(have)}")
    return AfterSkill(name, kmin, kmax)


def load_policy(spec: AfterSkill, obs_size: int, action_size: int):
    """``act(obs [O]) -> action [A]``: the library skill's mean action, clipped to [-1, 1].

    The skill file (``Skill.save``'s format: ``policy/params/...`` arrays of the new-skill network,
    ``obs_mean`` / ``obs_std``; the sidecar's ``hidden`` and ``action_size``) is read here, and its
    network's mean rebuilt with flax as ``parallel_skills.networks.GaussianPolicy`` computes it (the
    same layers, so the same numbers: ``tests/test_layout.py`` compares them), so that tasks/ needs
    nothing of the algorithm."""
    import json

    import flax.linen as nn
    import numpy as np

    path = library_file(spec.skill)
    with open(path[:-4] + ".json") as f:
        meta = json.load(f)
    with np.load(path) as data:
        arrays = {k: jnp.asarray(data[k]) for k in data.files}
    hidden, a_size = [int(h) for h in meta["hidden"]], int(meta["action_size"])
    if arrays["obs_mean"].shape != (obs_size,) or a_size != action_size:
        raise ValueError(f"skill {path} has observation size {arrays['obs_mean'].shape[0]} and action size "
                         f"{a_size}; the task has {obs_size} and {action_size}")
    params = {}
    for key, value in arrays.items():
        if key.startswith("policy/params/"):
            node = params
            *parents, leaf = key[len("policy/params/"):].split("/")
            for name in parents:
                node = node.setdefault(name, {})
            node[leaf] = value

    def act(obs):
        x = jnp.clip((obs - arrays["obs_mean"]) / arrays["obs_std"], -10.0, 10.0)
        for n, width in enumerate(hidden):
            x = nn.Dense(width).apply({"params": params["torso"][f"dense_{n}"]}, x)
            x = jnp.tanh(nn.LayerNorm().apply({"params": params["torso"]["layer_norm"]}, x)) if n == 0 else nn.elu(x)
        raw_mean = jnp.split(nn.Dense(2 * a_size).apply({"params": params["head"]}, x), 2, axis=-1)[0]
        return jnp.clip(jnp.tanh(raw_mean), -1.0, 1.0)

    return act


def run_skill(s0, act, dynamics, observe, steps: jax.Array, max_steps: int):
    """The state ``act`` reaches from ``s0`` in ``steps`` (≤ ``max_steps``) env steps of ``dynamics``:
    one ``lax.scan`` of ``max_steps`` steps whose later ones leave the state as it is."""

    def body(s, t):
        nxt = dynamics(s, act(observe(s)))
        return jax.tree_util.tree_map(lambda a, b: jnp.where(t < steps, a, b), nxt, s), None

    s, _ = jax.lax.scan(body, s0, jnp.arange(max_steps))
    return s


def build_pool(spec: AfterSkill, act, table_reset, dynamics, observe, size: int = None, seed: int = None):
    """The pool: state i is ``table_reset(k_i)`` run for K_i ~ U{kmin..kmax} env steps of ``act``,
    k_i the i-th of ``size`` keys split from ``PRNGKey(seed)`` and K_i drawn with
    ``fold_in(k_i, 1)``. A pytree of the state with a leading axis [size]."""
    size = POOL_SIZE if size is None else int(size)
    seed = POOL_SEED if seed is None else int(seed)

    def one(k):
        steps = jax.random.randint(jax.random.fold_in(k, 1), (), spec.kmin, spec.kmax + 1)
        return run_skill(table_reset(k), act, dynamics, observe, steps, spec.kmax)

    return jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(seed), size))


def sample(rng: jax.Array, pool, table_reset):
    """One reset: with probability 1/2 ``table_reset(k)`` itself, else a pool state drawn uniformly."""
    k_table, k_pick, k_use = jax.random.split(rng, 3)
    s0 = table_reset(k_table)
    size = jax.tree_util.tree_leaves(pool)[0].shape[0]
    after = jax.tree_util.tree_map(lambda x: x[jax.random.randint(k_pick, (), 0, size)], pool)
    use = jax.random.bernoulli(k_use)
    return jax.tree_util.tree_map(lambda a, b: jnp.where(use, a, b), after, s0)
