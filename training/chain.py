"""Chained curriculum (paper App. C): SkillS on lift green, yellow, blue, then stack, each stage's
new skill joining the skills of the stages after it.

    python -m training.chain --physics kinematic --out runs/chain

Stage ``T`` is ``python -m training.run --task T --skills useful --skill_dir DIR/skills --out DIR/T``
(a subprocess; its own run directory, log, checkpoints and export). When it ends, its new skill is
evaluated alone over ``--eval_episodes`` episodes (``training.evaluate``) and written to
``DIR/skills/T.npz`` + ``.json`` (sidecar: sizes, the stage and chain commands, seed, that success
and the command that measures it); later stages find it there (stack's useful set includes
``lift_green``). ``DIR/chain.json`` records every stage's command, wall time
(``training_wall_time_s``: summed over resumes) and success.

Rerunning the same command continues a chain: finished stages are skipped, an interrupted stage is
resumed from its latest checkpoint (``training.run --resume``). A rerun may raise stage budgets
(``--lift_timesteps``, ``--stack_timesteps``, ``--timesteps STAGE=N``): a stage below its new budget
is extended (``training.run --resume --num_timesteps N``, which keeps the shorter run's outputs) and
published again, unless a later stage already trained with its skill (refused: that stage would be
stale). Any other change of the command is refused. Bad input: one ``error:`` line, exit 2, nothing
written.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time

from training.cli import (Parser, UsageError, check_writable, main_guard, nonnegative_int, positive_int,
                          write_json_atomic)
from training.rundir import exported_budget, read_record

STAGES = ("lift_green", "lift_yellow", "lift_blue", "stack")
# Env steps per stage on a CPU: kinematic lift reaches 0.8-0.9 after 250k-300k (docs/research/learning.md);
# stack's new skill alone 0.13 at 1M, 0.84-0.88 at 2M (seed 0, README Results).
DEFAULT_TIMESTEPS = {"lift": 300_000, "stack": 2_000_000}
# Arguments that only set budgets: a rerun may raise them (the stages below them are extended).
BUDGET_ARGS = ("lift_timesteps", "stack_timesteps", "timesteps")
PUBLISH = ("last", "best")  # --publish
SELECTION_SEED = 1  # --publish best compares the candidates on these episodes, not the reported ones (seed 0)


def build_parser():
    import tasks
    from training.skill_library import SOURCES

    p = Parser(prog="python -m training.chain", description=__doc__.splitlines()[0])
    p.add_argument("--physics", default="kinematic", help=f"one of {', '.join(tasks.PHYSICS)}; default kinematic")
    p.add_argument("--out", required=True, help="chain directory (rerun the same command to continue it)")
    p.add_argument("--seed", type=nonnegative_int, default=0)
    p.add_argument("--stages", default=",".join(STAGES),
                   help=f"comma-separated tasks, in order (default {','.join(STAGES)})")
    p.add_argument("--lift_timesteps", type=positive_int, default=DEFAULT_TIMESTEPS["lift"],
                   help="env steps of each lift stage (default 300k)")
    p.add_argument("--stack_timesteps", type=positive_int, default=DEFAULT_TIMESTEPS["stack"],
                   help="env steps of the stack stage and any other task (default 2M)")
    p.add_argument("--timesteps", default="", metavar="STAGE=N[,STAGE=N]",
                   help="env steps of single stages, over the two above (e.g. lift_blue=450000)")
    p.add_argument("--skill_source", default="scripted", choices=list(SOURCES),
                   help="where the basic skills come from (the chain's own new skills always come from DIR/skills)")
    p.add_argument("--num_envs", type=positive_int, default=None)
    p.add_argument("--start_states", default="table",
                   help="every stage's reset distribution (training.run --start_states): table (the paper's) or "
                        "mixed (kinematic; also one cube on or beside another) or TOP_on_BOTTOM (kinematic; half with "
                        "that cube on the other, e.g. yellow_on_blue; _loose: as a learnt skill leaves it) or after:NAME:K (kinematic; half where library skill NAME leaves the table resets after K or KMIN-KMAX steps); each skill is published with its "
                        "success on the paper's resets, and on these")
    p.add_argument("--config", default=None, help="JSON file of TrainConfig fields, passed to every stage")
    p.add_argument("--eval_episodes", type=positive_int, default=64,
                   help="episodes of the final evaluation of each stage's new skill (default 64)")
    p.add_argument("--publish", default="last", choices=list(PUBLISH),
                   help="which new skill of a stage is published: last (the run's final one; default) or best: "
                        "of the final one and the run's best evaluated one (best_new_skill.npz), the one with the "
                        "higher success over --eval_episodes episodes of a selection seed (1) on the stage's "
                        "resets; the published success is then measured as always (seed 0)")
    return p


def parse_stage_timesteps(text: str) -> dict:
    """``--timesteps "lift_blue=450000,stack=3000000"`` -> {"lift_blue": 450000, "stack": 3000000}."""
    out = {}
    for item in (t.strip() for t in text.split(",")):
        if not item:
            continue
        name, _, value = item.partition("=")
        if not value.strip().isdigit() or int(value) < 1:
            raise UsageError(f"--timesteps item {item!r} is not STAGE=N with N a positive integer")
        out[name.strip()] = int(value)
    return out


def stage_timesteps(task: str, args) -> int:
    per_stage = parse_stage_timesteps(args.timesteps)
    if task in per_stage:
        return per_stage[task]
    return args.lift_timesteps if task.startswith("lift") else args.stack_timesteps


def stage_argv(task: str, args, skill_dir: str, run_dir: str, resume: bool) -> list[str]:
    """The ``training.run`` arguments of one stage (a resume also names the budget: it may extend)."""
    if resume:
        return ["--resume", "--out", run_dir, "--num_timesteps", str(stage_timesteps(task, args))]
    argv = ["--task", task, "--physics", args.physics, "--seed", str(args.seed), "--skills", "useful",
            "--skill_source", args.skill_source, "--skill_dir", skill_dir,
            "--num_timesteps", str(stage_timesteps(task, args)), "--out", run_dir]
    if args.num_envs:
        argv += ["--num_envs", str(args.num_envs)]
    if args.config:
        argv += ["--config", args.config]
    if args.start_states != "table":
        argv += ["--start_states", args.start_states]
    return argv


def validate(args) -> list[str]:
    import tasks
    from training import skill_library

    stages = [s for s in args.stages.split(",") if s]
    if not stages:
        raise UsageError("--stages is empty; give comma-separated task names, e.g. lift_green,stack")
    for s in stages:
        if s not in tasks.names():
            raise UsageError(f"unknown task {s!r} in --stages; valid tasks: {', '.join(tasks.names())}")
        if s not in skill_library.TABLE:
            raise UsageError(f"task {s!r} has no skill table (it cannot be a SkillS stage); valid: "
                             f"{', '.join(sorted(skill_library.TABLE))}")
    if len(set(stages)) != len(stages):
        raise UsageError(f"--stages repeats a task: {args.stages}")
    unknown = sorted(set(parse_stage_timesteps(args.timesteps)) - set(stages))
    if unknown:
        raise UsageError(f"--timesteps names {', '.join(unknown)}, not a stage of this chain; stages: {', '.join(stages)}")
    if args.physics not in tasks.PHYSICS:
        raise UsageError(f"unknown physics {args.physics!r}; valid: {', '.join(tasks.PHYSICS)}")
    try:
        tasks.check_start_states(stages[0], args.physics, args.start_states)
    except ValueError as e:
        raise UsageError(f"--start_states: {e}") from None
    if args.config and not os.path.isfile(args.config):
        raise UsageError(f"config file {args.config} does not exist")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise UsageError(f"{args.out} exists and is not a directory")
    check_writable(args.out, "the chain directory")
    return stages


def same_chain(command_a: str, command_b: str) -> bool:
    """Whether two chain commands differ at most in their budgets (``BUDGET_ARGS``) and spelling."""
    parser = build_parser()

    def settings(cmd):
        args = vars(parser.parse_args(cmd.split()[3:]))  # (after "python -m training.chain")
        args["out"] = os.path.normpath(args["out"])
        return {k: v for k, v in args.items() if k not in BUDGET_ARGS}

    try:
        return settings(command_a) == settings(command_b)
    except SystemExit:  # a command this version does not parse
        return False


def load_record(record_path: str, chain_command: str) -> dict:
    """The chain's record: new, or the one a previous call of the same chain (``same_chain``) left;
    ``command`` is the latest call's, ``commands`` all of them."""
    if not os.path.isfile(record_path):
        return {"command": chain_command, "commands": [chain_command], "stages": {}}
    try:
        with open(record_path) as f:
            record = json.load(f)
        assert isinstance(record, dict) and isinstance(record.get("stages"), dict)
    except (OSError, ValueError, AssertionError):
        raise UsageError(f"{record_path} is unreadable; choose a new --out") from None
    if not same_chain(str(record.get("command")), chain_command):
        raise UsageError(f"{record_path} was made by another command ({record.get('command')}); continue it with "
                         "that command (stage budgets may be raised), or choose a new --out")
    commands = record.get("commands") or [record["command"]]
    if commands[-1] != chain_command:
        commands.append(chain_command)
    record.update(command=chain_command, commands=commands)
    return record


def check_budgets(stages: list[str], args, out: str) -> None:
    """Refuse a budget below a stage's, and the extension of a stage whose skill a later stage
    (started already) trained with."""
    extended = []
    for task in stages:
        cfg_path = os.path.join(out, task, "config.json")
        if not os.path.isfile(cfg_path):
            continue
        try:
            run = read_record(os.path.join(out, task))
            budget = int(run.num_timesteps)
        except (UsageError, ValueError, TypeError):
            raise UsageError(f"{cfg_path} is unreadable (the stage's training run); choose a new --out") from None
        wanted = stage_timesteps(task, args)
        if wanted < budget:
            raise UsageError(f"stage {task} has a budget of {budget} env steps ({cfg_path}); the command asks for "
                             f"{wanted}: a chain's budgets can be raised, not lowered")
        users = [t for t in extended if t in run.skills]
        if users:
            raise UsageError(f"stage {task} was trained with the skill of {', '.join(users)}, which this command "
                             f"extends; it would be stale: choose a new --out")
        if wanted > budget:
            extended.append(task)


def publish_skill(task: str, args, run_dir: str, skill_dir: str, chain_command: str) -> dict:
    """Evaluate the stage's new skill alone and write it to ``skill_dir/<task>.npz`` + sidecar
    (``--publish best``: the better of the final and the best evaluated new skill, ``select_skill``)."""
    from parallel_skills import Skill
    from training.evaluate import evaluate_policy

    src, selection = os.path.join(run_dir, "new_skill.npz"), None
    if args.publish == "best":
        src, selection = select_skill(task, args, run_dir)
    result = evaluate_policy(task, args.physics, src, episodes=args.eval_episodes, seed=0)
    success = float(result["success"].mean())
    ret = float(result["return"].mean())
    skill = Skill.load(src)
    meta = {k: v for k, v in skill.metadata.items() if k not in ("name", "arch")}
    dst = os.path.join(skill_dir, f"{task}.npz")
    eval_cmd = (f"python -m training.evaluate --task {task} --physics {args.physics} --policy {dst} "
                f"--episodes {args.eval_episodes}")
    meta.update(stage_command=meta.pop("command", None), command=chain_command, chain_stage=task,
                trained_with_method="SkillS (training.run)", success=success, eval_return=ret,
                eval_episodes=args.eval_episodes, eval_command=eval_cmd, start_states=args.start_states)
    if args.start_states != "table":  # the success above is on the paper's resets; this on the stages' own
        wide = evaluate_policy(task, args.physics, src, episodes=args.eval_episodes, seed=0,
                               start_states=args.start_states)
        meta["start_states_success"] = dict(start_states=args.start_states, success=float(wide["success"].mean()),
                                            eval_return=float(wide["return"].mean()),
                                            eval_command=f"{eval_cmd} --start_states {args.start_states}")
    result = {"success": success, "return": ret, "skill": dst}
    if selection is not None:
        meta["selection"] = result["selection"] = selection
    Skill.save(dataclasses.replace(skill, name=task, metadata={}), dst, **meta)
    return result


def select_skill(task: str, args, run_dir: str):
    """``--publish best``: the run's final new skill or its best evaluated one (``best_new_skill.npz``),
    whichever succeeds more over ``--eval_episodes`` episodes of ``SELECTION_SEED`` on the stage's
    resets (ties: the final one). Returns (path, the selection's record for the sidecar)."""
    from training.evaluate import evaluate_policy
    from training.run_files import BEST_NEW_SKILL

    last, best = os.path.join(run_dir, "new_skill.npz"), os.path.join(run_dir, BEST_NEW_SKILL)
    if not os.path.isfile(best):
        return last, {"published": "last", "why": f"{BEST_NEW_SKILL} missing (a run older than the option)"}
    scores = {}
    for name, path in (("last", last), ("best", best)):
        r = evaluate_policy(task, args.physics, path, episodes=args.eval_episodes, seed=SELECTION_SEED,
                            start_states=args.start_states)
        scores[name] = float(r["success"].mean())
    with open(best[:-4] + ".json") as f:
        best_meta = json.load(f)
    chosen = "best" if scores["best"] > scores["last"] else "last"
    return (best if chosen == "best" else last), {
        "published": chosen, "selection_seed": SELECTION_SEED, "selection_episodes": args.eval_episodes,
        "start_states": args.start_states, "success_last": scores["last"], "success_best": scores["best"],
        "best_env_steps": best_meta.get("env_steps"), "best_run_success": best_meta.get("success")}


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    stages = main_guard(lambda: validate(args))
    chain_command = " ".join(["python -m training.chain"] + argv)
    out = args.out
    skill_dir = os.path.join(out, "skills")
    record_path = os.path.join(out, "chain.json")
    record = main_guard(lambda: load_record(record_path, chain_command))
    main_guard(lambda: check_budgets(stages, args, out))
    os.makedirs(skill_dir, exist_ok=True)

    def save_record():
        write_json_atomic(record_path, record, indent=2)

    save_record()
    t_chain = time.perf_counter()
    for task in stages:
        run_dir = os.path.join(out, task)
        published = os.path.join(skill_dir, f"{task}.json")
        budget = stage_timesteps(task, args)
        done = record["stages"].get(task)
        if os.path.isfile(published) and done and done.get("num_timesteps", budget) >= budget:
            print(f"[chain] {task}: done (success {done['success']:.3f}), skipped", flush=True)
            continue
        exported = main_guard(lambda: exported_budget(run_dir)) if os.path.isdir(run_dir) else None
        finished = exported is not None and exported >= budget
        resume = os.path.isdir(run_dir) and not finished
        sargv = stage_argv(task, args, skill_dir, run_dir, resume)
        if not finished:
            print(f"[chain] {task}: python -m training.run {' '.join(sargv)}", flush=True)
            t0 = time.perf_counter()
            code = subprocess.call([sys.executable, "-m", "training.run"] + sargv)
            if code != 0:
                print(f"error: stage {task} failed (training.run exit code {code}); rerun the same command to "
                      "continue the chain", file=sys.stderr)
                sys.exit(code)
            wall = time.perf_counter() - t0
        else:
            wall = record["stages"].get(task, {}).get("wall_time_s", 0.0)
        result = publish_skill(task, args, run_dir, skill_dir, chain_command)
        record["stages"][task] = dict(result, run_dir=run_dir, wall_time_s=round(wall, 1),
                                      training_wall_time_s=training_wall_time(run_dir), resumed=resume,
                                      num_timesteps=budget,
                                      run_command="python -m training.run " + " ".join(
                                          stage_argv(task, args, skill_dir, run_dir, False)))
        save_record()
        took = (f"{wall:.0f} s" if not finished else
                f"trained before this call: {stage_training_wall_time(record['stages'][task], run_dir) or 0:.0f} s")
        print(f"[chain] {task}: new skill success={result['success']:.4f} over {args.eval_episodes} episodes "
              f"-> {result['skill']} ({took})", flush=True)
    total = total_training_wall_time(record)
    summary = ", ".join("%s %.3f" % (t, record["stages"][t]["success"]) for t in stages)
    print(f"[chain] done: {summary}; "
          f"training wall time {total:.0f} s (this call {time.perf_counter() - t_chain:.0f} s)")


def total_training_wall_time(record: dict) -> float:
    """Seconds of training of the chain's finished stages (``stage_training_wall_time``; else the
    last call's ``wall_time_s``)."""
    return sum(stage_training_wall_time(s, s.get("run_dir", "")) or s["wall_time_s"]
               for s in record["stages"].values())


def stage_training_wall_time(stage: dict, run_dir: str):
    """A chain stage's training wall time summed over its resumes: its record's
    ``training_wall_time_s``, else ``run_dir``'s metrics.csv (records written before that field),
    else None."""
    return stage.get("training_wall_time_s") or training_wall_time(run_dir)


def training_wall_time(run_dir: str):
    """The stage's training wall time in seconds, summed over its resumes (``parallel_skills.train``
    carries it in the checkpoint): the last ``wall_time`` of ``run_dir/metrics.csv``, or None. The
    record's ``wall_time_s`` is only the last call's subprocess (a resumed stage's remainder)."""
    from training.logging_utils import read_metrics

    path = os.path.join(run_dir, "metrics.csv")
    rows = read_metrics(path) if os.path.isfile(path) else []
    value = rows[-1].get("wall_time") if rows else None
    return round(float(value), 1) if isinstance(value, float) else None


if __name__ == "__main__":
    main()
