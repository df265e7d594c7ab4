"""Physical plausibility limits of a TD-SLIP hopper: the one place that says what is too much.

Two kinds of checks guard the package against absurd numbers, and they live in different places:

* **Always invalid** values are refused where they are built, by :mod:`.params`: non-numbers, NaN and
  infinities, non-positive masses, lengths, stiffnesses and gravity, negative damping, touchdown angles
  outside (0, pi/2), non-positive ramp durations, and hopper parameters whose products and ratios
  under- or overflow a double (:class:`~.params.HopperParams`).
* **Implausible** values are legal numbers that no hopper of the given size meets: a torque of 1e12 N m,
  an apex at 1e9 m, a ramp of 1e-9 s. :class:`PlausibilityLimits` holds those bounds for one hopper,
  scaled with it (m, g, r0, k), so the same multiples fit the paper's human-sized hopper (m = 80 kg,
  r0 = 1 m, kbar = 36, zeta0 = 0.08) and a 2 kg toy alike.

What happens at a limit depends on what crosses it:

* an **input** beyond the limits is rejected with ParameterError naming the field and the limit:
  :meth:`PlausibilityLimits.check_command` for a stance command, :meth:`PlausibilityLimits.check_apex`
  for an initial or reset apex, :func:`check_hopper` for the hopper itself. The plant node, its reset
  service and the command line call them before handing a value to an integrator; the integrators
  themselves refuse an initial apex beyond the limits (they cannot start from it);
* a **state** beyond the limits, reached by the motion, ends the run as the named failure
  ``state_limit`` (:class:`~.events.FailureKind`). Every integrator (the 1 kHz stepper, the exact map,
  the batched engine) applies the same rules, :meth:`PlausibilityLimits.torque_failure` when the leg
  touches down (the hip would have to produce the commanded torque),
  :meth:`PlausibilityLimits.apex_failure` when it lifts off (the coming apex is known in closed form) and
  :meth:`PlausibilityLimits.push_failure` when a push at the apex changes its speed (:mod:`.perturbations`);
  the stance itself is bounded by ``max_stance_time`` (the failure ``no_liftoff``).

These rules bound every reported number without a check inside the integration: a stance that
starts from an admissible apex with an admissible torque cannot gain more than ``max_torque`` times a
half turn of hip work (theta only decreases, from below pi/2 to above -pi/2, or the stance fails), so
its energy stays below :attr:`PlausibilityLimits.max_energy`; the flights that follow an admissible
apex are then bounded too (:attr:`PlausibilityLimits.max_flight_time`).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, fields
from typing import Any, overload

import numpy as np
import numpy.typing as npt

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.events import FailureKind, HopperState
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand

MAX_TORQUE_BODY_WEIGHTS = 20.0
"""Default actuator limit |tau0| <= 20 m g r0 (15.7 kN m for the paper's hopper). The energy-regulated
gait of the paper needs about 0.35 m g r0 (-273 N m); the deadbeat controller asks for up to 9.7 m g r0
in the first stride of the fig. 13 sweep (from 5 m/s at 1 m to 9.4 m/s in one stride), and the limit keeps
a factor 2 over that, so that no command of the package's own controllers is refused, while the torques
of a unit slip or a diverged solver (1e12 N m and beyond) are."""
MAX_APEX_HEIGHT_LEGS = 10.0
"""Default bound on apex heights, 10 r0. The paper's figures stay below 3 r0 (fixed points up to
ybar ~ 3, basins up to 2.4); a fall from 10 r0 takes 1.4 s for r0 = 1 m."""
MAX_APEX_FROUDE = 10.0
"""Default bound on apex speeds, 10 sqrt(g r0) (31 m/s for r0 = 1 m: 2.5 times a sprinter's top speed).
The paper's gaits run up to ~8 m/s (xdotbar ~ 2.6), its fig. 13 sweep to xdotbar = 3, its basins to
Ebar = 12 (about 15 m/s at the ground)."""
MIN_RAMP_SPRING_PERIODS = 1e-3
"""Default lower bound on t_f: a thousandth of the leg's natural period 2 pi sqrt(m/k) (0.34 ms for the
paper's hopper, whose stance lasts ~0.13 s). A shorter ramp delivers no useful impulse at a plausible
torque; a t_f in milliseconds given as seconds lands here."""


def check_hopper(params: HopperParams) -> None:
    """Refuse a hopper outside the model's range, naming the field: the leg must be underdamped.

    zeta0 = c/(2 sqrt(m k)) < 1 is what the analytic map and therefore every controller of the package
    need (the plant node's ``damping`` parameter promises it). The integrators themselves accept an
    overdamped leg; this check belongs where a hopper is configured (node parameters, command line).
    """
    if not params.zeta0 < 1.0:
        raise ParameterError(
            f"the leg damping c = {params.c:.6g} N s/m gives zeta0 = c/(2 sqrt(m k)) = {params.zeta0:.6g}, "
            "but the model needs an underdamped leg, zeta0 < 1"
        )


MIN_RTOL = 100.0 * sys.float_info.epsilon
"""Smallest relative tolerance of the adaptive integrators (scipy's own floor for solve_ivp)."""


def check_tolerances(rtol: float, atol: float) -> None:
    """Refuse tolerances with which an adaptive integrator cannot finish (0, NaN, inf, negative).

    rtol must lie in [MIN_RTOL, 1): below, DOP853's steps shrink without end; at 1 and above no digit is
    controlled. atol must be finite and non-negative.
    """
    if not MIN_RTOL <= rtol < 1.0:  # False for NaN too
        raise ParameterError(f"rtol must lie in [{MIN_RTOL:.3g}, 1), got {rtol!r}")
    if not 0.0 <= atol < math.inf:
        raise ParameterError(f"atol must be finite and non-negative, got {atol!r}")


FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class PlausibilityLimits:
    """The plausibility bounds of one hopper (SI); :meth:`for_hopper` gives the defaults.

    max_torque [N m]: the actuator's limit on |tau0|, the peak of the ramp torque;
    min_ramp_duration, max_ramp_duration [s]: the range of t_f;
    max_apex_height [m], max_apex_speed [m/s]: bounds on apex heights and |apex speeds|, initial, reset
    and reached alike;
    max_stance_time [s]: a stance longer than this fails as ``no_liftoff``.
    Every field must be positive and finite (ParameterError otherwise); change one with
    ``dataclasses.replace``.
    """

    params: HopperParams
    max_torque: float
    min_ramp_duration: float
    max_ramp_duration: float
    max_apex_height: float
    max_apex_speed: float
    max_stance_time: float

    def __post_init__(self) -> None:
        for name in (
            "max_torque",
            "min_ramp_duration",
            "max_ramp_duration",
            "max_apex_height",
            "max_apex_speed",
            "max_stance_time",
        ):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 < value < math.inf):
                raise ParameterError(f"{name} must be a positive finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.min_ramp_duration > self.max_ramp_duration:
            raise ParameterError(
                f"min_ramp_duration {self.min_ramp_duration!r} s exceeds max_ramp_duration "
                f"{self.max_ramp_duration!r} s"
            )

    @classmethod
    def for_hopper(cls, params: HopperParams) -> PlausibilityLimits:
        """The default limits of ``params``: |tau0| <= 20 m g r0, t_f in [1e-3, 10] natural periods of the
        leg, apexes up to 10 r0 high and 10 sqrt(g r0) fast, stances up to 10 natural periods (see the
        module constants for the reasons)."""
        spring_period = 2.0 * math.pi / params.omega0
        return cls(
            params=params,
            max_torque=MAX_TORQUE_BODY_WEIGHTS * units.energy_scale(params),
            min_ramp_duration=MIN_RAMP_SPRING_PERIODS * spring_period,
            max_ramp_duration=dynamics.max_stance_duration(params),
            max_apex_height=MAX_APEX_HEIGHT_LEGS * units.length_scale(params),
            max_apex_speed=MAX_APEX_FROUDE * units.speed_scale(params),
            max_stance_time=dynamics.max_stance_duration(params),
        )

    @classmethod
    def of(cls, params: HopperParams, limits: PlausibilityLimits | None) -> PlausibilityLimits:
        """``limits``, or the defaults of ``params`` when None; ParameterError if made for another hopper."""
        if limits is None:
            return cls.for_hopper(params)
        if limits.params != params:
            raise ParameterError(f"the limits were made for {limits.params}, not for {params}")
        return limits

    # --- derived bounds -----------------------------------------------------------------------

    @property
    def max_energy(self) -> float:
        """Bound [J] on the mechanical energy of any motion within the limits: the most energetic admissible
        apex plus the most hip work one stance can do (max_torque over a half turn)."""
        p = self.params
        apex = p.m * p.g * self.max_apex_height + 0.5 * p.m * self.max_apex_speed**2
        return apex + math.pi * self.max_torque

    @property
    def max_flight_time(self) -> float:
        """Bound [s] on a flight: a rise to the highest admissible apex and the fall back to the ground."""
        return 2.0 * math.sqrt(2.0 * self.max_apex_height / self.params.g)

    # --- inputs: ParameterError ---------------------------------------------------------------

    def check_command(self, command: StanceCommand) -> None:
        """Refuse a stance command beyond the actuator limit or the t_f range, naming field and limit."""
        if not abs(command.tau0) <= self.max_torque:
            raise ParameterError(
                f"tau0 = {command.tau0!r} N m exceeds the actuator limit |tau0| <= {self.max_torque:.6g} N m"
            )
        if not self.min_ramp_duration <= command.t_f <= self.max_ramp_duration:
            raise ParameterError(
                f"t_f = {command.t_f!r} s is outside [{self.min_ramp_duration:.6g}, "
                f"{self.max_ramp_duration:.6g}] s"
            )

    def check_apex(self, apex: ApexState) -> None:
        """Refuse an initial or reset apex beyond the limits, naming field and limit."""
        reason = self.apex_violation(apex.y, apex.xdot)
        if reason is not None:
            raise ParameterError(reason)

    # --- states: the failure state_limit --------------------------------------------------------

    @overload
    def torque_exceeded(self, tau0: float) -> bool: ...
    @overload
    def torque_exceeded(self, tau0: FloatArray) -> BoolArray: ...
    def torque_exceeded(self, tau0: Any) -> Any:
        """True where the ramp torque tau0 [N m] is beyond the actuator limit (a float or an array)."""
        return abs(tau0) > self.max_torque

    @overload
    def apex_exceeded(self, y: float, xdot: float) -> bool: ...
    @overload
    def apex_exceeded(self, y: FloatArray, xdot: FloatArray) -> BoolArray: ...
    def apex_exceeded(self, y: Any, xdot: Any) -> Any:
        """True where the apex (y [m], xdot [m/s]) is beyond the limits (floats or arrays)."""
        return (y > self.max_apex_height) | (abs(xdot) > self.max_apex_speed)

    def apex_violation(self, y: float, xdot: float) -> str | None:
        """Why the apex (y, xdot) is beyond the limits, or None."""
        if y > self.max_apex_height:
            return f"apex height y = {y!r} m exceeds max_apex_height = {self.max_apex_height:.6g} m"
        if abs(xdot) > self.max_apex_speed:
            return f"apex speed xdot = {xdot!r} m/s exceeds max_apex_speed = {self.max_apex_speed:.6g} m/s"
        return None

    def torque_failure(self, tau0: float) -> tuple[FailureKind, str] | None:
        """The failure of a touchdown whose ramp torque the actuator cannot produce, or None."""
        if self.torque_exceeded(tau0):
            return FailureKind.STATE_LIMIT, (
                f"touchdown with tau0 = {tau0:.6g} N m beyond the actuator limit {self.max_torque:.6g} N m"
            )
        return None

    def apex_failure(self, y_apex: float, xdot: float) -> tuple[FailureKind, str] | None:
        """The failure of a liftoff whose coming apex (y_apex, xdot) is beyond the limits, or None."""
        reason = self.apex_violation(y_apex, xdot)
        return None if reason is None else (FailureKind.STATE_LIMIT, f"liftoff towards an {reason}")

    def push_failure(self, y: float, xdot: float, push: float) -> tuple[FailureKind, str] | None:
        """The failure of a push of ``push`` [m/s] at the apex (y, xdot before it) that takes the apex beyond
        the limits, or None."""
        reason = self.apex_violation(y, xdot + push)
        return (
            None
            if reason is None
            else (FailureKind.STATE_LIMIT, f"a push of {push:.6g} m/s at the apex: {reason}")
        )

    def state_violation(self, state: HopperState) -> str | None:
        """Why a reported state is not finite or beyond the limits (torque, energy), or None.

        For integrators and tests that watch a trajectory; the integrators here never report such a state.
        """
        for field in fields(state):
            value = getattr(state, field.name)
            if not isinstance(value, float):
                continue  # stride, phase
            if not math.isfinite(value):
                return f"{field.name} = {value!r} is not finite"
        if self.torque_exceeded(state.hip_torque):
            return f"hip torque {state.hip_torque!r} N m exceeds the actuator limit {self.max_torque:.6g} N m"
        if state.energy > self.max_energy:
            return f"energy {state.energy!r} J exceeds max_energy = {self.max_energy:.6g} J"
        return None


# The checks of the value objects (params) and of the limits, per lane of a batch: the engines that take
# arrays (the batched engine, the compiled stride, energy_exact's planner) validate their lanes with these.
Checks = tuple[tuple[str, FloatArray, npt.NDArray[np.bool_], str], ...]
"""(field name, values, valid per lane, requirement)."""


def check_lanes(checks: Checks) -> None:
    """ParameterError naming the field and the first lane of the first check that fails."""
    for name, values, valid, requirement in checks:
        if not np.all(valid):
            lane = int(np.flatnonzero(~valid)[0])
            raise ParameterError(f"{name} must be {requirement}, got {values[lane]!r} in lane {lane}")


def validate_lanes(
    limits: PlausibilityLimits,
    y: FloatArray,
    xdot: FloatArray,
    angle: FloatArray,
    stance: Checks,
) -> None:
    """The checks of ApexState, of the stance (``stance``: those of StanceCommand for ramps) and
    limits.check_apex, per lane; the message names the field and a lane."""
    check_lanes(
        (
            ("apex height y", y, np.isfinite(y) & (y > 0.0), "a positive finite number"),
            ("apex speed xdot", xdot, np.isfinite(xdot), "finite"),
            ("touchdown_angle", angle, (angle > 0.0) & (angle < math.pi / 2), "in (0, pi/2) rad"),
            *stance,
        )
    )
    beyond = limits.apex_exceeded(y, xdot)
    if np.any(beyond):
        lane = int(np.flatnonzero(beyond)[0])
        raise ParameterError(f"{limits.apex_violation(float(y[lane]), float(xdot[lane]))} in lane {lane}")


def ramp_checks(tau0: FloatArray, t_f: FloatArray) -> Checks:
    """The checks of StanceCommand's ramp (tau0, t_f), per lane, for :func:`validate_lanes`."""
    return (
        ("tau0", tau0, np.isfinite(tau0), "finite"),
        ("t_f", t_f, np.isfinite(t_f) & (t_f > 0.0), "a positive finite number"),
    )
