"""n-step TD targets for the new skill's critic, and for the scheduler's within skill executions (paper App. B.3: the learner trains on
trajectories of length 10; docs/design.md "New skill").

With 1-step TD the new skill's critic learns a sparse reward only by bootstrapping through its
own, usually wrong, values: on stack, where the reward starts tens of steps after the gripper
opens, it ranked "keep holding" above "open" at hover states (docs/research/learning.md). n-step returns
carry the observed rewards of the next n steps straight into Q(s_t, a_t):

    R_t = Σ_{j<m} γ^j r_{t+j},    y_t = R_t + γ^m · d_{t+m−1} · E_{a'~π} Q'(s_{t+m}, a'),

where m ≤ n stops at the first episode end (termination: d = 0, no bootstrap; time-limit
truncation: d = 1, bootstrap from the true last observation). The returns are uncorrected
(no importance weights): the steps after t follow the behaviour (scheduler + skills), as in
Acme's n-step adders.

The collector emits each transition's n-step fields n − 1 steps late: it keeps the last n − 1
steps of every env (``pending``) and completes them with the next unroll.
"""

from __future__ import annotations

from typing import Dict

import jax.numpy as jnp

def nstep_fields(window, n: int, gamma: float) -> Dict[str, jnp.ndarray]:
    """n-step returns of the first T = W − n + 1 steps of a window of W consecutive steps per env.

    window (a ``replay.PendingStep``, or anything with these attributes): reward [W, B], discount
    [W, B] (0 at termination, else 1), next_obs [W, B, O], done [W, B] (the episode ended at this
    step: termination, truncation or a non-finite step), weight [W, B] (0 for steps that must not
    be learnt from).

    Returns, for t < T (each [T, B] or [T, B, O]):
      nstep_reward   R_t = Σ_{j<m} γ^j r_{t+j}
      nstep_discount γ^(m−1) · d_{t+m−1}: the learner's target r + γ·discount·Q' is then
                     R_t + γ^m·d·Q'(s_{t+m}) (for n = 1: the 1-step discount unchanged)
      nstep_next_obs s_{t+m} (the last included step's next_obs)
      nstep_weight   Π_{j<m} weight_{t+j} (a bad step anywhere in the return drops the sample)
      nstep_steps    m (int32)
    with m = min(n, steps to the end of t's episode, counting the ending step).
    """
    n = int(n)
    w = window.reward.shape[0]
    t = w - n + 1
    if n < 1 or t < 1:
        raise ValueError(f"a window of {w} steps has no complete {n}-step return")

    def at(key, j):
        return getattr(window, key)[j:j + t].astype(jnp.float32)

    ret = at("reward", 0)
    disc = at("discount", 0)
    next_obs = window.next_obs[0:t]
    weight = at("weight", 0)
    alive = 1.0 - at("done", 0)  # step t + j belongs to t's episode
    steps = jnp.ones(ret.shape, jnp.int32)  # m
    for j in range(1, n):
        ret = ret + alive * (gamma ** j) * at("reward", j)
        disc = jnp.where(alive > 0, (gamma ** j) * at("discount", j), disc)
        next_obs = jnp.where(alive[..., None] > 0, window.next_obs[j:j + t], next_obs)
        weight = jnp.where(alive > 0, weight * at("weight", j), weight)
        steps = steps + (alive > 0).astype(jnp.int32)
        alive = alive * (1.0 - at("done", j))
    return {"nstep_reward": ret, "nstep_discount": disc, "nstep_next_obs": next_obs, "nstep_weight": weight,
            "nstep_steps": steps}


def execution_nstep_fields(window, n: int, gamma: float, boundary: jnp.ndarray) -> Dict[str, jnp.ndarray]:
    """The scheduler's n-step returns (``SchedulerConfig.n_step``): ``nstep_fields`` whose returns
    also stop after a step where ``boundary`` [W, B] holds (the step's skill execution ends there:
    the next step is a decision of the scheduler, actual or, with the augmentation, of the
    duplicate's labelling).

    Inside one skill execution no decision is taken, so the return of the next m steps is the
    return of the option being evaluated, Q(s_t, c, i, k) = R_t + γ^m·Q(s_{t+m}, c − m, i, k)
    (m < c), and R_t + γ^m·V(s_{t+m}) at the execution's end (m = c): the n-step target of Eq. 3
    needs no off-policy correction (the frozen skills' actions, noise included, are the option's
    own). Returns ``nstep_fields``' dict, ``nstep_steps`` = m [T, B] int32 included."""
    return nstep_fields(window.replace(done=window.done | boundary), n, gamma)


def own_nstep_fields(window, n: int, gamma: float, new_skill_index: int) -> Dict[str, jnp.ndarray]:
    """The new skill's n-step returns over its own steps only (``NewSkillConfig.n_step_returns``
    "own"): ``nstep_fields`` whose returns also stop after a step whose *next* step another skill
    took (``window.skill`` [W, B] ≠ ``new_skill_index``), bootstrapping there from Q'.

    The first step's action may be anyone's (Q(s_t, a_t) is defined for any a_t); the steps after it
    enter the return only while the new skill acts, so the target values what the new skill does
    from s_{t+1} on, not what the scheduler's next skills do (Tree-backup's trace cut, Precup et al.
    2000, with the traces 1 on the new skill's own steps and 0 on the others'). Where the behaviour
    would soon release a held cube, the uncorrected return credits holding with that release; this
    one credits holding with what the new skill itself does next. The window's last step has no
    next step in it and never needs one (it only ends returns). Returns ``nstep_fields``' dict."""
    other_next = window.skill[1:] != new_skill_index
    cut = jnp.concatenate([other_next, jnp.zeros_like(other_next[:1])], axis=0)
    return nstep_fields(window.replace(done=window.done | cut), n, gamma)
