"""What an apex-hop environment is: the hopper, the task, how an action becomes a command, the perturbations,
the stride budget; and the observation and action spaces that follow.

**Action** (a Box on [-1, 1]^n, n = 3, or 2 with a fixed ramp duration; an action outside it is clipped to it,
a non-finite one refused): a linear map onto the stance command, SI: command = centre + half_width * action,
clipped to [command_low, command_high]
(touchdown angle [rad], tau0 [N m], t_f [s]; the ramp of eq. 18, tau(s) = tau0 (1 - s / t_f)).

* direct (``policy`` None): centre and half-width are those of [command_low, command_high];
* residual (``policy`` a :class:`~tdslip_ros.model.policies.registry.PolicySpec`): the centre is the policy's
command
  at the measured apex (planned with the controller's model, the mismatch of the perturbations), the
  half-width ``residual_half_width``. Where the policy has no command, its last one is kept (at the first
  stride: the middle of the command range).
* ``ramp_duration``: None, t_f is acted on; a number [s], t_f held at it; ``"liftoff"``, the paper's rule: t_f
  the liftoff time the analytic map predicts for the command's angle and tau0 at the measured apex
  (:func:`~tdslip_ros.model.policies.controllers.ramp_to_liftoff`, the controller's model), the middle of the
  t_f range where it predicts none. Either way clipped to the t_f range, and the action has no t_f component.

The action is normalised (a linear rescaling of SI bounds, not the paper's nondimensionalisation); the
observation stays SI.

**Observation** (a Box, float64, SI): the measured apex height above the ground of the last stance [m], the
measured forward speed [m/s], the task's target in its unit (not for ``survive``), then, for each distance d
in ``lookahead`` [m], the ground height at x + d relative to the ground of the last stance [m] (a perfect
map of the terrain ahead). Each component is clipped to the box (a noise draw beyond it would be).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from gymnasium import spaces

from tdslip_ros.envs.tasks import Task
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.policies.registry import DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED, POLICIES, PolicySpec
from tdslip_ros.model.stability.basins import EXACT_TOLERANCE

COMMAND_FIELDS = ("touchdown_angle", "tau0", "t_f")
LIFTOFF_RULE = "liftoff"
"""``ramp_duration`` of the paper's rule: the ramp ends at the predicted liftoff."""
DEFAULT_COMMAND_LOW = (math.radians(5.0), -800.0, 0.02)
"""rad, N m, s: the paper's hopper (m g r0 = 785 N m, stance about 0.13 s at 5 m/s)."""
DEFAULT_COMMAND_HIGH = (math.radians(45.0), 800.0, 0.3)
DEFAULT_RESIDUAL_HALF_WIDTH = (math.radians(5.0), 150.0, 0.05)
"""rad, N m, s: how far a residual action moves the policy's command."""
DEFAULT_INITIAL_HEIGHT = (DEFAULT_APEX_HEIGHT - 0.05, DEFAULT_APEX_HEIGHT + 0.05)
"""m: the initial apex height above flat ground is drawn uniformly from this range at each reset."""
DEFAULT_INITIAL_SPEED = (DEFAULT_APEX_SPEED - 0.25, DEFAULT_APEX_SPEED + 0.25)
"""m/s: likewise the initial apex speed."""
DEFAULT_MAX_STRIDES = 100
OBSERVATION_BOUND_FACTOR = 2.0
"""The observed height and speed lie within this factor times the plausibility limits' bounds."""


@dataclass(frozen=True, eq=False)
class HopConfig:
    """An apex-hop environment (module docstring); every field SI."""

    params: HopperParams = PAPER_PARAMS
    task: Task = field(default_factory=Task)
    policy: PolicySpec | None = None
    perturbations: Perturbations = field(default_factory=Perturbations)
    max_strides: int = DEFAULT_MAX_STRIDES
    lookahead: tuple[float, ...] = ()
    initial_height: tuple[float, float] = DEFAULT_INITIAL_HEIGHT
    initial_speed: tuple[float, float] = DEFAULT_INITIAL_SPEED
    command_low: tuple[float, float, float] = DEFAULT_COMMAND_LOW
    command_high: tuple[float, float, float] = DEFAULT_COMMAND_HIGH
    residual_half_width: tuple[float, float, float] = DEFAULT_RESIDUAL_HALF_WIDTH
    ramp_duration: float | str | None = None
    tolerance: float = EXACT_TOLERANCE
    """DOP853's rtol and atol on the stance (the studies' tolerance)."""

    @classmethod
    def of(cls, **settings: Any) -> HopConfig:
        """From the environments' keyword arguments: the fields, ``task`` also by name (its defaults)."""
        if isinstance(settings.get("task"), str):
            settings["task"] = Task(settings["task"])
        return cls(**settings)

    def __post_init__(self) -> None:
        limits = self.limits
        self.perturbations.scalars()  # ParameterError for per-lane values: an env's lanes share perturbations
        self.perturbations.check_limits(limits)
        if not (isinstance(self.max_strides, int) and self.max_strides > 0):
            raise ParameterError(f"max_strides must be a positive integer, got {self.max_strides!r}")
        low, high = np.asarray(self.command_low), np.asarray(self.command_high)
        if not (np.all(np.isfinite(low)) and np.all(low < high)):
            raise ParameterError(
                f"command_low {self.command_low} must be finite and below {self.command_high}"
            )
        torque = max(abs(low[1]), abs(high[1]))
        if not (0.0 < low[0] and high[0] < math.pi / 2 and low[2] > 0.0 and torque <= limits.max_torque):
            raise ParameterError(
                "the command range must keep the touchdown angle in (0, pi/2) rad, t_f > 0 s and |tau0| "
                f"within the actuator limit {limits.max_torque:.6g} N m"
            )
        if isinstance(self.ramp_duration, str):
            if self.ramp_duration != LIFTOFF_RULE:
                raise ParameterError(f"ramp_duration must be a number, {LIFTOFF_RULE!r} or None")
        elif self.ramp_duration is not None and not low[2] <= self.ramp_duration <= high[2]:
            raise ParameterError(f"ramp_duration {self.ramp_duration!r} s is outside the t_f range")
        for name, (lo, hi), bound in (
            ("initial_height", self.initial_height, limits.max_apex_height),
            ("initial_speed", self.initial_speed, limits.max_apex_speed),
        ):
            if not 0.0 < lo <= hi <= bound:
                raise ParameterError(f"{name} must be an interval within (0, {bound:.6g}], got {(lo, hi)}")
        # Refused here, not at the first step:
        if self.policy is not None and self.policy.name not in POLICIES:
            raise ParameterError(f"a residual needs a policy answering with a ramp, not {self.policy.name}")
        half_width = np.asarray(self.residual_half_width, dtype=np.float64)
        if half_width.shape != (3,) or not np.all(np.isfinite(half_width) & (half_width >= 0.0)):
            raise ParameterError(
                f"residual_half_width must be 3 finite widths >= 0, got {self.residual_half_width!r}"
            )
        if not (math.isfinite(self.tolerance) and self.tolerance > 0.0):
            raise ParameterError(f"tolerance must be positive, got {self.tolerance!r}")
        if not all(math.isfinite(distance) for distance in self.lookahead):
            raise ParameterError(f"lookahead distances must be finite, got {self.lookahead!r}")
        if self.task.has_target:
            low_bound, high_bound = self.observation_bounds()
            if not low_bound[2] <= self.task.target <= high_bound[2]:
                raise ParameterError(
                    f"task {self.task.name}: target {self.task.target!r} lies outside what the observation "
                    f"can hold, [{low_bound[2]:.6g}, {high_bound[2]:.6g}]"
                )

    @property
    def limits(self) -> PlausibilityLimits:
        return PlausibilityLimits.for_hopper(self.params)

    @property
    def acted(self) -> int:
        """How many command fields the action sets (t_f only without a fixed ramp duration)."""
        return 3 if self.ramp_duration is None else 2

    def action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(self.acted,), dtype=np.float64)

    def observation_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        limits = self.limits
        height = OBSERVATION_BOUND_FACTOR * limits.max_apex_height
        speed = OBSERVATION_BOUND_FACTOR * limits.max_apex_speed
        low = [-height, -speed]
        high = [height, speed]
        if self.task.has_target:
            target_bound = {"speed": speed, "height": height, "energy": limits.max_energy}[self.task.name]
            low.append(-target_bound)
            high.append(target_bound)
        low += [-height] * len(self.lookahead)
        high += [height] * len(self.lookahead)
        return np.array(low), np.array(high)

    def observation_space(self) -> spaces.Box:
        low, high = self.observation_bounds()
        return spaces.Box(low, high, dtype=np.float64)
