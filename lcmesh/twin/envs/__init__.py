"""Gymnasium and PettingZoo environments over the twin (LC-Opt's MDPs, Tables 1 and 2).

- ``lcmesh/Cabinet-v0``: :class:`CabinetEnv`, the blade-group MDP over all cabinets (towers static).
- ``lcmesh/Tower-v0``: :class:`TowerEnv`, the cooling-tower MDP over all towers (cabinets static).
- :class:`CoolingParallelEnv`: every cabinet and tower as a PettingZoo parallel agent.

``make_normalized(env)`` gives the LC-Opt [-1, 1] form. Episode settings: :class:`EpisodeConfig`.
"""

from __future__ import annotations

import gymnasium

from lcmesh.twin.envs.cabinet import CabinetEnv
from lcmesh.twin.envs.episode import Clamp, EpisodeConfig, EpisodeDriver
from lcmesh.twin.envs.parallel import CoolingParallelEnv
from lcmesh.twin.envs.tower import TowerEnv
from lcmesh.twin.envs.wrappers import NormalizedAction, NormalizedObservation, make_normalized

ENV_IDS = {
    "lcmesh/Cabinet-v0": "lcmesh.twin.envs.cabinet:CabinetEnv",
    "lcmesh/Tower-v0": "lcmesh.twin.envs.tower:TowerEnv",
}

for _env_id, _entry_point in ENV_IDS.items():
    if _env_id not in gymnasium.registry:
        # the envs end their own episodes (EpisodeConfig.episode_steps), so no TimeLimit wrapper
        gymnasium.register(id=_env_id, entry_point=_entry_point)

__all__ = [
    "ENV_IDS",
    "CabinetEnv",
    "Clamp",
    "CoolingParallelEnv",
    "EpisodeConfig",
    "EpisodeDriver",
    "NormalizedAction",
    "NormalizedObservation",
    "TowerEnv",
    "make_normalized",
]
