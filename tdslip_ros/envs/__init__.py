"""Learning environments (Gymnasium) on the exact TD-SLIP plant: ``tdslip_ros/ApexHop-v0`` (docs/envs.md).

Importing this package registers the environment, so that ``gymnasium.make("tdslip_ros/ApexHop-v0")`` makes
the single env and ``gymnasium.make_vec("tdslip_ros/ApexHop-v0", num_envs=N)`` the vector env.
"""

from __future__ import annotations

import gymnasium

from tdslip_ros.envs.apex_hop import ApexHopEnv
from tdslip_ros.envs.config import HopConfig
from tdslip_ros.envs.tasks import TASKS, Task
from tdslip_ros.envs.vector import ApexHopVectorEnv

ENV_ID = "tdslip_ros/ApexHop-v0"

__all__ = ["ENV_ID", "TASKS", "ApexHopEnv", "ApexHopVectorEnv", "HopConfig", "Task"]

if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        ENV_ID,
        entry_point="tdslip_ros.envs.apex_hop:ApexHopEnv",
        vector_entry_point="tdslip_ros.envs.vector:ApexHopVectorEnv",
        disable_env_checker=False,
    )
