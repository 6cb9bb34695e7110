"""Networks (flax.linen) for the scheduler and the new skill (paper §4, App. B.3).

Torsos follow Acme's ``LayerNormMLP``: first layer Dense → LayerNorm → tanh, later layers
Dense → elu (all layers activated: the torso output is a feature vector).

* ``GaussianPolicy``: obs [..., O] → (mean [..., A], std [..., A]); mean = tanh(raw) ∈ (−1, 1),
  std = softplus(raw) + min_std. Actions are sampled from the *unsquashed* Gaussian and
  clipped to [−1, 1]; log-probs are plain Gaussian densities of the stored (clipped) action
  (no tanh-squashed distribution: other skills' actions sit exactly at ±1).
* ``SchedulerPolicy``: obs → (logits_i [..., N+1], logits_k [..., M]), independent heads.
* ``QCritic``: (obs, action) → q; ``QEnsemble``: several QCritics → q [..., E].
* ``SchedulerCritic``: Q(s, c, i, k) for P queried (c, i, k) triples per state, torso once
  per state.

Joint scheduler actions are enumerated by ``all_pairs`` in i-major, k-minor order:
pair p = i·M + k_idx.
"""

from __future__ import annotations

import math
from typing import Sequence, Tuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np


class LayerNormMLP(nn.Module):
    """Acme-style torso: Dense→LayerNorm→tanh, then Dense→elu. [..., D] -> [..., hidden[-1]]."""

    hidden: Tuple[int, ...]

    @nn.compact
    def __call__(self, x):
        for n, width in enumerate(self.hidden):
            x = nn.Dense(width, kernel_init=nn.initializers.variance_scaling(1.0, "fan_in", "uniform"),
                         name=f"dense_{n}")(x)
            if n == 0:
                x = nn.LayerNorm(name="layer_norm")(x)
                x = jnp.tanh(x)
            else:
                x = nn.elu(x)
        return x


# --------------------------------------------------------------------------- Gaussian policy

class GaussianPolicy(nn.Module):
    """New-skill policy π_N(a|s) (paper §4.2, App. B.3): isotropic Gaussian.

    obs [..., O] -> (mean [..., A] in (−1, 1), std [..., A] > min_std).
    """

    action_size: int
    hidden: Tuple[int, ...] = (128, 256, 128)
    min_std: float = 0.05  # NewSkillConfig.min_std

    @nn.compact
    def __call__(self, obs):
        h = LayerNormMLP(tuple(self.hidden), name="torso")(obs)
        out = nn.Dense(2 * self.action_size,
                       kernel_init=nn.initializers.variance_scaling(1e-4, "fan_in", "uniform"),
                       name="head")(h)
        raw_mean, raw_std = jnp.split(out, 2, axis=-1)
        mean = jnp.tanh(raw_mean)
        std = nn.softplus(raw_std) + self.min_std
        return mean, std


def gaussian_log_prob(mean: jnp.ndarray, std: jnp.ndarray, action: jnp.ndarray) -> jnp.ndarray:
    """log N(action; mean, diag(std²)) summed over the last axis. [..., A] x3 -> [...]."""
    z = (action - mean) / std
    return jnp.sum(-0.5 * z * z - jnp.log(std) - 0.5 * math.log(2.0 * math.pi), axis=-1)


def sample_action(mean: jnp.ndarray, std: jnp.ndarray, key: jax.Array) -> jnp.ndarray:
    """a = clip(mean + std·ε, −1, 1), ε ~ N(0, I). [..., A] -> [..., A]."""
    eps = jax.random.normal(key, mean.shape, mean.dtype)
    return jnp.clip(mean + std * eps, -1.0, 1.0)


def deterministic_action(mean: jnp.ndarray, std: jnp.ndarray = None) -> jnp.ndarray:
    """The deterministic (evaluation) action: the mean, already in (−1, 1). [..., A]."""
    del std
    return mean


# --------------------------------------------------------------------------- scheduler policy

NEVER = -1e9  # a logit whose probability underflows to exactly 0 in float32


def length_bias(num_lengths: int, initial_max_length_prob: float) -> np.ndarray:
    """Initial k-head bias (App. A.3): log-probs with P(k = max K) = p (last index) and
    (1 − p)/(M − 1) for each other length. [M] float32 (zeros if M == 1)."""
    if num_lengths == 1:
        return np.zeros((1,), np.float32)
    p = float(initial_max_length_prob)
    probs = np.full((num_lengths,), (1.0 - p) / (num_lengths - 1), np.float64)
    probs[-1] = p
    return np.log(probs).astype(np.float32)


class SchedulerPolicy(nn.Module):
    """Scheduler π_S(i, k | s) = π(i|s)·π(k|s) (paper §4.1): two categorical heads.

    obs [..., O] -> (logits_i [..., N+1], logits_k [..., M]).
    Init: both heads have zero kernels; the i-head bias is 0 (uniform over skills) and the
    k-head bias is ``length_bias`` (P(k = max K) = initial_max_length_prob, rest uniform).
    The skill lengths must be sorted ascending so that the last index is max K.
    ``new_skill_choice`` False: the last skill's (the new skill's) i-bias starts at −1e9, so its
    probability is exactly 0 in float32; its logit's gradient, π − q = 0, is then exactly 0 too,
    and it stays unchosen through training (and in exports, which carry the bias).
    """

    num_skills: int  # N + 1, including the new skill.
    num_lengths: int  # M.
    hidden: Tuple[int, ...] = (128, 256, 128)
    initial_max_length_prob: float = 0.95
    new_skill_choice: bool = True

    @nn.compact
    def __call__(self, obs):
        h = LayerNormMLP(tuple(self.hidden), name="torso")(obs)
        bias_i = np.zeros((self.num_skills,), np.float32)
        if not self.new_skill_choice:
            bias_i[-1] = NEVER
        logits_i = nn.Dense(self.num_skills, kernel_init=nn.initializers.zeros,
                            bias_init=lambda *_: jnp.asarray(bias_i), name="head_i")(h)
        bias = jnp.asarray(length_bias(self.num_lengths, self.initial_max_length_prob))
        logits_k = nn.Dense(self.num_lengths, kernel_init=nn.initializers.zeros,
                            bias_init=lambda *_: bias, name="head_k")(h)
        return logits_i, logits_k


def all_pairs(num_skills: int, skill_lengths: Sequence[int]) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All joint actions z = (i, k), i-major / k-minor: pair p = i·M + k_idx.

    Returns numpy int32 arrays (i [P], k_idx [P], k_value [P]) with P = num_skills·M.
    """
    m = len(skill_lengths)
    i = np.repeat(np.arange(num_skills, dtype=np.int32), m)
    k_idx = np.tile(np.arange(m, dtype=np.int32), num_skills)
    k_value = np.asarray(skill_lengths, np.int32)[k_idx]
    return i, k_idx, k_value


def joint_log_probs(logits_i: jnp.ndarray, logits_k: jnp.ndarray) -> jnp.ndarray:
    """log π(i, k|s) = log_softmax(logits_i)[i] + log_softmax(logits_k)[k] for all pairs in
    ``all_pairs`` order. ([..., N+1], [..., M]) -> [..., (N+1)·M]."""
    li = jax.nn.log_softmax(logits_i, axis=-1)
    lk = jax.nn.log_softmax(logits_k, axis=-1)
    joint = li[..., :, None] + lk[..., None, :]
    return joint.reshape(joint.shape[:-2] + (-1,))


def categorical_entropy(logits: jnp.ndarray) -> jnp.ndarray:
    """H = −Σ p log p over the last axis. [..., C] -> [...]."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return -jnp.sum(jnp.exp(logp) * logp, axis=-1)


# --------------------------------------------------------------------------- critics

class QCritic(nn.Module):
    """New-skill critic Q(s, a): concat(obs, action) → LayerNormMLP → Dense(1).

    (obs [..., O], action [..., A]) -> q [...].
    """

    hidden: Tuple[int, ...] = (128, 256, 128)

    @nn.compact
    def __call__(self, obs, action):
        x = jnp.concatenate([obs, action], axis=-1)
        h = LayerNormMLP(tuple(self.hidden), name="torso")(x)
        return nn.Dense(1, name="head")(h)[..., 0]


class QEnsemble(nn.Module):
    """``num_critics`` independent ``QCritic`` networks (own parameters, one vmapped apply): the
    new skill's clipped double-Q critic (Fujimoto et al. 2018).

    (obs [..., O], action [..., A]) -> q [..., num_critics].
    """

    hidden: Tuple[int, ...] = (128, 256, 128)
    num_critics: int = 2

    @nn.compact
    def __call__(self, obs, action):
        ensemble = nn.vmap(QCritic, variable_axes={"params": 0}, split_rngs={"params": True},
                           in_axes=None, out_axes=-1, axis_size=self.num_critics)
        return ensemble(hidden=tuple(self.hidden), name="critics")(obs, action)


class SchedulerCritic(nn.Module):
    """Scheduler critic Q(s, c, i, k) (paper Eq. 3; docs/design.md "Scheduler and counters").

    __call__(obs [B, O], c [B, P] int, i [B, P] int, k_idx [B, P] int) -> q [B, P].
    __call__(obs [B, O], c [B, U] int) -> table [B, U, (N+1)·M]: Q(s, c_u, i, k) of every pair
    for each queried counter value (``i`` and ``k_idx`` omitted).

    The torso runs once per state. A head on [features, c / max_length] (run once per queried
    counter value) outputs one value per (i, k) pair, DQN style, and each query reads its own
    pair: every skill and length has its own output unit, so values of different skills are not
    forced to share a state dependence. The head's cost grows with the number of counter values
    queried, not of pairs: the learner queries each distinct c once (``pair_values``).
    """

    num_skills: int
    num_lengths: int
    max_length: int
    hidden: Tuple[int, ...] = (128, 256, 128)
    head_hidden: Tuple[int, ...] = (128,)

    @nn.compact
    def __call__(self, obs, c, i=None, k_idx=None):
        feat = LayerNormMLP(tuple(self.hidden), name="torso")(obs)  # [B, H]
        head = tuple(self.head_hidden)
        if not head:
            raise ValueError("SchedulerCritic needs at least one head layer")
        x = nn.Dense(head[0], name="head_feat")(feat)[..., None, :]  # [B, 1, w0] (carries the bias)
        c_scaled = (jnp.asarray(c, feat.dtype) / float(self.max_length))[..., None]  # [B, U, 1]
        x = nn.elu(x + nn.Dense(head[0], use_bias=False, name="head_c")(c_scaled))  # [B, U, w0]
        for n, width in enumerate(head[1:]):
            x = nn.elu(nn.Dense(width, name=f"head_{n + 1}")(x))
        table = nn.Dense(self.num_skills * self.num_lengths, name="head_out")(x)  # [B, U, (N+1)·M]
        if i is None:
            return table
        return read_pairs(table, i, k_idx, self.num_lengths)


def read_pairs(table: jnp.ndarray, i, k_idx, num_lengths: int) -> jnp.ndarray:
    """Q of pair (i, k_idx) from a critic table row: table [..., (N+1)·M], i / k_idx [...] -> [...]."""
    pair = jnp.asarray(i, jnp.int32) * num_lengths + jnp.asarray(k_idx, jnp.int32)
    return jnp.take_along_axis(table, pair[..., None], axis=-1)[..., 0]


def pair_values(table: jnp.ndarray, num_lengths: int) -> jnp.ndarray:
    """Q(s, c = k, i, k) of every pair (i-major, ``all_pairs`` order) from a critic table queried
    at c = each skill length in order: table [B, M, (N+1)·M] -> [B, (N+1)·M]. Row u of the
    table holds c = K[u]; pair p = i·M + k_idx is read from row k_idx."""
    b, m, width = table.shape
    if m != num_lengths or width % num_lengths:
        raise ValueError(f"table of shape {table.shape} is not one row per skill length ({num_lengths})")
    k_idx = jnp.arange(width) % num_lengths  # [P]
    return jnp.take_along_axis(table, k_idx[None, None, :], axis=1)[:, 0, :]
