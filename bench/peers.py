"""Brax's own PPO and SAC on the project's manipulation tasks, with the sparse task reward or a
shaped one, scored as SkillS is scored: what a practitioner would run instead of SkillS.

    python bench/peers.py --tasks lift,stack --algos ppo,sac --rewards sparse,shaped --seeds 0,1,2 \\
        --out runs/peers --jobs 2                       # the comparison (resumable: finished runs skipped)
    python bench/peers.py --smoke --out /tmp/peers      # every part, tiny, on a CPU (under 2 minutes)
    python bench/peers.py --report --out runs/peers     # one table: time to 0.8 against SkillS's archived runs

The learners are Brax's trainers themselves (``brax.training.agents.ppo.train.train``,
``brax.training.agents.sac.train.train``), called with the hyperparameters below, on the
kinematic task env (``tasks.make``) wrapped by ``TaskReward`` (the reward variant) and, through
the trainers' ``wrap_env_fn``, Brax's own ``VmapWrapper`` and ``EpisodeWrapper`` plus
``FreshAutoReset`` (below). Brax 0.14's trainers call ``jax.device_put_replicated``, which the
installed JAX no longer has: ``install_device_put_replicated`` defines it when missing (a shim).

Rewards (``--rewards``):

* ``sparse``: the task's own sparse reward (paper App. C.1.3), what SkillS learns from.
* ``shaped``: the weighted sum ``shaped_terms`` builds from the App. C.1.3 dense terms, for the
  task's top cube T (lift: the lifted cube; stack: the cube stacked) and bottom cube B (stack):

  ========  ======  ===========================================================================
  term      weight  what it is
  ========  ======  ===========================================================================
  reach     1       R_reach(pinch, T), Eq. (reach): 1 within the tolerance [0.055, 0.055, 0.02] m,
                    else 1 - tanh²(ε·scaled distance) (``tasks.manipulation.rewards.reach_dense``)
  centre    1       Eq. (reach) again, with the gripper's grasp window as the tolerance (1 cm
                    horizontally, 1.5 cm vertically: ``kinematic.GRASP_TOL_XY`` / ``_Z``) and ε
                    such that it is 0.1 at 0.1 m (``CENTRE_MARGIN``): reach's tolerance pays in
                    full 5 cm off the cube, where no grasp is possible
  grasp     1       R_grasp,aux of "lift arm with closed fingers": the grasp sensor, with T
                    between the pads (the pinch within reach's tolerance of T). Not the appendix's
                    whole R_grasp = 0.5 (R_closed + R_grasp,aux): its R_closed pays for closing
                    the fingers on nothing, and PPO parked them closed beside the cube for it
  lift      1       (lift tasks) Eq. (lift)'s ramp on T's height while T is held, with z_min
                    lowered from 0.08 m to the table (T's resting height, 0.02 m) so that the
                    ramp starts where the cube lies; 1 at z_desired = 0.18 m
  hover     1       (stack tasks) R_hover(T, B), Eq. (hover): T 0.04 m above B within the reach
                    tolerance, shaped as reach (``rewards.hover_dense``)
  task      5       the sparse task reward itself (lift: T at 0.18 m or higher; stack: T on B,
                    released, the gripper away)
  ========  ======  ===========================================================================

  Every term is in [0, 1]: a step pays at most 9. Only lift_* and stack_*_on_* tasks (and their
  short names lift, stack) have one. Success is never shaped: it is the task's sparse test.

Hyperparameters (``hyperparameters``; each run's config.json records every argument the trainer
got, Brax's defaults included): MuJoCo Playground's tuned settings as the starting point.
PPO: ``mujoco_playground/config/manipulation_params.py``, ``brax_ppo_config("PandaPickCube")``
(Playground's pick-a-cube task, the nearest to lift and stack). SAC: Playground has no SAC entry
for manipulation; ``brax_sac_config`` of
``mujoco_playground/config/dm_control_suite_params.py`` (the one SAC setting it ships). Changed
(``CPU_CHANGES``, each with its reason): PPO num_envs 2048 -> 256 (one CPU core) and with it
batch_size 512 -> 64 (each update still uses 8 unrolls per env, 32 minibatches, as Playground's);
num_resets_per_eval 10 -> 0 for PPO (SAC has no such option), replaced by ``FreshAutoReset``;
SAC max_replay_size capped at the run's budget. The episode length is the task's (600 steps of
0.05 s), not Playground's.

Scoring: the project's evaluator (``parallel_skills.evaluation.rollout_episodes``: an episode
succeeds if the task's success test holds at any step) runs the policy's deterministic action
(Brax's ``make_policy(params, deterministic=True)``; SkillS's new skill is evaluated with its mean
action too) on ``--eval_episodes`` (32, as the paper runner's SkillS runs) fresh episodes of the
task env with the run's reward (``TaskReward``: the success test is the task's, never shaped),
``--num_evals`` times at equal env-step intervals (Brax's epochs). PPO hands
the params to ``policy_params_fn``; SAC has no such hook, so its runs save Brax's own checkpoint
at each evaluation (``checkpoint_logdir``: RUN/checkpoints, the latest kept) and ``progress_fn``
loads it (Brax's SAC evaluator, which cannot be switched off, runs one episode of ``idle_env``).
The evaluation keys derive from (seed, evaluation index) as SkillS's do.

Layout: ``OUT/<task>/<algo>-<reward>/s<seed>/`` with ``config.json`` and ``metrics.csv``
(env_steps, wall_time, eval/success, eval/return, eval/final_success: one row per evaluation;
wall_time counts from the trainer's call, compilation and evaluations included, as SkillS's
runs count it; eval/return is the return of the reward the run trains on, sparse or shaped),
the run's log next to it
(``s<seed>.log``) when run as a job: archived as they are under docs/results/peers/ (docs/peers.md).
A run whose metrics reached its budget is skipped; one cut before is moved aside and started
again (Brax's trainers do not resume).

``--smoke``: lift, PPO with the shaped reward and SAC with the sparse one (both learners, both
rewards; ``--algos`` / ``--rewards`` choose others), 640 env steps, 2 evaluations of 4 episodes of
20 steps, small networks, XLA compiling at optimisation level 0 (its figures mean nothing), then
the report: every part of a run, at sizes a CPU runs in seconds (the compilations dominate).

``--report``: per task and learner, env steps and wall clock until the first evaluation at or
above ``--threshold`` (mean over seeds; a seed that never reaches it counts its last evaluation,
and the mean is then a lower bound, "≥"), the best success, and the peer's figures divided by
SkillS's (``--skills_runs``/<task>/``--skills_variant``/s<seed>/metrics.csv, the same seeds).
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import inspect
import json
import os
import shutil
import sys
import time

sys.path.insert(1, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # the checkout, uninstalled

from training.cli import Parser, UsageError, main_guard, write_json_atomic  # noqa: E402

ALGOS = ("ppo", "sac")
REWARDS = ("sparse", "shaped")
# Env steps per task: ≥ 10x SkillS's env steps to 0.8 on the archived default runs.
BUDGETS = {"lift": 3_000_000, "stack": 12_000_000}
NUM_EVALS = 40
EVAL_EPISODES = 32  # the paper runner's SkillS runs (training.run's BASE_CONFIG)
THRESHOLD = 0.8
SKILLS_RUNS = os.path.join("docs", "results", "paper_runs")
METRICS = ["env_steps", "wall_time", "eval/success", "eval/return", "eval/final_success"]

SHAPED_WEIGHTS = {"reach": 1.0, "centre": 1.0, "grasp": 1.0, "lift": 1.0, "hover": 1.0, "task": 5.0}
# The shaped reward's "centre" term: Eq. (reach) with the kinematic gripper's grasp window as the
# tolerance (``kinematic.GRASP_TOL_XY`` / ``GRASP_TOL_Z``) and ε such that the term is 0.1 at this
# distance (m; the appendix leaves ε open: tasks/manipulation/rewards.py).
CENTRE_MARGIN = 0.1

PLAYGROUND_PPO_SOURCE = 'mujoco_playground/config/manipulation_params.py: brax_ppo_config("PandaPickCube")'
PLAYGROUND_SAC_SOURCE = "mujoco_playground/config/dm_control_suite_params.py: brax_sac_config (no manipulation entry)"
PLAYGROUND = {
    "ppo": dict(num_envs=2048, batch_size=512, num_minibatches=32, num_updates_per_batch=8, unroll_length=10,
                discounting=0.97, learning_rate=1e-3, entropy_cost=2e-2, reward_scaling=1.0,
                normalize_observations=True, action_repeat=1, num_resets_per_eval=10),
    "sac": dict(num_envs=128, batch_size=512, grad_updates_per_step=8, discounting=0.99, learning_rate=1e-3,
                reward_scaling=1.0, normalize_observations=True, action_repeat=1, max_replay_size=4 * 1048576,
                min_replay_size=8192),
}
PLAYGROUND_NETWORKS = {
    "ppo": dict(policy_hidden_layer_sizes=(32, 32, 32, 32), value_hidden_layer_sizes=(256, 256, 256, 256, 256)),
    "sac": dict(q_network_layer_norm=True),  # (hidden layers: Brax's default, 256 x 256)
}
CPU_CHANGES = {
    "ppo": {
        "num_envs": (256, "one CPU core: 2048 envs only make each unroll slower, not more parallel"),
        "batch_size": (64, "scaled with num_envs: each update still takes 8 unrolls per env in 32 minibatches "
                           "(batch_size x num_minibatches = 8 x num_envs, as Playground's 512 x 32 = 8 x 2048)"),
        "num_resets_per_eval": (0, "Playground's 10 host resets between evaluations would cut the task's "
                                   "600-step episodes short at these budgets; FreshAutoReset gives every "
                                   "episode a fresh start instead"),
    },
    "sac": {
        "max_replay_size": ("min(4194304, num_timesteps)", "a buffer larger than the run's env steps is never "
                                                           "filled (Brax allocates it whole)"),
    },
}
# --smoke: every part at sizes a CPU runs in seconds (episodes of 20 steps).
SMOKE_EPISODE_LENGTH = 20
SMOKE = {
    "ppo": dict(num_envs=8, batch_size=8, num_minibatches=4, num_updates_per_batch=2, unroll_length=5),
    "sac": dict(num_envs=8, batch_size=16, grad_updates_per_step=2, max_replay_size=4096, min_replay_size=64),
}
SMOKE_NETWORKS = {"ppo": dict(policy_hidden_layer_sizes=(16,), value_hidden_layer_sizes=(16,)),
                  "sac": dict(hidden_layer_sizes=(16,))}
SMOKE_LEARNERS = (("ppo", "shaped"), ("sac", "sparse"))  # both learners, both rewards, in two runs
SMOKE_BUDGET = 640
SMOKE_EVALS = 2
SMOKE_EVAL_EPISODES = 4


# ----------------------------------------------------------------------------- JAX compatibility

def install_device_put_replicated() -> bool:
    """Define ``jax.device_put_replicated(x, devices)`` if this JAX lacks it (Brax 0.14's PPO and SAC
    trainers replicate their training state with it). As the removed function did: every leaf of
    ``x`` stacked ``len(devices)`` times along a new leading axis, one slice on each device (a
    ``NamedSharding`` over a 1-D mesh of ``devices``), the layout ``jax.pmap`` takes. Returns whether
    it was installed (False: JAX has its own)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    if hasattr(jax, "device_put_replicated"):
        return False

    def device_put_replicated(x, devices):
        devices = list(devices)
        mesh = jax.sharding.Mesh(np.array(devices), ("replica",))
        sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("replica"))

        def put(leaf):
            leaf = jnp.asarray(leaf)
            return jax.device_put(jnp.broadcast_to(leaf, (len(devices),) + leaf.shape), sharding)

        return jax.tree_util.tree_map(put, x)

    jax.device_put_replicated = device_put_replicated
    return True


# ----------------------------------------------------------------------------- rewards

def task_cubes(task: str):
    """(top cube, bottom cube or None) of a lift_* / stack_*_on_* task; ValueError for the others."""
    from tasks.manipulation import task_defs

    name = task_defs.canonical(task)
    if name.startswith("lift_"):
        return name[len("lift_"):], None
    if name.startswith("stack_") and "_on_" in name:
        top, bottom = name[len("stack_"):].split("_on_")
        return top, bottom
    raise ValueError(f"task {task!r} has no shaped reward here: use lift, stack, lift_<cube> or stack_<cube>_on_<cube>")


def shaped_terms(task: str, inp) -> dict:
    """The shaped reward's terms (module docstring), each in [0, 1], from ``task_defs.Inputs``."""
    import jax.numpy as jnp

    from tasks.manipulation import kinematic as K
    from tasks.manipulation import layout as L
    from tasks.manipulation import rewards as R
    from tasks.manipulation import task_defs

    top, bottom = task_cubes(task)
    p_top = inp.cubes[..., L.CUBE_INDEX[top], :]
    held = R.reach_sparse(inp.pinch_pos, p_top) * inp.grasp  # the grasp sensor, T between the pads
    window = jnp.asarray([K.GRASP_TOL_XY, K.GRASP_TOL_XY, K.GRASP_TOL_Z])
    off = jnp.linalg.norm((inp.pinch_pos - p_top) / window, axis=-1)
    epsilon = R.epsilon_for_margin(CENTRE_MARGIN / K.GRASP_TOL_XY)
    centre = jnp.where(off <= 1.0, 1.0, 1.0 - jnp.tanh(off * epsilon) ** 2)
    terms = {"reach": R.reach_dense(inp.pinch_pos, p_top), "centre": centre, "grasp": held}
    if bottom is None:
        height = (p_top[..., 2] - L.CUBE_HALF) / (R.LIFT_Z_DESIRED - L.CUBE_HALF)
        terms["lift"] = held * jnp.clip(height, 0.0, 1.0)
    else:
        terms["hover"] = R.hover_dense(p_top, inp.cubes[..., L.CUBE_INDEX[bottom], :])
    terms["task"] = task_defs.get(task).reward(inp)
    return terms


def shaped_terms_names(task: str) -> list:
    """The names of ``shaped_terms(task, ...)``, in its order."""
    return ["reach", "centre", "grasp", "lift" if task_cubes(task)[1] is None else "hover", "task"]


def shaped_reward(task: str, inp):
    """Σ weight · term over ``shaped_terms`` (weights ``SHAPED_WEIGHTS``)."""
    return sum(SHAPED_WEIGHTS[name] * value for name, value in shaped_terms(task, inp).items())


def observation_inputs(obs):
    """``task_defs.Inputs`` of one observation [OBS_SIZE] (``schedules.inputs_from_obs``)."""
    import jax

    from training.experiments.schedules import inputs_from_obs

    return jax.tree_util.tree_map(lambda x: x[0], inputs_from_obs(obs[None]))


# ----------------------------------------------------------------------------- env wrappers

def _wrappers():
    """The two wrapper classes (defined on first use: importing this module imports no Brax)."""
    import jax
    import jax.numpy as jnp
    from brax.envs.base import Wrapper

    class TaskReward(Wrapper):
        """The task env paying ``reward`` ("sparse": its own; "shaped": ``shaped_reward`` of the
        observation), with ``done`` always 0: time limits are Brax's ``EpisodeWrapper``'s, which
        marks them as truncations (both trainers then treat the last step as no termination)."""

        def __init__(self, env, task: str, reward: str):
            super().__init__(env)
            if reward not in REWARDS:
                raise ValueError(f"unknown reward {reward!r}; valid: {', '.join(REWARDS)}")
            if reward == "shaped":
                task_cubes(task)
            self.task, self.reward = task, reward

        def step(self, state, action):
            state = self.env.step(state, action)
            reward = state.reward
            if self.reward == "shaped":
                reward = shaped_reward(self.task, observation_inputs(state.obs))
            return state.replace(reward=jnp.asarray(reward, state.reward.dtype), done=jnp.zeros_like(state.done))

    class FreshAutoReset(Wrapper):
        """Brax's ``AutoResetWrapper``, except that an env whose episode ended starts the next one
        from a new draw of the task's reset distribution (``env.reset`` with a key carried in
        ``info["reset_key"]``) instead of the first start it was given: with a few hundred envs and
        no host resets, Brax's would train on a few hundred start states only."""

        def reset(self, rng):
            state = self.env.reset(rng)
            state.info["reset_key"] = jax.vmap(lambda k: jax.random.fold_in(k, 1))(rng)
            return state

        def step(self, state, action):
            if "steps" in state.info:
                state.info.update(steps=jnp.where(state.done, jnp.zeros_like(state.info["steps"]), state.info["steps"]))
            state = self.env.step(state.replace(done=jnp.zeros_like(state.done)), action)
            keys = jax.vmap(jax.random.split)(state.info["reset_key"])
            fresh = self.env.reset(keys[:, 0])
            done = state.done

            def pick(new, old):
                return jnp.where(jnp.reshape(done, done.shape + (1,) * (old.ndim - done.ndim)), new, old)

            info = dict(state.info, reset_key=keys[:, 1])
            pipeline_state = jax.tree_util.tree_map(pick, fresh.pipeline_state, state.pipeline_state)
            return state.replace(pipeline_state=pipeline_state, obs=jax.tree_util.tree_map(pick, fresh.obs, state.obs),
                                 info=info)

    return TaskReward, FreshAutoReset


def idle_env(observation_size: int, action_size: int):
    """A Brax env of the given sizes in which nothing happens (zero observations and rewards).
    Brax's SAC trainer always runs its own evaluator, with no switch to turn it off: it runs on this
    env (``eval_env``), since the project's evaluator replaces it, so that it costs neither an
    env's compilation nor its steps."""
    import jax.numpy as jnp
    from brax.envs.base import Env, State

    class Idle(Env):
        observation_size = property(lambda self: observation_size)
        action_size = property(lambda self: action_size)
        backend = property(lambda self: "idle")

        def reset(self, rng):
            zero = jnp.zeros(())
            return State(pipeline_state=None, obs=jnp.zeros(observation_size), reward=zero, done=zero)

        def step(self, state, action):
            return state

    return Idle()


def wrap_for_training(env, episode_length: int = 1000, action_repeat: int = 1, randomization_fn=None):
    """The trainers' ``wrap_env_fn``: Brax's ``VmapWrapper`` and ``EpisodeWrapper``, then
    ``FreshAutoReset`` (in place of Brax's ``AutoResetWrapper``)."""
    from brax.envs.wrappers.training import EpisodeWrapper, VmapWrapper

    if randomization_fn is not None:
        raise ValueError("the kinematic tasks have no domain randomization")
    return _wrappers()[1](EpisodeWrapper(VmapWrapper(env), episode_length, action_repeat))


def make_env(task: str, reward: str, smoke: bool = False):
    """(the task env the evaluator runs, the env the trainer trains on: ``TaskReward`` of it)."""
    import tasks

    env = tasks.make(task, physics="kinematic", **({"episode_length": SMOKE_EPISODE_LENGTH} if smoke else {}))
    return env, _wrappers()[0](env, task, reward)


# ----------------------------------------------------------------------------- hyperparameters

def hyperparameters(algo: str, num_timesteps: int, smoke: bool = False):
    """(trainer keyword arguments, network factory keyword arguments) of ``algo``: Playground's,
    with ``CPU_CHANGES`` (and ``SMOKE`` sizes with ``smoke``)."""
    kwargs = dict(PLAYGROUND[algo])
    network = dict(PLAYGROUND_NETWORKS[algo])
    for name, (value, _) in CPU_CHANGES[algo].items():
        kwargs[name] = value
    if algo == "sac":
        kwargs["max_replay_size"] = min(PLAYGROUND["sac"]["max_replay_size"], int(num_timesteps))
    if smoke:
        kwargs.update(SMOKE[algo])
        network.update(SMOKE_NETWORKS[algo])
    return kwargs, network


def trainer_arguments(train_fn, given: dict) -> dict:
    """Every JSON-representable argument ``train_fn`` runs with: its defaults, then ``given``."""
    out = {}
    for name, p in inspect.signature(train_fn).parameters.items():
        value = given.get(name, p.default)
        if value is inspect.Parameter.empty or callable(value):
            continue
        try:
            json.dumps(value)
        except TypeError:
            continue
        out[name] = value
    return out


def versions() -> dict:
    import brax
    import jax
    import jaxlib

    return {"jax": jax.__version__, "jaxlib": jaxlib.__version__, "brax": brax.__version__,
            "python": sys.version.split()[0]}


# ----------------------------------------------------------------------------- evaluation and files

def make_evaluation(env, make_policy, num_episodes: int, seed: int):
    """``evaluate(params, index) -> {"eval/success", "eval/return", "eval/final_success"}``: the
    project's evaluator (``rollout_episodes``, jitted once) on ``num_episodes`` episodes of ``env``,
    acting with ``make_policy(params, deterministic=True)``; the keys from (seed, index) as SkillS's."""
    import jax
    import numpy as np

    from parallel_skills.evaluation import rollout_episodes

    def run(params, key):
        policy = make_policy(params, deterministic=True)
        return rollout_episodes(env, lambda obs, k: policy(obs, k)[0], key, num_episodes, env.episode_length)

    run = jax.jit(run)
    base_key = jax.random.PRNGKey(seed + 10_000)

    def evaluate(params, index: int) -> dict:
        ev = jax.device_get(run(params, jax.random.fold_in(base_key, index)))
        return {"eval/success": float(np.mean(ev["success"])), "eval/return": float(np.mean(ev["return"])),
                "eval/final_success": float(np.mean(ev["final_success"]))}

    return evaluate


class Recorder:
    """Evaluates the params the trainer hands over (``record(step, make_policy, params)``) and
    appends one row to RUN/metrics.csv; step 0 (before training) is not recorded."""

    def __init__(self, run_dir: str, env, num_episodes: int, seed: int, label: str):
        self.env, self.num_episodes, self.seed, self.label = env, num_episodes, seed, label
        self.evaluate = None
        self.index = 0
        self.t0 = time.perf_counter()
        self.file = open(os.path.join(run_dir, "metrics.csv"), "w", newline="")
        self.writer = csv.DictWriter(self.file, fieldnames=METRICS)
        self.writer.writeheader()
        self.file.flush()

    def record(self, step: int, make_policy, params):
        if step == 0:
            return
        if self.evaluate is None:
            self.evaluate = make_evaluation(self.env, make_policy, self.num_episodes, self.seed)
        self.index += 1
        row = self.evaluate(params, self.index)
        row = {"env_steps": int(step), "wall_time": time.perf_counter() - self.t0, **row}
        self.writer.writerow(row)
        self.file.flush()
        print(f"{self.label} env_steps={row['env_steps']} wall={row['wall_time']:.0f}s "
              f"success={row['eval/success']:.3f} return={row['eval/return']:.2f}", flush=True)

    def close(self):
        self.file.close()


def train_run(task: str, algo: str, reward: str, seed: int, num_timesteps: int, run_dir: str,
              num_evals: int = NUM_EVALS, eval_episodes: int = EVAL_EPISODES, smoke: bool = False,
              command: str = "") -> str:
    """One run: writes RUN/config.json, then trains with Brax's trainer, one metrics.csv row per
    evaluation. Returns ``run_dir``."""
    install_device_put_replicated()
    env, train_env = make_env(task, reward, smoke)
    kwargs, network = hyperparameters(algo, num_timesteps, smoke)
    os.makedirs(run_dir, exist_ok=True)
    label = f"{task} {algo}-{reward} s{seed}"
    common = dict(num_timesteps=int(num_timesteps), episode_length=env.episode_length, seed=int(seed),
                  num_evals=int(num_evals) + 1, wrap_env_fn=wrap_for_training)  # (+1: Brax's evaluation at step 0)
    if algo == "ppo":
        from brax.training.agents.ppo import networks as algo_networks
        from brax.training.agents.ppo import train as algo_train

        factory = functools.partial(algo_networks.make_ppo_networks, **network)
        common.update(run_evals=False)  # (the project's evaluator replaces Brax's)
    else:
        from brax.training.agents.sac import networks as algo_networks
        from brax.training.agents.sac import train as algo_train

        factory = functools.partial(algo_networks.make_sac_networks, **network)
        # SAC always runs Brax's evaluator: one episode of an idle env (the project's replaces it).
        common.update(num_eval_envs=1, deterministic_eval=True,
                      eval_env=idle_env(env.observation_size, env.action_size),
                      checkpoint_logdir=os.path.abspath(os.path.join(run_dir, "checkpoints")))
    recorded = {**kwargs, **common}
    if algo == "sac":
        recorded["checkpoint_logdir"] = "checkpoints"  # (in the run directory: no machine path)
    network_defaults = trainer_arguments(factory.func, network)
    network_defaults.pop("observation_size", None)
    network_defaults.pop("action_size", None)
    config = {
        "bench": "bench/peers.py", "command": command, "task": task, "physics": "kinematic", "algo": algo,
        "reward": reward, "reward_weights": ({k: SHAPED_WEIGHTS[k] for k in shaped_terms_names(task)}
                                             if reward == "shaped" else {"task": 1.0}),
        "seed": int(seed), "num_timesteps": int(num_timesteps), "evaluations": int(num_evals),
        "eval_episodes": int(eval_episodes), "episode_length": env.episode_length, "smoke": smoke,
        "trainer": f"brax.training.agents.{algo}.train.train",
        "hyperparameters": trainer_arguments(algo_train.train, recorded),
        "network": {"factory": f"brax.training.agents.{algo}.networks.make_{algo}_networks", **network_defaults},
        "source": PLAYGROUND_PPO_SOURCE if algo == "ppo" else PLAYGROUND_SAC_SOURCE,
        "playground": {**PLAYGROUND[algo], "network": PLAYGROUND_NETWORKS[algo]},
        "cpu_changes": {k: {"value": v, "why": why} for k, (v, why) in CPU_CHANGES[algo].items()},
        "env_wrappers": "TaskReward, VmapWrapper, EpisodeWrapper, FreshAutoReset (bench/peers.py)",
        "versions": versions(),
    }
    write_json_atomic(os.path.join(run_dir, "config.json"), config, indent=1, default=list)
    recorder = Recorder(run_dir, train_env, eval_episodes, seed, label)
    try:
        if algo == "ppo":
            algo_train.train(train_env, network_factory=factory, **kwargs, **common, policy_params_fn=recorder.record)
        else:
            algo_train.train(train_env, network_factory=factory, **kwargs, **common,
                             progress_fn=_sac_progress(recorder, env, factory, common["checkpoint_logdir"],
                                                       kwargs["normalize_observations"]))
    finally:
        recorder.close()
    return run_dir


def _sac_progress(recorder: Recorder, env, factory, checkpoints: str, normalize: bool):
    """SAC's ``progress_fn``: loads the checkpoint Brax saved at this step (removing older ones) and
    records its evaluation."""
    from brax.training.acme import running_statistics
    from brax.training.agents.sac import checkpoint
    from brax.training.agents.sac import networks as sac_networks

    network = factory(observation_size=env.observation_size, action_size=env.action_size,
                      preprocess_observations_fn=running_statistics.normalize if normalize else (lambda x, y: x))
    make_policy = sac_networks.make_inference_fn(network)

    def progress(step, metrics):
        if step == 0:
            return
        path = os.path.join(checkpoints, f"{int(step):012d}")
        params = checkpoint.load(path)
        for name in os.listdir(checkpoints):
            if name != os.path.basename(path) and name.isdigit():
                shutil.rmtree(os.path.join(checkpoints, name), ignore_errors=True)
        recorder.record(step, make_policy, params)

    return progress


# ----------------------------------------------------------------------------- runs on disk

def run_dir_of(out: str, task: str, algo: str, reward: str, seed: int) -> str:
    return os.path.join(out, task, f"{algo}-{reward}", f"s{seed}")


def read_rows(run_dir: str) -> list:
    """The evaluation rows of RUN/metrics.csv ([] if none)."""
    from training.logging_utils import read_metrics

    path = os.path.join(run_dir, "metrics.csv")
    if not os.path.isfile(path):
        return []
    return [r for r in read_metrics(path) if isinstance(r.get("env_steps"), float)]


def run_status(run_dir: str, budget: int) -> str:
    """"done" (its metrics reached ``budget`` env steps), "restart" (started, cut before) or "new"."""
    if not os.path.isdir(run_dir):
        return "new"
    rows = read_rows(run_dir)
    return "done" if rows and rows[-1]["env_steps"] >= budget else "restart"


# ----------------------------------------------------------------------------- report

@dataclasses.dataclass(frozen=True)
class Reach:
    """A learner's time to the threshold over its seeds: mean env steps and wall seconds (a seed that
    never reached it counts its last evaluation: ``lower_bound``), seeds that reached it, the mean
    of each seed's best success."""

    steps: float
    wall: float
    reached: int
    seeds: int
    best: float

    @property
    def lower_bound(self) -> bool:
        return self.reached < self.seeds


def time_to_threshold(runs: list, threshold: float, key: str):
    """``Reach`` of ``runs`` (each a list of metrics rows), None without runs."""
    from training.experiments.time_to_success import first_success

    runs = [r for r in runs if r]
    if not runs:
        return None
    steps, walls, reached, best = [], [], 0, []
    for rows in runs:
        hit = first_success(rows, threshold, key=key)
        reached += hit is not None
        row = hit if hit is not None else rows[-1]
        steps.append(float(row["env_steps"]))
        walls.append(float(row["wall_time"]))
        best.append(max(float(r[key]) for r in rows if isinstance(r.get(key), float)))
    n = len(runs)
    return Reach(sum(steps) / n, sum(walls) / n, reached, n, sum(best) / n)


def ratio(peer: Reach, skills: Reach, field: str):
    """(peer's figure / SkillS's, qualifier): "" exact, "≥" where only the peer's is a lower bound,
    "≤" where only SkillS's is; None where both are (nothing follows)."""
    if peer.lower_bound and skills.lower_bound:
        return None
    value = getattr(peer, field) / getattr(skills, field)
    return value, ("≥" if peer.lower_bound else "≤" if skills.lower_bound else "")


def _steps_text(n: float) -> str:
    return f"{n / 1e6:.2f}M" if n >= 1e6 else f"{n / 1e3:.1f}k"


def report(out: str, task_list: list, learners: list, seeds: list, skills_runs: str, skills_variant: str,
           threshold: float) -> str:
    """The table (markdown) of ``--report``: SkillS's row, then one per (algo, reward) of ``learners``."""
    lines = [f"Time to success ≥ {threshold:g} (the first evaluation at or above it; mean over seeds; ≥: a seed "
             "never reached it and counts its last evaluation). Ratios: the peer's figure / SkillS's.", "",
             "| task | learner | seeds reached | env steps | wall s | best success | env steps / SkillS | "
             "wall / SkillS |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for task in task_list:
        skills = time_to_threshold([read_rows(os.path.join(skills_runs, task, skills_variant, f"s{s}")) for s in seeds],
                                   threshold, "eval/new_skill_success")
        rows = [(f"SkillS ({skills_variant})", skills)]
        rows += [(f"{a}-{r}", time_to_threshold([read_rows(run_dir_of(out, task, a, r, s)) for s in seeds],
                                                threshold, "eval/success")) for a, r in learners]
        for name, reach in rows:
            if reach is None:
                lines.append(f"| {task} | {name} | no runs | – | – | – | – | – |")
                continue
            mark = "≥ " if reach.lower_bound else ""
            cells = [f"{reach.reached}/{reach.seeds}", mark + _steps_text(reach.steps), f"{mark}{reach.wall:.0f}",
                     f"{reach.best:.2f}"]
            for field in ("steps", "wall"):
                r = None if skills is None or reach is skills else ratio(reach, skills, field)
                cells.append("–" if r is None else f"{r[1]} {r[0]:.1f}x".strip())
            lines.append(f"| {task} | {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- command line

def _items(text: str, valid, what: str) -> list:
    items = [x.strip() for x in text.split(",") if x.strip()]
    bad = [x for x in items if x not in valid]
    if not items or bad:
        raise UsageError(f"--{what}: unknown {', '.join(bad) or '(none given)'}; valid: {', '.join(valid)}")
    if len(set(items)) != len(items):
        raise UsageError(f"--{what}: an item is given twice in {text!r}")
    return items


def _budgets(text, task_list: list, smoke: bool) -> dict:
    budgets = {t: SMOKE_BUDGET for t in task_list} if smoke else dict(BUDGETS)
    for item in filter(None, (text or "").split(",")):
        task, sep, value = item.partition("=")
        if not sep or not value.strip().isdigit() or int(value) < 1:
            raise UsageError(f"bad --num_timesteps item {item!r}: use task=env_steps (a positive integer)")
        budgets[task.strip()] = int(value)
    missing = [t for t in task_list if t not in budgets]
    if missing:
        raise UsageError(f"no budget for {', '.join(missing)}: give --num_timesteps {missing[0]}=N")
    return budgets


def build_parser():
    p = Parser(prog="python bench/peers.py", description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default=None, help="comma-separated lift_* / stack_*_on_* tasks (default lift,stack; "
                   "--smoke: lift)")
    p.add_argument("--algos", default=None, help="ppo, sac (default both)")
    p.add_argument("--rewards", default=None, help="sparse, shaped (default both; each algo with each reward)")
    p.add_argument("--seeds", default=None, help="default 0,1,2 (--smoke: 0)")
    p.add_argument("--out", required=True, help="runs go to OUT/<task>/<algo>-<reward>/s<seed>/")
    p.add_argument("--num_timesteps", default=None,
                   help="task=env_steps,... (default " + ",".join(f"{t}={n}" for t, n in BUDGETS.items()) + ")")
    p.add_argument("--num_evals", type=int, default=None, help=f"evaluations per run, at equal env-step intervals "
                   f"(default {NUM_EVALS})")
    p.add_argument("--eval_episodes", type=int, default=None, help=f"episodes per evaluation (default {EVAL_EPISODES})")
    p.add_argument("--jobs", type=int, default=1, help="runs at once, each in its own process pinned to its own core "
                   "(1: one after another in this process)")
    p.add_argument("--smoke", action="store_true", help="every part tiny (2 evaluations of 4 episodes of 20 steps, "
                   f"{SMOKE_BUDGET} env steps, small networks; lift; PPO shaped and SAC sparse unless --algos or "
                   "--rewards is given), then the report")
    p.add_argument("--dry_run", action="store_true", help="print the plan only")
    p.add_argument("--report", action="store_true", help="print the table from the runs in OUT; train nothing")
    p.add_argument("--skills_runs", default=SKILLS_RUNS, help="SkillS's runs for the report: "
                   "DIR/<task>/<variant>/s<seed>/metrics.csv (default the archive, docs/results/paper_runs)")
    p.add_argument("--skills_variant", default="default", help="SkillS's variant there (default: default, the "
                   "name under which the paper runner archives today's default recipe)")
    p.add_argument("--threshold", type=float, default=THRESHOLD)
    return p


def plan(args):
    """The validated plan: (tasks, learners: [(algo, reward)], seeds, budgets, num_evals, eval_episodes)."""
    import tasks as task_registry

    default_tasks = "lift" if args.smoke else ",".join(BUDGETS)
    task_list = [t.strip() for t in (args.tasks or default_tasks).split(",") if t.strip()]
    for t in task_list or [""]:
        if t not in task_registry.names():
            raise UsageError(f"--tasks: unknown task {t!r}; valid: {', '.join(task_registry.names())}")
        try:
            task_cubes(t)
        except ValueError as e:
            raise UsageError(f"--tasks: {e}") from None
    algos = _items(args.algos or ",".join(ALGOS), ALGOS, "algos")
    rewards = _items(args.rewards or ",".join(REWARDS), REWARDS, "rewards")
    learners = [(a, r) for a in algos for r in rewards]
    if args.smoke and args.algos is None and args.rewards is None:
        learners = list(SMOKE_LEARNERS)
    try:
        seeds = [int(s) for s in (args.seeds or ("0" if args.smoke else "0,1,2")).split(",") if s.strip()]
    except ValueError:
        raise UsageError(f"--seeds must be non-negative integers separated by commas, got {args.seeds!r}") from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise UsageError(f"--seeds must be distinct non-negative integers separated by commas, got {args.seeds!r}")
    budgets = _budgets(args.num_timesteps, task_list, args.smoke)
    num_evals = args.num_evals if args.num_evals is not None else (SMOKE_EVALS if args.smoke else NUM_EVALS)
    episodes = args.eval_episodes if args.eval_episodes is not None else (
        SMOKE_EVAL_EPISODES if args.smoke else EVAL_EPISODES)
    for name, value in (("--num_evals", num_evals), ("--eval_episodes", episodes), ("--jobs", args.jobs)):
        if value < 1:
            raise UsageError(f"{name} must be a positive integer, got {value}")
    if not 0.0 < args.threshold <= 1.0:
        raise UsageError(f"--threshold must be in (0, 1], got {args.threshold}")
    return task_list, learners, seeds, budgets, num_evals, episodes


def _job_command(args, task, algo, reward, seed, budget, num_evals, episodes) -> list:
    cmd = [sys.executable, os.path.abspath(__file__), "--tasks", task, "--algos", algo, "--rewards", reward,
           "--seeds", str(seed), "--out", args.out, "--num_timesteps", f"{task}={budget}",
           "--num_evals", str(num_evals), "--eval_episodes", str(episodes)]
    return cmd + (["--smoke"] if args.smoke else [])


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.smoke:  # compile fast: the smoke run checks the script, its figures mean nothing
        os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "1"  # (read when JAX starts; JAX may have started)
        import jax

        jax.config.update("jax_disable_most_optimizations", True)
    task_list, learners, seeds, budgets, num_evals, episodes = main_guard(lambda: plan(args))
    if args.report:
        print(report(args.out, task_list, learners, seeds, args.skills_runs, args.skills_variant, args.threshold))
        return
    runs = []
    for task in task_list:
        for algo, reward in learners:
            for seed in seeds:
                run_dir = run_dir_of(args.out, task, algo, reward, seed)
                status = run_status(run_dir, budgets[task])
                print(f"{task:<22} {algo}-{reward:<7} s{seed}: {status}", flush=True)
                if status != "done":
                    runs.append((task, algo, reward, seed, run_dir, status))
    if args.dry_run:
        return
    for *_, run_dir, status in runs:
        if status == "restart":  # cut before its budget: Brax's trainers do not resume; keep it aside
            aside = f"{run_dir}.cut-{time.strftime('%Y%m%d-%H%M%S')}"
            shutil.move(run_dir, aside)
            print(f"  (moved {run_dir} to {aside}: started again)", flush=True)
    command = " ".join(["python bench/peers.py"] + argv)
    failed = []
    if args.jobs > 1 and len(runs) > 1:
        from training.experiments.paper import run_jobs

        jobs = []
        for task, algo, reward, seed, run_dir, _ in runs:
            os.makedirs(os.path.dirname(run_dir), exist_ok=True)
            jobs.append((_job_command(args, task, algo, reward, seed, budgets[task], num_evals, episodes),
                         f"{run_dir}.log"))
        codes = run_jobs(jobs, args.jobs)
        failed = [log for (_, log), c in zip(jobs, codes) if c != 0]
    elif runs:
        from training.run import enable_compilation_cache

        enable_compilation_cache()
        for task, algo, reward, seed, run_dir, _ in runs:
            train_run(task, algo, reward, seed, budgets[task], run_dir, num_evals, episodes, args.smoke, command)
    if args.smoke or len(runs) > 1:
        print(report(args.out, task_list, learners, seeds, args.skills_runs, args.skills_variant, args.threshold))
    if failed:
        print(f"{len(failed)} run(s) failed; their logs: {', '.join(failed)}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
