"""The apex-hop environment vectorised on the batched engine: every lane that hops in a step hops in one call
(:class:`~.lanes.HopperLanes`), not in N copies of the single environment.

Lane i is exactly the single environment (:class:`~.apex_hop.ApexHopEnv`) reset with seed + i, as in
Gymnasium's ``SyncVectorEnv``: same observations, rewards, terminations, truncations and infos.

**Autoreset: next step** (``AutoresetMode.NEXT_STEP``, Gymnasium's default and ``SyncVectorEnv``'s): the
step that ends a lane's episode returns its last observation; the lane's next step ignores its action and
starts the next episode, returning the reset observation with reward 0, terminated and truncated False, and
no info entries (their masks ``_key`` False).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from tdslip_ros.envs.config import HopConfig
from tdslip_ros.envs.lanes import HopperLanes, check_seeds
from tdslip_ros.model.dynamics import FloatArray


class ApexHopVectorEnv(VectorEnv[FloatArray, FloatArray, FloatArray]):
    """``num_envs`` hoppers of one :class:`~tdslip_ros.envs.config.HopConfig` (settings as for ApexHopEnv)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int, **settings: Any) -> None:
        if not (isinstance(num_envs, int) and num_envs > 0):
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.config = HopConfig.of(**settings)
        self.num_envs = num_envs
        self.single_observation_space = self.config.observation_space()
        self.single_action_space = self.config.action_space()
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._lanes = HopperLanes(self.config, num_envs)
        self._observation_size = self.config.observation_bounds()[0].size
        self._generators: list[np.random.Generator] = []
        """Each lane's np_random (Gymnasium's: seeded at a seeded reset, else at the first), none before."""
        self._autoreset = np.zeros(num_envs, dtype=bool)

    def reset(
        self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Every lane's next episode; seed: one for all (lane i takes seed + i), or one per lane."""
        if options:
            raise ValueError(f"ApexHop takes no reset options, got {sorted(options)}")
        if seed is None or isinstance(seed, int | np.integer):
            seeds = [None if seed is None else int(seed) + lane for lane in range(self.num_envs)]
        else:
            seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(f"{len(seeds)} seeds for {self.num_envs} lanes")
        check_seeds(seeds)  # before any lane's generator is seeded
        if not self._generators:
            self._generators = [seeding.np_random(lane_seed)[0] for lane_seed in seeds]
        for lane, lane_seed in enumerate(seeds):
            if lane_seed is not None:
                self._generators[lane] = seeding.np_random(lane_seed)[0]
        self._autoreset[:] = False
        return self._lanes.reset(np.arange(self.num_envs), seeds, self._generators), {}

    def step(
        self, actions: FloatArray
    ) -> tuple[FloatArray, FloatArray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._generators:
            raise ResetNeeded("call reset before step")
        count = self.num_envs
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (count, self.config.acted):
            raise ValueError(f"actions must have the shape {(count, self.config.acted)}, got {actions.shape}")
        resetting = np.flatnonzero(self._autoreset)
        stepping = np.flatnonzero(~self._autoreset)
        observation = np.empty((count, self._observation_size))
        reward = np.zeros(count)
        terminated = np.zeros(count, dtype=bool)
        truncated = np.zeros(count, dtype=bool)
        info: dict[str, Any] = {}
        if resetting.size:
            observation[resetting] = self._lanes.reset(
                resetting, [None] * resetting.size, [self._generators[lane] for lane in resetting]
            )
        if stepping.size:
            strides = self._lanes.step(stepping, actions[stepping])
            observation[stepping] = strides.observation
            reward[stepping] = strides.reward
            terminated[stepping] = strides.terminated
            truncated[stepping] = strides.truncated
            mask = np.zeros(count, dtype=bool)
            mask[stepping] = True
            for key, values in strides.info.items():
                # As SyncVectorEnv gathers infos: zeros (None for texts) where a lane has no entry.
                full = (
                    np.full(count, None, dtype=object)
                    if values.dtype == object
                    else np.zeros(count, values.dtype)
                )
                full[stepping] = values
                info[key], info[f"_{key}"] = full, mask.copy()
        self._autoreset = terminated | truncated
        return observation, reward, terminated, truncated, info
