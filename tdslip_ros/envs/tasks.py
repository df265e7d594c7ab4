"""The tasks of the apex-hop environments and their rewards, one reward per stride.

Every reward is dimensionless, in [0, 1], and computed from the *true* apex the stride reached (the
sensor's noise is the controller's problem, not the scorer's). A stride that ends in a failure of the plant
(:mod:`tdslip_ros.model.events`) is rewarded 0 and ends the episode, so that surviving always pays:

* ``speed``: r = exp(-((xdot' - target) / scale)^2), xdot' the next apex's forward speed [m/s], target and
  scale in m/s;
* ``height``: r = exp(-((y' - target) / scale)^2), y' the next apex's height above the ground of the stance
  just ended [m], target and scale in m;
* ``energy``: r = exp(-((E' - target) / scale)^2), E' = m (g y' + xdot'^2 / 2) the next apex's energy [J]
  (the potential energy above the ground of the stance just ended), target and scale in J;
* ``survive``: r = 1 (no target).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.policies.registry import DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED, DEFAULT_TARGET_ENERGY

TASKS = ("speed", "height", "energy", "survive")
UNITS = {"speed": "m/s", "height": "m", "energy": "J", "survive": ""}
DEFAULT_TARGETS = {
    "speed": DEFAULT_APEX_SPEED,
    "height": DEFAULT_APEX_HEIGHT,
    "energy": DEFAULT_TARGET_ENERGY,
    "survive": 0.0,
}
"""The node suite's default apex (1 m, 5 m/s) and its energy on the paper's hopper."""
DEFAULT_SCALES = {"speed": 0.5, "height": 0.1, "energy": 50.0, "survive": 1.0}
"""m/s, m, J: the tracking errors rewarded exp(-1) = 0.37 (50 J is 0.06 m g r0 on the paper's hopper)."""


@dataclass(frozen=True)
class Task:
    """A task by name (:data:`TASKS`), its target and the error scale of its reward, both in the task's
    unit (:data:`UNITS`; module docstring)."""

    name: str = "speed"
    target: float = math.nan
    scale: float = math.nan

    def __post_init__(self) -> None:
        if self.name not in TASKS:
            raise ParameterError(f"unknown task {self.name!r}; one of {', '.join(TASKS)}")
        if math.isnan(self.target):
            object.__setattr__(self, "target", DEFAULT_TARGETS[self.name])
        if math.isnan(self.scale):
            object.__setattr__(self, "scale", DEFAULT_SCALES[self.name])
        if not (math.isfinite(self.target) and math.isfinite(self.scale) and self.scale > 0.0):
            raise ParameterError(
                f"task {self.name}: target must be finite and scale positive and finite, got "
                f"{self.target!r} and {self.scale!r}"
            )

    @property
    def has_target(self) -> bool:
        """The observation carries the target (every task but survive)."""
        return self.name != "survive"

    def tracked(self, params: HopperParams, y: FloatArray, xdot: FloatArray) -> FloatArray:
        """The quantity the task tracks at apexes (y [m] above the ground, xdot [m/s]), in its unit."""
        if self.name == "speed":
            return xdot
        if self.name == "height":
            return y
        return params.m * (params.g * y + 0.5 * xdot**2)

    def reward(
        self, params: HopperParams, y: FloatArray, xdot: FloatArray, failed: npt.NDArray[np.bool_]
    ) -> FloatArray:
        """The reward of strides that reached the apexes (y, xdot) (NaN where ``failed``)."""
        if self.name == "survive":
            return np.where(failed, 0.0, 1.0)
        with np.errstate(invalid="ignore"):
            error = (self.tracked(params, y, xdot) - self.target) / self.scale
        return np.where(failed, 0.0, np.exp(-(error**2)))
