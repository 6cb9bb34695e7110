"""Train one skill of the library (a Gaussian-MLP new-skill network) on its dense reward task.

    python -m training.train_skill --skill reach_green --physics kinematic --out checkpoints/kinematic/reach_green.npz
    python -m training.train_skill --skill lift_arm_closed --physics kinematic --seed 1 \\
        --out checkpoints/kinematic/lift_arm_closed.s1.npz

The skill's task is the task named like it (``tasks.names()``: ``reach_green``, ``open_fingers``,
``lift_arm_open``, ``lift_arm_closed``, ``hover_green_on_yellow``, ...: the dense skill rewards of
the paper's App. C; and the higher skills, lift X / stack X on Y, whose shipped versions come from
SkillS runs, ``training.chain``, and are cloned here only where a chain's skill fails in states
later tasks bring it to, with ``--bc_prefix``). ``--start_states mixed`` (kinematic) draws every reset of cloning,
fine-tuning and selection from the wider distribution of ``tasks.make``'s ``start_states`` (one
cube on or beside another in two thirds of them): the states a chain's later stages bring a skill
to. Two stages (docs/research/learning.md, docs/research/skills.md):

1. **Behaviour cloning** of the skill's scripted controller (``tasks.manipulation.scripted``) with
   DART-style data: ``--bc_envs`` × ``--bc_steps`` env steps that execute the scripted action plus
   N(0, ``--bc_noise``) noise and are labelled with the clean scripted action; ``--bc_updates`` Adam
   updates of batch ``NewSkillConfig.batch_size`` on the Gaussian negative log-likelihood of the
   new-skill network (``NewSkillConfig`` defaults: torso (128, 256, 128), min_std 0.05), inputs
   normalised with the data's observation statistics (``parallel_skills.normalization``).
2. **Fine-tuning** with the project's own off-policy learner: ``parallel_skills.train`` with
   ``method="scratch"`` (CRR, the new skill acting alone on the dense reward) for ``--crr_steps`` env
   steps, started from the cloned policy and its observation statistics. The fine-tuned policy is
   kept only if its success beats the clone's on a separate selection evaluation (``--eval_episodes``
   episodes of other seeds than the recorded ones); otherwise the clone is shipped. The sidecar's ``trained_with`` says which (``"bc"`` or ``"bc+crr"``).
   ``--crr_steps 0`` skips fine-tuning.

Writes ``--out`` (``.npz``) and its JSON sidecar (``Skill.save``): name, task, domain, physics,
obs / action sizes, network sizes, the exact command, seed, what it was trained with, and its
success over ``--eval_episodes`` (64) episodes measured exactly as ``python -m training.evaluate
--task SKILL --physics PHYSICS --policy OUT --episodes 64 --seed EVAL_SEED`` prints it (recorded as
``eval_command``; on the paper's resets whatever ``--start_states``; with ``--start_states mixed`` also
``start_states_success``, the same with ``--start_states mixed``). Existing files are never overwritten; bad input is one ``error:`` line, exit 2.
The last line printed is ``success=<fraction> return=<mean>``.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time

from training.cli import Parser, UsageError, check_writable, main_guard, nonnegative_int, positive_int

DOMAIN = "manipulation"


def _nonnegative_float(text: str) -> float:
    import argparse

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative number, got {text!r}") from None
    if not value >= 0.0:
        raise argparse.ArgumentTypeError(f"expected a non-negative number, got {text!r}")
    return value


def build_parser():
    import tasks

    p = Parser(prog="python -m training.train_skill", description=__doc__.splitlines()[0])
    p.add_argument("--skill", required=True, help="skill = its task's name (a scripted controller's): " + ", ".join(trainable_skills()))
    p.add_argument("--physics", default="kinematic", help=f"one of {', '.join(tasks.PHYSICS)}; default kinematic")
    p.add_argument("--out", required=True, help="PATH.npz to write (with PATH.json); never overwritten")
    p.add_argument("--seed", type=nonnegative_int, default=0)
    p.add_argument("--start_states", default="table",
                   help="reset distribution of every stage: table (the paper's) or mixed (kinematic; also one cube "
                        "on or beside another) or TOP_on_BOTTOM (kinematic; half with that cube on the other, e.g. "
                        "yellow_on_blue) or after:NAME:K (kinematic; half where library skill NAME leaves the table resets after K steps)")
    p.add_argument("--bc_envs", type=positive_int, default=512, help="envs collecting cloning data (default 512)")
    p.add_argument("--bc_steps", type=positive_int, default=200, help="steps per env of cloning data (default 200)")
    p.add_argument("--bc_noise", type=_nonnegative_float, default=0.3,
                   help="std of the Gaussian noise added to the executed scripted action (default 0.3)")
    p.add_argument("--bc_updates", type=nonnegative_int, default=4000, help="Adam updates of cloning (default 4000)")
    p.add_argument("--bc_prefix", default="",
                   help="NAME:K[,NAME:K...]: in --bc_prefix_fraction of the cloning envs, run these scripted "
                        "controllers first (K steps each, same noise, not recorded), so the data also start where "
                        "a schedule's earlier skills leave the scene (e.g. stack_yellow_on_blue:200 before "
                        "stack_green_on_yellow)")
    p.add_argument("--bc_prefix_fraction", type=_nonnegative_float, default=0.5,
                   help="fraction of the cloning envs that run --bc_prefix first (default 0.5)")
    p.add_argument("--crr_steps", type=nonnegative_int, default=100_000,
                   help="env steps of CRR fine-tuning with parallel_skills.train (0: clone only; default 100000)")
    p.add_argument("--crr_envs", type=positive_int, default=None,
                   help="envs of the fine-tuning run (default: the trainer's device default, 32 on CPU)")
    p.add_argument("--eval_episodes", type=positive_int, default=64, help="episodes of the recorded success (64)")
    p.add_argument("--eval_seed", type=nonnegative_int, default=0,
                   help="--seed of the training.evaluate run the recorded success equals (default 0)")
    p.add_argument("--also_eval", nargs="+", default=[], metavar="PHYSICS",
                   help="also measure the saved skill with training.evaluate on these backends of the same scene "
                        "(e.g. --physics mujoco --also_eval mjx warp); recorded under the sidecar's 'evaluations'")
    return p


def also_eval_choices(physics: str) -> tuple[str, ...]:
    """Backends that share ``physics``' scene (the physics MJCF: mujoco, mjx, warp), other than it."""
    from training.skill_library import library_dir

    import tasks

    return tuple(p for p in tasks.PHYSICS if p != physics and library_dir(p) == library_dir(physics))


def evaluate_in_subprocess(task: str, physics: str, policy: str, episodes: int, seed: int) -> tuple[float, float]:
    """``python -m training.evaluate`` in its own process (MJX pins its process to one core: the
    trainer's process keeps both); returns the (success, return) of its last line."""
    import subprocess

    cmd = [sys.executable, "-m", "training.evaluate", "--task", task, "--physics", physics, "--policy", policy,
           "--episodes", str(episodes), "--seed", str(seed)]
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])))
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines or not lines[-1].startswith("success="):
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"training.evaluate on {physics} failed (exit {done.returncode}): {tail}")
    fields = dict(kv.split("=") for kv in lines[-1].split())
    return float(fields["success"]), float(fields["return"])


def trainable_skills() -> list[str]:
    """Skills this command trains: the tasks with a scripted controller to clone — the dense skill
    tasks and the higher skills lift X / stack X on Y (sparse; the chain trains them with SkillS
    instead), not the paper's full tasks (pyramid, triple stack) nor the short names lift / stack."""
    from tasks.manipulation import scripted, task_defs

    full = set(task_defs.ALIASES) | {"pyramid", "triple_stack"}
    return [n for n in task_defs.names() if n in scripted.names() and n not in full]


def parse_prefix(text: str) -> tuple[tuple[str, int], ...]:
    """``--bc_prefix`` ``NAME:K[,NAME:K...]`` -> ((scripted controller, K), ...); UsageError naming the
    form and the controllers otherwise. '' -> ()."""
    from tasks.manipulation import scripted

    if not text:
        return ()
    steps = []
    for part in text.split(","):
        name, colon, k = part.partition(":")
        if not colon or not k.isdigit() or int(k) < 1:
            raise UsageError(f"--bc_prefix {text!r}: step {part!r} is not NAME:K (a scripted controller held K ≥ 1 "
                             f"env steps), e.g. stack_yellow_on_blue:200")
        if name not in scripted.names():
            raise UsageError(f"--bc_prefix {text!r}: {name!r} is not a scripted controller; valid: "
                             f"{', '.join(scripted.names())}")
        steps.append((name, int(k)))
    return tuple(steps)


def _command(argv) -> str:
    return " ".join(["python -m training.train_skill"] + list(argv))


def _check_out(out: str) -> str:
    if not out.endswith(".npz"):
        raise UsageError(f"--out must be a PATH.npz (its sidecar is PATH.json), got {out!r}")
    base = out[:-4]
    for path in (base + ".npz", base + ".json"):
        if os.path.exists(path):
            raise UsageError(f"{path} already exists; choose a new --out (skills are never overwritten)")
    check_writable(out, "the skill file")
    return base


def make_env(skill: str, physics: str, num_envs: int, start_states: str = "table"):
    import tasks

    overrides = {} if start_states == "table" else {"start_states": start_states}
    if physics == "mjx":
        from tasks.manipulation.mjx_env import pin_to_one_core

        pin_to_one_core()  # MJX-jax can deadlock on 2 unpinned CPU cores (STACK.md)
    if physics in ("mjx", "warp"):
        overrides["max_envs"] = num_envs  # MJX-Warp sizes its contact buffer for the batch
    return tasks.make(skill, physics=physics, **overrides)


# ----------------------------------------------------------------------------- behaviour cloning

def collect_dart(env, controller, key, num_envs: int, num_steps: int, noise: float, prefix=()):
    """DART-style cloning data: execute clip(controller(obs) + N(0, noise²)), label with the clean
    controller action. ``prefix``: ((controller, K), ...) run first, each K steps with the same noise
    and not recorded, so the data start where those skills leave the scene (e.g. yellow stacked on
    blue before ``stack_green_on_yellow``). Returns {"obs" [E·T, O], "action" [E·T, A]} (jitted
    rollout)."""
    import jax
    import jax.numpy as jnp

    def noisy_steps(state, ctl, key, steps, record):
        ctl = jax.vmap(ctl)

        def body(s, k):
            k_ctl, k_noise = jax.random.split(k)
            label = ctl(s.obs, jax.random.split(k_ctl, num_envs)).astype(jnp.float32)
            act = jnp.clip(label + noise * jax.random.normal(k_noise, label.shape), -1.0, 1.0)
            return jax.vmap(env.step)(s, act), ((s.obs, label) if record else None)

        return jax.lax.scan(body, state, jax.random.split(key, steps))

    @jax.jit
    def run(key):
        k0, k1 = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(k0, num_envs))
        for (ctl, k), kp in zip(prefix, jax.random.split(jax.random.fold_in(key, 1), max(len(prefix), 1))):
            state, _ = noisy_steps(state, ctl, kp, k, record=False)
        _, (obs, label) = noisy_steps(state, controller, k1, num_steps, record=True)
        return {"obs": obs.reshape(-1, obs.shape[-1]), "action": label.reshape(-1, label.shape[-1])}

    return run(key)


def behaviour_clone(data, action_size: int, config, key, num_updates: int):
    """Gaussian NLL of the new-skill policy network on ``data`` (inputs normalised with the data's
    statistics). Returns (policy params, RunningStats, final mean NLL)."""
    import jax
    import jax.numpy as jnp
    import optax

    from parallel_skills import learners, networks
    from parallel_skills import normalization as norm

    obs, act = data["obs"], data["action"]
    stats = norm.update(norm.init(obs.shape[-1]), obs)
    x_all = norm.normalize(stats, obs)
    policy, _ = learners.new_skill_networks(action_size, config)
    k_init, k_train = jax.random.split(key)
    params = policy.init(k_init, x_all[:1])
    opt = optax.chain(optax.clip_by_global_norm(config.grad_clip_norm), optax.adam(config.learning_rate))
    n, batch = x_all.shape[0], config.batch_size

    def loss_fn(p, x, a):
        mean, std = policy.apply(p, x)
        return -jnp.mean(networks.gaussian_log_prob(mean, std, a))

    @jax.jit
    def fit(params, key):
        def body(carry, k):
            p, o = carry
            idx = jax.random.randint(k, (batch,), 0, n)
            loss, g = jax.value_and_grad(loss_fn)(p, x_all[idx], act[idx])
            upd, o = opt.update(g, o, p)
            return (optax.apply_updates(p, upd), o), loss

        (p, _), losses = jax.lax.scan(body, (params, opt.init(params)), jax.random.split(key, num_updates))
        return p, jnp.mean(losses[-100:]) if num_updates else jnp.nan

    params, nll = fit(params, k_train)
    return params, stats, float(nll)


# ----------------------------------------------------------------------------- CRR fine-tuning

FINETUNE_SAMPLES_PER_INSERT = 16.0


def finetune(env, policy_params, stats, seed: int, num_timesteps: int, num_envs=None):
    """``parallel_skills.train`` with ``method="scratch"`` started from ``policy_params`` (online and
    target policy) and the cloning data's observation statistics. Returns (policy params, stats,
    train metrics)."""
    import jax
    import jax.numpy as jnp

    from parallel_skills import NewSkillConfig, TrainConfig, make_trainer, train
    from parallel_skills.config import resolve

    # Pinned, not the trainer's CPU recipe (which may change with what SkillS needs): the shipped
    # skills were fine-tuned with these settings.
    cfg = TrainConfig(method="scratch", num_envs=num_envs, eval_episodes=8, eval_every=10**9,  # evaluates once, at the end
                      new_skill=NewSkillConfig(samples_per_insert=FINETUNE_SAMPLES_PER_INSERT))
    resolved, _ = resolve(cfg)
    trainer = make_trainer(env, [], resolved)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(seed))
    copy = lambda tree: jax.tree.map(jnp.array, tree)  # noqa: E731 (own buffers: train() donates its state)
    new_skill = state.new_skill.replace(policy_params=copy(policy_params), target_policy_params=copy(policy_params))
    state = state.replace(new_skill=new_skill, normalizer=copy(stats))
    _, params, metrics = train(env, [], num_timesteps=num_timesteps, seed=seed, config=cfg, initial_state=state)
    return params.new_skill, params.normalizer, metrics


# ----------------------------------------------------------------------------- main

def skill_from(name, policy_params, stats, action_size, config):
    from parallel_skills import Skill
    from parallel_skills.skills import GaussianSkillParams

    return Skill.gaussian_mlp(name, GaussianSkillParams.from_normalizer(policy_params, stats),
                              action_size, config.hidden)


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)

    def validate():
        import tasks

        if args.skill not in trainable_skills():
            hint = ""
            if args.skill in tasks.names():
                from tasks.manipulation import task_defs

                hint = (f" (short for {task_defs.ALIASES[args.skill]})" if args.skill in task_defs.ALIASES else
                        " (a task without a scripted controller, or one of the paper's full tasks: not a library skill)")
            raise UsageError(f"unknown skill {args.skill!r}{hint}; valid: {', '.join(trainable_skills())}")
        if args.physics not in tasks.PHYSICS:
            raise UsageError(f"unknown physics {args.physics!r}; valid: {', '.join(tasks.PHYSICS)}")
        tasks.check_start_states(args.skill, args.physics, args.start_states)  # ValueError: one line
        args.prefix_steps = prefix = parse_prefix(args.bc_prefix)  # ((scripted controller name, K), ...)
        if not args.bc_prefix_fraction <= 1.0:
            raise UsageError(f"--bc_prefix_fraction must be in [0, 1], got {args.bc_prefix_fraction}")
        from tasks.manipulation import layout

        used = sum(k for _, k in prefix) + args.bc_steps
        if prefix and used > layout.DEFAULT_EPISODE_LENGTH:
            raise UsageError(f"--bc_prefix steps + --bc_steps = {used}: more than an episode "
                             f"({layout.DEFAULT_EPISODE_LENGTH} steps)")
        allowed = also_eval_choices(args.physics)
        for p in args.also_eval:
            if p not in allowed:
                raise UsageError(f"--also_eval {p!r}: not another backend of the {args.physics} scene; valid: "
                                 f"{', '.join(allowed) or 'none'}")
        return _check_out(args.out)

    base = main_guard(validate)
    from training.run import enable_compilation_cache

    enable_compilation_cache()
    _train_skill(args, argv, base)


def _train_skill(args, argv, base):
    import jax
    import jax.numpy as jnp
    import numpy as np

    from parallel_skills import NewSkillConfig
    from tasks.manipulation import scripted
    from training.evaluate import evaluate_policy

    t0 = time.perf_counter()
    config = NewSkillConfig()
    env = make_env(args.skill, args.physics, args.bc_envs, args.start_states)
    key = jax.random.PRNGKey(args.seed)
    k_data, k_bc, k_sel = jax.random.split(key, 3)
    print(f"skill={args.skill} physics={args.physics} seed={args.seed}: cloning the scripted controller "
          f"({args.bc_envs} envs x {args.bc_steps} steps, noise {args.bc_noise}, {args.bc_updates} updates)", flush=True)
    prefix = tuple((scripted.get(n), k) for n, k in args.prefix_steps)
    n_pre = int(round(args.bc_prefix_fraction * args.bc_envs)) if prefix else 0
    parts = []
    if args.bc_envs - n_pre:
        parts.append(collect_dart(env, scripted.get(args.skill), k_data, args.bc_envs - n_pre, args.bc_steps,
                                  args.bc_noise))
    if n_pre:
        print(f"  {n_pre} of the envs run {args.bc_prefix} first", flush=True)
        parts.append(collect_dart(env, scripted.get(args.skill), jax.random.fold_in(k_data, 1), n_pre,
                                  args.bc_steps, args.bc_noise, prefix))
    data = {k: jnp.concatenate([d[k] for d in parts]) for k in parts[0]} if len(parts) > 1 else parts[0]
    bc_params, bc_stats, nll = behaviour_clone(data, int(env.action_size), config, k_bc, args.bc_updates)
    t_bc = time.perf_counter() - t0
    del data

    eval_env = make_env(args.skill, args.physics, args.eval_episodes, args.start_states)
    selection_seed = 1_000_003 + args.seed  # selection episodes differ from the recorded ones

    bc_skill = skill_from(args.skill, bc_params, bc_stats, env.action_size, config)
    from parallel_skills.evaluation import rollout_episodes

    @jax.jit  # one compiled evaluator for both candidates: the parameters are an argument
    def _select_eval(params, key):
        return rollout_episodes(eval_env, lambda obs, k: bc_skill.apply(params, obs, k), key, args.eval_episodes)

    def select_eval(skill):
        r = _select_eval(skill.params, jax.random.PRNGKey(selection_seed))
        return float(np.mean(r["success"])), float(np.mean(r["return"]))

    bc_sel = select_eval(bc_skill)
    print(f"cloned in {t_bc:.0f} s (final NLL {nll:.3f}): selection success={bc_sel[0]:.3f} "
          f"return={bc_sel[1]:.1f}", flush=True)
    chosen, trained_with, report = bc_skill, "bc", {"bc": {
        "envs": args.bc_envs, "steps": args.bc_steps, "noise": args.bc_noise, "updates": args.bc_updates,
        "prefix": args.bc_prefix or None, "prefix_envs": n_pre,
        "batch_size": config.batch_size, "learning_rate": config.learning_rate, "final_nll": nll,
        "selection_success": bc_sel[0], "wall_time_s": round(t_bc, 1)}}
    if args.crr_steps > 0:
        t1 = time.perf_counter()
        from parallel_skills import TrainConfig
        from parallel_skills.config import resolve

        n_ft = resolve(TrainConfig(num_envs=args.crr_envs))[0].num_envs  # the trainer's device default if None
        env_ft = make_env(args.skill, args.physics, n_ft, args.start_states)
        ft_params, ft_stats, m = finetune(env_ft, bc_params, bc_stats, args.seed, args.crr_steps, n_ft)
        ft_skill = skill_from(args.skill, ft_params, ft_stats, env.action_size, config)
        ft_sel = select_eval(ft_skill)
        keep = ft_sel[0] > bc_sel[0]  # only a higher success replaces the clone
        t_ft = time.perf_counter() - t1
        print(f"CRR fine-tuning ({m['env_steps']:,} env steps, {t_ft:.0f} s): selection success={ft_sel[0]:.3f} "
              f"return={ft_sel[1]:.1f} -> keeping {'the fine-tuned policy' if keep else 'the clone'}", flush=True)
        report["crr"] = {"env_steps": int(m["env_steps"]), "selection_success": ft_sel[0],
                         "selection_return": ft_sel[1], "kept": bool(keep), "wall_time_s": round(t_ft, 1),
                         "num_envs": int(n_ft),
                         "method": "parallel_skills.train(method='scratch'), CPU defaults, new-skill samples_per_insert 16"}
        if keep:
            chosen, trained_with = ft_skill, "bc+crr"
    report["selection_seed"] = selection_seed

    # Record exactly what `training.evaluate` prints for the saved file: save, evaluate the file.
    meta = dict(task=args.skill, domain=DOMAIN, physics=args.physics, obs_size=int(env.observation_size),
                min_std=config.min_std, command=_command(argv), seed=args.seed, trained_with=trained_with,
                start_states=args.start_states,
                scripted_teacher=args.skill, training=report)
    tmp = tempfile.mkdtemp(prefix="train_skill_")
    try:
        tmp_path = os.path.join(tmp, "skill.npz")
        chosen.save(tmp_path, **meta)
        res = evaluate_policy(args.skill, args.physics, tmp_path, episodes=args.eval_episodes, seed=args.eval_seed)
        evaluations = {}
        for p in args.also_eval:
            t_p = time.perf_counter()
            s_p, r_p = evaluate_in_subprocess(args.skill, p, tmp_path, args.eval_episodes, args.eval_seed)
            evaluations[p] = dict(success=s_p, eval_return=r_p, success_episodes=args.eval_episodes,
                                  eval_seed=args.eval_seed, wall_time_s=round(time.perf_counter() - t_p, 1),
                                  eval_command=(f"python -m training.evaluate --task {args.skill} --physics {p} "
                                                f"--policy {args.out} --episodes {args.eval_episodes} "
                                                f"--seed {args.eval_seed}"))
            print(f"{p}: success={s_p:.4f} return={r_p:.3f} ({evaluations[p]['wall_time_s']:.0f} s)", flush=True)
        if evaluations:
            meta["evaluations"] = evaluations
        if args.start_states != "table":  # the recorded success is on the paper's resets; this on the wider ones
            wide = evaluate_policy(args.skill, args.physics, tmp_path, episodes=args.eval_episodes,
                                   seed=args.eval_seed, start_states=args.start_states)
            meta["start_states_success"] = dict(
                start_states=args.start_states, success=float(np.mean(wide["success"])),
                eval_return=float(np.mean(wide["return"])), success_episodes=args.eval_episodes,
                eval_seed=args.eval_seed,
                eval_command=(f"python -m training.evaluate --task {args.skill} --physics {args.physics} --policy "
                              f"{args.out} --episodes {args.eval_episodes} --seed {args.eval_seed} "
                              f"--start_states {args.start_states}"))
            print(f"start states {args.start_states}: success={meta['start_states_success']['success']:.4f}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    success, ret = float(np.mean(res["success"])), float(np.mean(res["return"]))
    eval_cmd = (f"python -m training.evaluate --task {args.skill} --physics {args.physics} --policy {args.out} "
                f"--episodes {args.eval_episodes} --seed {args.eval_seed}")
    wall = time.perf_counter() - t0
    main_guard(lambda: _check_out(args.out))  # still nothing there (never overwrite)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    chosen.save(args.out, **meta, success=success, success_episodes=args.eval_episodes, eval_seed=args.eval_seed,
                eval_return=ret, eval_command=eval_cmd, wall_time_s=round(wall, 1))
    print(f"saved {args.out} + {base}.json (trained_with={trained_with}, {wall:.0f} s)")
    print(f"success={success:.4f} return={ret:.3f}")


if __name__ == "__main__":
    main()
