"""Task registry: ``tasks.make(name, physics=..., **overrides)`` returns a Brax-API env.

Every task of the manipulation domain (``tasks.names()``) exists for every physics backend:
``kinematic`` (pure JAX, no physics engine), ``mjx`` (MuJoCo MJX, impl jax), ``warp`` (MJX, impl
warp) and ``mujoco`` (classic MuJoCo C engine called from JAX through a host callback, ``tasks.host_call``).

The OP3 locomotion tasks (``LOCOMOTION_TASKS``: ``getup_and_walk``, ``op3_getup``, ``op3_walk``,
``goal_scoring``; docs/locomotion.md) exist for ``mujoco`` and ``mjx`` and need the extra ``locomotion``.

``warp`` alone needs the package warp-lang (the extra ``warp``); everything else imports and runs
without it.
"""

from __future__ import annotations

import importlib.util

from tasks.manipulation import task_defs

PHYSICS = ("kinematic", "mjx", "warp", "mujoco")
LOCOMOTION_PHYSICS = ("mujoco", "mjx")
LOCOMOTION_TASKS = ("getup_and_walk", "op3_getup", "op3_walk", "goal_scoring")
WARP_MISSING = ("physics 'warp' needs the package warp-lang, which is not installed "
                "(pip install 'parallel-skills[warp]'); the other physics run without it")


def warp_installed() -> bool:
    """Whether the package warp-lang (module ``warp``) can be imported, without importing it."""
    try:
        return importlib.util.find_spec("warp") is not None
    except (ImportError, ValueError):
        return False


def names() -> list[str]:
    """Names of all tasks (sparse tasks and dense skill rewards), manipulation and locomotion."""
    return sorted(task_defs.names() + list(LOCOMOTION_TASKS))


def check_start_states(name: str, physics: str, start_states: str) -> None:
    """ValueError (one line) unless task ``name`` on ``physics`` has the reset distribution
    ``start_states`` (``"table"``: every manipulation backend; the others: kinematic only)."""
    from tasks.manipulation.kinematic import check_start_states as check_kinematic

    check_kinematic(start_states)
    if start_states == "table":
        return
    if name in LOCOMOTION_TASKS:
        raise ValueError(f"start_states {start_states!r} is for the manipulation tasks; {name!r} has its own resets")
    if physics != "kinematic":
        raise ValueError(f"start_states {start_states!r} is implemented for the kinematic physics only; "
                         f"physics {physics!r} resets with 'table'")


def make(name: str, physics: str = "kinematic", **overrides):
    """Build task ``name`` on backend ``physics``. Overrides: ``episode_length``, ``start_states``
    (a manipulation task's reset distribution, ``tasks.manipulation.kinematic.START_STATES``:
    ``"table"``, every backend; ``"mixed"``, kinematic) and backend options."""
    start_states = overrides.pop("start_states", "table")
    if name in LOCOMOTION_TASKS:
        if physics not in LOCOMOTION_PHYSICS:
            raise ValueError(f"locomotion task {name!r} runs on physics {' or '.join(LOCOMOTION_PHYSICS)}, not {physics!r}")
        check_start_states(name, physics, start_states)
        from tasks.locomotion.env import make_locomotion_env

        return make_locomotion_env(name, physics=physics, **overrides)
    if name not in task_defs.TASKS:
        raise ValueError(f"unknown task {name!r}; valid tasks: {', '.join(names())}")
    if physics in PHYSICS:
        check_start_states(name, physics, start_states)
    if physics == "kinematic":
        from tasks.manipulation.kinematic import KinematicBlocks

        return KinematicBlocks(name, start_states=start_states, **overrides)
    if physics == "warp" and not warp_installed():
        raise ValueError(WARP_MISSING)
    if physics in ("mjx", "warp"):
        try:
            from tasks.manipulation.mjx_env import make_mjx_env
        except ImportError as e:  # pragma: no cover - until the MJX domain lands
            raise ValueError(f"physics {physics!r} is not available: {e}") from None
        return make_mjx_env(name, impl="jax" if physics == "mjx" else "warp", **overrides)
    if physics == "mujoco":
        try:
            from tasks.manipulation.mujoco_env import make_mujoco_env
        except ImportError as e:  # pragma: no cover
            raise ValueError(f"physics {physics!r} is not available: {e}") from None
        return make_mujoco_env(name, **overrides)
    raise ValueError(f"unknown physics {physics!r}; valid: {', '.join(PHYSICS)}")
