"""parallel-skills: SkillS (Vezzani et al., ICLR 2023) as a massively parallel JAX trainer.

Public API (Brax style)::

    from parallel_skills import Skill, TrainConfig, train
    make_policy, params, metrics = train(env, skills, num_timesteps=..., seed=0)
"""

from parallel_skills.config import NewSkillConfig, SchedulerConfig
from parallel_skills.skills import Skill, SkillSet
from parallel_skills.train import TrainConfig, make_trainer, train

__all__ = ["NewSkillConfig", "SchedulerConfig", "Skill", "SkillSet", "TrainConfig", "make_trainer", "train"]
__version__ = "0.1.0"
