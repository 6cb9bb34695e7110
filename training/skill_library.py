"""Skill sets per task from the paper's App. C skill table ("useful" and "distractor" skills), and
the skills they name, assembled for training (``load_skills``).

Names refer to skills, backed either by the scripted controllers of ``tasks.manipulation.scripted``
(``source="scripted"``) or by the shipped neural library ``checkpoints/<library_dir(physics)>/<name>.npz``
(``source="library"``, Gaussian-MLP skills trained by ``training.train_skill``): see ``load_skills``.
``many_useful`` is the paper's "many useful skills" ablation: 3 seeds of each useful skill, named
``NAME`` (seed 0), ``NAME.s1`` and ``NAME.s2``, which only the library has.
"""

from __future__ import annotations

import os
import re

import checkpoints

_LIFT_USEFUL = ["reach_green", "lift_arm_closed"]
_LIFT_DISTRACT = ["reach_yellow", "reach_blue", "open_fingers", "lift_arm_open"]
_STACK_USEFUL = _LIFT_USEFUL + ["lift_green", "hover_green_on_yellow"]
_STACK_DISTRACT = _LIFT_DISTRACT + ["lift_yellow", "lift_blue"]

TABLE = {
    "lift": (_LIFT_USEFUL, _LIFT_DISTRACT),
    "stack": (_STACK_USEFUL, _STACK_DISTRACT),
    "pyramid": (
        _STACK_USEFUL + ["stack_green_on_yellow", "lift_yellow", "lift_blue", "reach_yellow", "reach_blue"],
        ["lift_arm_open", "open_fingers", "stack_yellow_on_blue"],
    ),
    "triple_stack": (
        _STACK_USEFUL + ["stack_green_on_yellow", "stack_yellow_on_blue", "lift_yellow", "reach_yellow",
                         "hover_yellow_on_blue"],
        ["lift_arm_open", "open_fingers", "reach_blue", "lift_blue"],
    ),
}
TABLE["lift_green"] = TABLE["lift"]
# Lift yellow / blue (the chain's stages before stack, training.chain): lift green's table with the
# reach skill of the lifted cube (the reach of green becomes a distractor).
TABLE["lift_yellow"] = (["reach_yellow", "lift_arm_closed"], ["reach_green", "reach_blue", "open_fingers", "lift_arm_open"])
TABLE["lift_blue"] = (["reach_blue", "lift_arm_closed"], ["reach_green", "reach_yellow", "open_fingers", "lift_arm_open"])
TABLE["stack_green_on_yellow"] = TABLE["stack"]
# Stack yellow on blue (the chain's stage for triple stack's useful skill ``stack_yellow_on_blue``):
# stack's table with the cubes renamed, green -> yellow, yellow -> blue (reach / lift / hover of the
# moved cube; the other cubes' reach and lift skills are distractors).
TABLE["stack_yellow_on_blue"] = (["reach_yellow", "lift_arm_closed", "lift_yellow", "hover_yellow_on_blue"],
                                 ["reach_green", "reach_blue", "open_fingers", "lift_arm_open", "lift_green",
                                  "lift_blue"])
# Locomotion (paper Sec. 5): GetUpAndWalk composes the get-up and walking skills; GoalScoring adapts the
# walking skill. The OP3 skills are the CEM-tuned controllers of tasks.locomotion.controllers
# (checkpoints/op3/, docs/research/op3_skills.md), named after their dense skill tasks; the paper gives no
# distractor skills for this domain.
TABLE["getup_and_walk"] = (["op3_getup", "op3_walk"], [])
TABLE["goal_scoring"] = (["op3_walk"], [])
OP3_PREFIX = "op3_"

SET_NAMES = ("useful", "useful+distractors", "distractors", "many_useful")
SOURCES = ("scripted", "library")
MANY_SEEDS = 3  # skills per useful skill in "many_useful" (paper App. C: 3 seeds)
# The shipped skill library: checkpoints/<library_dir(physics)>/<name>.npz + .json (package data of
# the installed ``checkpoints`` package).
LIBRARY_ROOT = checkpoints.library_root()
_SEED_SUFFIX = re.compile(r"^(?P<base>.+)\.s(?P<seed>[0-9]+)$")


def skill_names(task: str, which: str = "useful") -> list[str]:
    """Skill names of set ``which`` for ``task`` (appendix table)."""
    if task not in TABLE:
        raise ValueError(f"no skill table for task {task!r}; tasks with skill sets: {', '.join(sorted(TABLE))}")
    useful, distract = TABLE[task]
    if which == "useful":
        return list(useful)
    if which == "distractors":
        if not distract:
            raise ValueError(f"task {task!r} has no distractor skills; valid skill sets for it: useful, many_useful")
        return list(distract)
    if which == "useful+distractors":
        return list(useful) + list(distract)
    if which == "many_useful":
        return [n if s == 0 else f"{n}.s{s}" for n in useful for s in range(MANY_SEEDS)]
    raise ValueError(f"unknown skill set {which!r}; valid: {', '.join(SET_NAMES)}")


def split_seed(name: str) -> tuple[str, int]:
    """``"reach_green.s1"`` -> ``("reach_green", 1)``; a name without suffix is seed 0."""
    m = _SEED_SUFFIX.match(name)
    return (m["base"], int(m["seed"])) if m else (name, 0)


# One library per scene: the kinematic domain's, and the physics scene's (scene.xml), which the three
# physics backends share (same MJCF, same observation / action code: docs/physics.md), so a skill
# trained on the CPU fast path (physics="mujoco") serves MJX and Warp too. Named "mjx" (issue 4).
LIBRARY_DIRS = {"kinematic": "kinematic", "mujoco": "mjx", "mjx": "mjx", "warp": "mjx"}


def library_dir(physics: str) -> str:
    """The library directory name under checkpoints/ of ``physics`` (see ``LIBRARY_DIRS``)."""
    return LIBRARY_DIRS.get(physics, physics)


def library_path(physics: str, name: str, root: str | None = None) -> str:
    """``checkpoints/<library_dir(physics)>/<name>.npz`` of the shipped library (``root`` replaces
    checkpoints/)."""
    return os.path.join(root or LIBRARY_ROOT, library_dir(physics), f"{name}.npz")


def how_to_make(name: str, seed: int, physics: str) -> str:
    """The commands that make library skill ``name`` (seed ``seed``) for ``physics``: ``train_skill`` for
    a dense-reward skill; for a higher skill (lift X, stack X on Y: a SkillS run's new skill) the
    ``training.chain`` stages that train it (stack X on Y after lift X, whose skill it uses), then
    ``training.ship``."""
    import tasks

    m = re.match(r"^(lift|stack)_(green|yellow|blue)", name)
    if m is None or name not in tasks.names():
        train_physics = "mujoco" if library_dir(physics) == "mjx" else physics  # the CPU fast path
        return (f"train it: python -m training.train_skill --skill {name} --physics {train_physics} --seed {seed} "
                f"--out {library_path(physics, name)}")
    stages = [name] if m[1] == "lift" else [f"lift_{m[2]}", name]
    chain = f"runs/chain_{name}" + (f"_s{seed}" if seed else "")
    return (f"a SkillS run makes it: python -m training.chain --physics {physics} --seed {seed} "
            f"--stages {','.join(stages)} --out {chain}, then python -m training.ship --chain {chain} --stage {name}")


def load_skills(names, physics: str, source: str = "scripted", obs_size: int | None = None,
                action_size: int | None = None, root: str | None = None, skill_dir: str | None = None) -> list:
    """The skills ``names`` as ``parallel_skills.Skill`` objects, from ``source``:

    * ``"scripted"``: ``Skill.from_fn(name, scripted.get(name))`` (any physics);
    * ``"library"``: ``Skill.load(library_path(physics, name))`` (``checkpoints/kinematic/`` or, for
      mujoco / mjx / warp, ``checkpoints/mjx/``), sizes checked against
      ``obs_size`` / ``action_size``, named ``name``.

    ``skill_dir``: a directory of the user's own skills; a name with ``skill_dir/<name>.npz`` (and its
    ``.json`` sidecar) is loaded from there, size-checked the same way, whatever ``source`` says
    (e.g. the new skills of earlier SkillS runs: ``training.chain``).

    ValueError (one line) naming the missing file or the mismatch."""
    import dataclasses

    from parallel_skills import Skill

    names = list(names)
    if skill_dir is not None:
        if not os.path.isdir(skill_dir):
            raise ValueError(f"skill directory {skill_dir} does not exist (or is not a directory)")
        own = {n for n in names if os.path.isfile(os.path.join(skill_dir, f"{n}.npz"))}
        rest = load_skills([n for n in names if n not in own], physics, source, obs_size, action_size, root)
        by_name = {s.name: s for s in rest}
        for n in sorted(own):
            path = os.path.join(skill_dir, f"{n}.npz")
            skill = Skill.load(path, obs_size=obs_size, action_size=action_size)
            by_name[n] = dataclasses.replace(skill, name=n, metadata=dict(skill.metadata, source="skill_dir", path=path))
        return [by_name[n] for n in names]
    if source == "scripted":
        from tasks.manipulation import scripted

        op3 = [n for n in names if n.startswith(OP3_PREFIX)]
        if op3:  # the OP3 controllers (locomotion); no mix with the arm's controllers
            from tasks.locomotion import controllers

            if len(op3) != len(names):
                raise ValueError(f"skills {', '.join(names)} mix OP3 and arm controllers")
            valid = [OP3_PREFIX + c for c in controllers.names()]
            for n in names:
                if n not in valid:
                    raise ValueError(f"no OP3 controller {n!r}; valid: {', '.join(valid)}")
            # collection_noise=False: the controllers keep their phase in the head actions (noise would
            # scramble it) and are tuned noise-free (docs/locomotion.md, "Collection noise").
            return [Skill.from_fn(n, controllers.get(n[len(OP3_PREFIX):]), collection_noise=False, source="scripted",
                                  path=str(controllers.CHECKPOINT_DIR / f"{n[len(OP3_PREFIX):]}.json")) for n in names]
        for n in names:
            base, seed = split_seed(n)
            if seed and base in scripted.names():
                raise ValueError(f"skill {n!r} is seed {seed} of {base!r}, which only the neural library has "
                                 f"(scripted controllers have no seeds): use the library source "
                                 f"(training.run --skill_source library)")
            if n not in scripted.names():
                raise ValueError(f"no scripted controller {n!r}; valid: {', '.join(scripted.names())}")
        return [Skill.from_fn(n, scripted.get(n), source="scripted") for n in names]
    if source != "library":
        raise ValueError(f"unknown skill source {source!r}; valid: {', '.join(SOURCES)}")
    skills = []
    for n in names:
        path = library_path(physics, n, root)
        base, seed = split_seed(n)
        if not (os.path.isfile(path) and os.path.isfile(path[:-4] + ".json")):
            missing = path if not os.path.isfile(path) else path[:-4] + ".json"
            raise ValueError(f"skill {n!r} is not in the {physics} skill library: {missing} does not exist "
                             f"({how_to_make(base, seed, physics)})")
        skill = Skill.load(path, obs_size=obs_size, action_size=action_size)
        skills.append(dataclasses.replace(skill, name=n, metadata=dict(skill.metadata, source="library", path=path)))
    return skills
