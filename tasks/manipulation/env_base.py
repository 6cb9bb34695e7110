"""What every Brax-API backend of the manipulation domain shares: sizes and control period.

Subclasses set ``backend`` and implement ``reset`` / ``step``.
"""

from __future__ import annotations

from brax.envs.base import Env

from tasks.manipulation import layout as L


class ManipulationEnv(Env):
    """Brax env base with the domain's fixed observation / action sizes and 20 Hz control."""

    @property
    def observation_size(self) -> int:
        return L.OBS_SIZE

    @property
    def action_size(self) -> int:
        return L.ACTION_SIZE

    @property
    def dt(self) -> float:
        return L.CONTROL_DT
