"""The methods a run trains with (``TrainConfig.method``; paper App. B, README "Configure"): each
one ``Method`` object saying who acts, which learners run on what batches, and the config
defaults it sets (``Method.resolve``). The trainer (``train``), the config (``config``) and the
command line (``training.run``) read these objects and never branch on a method's name; a new
method is one ``Method`` (``register``d) and its tests.

    method = methods.get(config.method)
    if method.learns_scheduler: ...

Who acts: the scheduler (``scheduler_acts``: SkillS's HCMPO scheduler, or RHPO's categorical,
a scheduler with K = {1}) or else the new skill alone. What learns:

* ``learns_scheduler``: the scheduler's HCMPO learner on its own (n-step) batches (SkillS);
* the new skill's CRR learner (every method), with the frozen skills' actions at its batch's
  states when its loss reads them (``config.baseline_reads_teacher``: kl_reg / dagger);
* ``mixture_learner``: instead of both, one RHPO update trains the categorical (the scheduler's
  policy) and the new skill as one of the mixture's components (``parallel_skills.rhpo``).
"""

from __future__ import annotations

import dataclasses
from typing import Dict, Optional, Sequence, Tuple


@dataclasses.dataclass(frozen=True)
class Method:
    """One way of training the new skill (see the module docstring)."""

    name: str
    help: str  # one phrase, for ``--method``'s help
    # The trainer keeps the frozen skills (they act through the scheduler, or teach the new skill).
    # False: the run has none (scratch), or uses its one skill only as the start (finetune).
    frozen_skills: bool = True
    scheduler_acts: bool = False  # else the new skill always acts
    learns_scheduler: bool = False  # the HCMPO scheduler learner runs
    mixture_learner: bool = False  # one RHPO update trains the categorical and the new skill
    # The new skill starts from the run's one (network) skill: its parameters and observation
    # statistics, the latter then kept fixed (``train.start_from_skill``).
    starts_from_skill: bool = False
    # NewSkillConfig.baseline the method sets: a loss that reads the frozen skills' actions.
    teacher_baseline: Optional[str] = None
    # NewSkillConfig.mpo_alpha (the CRR mix α) the method takes unless given (the paper sweeps
    # {0, 0.5, 1} and reports the best); None: the config's own.
    mix_alpha: Optional[float] = None
    # SchedulerConfig.skill_lengths the method needs (rhpo: (1,), a choice at every step).
    skill_lengths: Optional[Tuple[int, ...]] = None

    def resolve(self, cfg, given: Optional[Sequence[str]] = None):
        """``(cfg, notes)``: the resolved ``TrainConfig`` with this method's defaults set
        (``config.resolve`` calls it last). ``given``: the dotted fields the user set (None: a
        config built in code, whose fields are taken as set only where they differ from the
        defaults). A given field that contradicts the method: ValueError (one line)."""
        notes = []
        lengths = self.skill_lengths
        if lengths is not None and tuple(cfg.scheduler.skill_lengths) != lengths:
            if given is not None and "scheduler.skill_lengths" in given:
                raise ValueError(f"method {self.name} chooses a component at every step: scheduler.skill_lengths "
                                 f"must be {list(lengths)}, got {list(cfg.scheduler.skill_lengths)}")
            cfg = dataclasses.replace(cfg, scheduler=dataclasses.replace(cfg.scheduler, skill_lengths=lengths))
            notes.append(f"method {self.name}: scheduler skill_lengths={lengths} "
                         "(its categorical chooses a component every step)")
        if self.mix_alpha is not None or self.teacher_baseline is not None:
            sub, changes = cfg.new_skill, {}
            if self.teacher_baseline is not None and sub.baseline != self.teacher_baseline:
                changes["baseline"] = self.teacher_baseline
            if self.mix_alpha is not None and ((given is None and sub.mpo_alpha == 1.0)
                                               or (given is not None and "new_skill.mpo_alpha" not in given)):
                changes["mpo_alpha"] = self.mix_alpha
            changes = {f: v for f, v in changes.items() if getattr(sub, f) != v}
            if changes:
                cfg = dataclasses.replace(cfg, new_skill=dataclasses.replace(sub, **changes))
                notes.append(f"method {self.name}: new-skill " + ", ".join(
                    f"{f}={v:g}" if isinstance(v, float) else f"{f}={v}" for f, v in changes.items()))
        return cfg, notes


# The CRR mix α the paper's baselines take unless given (README "Configure").
MIX_ALPHA = 0.5

_REGISTRY: Dict[str, Method] = {}


def register(method: Method) -> Method:
    """Add ``method`` (a new name; ValueError for a taken one). Returns it."""
    if method.name in _REGISTRY:
        raise ValueError(f"method {method.name!r} is registered already")
    _REGISTRY[method.name] = method
    return method


def unregister(name: str) -> None:
    """Remove a registered method (tests that add their own)."""
    _REGISTRY.pop(name, None)


def names() -> Tuple[str, ...]:
    """The registered methods' names, in registration order (the paper's first)."""
    return tuple(_REGISTRY)


def get(name: str) -> Method:
    """The method called ``name``; ValueError (one line) naming the valid ones."""
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"method must be one of {', '.join(_REGISTRY)}, got {name!r}") from None


def all_methods() -> Tuple[Method, ...]:
    return tuple(_REGISTRY.values())


SKILLS = register(Method("skills", "SkillS (default): the scheduler chooses among the skills and the new skill",
                         scheduler_acts=True, learns_scheduler=True))
SCRATCH = register(Method("scratch", "the new skill alone, without skills", frozen_skills=False))
FINETUNE = register(Method("finetune", "the new skill alone, starting from --finetune_from", frozen_skills=False,
                           starts_from_skill=True))
KL_REG = register(Method("kl_reg", "the new skill alone, the skill set as its loss's prior",
                         teacher_baseline="kl_reg", mix_alpha=MIX_ALPHA))
DAGGER = register(Method("dagger", "the new skill alone, the skill set as its teacher", teacher_baseline="dagger",
                         mix_alpha=MIX_ALPHA))
RHPO = register(Method("rhpo", "a mixture of the skills and the new skill, chosen at every step",
                       scheduler_acts=True, mixture_learner=True, mix_alpha=MIX_ALPHA, skill_lengths=(1,)))
