"""Skill sets per task from the paper's App. C skill table ("useful" and "distractor" skills).

Names refer to skills; today they are backed by the scripted controllers of ``scripted`` (the
neural skill library replaces them where shipped).
"""

from __future__ import annotations

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
TABLE["stack_green_on_yellow"] = TABLE["stack"]

SET_NAMES = ("useful", "useful+distractors", "distractors")


def skill_names(task: str, which: str = "useful") -> list[str]:
    """Skill names of set ``which`` for ``task`` (appendix table)."""
    if task not in TABLE:
        raise ValueError(f"no skill table for task {task!r}; tasks with skill sets: {', '.join(sorted(TABLE))}")
    useful, distract = TABLE[task]
    if which == "useful":
        return list(useful)
    if which == "distractors":
        return list(distract)
    if which == "useful+distractors":
        return list(useful) + list(distract)
    raise ValueError(f"unknown skill set {which!r}; valid: {', '.join(SET_NAMES)}")
