"""parallel-skills: SkillS (Vezzani et al., ICLR 2023) as a massively parallel JAX trainer.

Public API (Brax style)::

    from parallel_skills import Skill, TrainConfig, train
    make_policy, params, metrics = train(env, skills, num_timesteps=..., seed=0)

The public names are loaded lazily (PEP 562), so that importing a JAX-free submodule such as
``parallel_skills.numpy_policy`` does not import JAX.
"""

from __future__ import annotations

import importlib
import sys
import types

_PUBLIC = {
    "NewSkillConfig": "parallel_skills.config",
    "SchedulerConfig": "parallel_skills.config",
    "Skill": "parallel_skills.skills",
    "SkillSet": "parallel_skills.skills",
    "TrainConfig": "parallel_skills.config",
    "Transition": "parallel_skills.replay",
    "make_trainer": "parallel_skills.train",
}

__all__ = sorted(list(_PUBLIC) + ["train"])
__version__ = "0.1.0"


def __getattr__(name):
    if name in _PUBLIC:
        value = getattr(importlib.import_module(_PUBLIC[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """``parallel_skills.train`` is both a submodule and the public function ``train``. Importing
    the submodule makes the import system bind it as the package attribute ``train``; this
    property keeps that attribute the function, as the eager ``from ... import train`` did."""

    @property
    def train(self):
        return importlib.import_module("parallel_skills.train").train

    @train.setter
    def train(self, value):
        del value  # the submodule stays reachable through sys.modules["parallel_skills.train"]


sys.modules[__name__].__class__ = _Package
