"""Named tasks of the manipulation domain: which reward (App. C.1.3) and which success test.

A task maps ``Inputs`` (positions read off any physics backend) to ``(reward, success)``; NumPy or
JAX arrays alike (see ``rewards``). Sparse tasks succeed when their sparse reward is 1; dense skill
tasks have the success tests stated per task below.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, NamedTuple

from tasks.manipulation import layout
from tasks.manipulation import rewards as R


class Inputs(NamedTuple):
    """What a reward needs. pinch_pos [..., 3]; aperture [...]; grasp [...] (0/1); cubes [..., 3, 3]
    (world positions in ``layout.CUBE_NAMES`` order)."""

    pinch_pos: Any
    aperture: Any
    grasp: Any
    cubes: Any


@dataclasses.dataclass(frozen=True)
class TaskDef:
    name: str
    kind: str  # "sparse" (a task) or "dense" (a skill reward)
    reward: Callable[[Inputs], Any]
    success: Callable[[Inputs], Any]
    description: str


def _cube(inp: Inputs, name: str):
    return inp.cubes[..., layout.CUBE_INDEX[name], :]


def _b(x):
    """Boolean array -> float array of the positions' dtype."""
    return x * 1.0


TASKS: dict[str, TaskDef] = {}


def _register(task: TaskDef) -> None:
    TASKS[task.name] = task


# --- sparse tasks -----------------------------------------------------------------------------
def _lift(x: str) -> TaskDef:
    def reward(inp):
        return R.lift_object_sparse(_cube(inp, x)[..., 2])

    return TaskDef(f"lift_{x}", "sparse", reward, reward, f"Lift {x} (sparse): z ≥ 0.18 m")


def _stack(top: str, bottom: str) -> TaskDef:
    def reward(inp):
        return R.stack_leave_sparse(_cube(inp, top), _cube(inp, bottom), inp.grasp, inp.pinch_pos)

    return TaskDef(
        f"stack_{top}_on_{bottom}", "sparse", reward, reward, f"Stack {top} on {bottom} and leave (sparse)"
    )


def _pyramid(inp):
    return R.pyramid_leave_sparse(
        _cube(inp, "green"), _cube(inp, "yellow"), _cube(inp, "blue"), inp.grasp, inp.pinch_pos
    )


def _triple(inp):
    return R.triple_stack_leave_sparse(
        _cube(inp, "green"), _cube(inp, "yellow"), _cube(inp, "blue"), inp.grasp, inp.pinch_pos
    )


for _c in layout.CUBE_NAMES:
    _register(_lift(_c))
    for _d in layout.CUBE_NAMES:
        if _d != _c:
            _register(_stack(_c, _d))

# Short names of the paper's two main tasks: the same task definitions under a second name.
ALIASES = {"lift": "lift_green", "stack": "stack_green_on_yellow"}
_register(dataclasses.replace(TASKS["lift_green"], name="lift", description="Lift green (sparse)"))
_register(
    dataclasses.replace(TASKS["stack_green_on_yellow"], name="stack", description="Stack green on yellow (sparse)")
)
_register(TaskDef("pyramid", "sparse", _pyramid, _pyramid, "Green on top of yellow and blue (sparse)"))
_register(TaskDef("triple_stack", "sparse", _triple, _triple, "Green on yellow on blue (sparse)"))


# --- dense skill rewards ----------------------------------------------------------------------
OPEN_SUCCESS_MARGIN = 0.005  # aperture within 5 mm of fully open counts as open
CLOSED_SUCCESS_APERTURE = layout.CUBE_SIZE + 0.005  # closed, or closed on a cube


def _reach(x: str) -> TaskDef:
    return TaskDef(
        f"reach_{x}",
        "dense",
        lambda inp: R.reach_dense(inp.pinch_pos, _cube(inp, x)),
        lambda inp: R.reach_sparse(inp.pinch_pos, _cube(inp, x)),
        f"Reach {x} (dense); success: pinch within the reach tolerance",
    )


def _hover(top: str, bottom: str) -> TaskDef:
    return TaskDef(
        f"hover_{top}_on_{bottom}",
        "dense",
        lambda inp: R.hover_dense(_cube(inp, top), _cube(inp, bottom)),
        lambda inp: _b(R.hover_dense(_cube(inp, top), _cube(inp, bottom)) >= 1.0) * inp.grasp,
        f"Hover {top} on {bottom} (dense); success: held within the hover tolerance",
    )


for _c in layout.CUBE_NAMES:
    _register(_reach(_c))
    for _d in layout.CUBE_NAMES:
        if _d != _c:
            _register(_hover(_c, _d))

_register(
    TaskDef(
        "open_fingers",
        "dense",
        lambda inp: R.open_fingers_dense(inp.aperture),
        lambda inp: _b(inp.aperture >= layout.APERTURE_OPEN - OPEN_SUCCESS_MARGIN),
        "Open fingers (dense); success: aperture within 5 mm of open",
    )
)
_register(
    TaskDef(
        "lift_arm_open",
        "dense",
        lambda inp: R.lift_arm_open_dense(inp.pinch_pos[..., 2], inp.aperture),
        lambda inp: _b(inp.pinch_pos[..., 2] >= R.LIFT_Z_DESIRED)
        * _b(inp.aperture >= layout.APERTURE_OPEN - OPEN_SUCCESS_MARGIN),
        "Lift arm with open fingers (dense); success: pinch z ≥ 0.18 with fingers open",
    )
)
_register(
    TaskDef(
        "lift_arm_closed",
        "dense",
        lambda inp: R.lift_arm_closed_dense(inp.pinch_pos[..., 2], inp.aperture, inp.grasp),
        lambda inp: _b(inp.pinch_pos[..., 2] >= R.LIFT_Z_DESIRED)
        * _b(inp.aperture <= CLOSED_SUCCESS_APERTURE),
        "Lift arm with closed fingers (dense); success: pinch z ≥ 0.18 with fingers closed",
    )
)


def canonical(name: str) -> str:
    """The task's full name, as skill tables and libraries name its skill: ``stack`` ->
    ``stack_green_on_yellow``; other names unchanged."""
    return ALIASES.get(name, name)


def names() -> list[str]:
    return sorted(TASKS)


def get(name: str) -> TaskDef:
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; valid tasks: {', '.join(names())}")
    return TASKS[name]
