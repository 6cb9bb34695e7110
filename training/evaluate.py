"""Evaluate a policy for whole episodes.

    python -m training.evaluate --task lift --physics kinematic --policy scripted:lift_green --episodes 64

``--policy``: ``scripted:NAME`` (a scripted controller, see ``tasks.manipulation.scripted``) or
``PATH.npz`` (a Gaussian-MLP skill with its JSON sidecar). The last line printed is
``success=<fraction> return=<mean>``.
"""

from __future__ import annotations

from training.cli import Parser, UsageError, main_guard, nonnegative_int, positive_int


def build_policy(spec: str, env):
    from tasks.manipulation import scripted

    if spec.startswith("scripted:"):
        name = spec.split(":", 1)[1]
        if name not in scripted.names():
            raise UsageError(f"unknown scripted policy {name!r}; valid: {', '.join(scripted.names())}")
        return scripted.get(name)
    if spec.endswith(".npz"):
        from parallel_skills.skills import Skill

        skill = Skill.load(spec, obs_size=env.observation_size, action_size=env.action_size)
        return lambda obs, key: skill.apply(skill.params, obs, key)
    raise UsageError(f"--policy must be 'scripted:NAME' or a skill 'PATH.npz', got {spec!r}")


def main(argv=None):
    import tasks

    p = Parser(prog="python -m training.evaluate", description=__doc__.splitlines()[0])
    p.add_argument("--task", default="lift", help="task name (see tasks.names())")
    p.add_argument("--physics", default="kinematic", help=f"one of {', '.join(tasks.PHYSICS)}")
    p.add_argument("--policy", required=True, help="scripted:NAME or PATH.npz")
    p.add_argument("--episodes", type=positive_int, default=64)
    p.add_argument("--episode_length", type=positive_int, default=None)
    p.add_argument("--seed", type=nonnegative_int, default=0)
    args = p.parse_args(argv)

    def run():
        if args.task not in tasks.names():
            raise UsageError(f"unknown task {args.task!r}; valid tasks: {', '.join(tasks.names())}")
        if args.physics not in tasks.PHYSICS:
            raise UsageError(f"unknown physics {args.physics!r}; valid: {', '.join(tasks.PHYSICS)}")
        overrides = {} if args.episode_length is None else {"episode_length": args.episode_length}
        if args.physics == "mjx":
            from tasks.manipulation.mjx_env import pin_to_one_core

            pin_to_one_core()  # MJX-jax can deadlock on 2 unpinned CPU cores (STACK.md)
        if args.physics in ("mjx", "warp"):
            overrides["max_envs"] = args.episodes  # MJX-Warp sizes its contact buffer for the batch
        env = tasks.make(args.task, physics=args.physics, **overrides)
        policy = build_policy(args.policy, env)

        import jax

        from parallel_skills.evaluation import make_evaluator

        result = make_evaluator(env, policy, args.episodes)(jax.random.PRNGKey(args.seed))
        success = float(result["success"].mean())
        ret = float(result["return"].mean())
        print(f"task={args.task} physics={args.physics} policy={args.policy} episodes={args.episodes}")
        print(f"success={success:.4f} return={ret:.3f}")

    main_guard(run)


if __name__ == "__main__":
    main()
