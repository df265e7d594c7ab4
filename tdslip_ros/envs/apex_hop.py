"""``tdslip_ros/ApexHop-v0``: the TD-SLIP hopper as a Gymnasium environment, one step one stride of the
exact plant (the batched engine, :mod:`tdslip_ros.model.plant.batch`, with one lane).

The settings are the fields of :class:`~tdslip_ros.envs.config.HopConfig` as keyword arguments (``task`` may
be a task's name); observation, action, rewards and seeding are documented in :mod:`.config`,
:mod:`.tasks` and :mod:`.lanes`, and in docs/envs.md.

An episode *terminates* at a failure of the plant (:mod:`tdslip_ros.model.events`; info ``failure`` names
it, "" otherwise) and is *truncated* after ``max_strides`` strides. On termination the observation is the
last apex measured (the failed stride reached none). ``info`` of a step: ``failure``, the stance's energy
flows ``hip_work``, ``damping_loss``, ``spring_loss`` [J] (NaN where the leg did not lift off), the applied
command ``touchdown_angle`` [rad], ``tau0`` [N m], ``t_f`` [s], the true next apex ``apex_height`` [m
above the stance's ground], ``apex_speed`` [m/s], ``x`` [m], the stance's ``ground`` [m] (NaN where not
reached), the ``push`` at the apex [m/s] and whether the hip ``saturated``. A step after the end, before a
reset, raises ResetNeeded.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.error import ResetNeeded

from tdslip_ros.envs.config import HopConfig
from tdslip_ros.envs.lanes import HopperLanes
from tdslip_ros.envs.render import draw_stride
from tdslip_ros.model.dynamics import FloatArray

ONLY_LANE = np.zeros(1, dtype=np.int64)


def scalar_info(info: dict[str, Any], lane: int) -> dict[str, Any]:
    """One lane's entries of a step's info arrays as Python scalars."""
    return {
        key: values[lane].item() if isinstance(values[lane], np.generic) else values[lane]
        for key, values in info.items()
    }


class ApexHopEnv(gym.Env[FloatArray, FloatArray]):
    """One hopper, one stride per step (module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, render_mode: str | None = None, **settings: Any) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or rgb_array, got {render_mode!r}")
        self.config = HopConfig.of(**settings)
        self.render_mode = render_mode
        self.observation_space = self.config.observation_space()
        self.action_space = self.config.action_space()
        self._lanes = HopperLanes(self.config, 1)
        self._stepped = False
        self._ended = True

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        if options:
            raise ValueError(f"ApexHop takes no reset options, got {sorted(options)}")
        super().reset(seed=seed)
        self._stepped = self._ended = False
        return self._lanes.reset(ONLY_LANE, [seed], [self.np_random])[0], {}

    def step(self, action: FloatArray) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:
        if self._ended:
            raise ResetNeeded("the episode has ended (or not begun): call reset")
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (self.config.acted,):
            raise ValueError(f"the action must have the shape {(self.config.acted,)}, got {action.shape}")
        strides = self._lanes.step(ONLY_LANE, action[None])
        terminated, truncated = bool(strides.terminated[0]), bool(strides.truncated[0])
        self._stepped, self._ended = True, terminated or truncated
        return (
            strides.observation[0],
            float(strides.reward[0]),
            terminated,
            truncated,
            scalar_info(strides.info, 0),
        )

    def render(self) -> Any:
        if self.render_mode != "rgb_array":
            return None
        lanes = self._lanes
        inputs = (
            {key: float(values[0]) for key, values in lanes.last_inputs.items()} if self._stepped else None
        )
        apex = (float(lanes.x[0]), float(lanes.y[0]), float(lanes.ground[0]))
        return draw_stride(self.config, inputs, apex, lanes.terrain(ONLY_LANE).take(0))
