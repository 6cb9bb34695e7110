"""Ship a chain stage's new skill into the skill library (issue 4: the higher skills of the
library, lift X and stack X on Y, are outputs of SkillS runs, as in the paper's App. C).

    python -m training.ship --chain runs/chain --stage lift_green

Copies ``CHAIN/skills/STAGE.npz`` byte for byte to ``checkpoints/<library>/NAME.npz`` (``library``
= ``skill_library.library_dir(physics)``; NAME is the stage's full task name, as skill tables use it:
``stack`` ships as ``stack_green_on_yellow``; a chain of ``--seed K`` > 0 ships ``NAME.sK``, as the
``many_useful`` skill set names seeds; ``--as_seed K`` ships under seed K's name instead), measures
the shipped file with ``training.evaluate`` (``--episodes`` 64, ``--seed`` 0) and writes the library
sidecar: sizes and network, the chain command and the stage's ``training.run`` command, the skills it
was trained with, its env steps and training wall time (summed over resumes), and that success with
the command that reproduces it.

Refused in one line (exit 2, nothing written): a stage the chain has not finished, a success
below the library's bar (``--min_success``, default 0.8; 0.7 for the MJX scene, issue 4), or a
destination that exists (remove it first to replace a shipped skill; a .npz of the same bytes without
its sidecar, left by a ship killed between its two renames, is completed instead).
"""

from __future__ import annotations

import json
import os
import shutil
import sys

from training.cli import Parser, UsageError, fail, main_guard, nonnegative_int, positive_int, write_json_atomic
from training.rundir import RunRecord, read_record

MIN_SUCCESS = {"mjx": 0.7}  # per library directory; every other library: DEFAULT_MIN_SUCCESS
DEFAULT_MIN_SUCCESS = 0.8


def build_parser():
    p = Parser(prog="python -m training.ship", description=__doc__.splitlines()[0])
    p.add_argument("--chain", required=True, help="the chain directory (training.chain --out)")
    p.add_argument("--stage", required=True, help="the stage (task) whose new skill to ship, e.g. lift_green")
    p.add_argument("--episodes", type=positive_int, default=64, help="evaluation episodes (default 64)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="evaluation seed (default 0)")
    p.add_argument("--min_success", type=float, default=None,
                   help=f"refuse a skill below this success (default {DEFAULT_MIN_SUCCESS}, MJX library 0.7)")
    p.add_argument("--root", default=None, help="library root (default: the repository's checkpoints/)")
    p.add_argument("--as_seed", type=nonnegative_int, default=None,
                   help="the library seed to ship as (default: the stage's training seed): 0 the skill's "
                        "default file NAME.npz, K > 0 NAME.sK; e.g. the best of several seeds' stages as the "
                        "default (the sidecar's seed stays the training seed, its library_seed records K)")
    return p


def library_file_name(stage: str, seed: int) -> str:
    """The library file name (without .npz) of a chain stage's skill trained with ``seed``: the skill
    tables' name (``stack`` -> ``stack_green_on_yellow``), ``NAME.sK`` for seed K > 0 (as
    ``many_useful`` names seeds); the sidecar's ``name`` stays NAME, its ``seed`` K."""
    from tasks.manipulation.task_defs import canonical

    return canonical(stage) + (f".s{seed}" if seed else "")


def stage_files(chain: str, stage: str) -> tuple[dict, dict, str]:
    """(chain record, the stage's record, the stage's skill file) of a finished stage."""
    record_path = os.path.join(chain, "chain.json")
    if not os.path.isfile(record_path):
        raise UsageError(f"{chain} is not a chain directory (no chain.json)")
    try:
        with open(record_path) as f:
            record = json.load(f)
        stages = record["stages"]
    except (OSError, ValueError, KeyError, TypeError):
        raise UsageError(f"{record_path} is unreadable") from None
    src = os.path.join(chain, "skills", f"{stage}.npz")
    if stage not in stages or not os.path.isfile(src):
        done = ", ".join(stages) or "none"
        raise UsageError(f"stage {stage!r} has not finished in {chain}; finished stages: {done}")
    return record, stages[stage], src


def library_sidecar(meta: dict, record: dict, stage_record: dict, run_config: RunRecord, *, stage: str,
                    success: float, ret: float, episodes: int, seed: int, eval_command: str,
                    ship_command: str, wall_time_s) -> dict:
    """The library sidecar of a shipped chain skill (the fields every shipped skill has, see
    tests/test_skill_library.py, plus the chain's provenance)."""
    from tasks.manipulation.task_defs import canonical

    name = canonical(stage)
    return {
        "name": name, "task": name, "domain": "manipulation", "physics": meta["physics"],
        "obs_size": meta["obs_size"], "action_size": meta["action_size"], "hidden": meta["hidden"],
        "min_std": run_config.train_config["new_skill"]["min_std"],
        "command": record["command"], "ship_command": ship_command, "seed": meta["seed"],
        "trained_with": "skills",
        "success": success, "eval_return": ret, "success_episodes": episodes, "eval_seed": seed,
        "eval_command": eval_command, "wall_time_s": wall_time_s,
        "training": {
            "method": "SkillS (training.run): HCMPO scheduler over frozen skills + CRR new skill, sparse reward",
            "chain_stage": stage, "stage_command": stage_record.get("run_command", meta.get("stage_command")),
            "skills": list(run_config.skills), "skill_set": run_config.skill_set,
            "env_steps": meta.get("env_steps"), "chain_success": stage_record.get("success"),
            "chain_eval_episodes": meta.get("eval_episodes"),
        },
    }


def ship(chain: str, stage: str, episodes: int = 64, seed: int = 0, min_success=None, root=None,
         ship_command: str = "", as_seed=None) -> dict:
    """Copy, evaluate, and write the sidecar (see the module docstring). Returns the sidecar."""
    from parallel_skills import Skill
    from training import skill_library
    from training.chain import stage_training_wall_time
    from training.evaluate import evaluate_policy
    from tasks.manipulation.task_defs import canonical
    from training.export import file_sha256

    record, stage_record, src = stage_files(chain, stage)
    run_dir = os.path.join(chain, stage)
    try:
        run_config = read_record(run_dir)
    except UsageError:
        raise UsageError(f"{run_dir}/config.json is missing or unreadable (the stage's training run)") from None
    skill = Skill.load(src)
    meta = skill.metadata
    physics = meta.get("physics")
    library = skill_library.library_dir(physics)
    bar = MIN_SUCCESS.get(library, DEFAULT_MIN_SUCCESS) if min_success is None else float(min_success)
    default_root = root is None
    name = canonical(stage)  # the library names a stage's skill as skill tables do (stack -> stack_green_on_yellow)
    file_name = library_file_name(stage, int(run_config.seed) if as_seed is None else int(as_seed))
    dst = skill_library.library_path(physics, file_name, root=root)
    dst_json = dst[:-4] + ".json"
    # A .npz without its sidecar and with the source's bytes is a ship killed between its two renames:
    # finished by this call. Anything else that exists is never replaced.
    orphan = os.path.exists(dst) and not os.path.exists(dst_json) and file_sha256(dst) == file_sha256(src)
    for path in (dst_json,) if orphan else (dst, dst_json):
        if os.path.exists(path):
            raise UsageError(f"{path} already exists; remove it first to replace the shipped skill")
    recorded = stage_record.get("success", meta.get("success"))
    if recorded is not None and recorded < bar:
        raise UsageError(f"stage {stage!r} succeeded in {recorded:.3f} of its chain evaluation, below the "
                         f"{library} library's bar {bar}; not shipped")

    # The chain's file is measured where it is and shipped byte for byte (same SHA-256, which the
    # exports of later stages record for it).
    result = evaluate_policy(name, physics, src, episodes=episodes, seed=seed)
    success = float(result["success"].mean())
    ret = float(result["return"].mean())
    if success < bar:
        raise UsageError(f"stage {stage!r} succeeded in {success:.3f} of {episodes} episodes, below the "
                         f"{library} library's bar {bar}; not shipped")
    policy = f"checkpoints/{library}/{file_name}.npz" if default_root else dst
    eval_command = (f"python -m training.evaluate --task {name} --physics {physics} --policy {policy} "
                    f"--episodes {episodes} --seed {seed}")
    wall = stage_training_wall_time(stage_record, run_dir)
    side = library_sidecar(meta, record, stage_record, run_config, stage=stage, success=success, ret=ret,
                           episodes=episodes, seed=seed, eval_command=eval_command,
                           ship_command=ship_command, wall_time_s=wall)
    side.update(arch=meta.get("arch", skill.arch), sha256=file_sha256(src))
    if as_seed is not None:  # shipped under another seed's name than its training seed's
        side["library_seed"] = int(as_seed)
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    shutil.copyfile(src, dst + ".tmp")
    os.replace(dst + ".tmp", dst)  # a kill from here on leaves the orphan .npz finished above
    write_json_atomic(dst_json, side, indent=2, sort_keys=True)
    return side


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.min_success is not None and not 0.0 <= args.min_success <= 1.0:
        fail(f"--min_success must be in [0, 1], got {args.min_success}")
    command = " ".join(["python -m training.ship"] + argv)
    side = main_guard(lambda: ship(args.chain, args.stage, args.episodes, args.seed, args.min_success, args.root,
                                   ship_command=command, as_seed=args.as_seed))
    shipped_as = library_file_name(args.stage, side.get("library_seed", side["seed"]))  # as the file was named
    print(f"shipped {args.stage} as {shipped_as}: success={side['success']:.4f} over {side['success_episodes']} episodes")


if __name__ == "__main__":
    main()
