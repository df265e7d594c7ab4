"""TD-SLIP equations of motion: the one home of the physics that every integrator here shares.

Flight is ballistic (paper eq. 1) and solved in closed form. Stance (eq. 2) has the toe fixed on
the ground, polar leg coordinates (r, theta) and the ramp hip torque of eq. 18:

    m rddot          = m r thetadot^2 - m g cos(theta) - k (r - r0) - c rdot
    d/dt(m r^2 thetadot) = m g r sin(theta) + tau(s),     s = time since touchdown,

body = toe + (-r sin(theta), r cos(theta)) (the convention of :mod:`tdslip_ros.model.params`). The
stance equations hold in the toe's frame, whatever the ground height toe_y the toe stands on (uneven
ground, :mod:`.terrain`); world heights add toe_y, and energies m g toe_y. An actuator limit tau_max
saturates the torque (:func:`hip_torque`).
The leg cannot pull: it lifts off when its force k (r0 - r) - c rdot crosses zero from above, and
the spring energy it still holds then is lost with the massless leg.

The functions below that an integrator calls inside its steps are plain arithmetic: they take
sin(theta) and cos(theta) from the caller, so the same code serves Python floats (the 1 kHz
stepper and the exact map, where ``math`` is fastest), numpy arrays (the batched engine's flight,
the stance laws) and the compiled kernels, which compile it for one lane (:mod:`.stance_kernel`,
:mod:`.plant.stride_kernels`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.events import FailureKind, HopperState, Phase
from tdslip_ros.model.params import HopperParams, ParameterError

FloatArray = npt.NDArray[np.float64]
Real = TypeVar("Real", float, FloatArray)


class Hopper(Protocol):
    """What the stance's arithmetic reads of a hopper: :class:`.params.HopperParams`, or the named tuple
    of the same fields that the compiled kernels pass (:class:`.stance_kernel.LaneHopper`)."""

    @property
    def m(self) -> float: ...
    @property
    def k(self) -> float: ...
    @property
    def r0(self) -> float: ...
    @property
    def c(self) -> float: ...
    @property
    def g(self) -> float: ...


NO_LIFTOFF_SPRING_PERIODS = 10.0
"""A stance longer than this many natural periods 2 pi sqrt(m/k) of the leg spring is a failure
(no_liftoff). A hop's stance lasts about half a period; a body that sinks onto its leg and stays
balanced (heavy damping, near-vertical leg, almost no speed) would otherwise never end."""


def max_stance_duration(params: HopperParams) -> float:
    """The no_liftoff bound [s]: NO_LIFTOFF_SPRING_PERIODS natural periods of the leg spring."""
    return NO_LIFTOFF_SPRING_PERIODS * 2.0 * math.pi / params.omega0


def touchdown_height(params: Hopper, cos_touchdown: Real) -> Real:
    """Body height [m] at which the leg, placed at rest length, touches the ground."""
    return params.r0 * cos_touchdown


PLACEMENT_LEAD_TIME = 5e-3
"""s: the least fall from an apex to the touchdown after it that a commanded leg placement may have.

A command answering an apex arrives a little after it (a lockstep plant takes it at the end of the tick
that held the apex, up to 1 ms later; realtime latencies stay below 2 ms at p99), while the body already
falls. With this lead the touchdown height lies at least g T^2/2 (0.12 mm) below the apex, so a command
planned at the apex still finds the body above its touchdown height when it arrives, instead of being
refused for a difference of a micrometre."""


def placement_clearance(g: Real) -> Real:
    """Height [m] the body falls from its apex in PLACEMENT_LEAD_TIME: the least apex-to-touchdown drop."""
    return 0.5 * g * PLACEMENT_LEAD_TIME**2


def can_place_leg(r0: Real, g: Real, apex_y: Real, cos_touchdown: Real) -> bool | npt.NDArray[np.bool_]:
    """True where a leg placed at theta_td (its cosine given) in a flight with apex height apex_y [m]
    touches down at least PLACEMENT_LEAD_TIME after the apex: the one admissibility test of a touchdown
    angle, shared by the controllers (which plan only such angles) and the plant (which refuses others).

    Arrays broadcast (r0 [m] and g [m/s^2] may hold several parameter sets); floats give a bool.
    """
    clear: bool | npt.NDArray[np.bool_] = apex_y - r0 * cos_touchdown >= placement_clearance(g)
    return clear


def check_placement(params: HopperParams, apex_y: float, touchdown_angle: float | None) -> None:
    """ParameterError if the leg cannot be placed (:func:`can_place_leg`) from an apex at apex_y [m] at
    touchdown_angle [rad], or at any angle when it is None (a policy that chooses its angle)."""
    if touchdown_angle is None:
        if not can_place_leg(params.r0, params.g, apex_y, 0.0):
            raise ParameterError(
                f"the leg cannot be placed from an apex at {apex_y} m at any touchdown angle: the apex must "
                f"be above {placement_clearance(params.g):.4g} m"
            )
    elif not can_place_leg(params.r0, params.g, apex_y, math.cos(touchdown_angle)):
        raise ParameterError(
            f"the leg cannot be placed from an apex at {apex_y} m at the touchdown angle "
            f"{math.degrees(touchdown_angle):.4g} deg: the apex must be at least "
            f"{params.r0 * math.cos(touchdown_angle) + placement_clearance(params.g):.4g} m high"
        )


def fall_time(y: Real, ydot: Real, y_target: Real, g: float) -> Real:
    """Time [s] for a ballistic body at (y, ydot) to reach y_target while descending.

    The caller guarantees y_target <= the apex height y + ydot^2 / (2 g).
    """
    root: Real = (ydot * ydot + 2.0 * g * (y - y_target)) ** 0.5
    return (ydot + root) / g


def ballistic(x: Real, y: Real, xdot: Real, ydot: Real, t: Real, g: float) -> tuple[Real, Real, Real, Real]:
    """Flight state (x, y, xdot, ydot) after time t (eq. 1, exact)."""
    return x + xdot * t, y + ydot * t - 0.5 * g * t * t, xdot, ydot - g * t


def polar_velocity(r: Real, sin_t: Real, cos_t: Real, xdot: Real, ydot: Real) -> tuple[Real, Real]:
    """(rdot, thetadot) of the body about the toe from its Cartesian velocity (eq. 6 at touchdown)."""
    return -xdot * sin_t + ydot * cos_t, (-xdot * cos_t - ydot * sin_t) / r


def touchdown_leg_rate(params: HopperParams, y: float, xdot: float, touchdown_angle: float) -> float:
    """thetadot [rad/s] at the touchdown after an apex (y above the ground, xdot), the leg at rest length
    and ``touchdown_angle``: a ramp starting at tau0 puts tau0 times it into the hip at touchdown (the
    open-loop policy's touchdown power)."""
    cos_td = math.cos(touchdown_angle)
    fall = fall_time(y, 0.0, touchdown_height(params, cos_td), params.g)
    return polar_velocity(params.r0, math.sin(touchdown_angle), cos_td, xdot, -params.g * fall)[1]


def cartesian_velocity(r: Real, sin_t: Real, cos_t: Real, rdot: Real, thetadot: Real) -> tuple[Real, Real]:
    """(xdot, ydot) of the body from its polar velocity about the toe (eq. 7 at liftoff)."""
    return -rdot * sin_t - r * thetadot * cos_t, rdot * cos_t - r * thetadot * sin_t


def ramp_torque(tau0: Real, t_f: Real, s: Real) -> Real:
    """Hip torque [N m] of eq. 18 at time s after touchdown: tau0 (1 - s/t_f) up to t_f, then 0.

    Integrators split the stance at s = t_f, so no step straddles the kink.
    """
    return tau0 * (1.0 - s / t_f) * (s <= t_f)


def hip_torque(tau0: Real, t_f: Real, s: Real, tau_max: Real | None) -> Real:
    """The ramp torque of :func:`ramp_torque` saturated at +-tau_max [N m] (None: no saturation).

    Saturation adds a kink at :func:`saturation_end`, where integrators split the stance too.
    """
    tau = ramp_torque(tau0, t_f, s)
    if tau_max is None:
        return tau
    if isinstance(tau, float):  # the 1 kHz stepper: plain floats are ten times faster than numpy's
        return min(max(tau, -tau_max), tau_max)
    saturated: Real = np.minimum(np.maximum(tau, -tau_max), tau_max)
    return saturated


def saturation_end(tau0: npt.ArrayLike, t_f: npt.ArrayLike, tau_max: npt.ArrayLike) -> FloatArray:
    """Time s [s] after touchdown at which a ramp from |tau0| > tau_max falls to tau_max and leaves the
    saturation: t_f (1 - tau_max/|tau0|); t_f (no kink before the ramp's end) where |tau0| <= tau_max."""
    tau0, t_f, tau_max = (np.asarray(value, dtype=np.float64) for value in (tau0, t_f, tau_max))
    with np.errstate(divide="ignore"):
        end: FloatArray = np.where(np.abs(tau0) > tau_max, saturation_time(tau0, t_f, tau_max), t_f)
    return end


def saturation_time(tau0: Real, t_f: Real, tau_max: Real) -> Real:
    """t_f (1 - tau_max/|tau0|) [s]: where the ramp from tau0 falls to +-tau_max (for |tau0| > tau_max)."""
    end: Real = t_f * (1.0 - tau_max / abs(tau0))
    return end


def leg_force(params: Hopper, r: Real, rdot: Real) -> Real:
    """Axial force [N] of the spring-damper leg, positive when it pushes the body away from the toe."""
    return params.k * (params.r0 - r) - params.c * rdot


def stance_accelerations(
    params: Hopper, r: Real, sin_t: Real, cos_t: Real, rdot: Real, thetadot: Real, tau: Real
) -> tuple[Real, Real]:
    """(rddot, thetaddot) of eq. 2 with hip torque tau [N m]."""
    rddot = r * thetadot * thetadot - params.g * cos_t + leg_force(params, r, rdot) / params.m
    thetaddot = (params.g * sin_t - 2.0 * rdot * thetadot) / r + tau / (params.m * r * r)
    return rddot, thetaddot


def stance_powers(params: Hopper, rdot: Real, thetadot: Real, tau: Real) -> tuple[Real, Real]:
    """(hip power tau thetadot, damper power c rdot^2) [W]; their integrals are the stride's energy flows."""
    return tau * thetadot, params.c * rdot * rdot


def stance_derivatives(
    params: Hopper, r: Real, sin_t: Real, cos_t: Real, rdot: Real, thetadot: Real, tau: Real
) -> tuple[Real, Real, Real, Real, Real, Real]:
    """The stance right-hand side: d/ds of (r, theta, rdot, thetadot, hip work, damper loss) under hip
    torque tau [N m]. The one source of every DOP853 engine's field: the exact map calls it on floats, the
    compiled stance (:mod:`.stance_kernel`, the batched engine's and the compiled stride's) compiles it for
    one lane."""
    rddot, thetaddot = stance_accelerations(params, r, sin_t, cos_t, rdot, thetadot, tau)
    hip_power, damper_power = stance_powers(params, rdot, thetadot, tau)
    return rdot, thetadot, rddot, thetaddot, hip_power, damper_power


STANCE_EVENT_NAMES = ("bottom", "liftoff", "reversal", "fall")
"""Stance events, in the order of :func:`stance_event_values`."""


def stance_event_values(
    params: Hopper, r: Real, cos_t: Real, rdot: Real, thetadot: Real
) -> tuple[Real, Real, Real, Real]:
    """Event functions; each event happens when its value crosses from > 0 to <= 0.

    bottom: -rdot (maximum compression); liftoff: the leg force; reversal: -thetadot (the body
    swings back); fall: the body height r cos(theta).
    """
    return -rdot, leg_force(params, r, rdot), -thetadot, r * cos_t


def stance_event_rates(
    params: Hopper,
    r: Real,
    sin_t: Real,
    cos_t: Real,
    rdot: Real,
    thetadot: Real,
    rddot: Real,
    thetaddot: Real,
) -> tuple[Real, Real, Real, Real]:
    """Time derivatives of :func:`stance_event_values` along the motion, for Newton's method."""
    return -rddot, -params.k * rdot - params.c * rddot, -thetaddot, rdot * cos_t - r * thetadot * sin_t


def spring_energy(params: Hopper, r: Real) -> Real:
    return 0.5 * params.k * (r - params.r0) ** 2


def stance_energy(params: HopperParams, r: Real, cos_t: Real, rdot: Real, thetadot: Real) -> Real:
    """Total mechanical energy [J] in stance: kinetic + gravitational + spring."""
    kinetic = 0.5 * params.m * (rdot * rdot + r * r * thetadot * thetadot)
    return kinetic + params.m * params.g * r * cos_t + spring_energy(params, r)


def apex_energy(m: Any, g: Any, y: Any, xdot: Any) -> Any:
    """Mechanical energy [J] of an apex at height y [m] with forward speed xdot [m/s], m (g y + xdot^2 / 2):
    the coordinate E of eq. 23. Plain arithmetic, for floats, arrays and complex steps alike; the compiled
    kernels call this same source (:mod:`tdslip_ros.model.analytic.map_kernels` registers it)."""
    return m * (g * y + 0.5 * xdot**2)


class MassAndGravity(Protocol):
    """What :func:`speed_from_energy` reads of a hopper: floats (:class:`.params.HopperParams`) or arrays
    over lanes (:class:`.arrays.ParamArrays`)."""

    @property
    def m(self) -> npt.ArrayLike: ...
    @property
    def g(self) -> npt.ArrayLike: ...


def speed_from_energy(params: MassAndGravity, y: npt.ArrayLike, energy: npt.ArrayLike) -> FloatArray:
    """Forward apex speed [m/s] with apex height y [m] and energy E [J], the inverse of :func:`apex_energy`
    in xdot >= 0 (eq. 23 coordinates); NaN where E < m g y."""
    m, g = np.asarray(params.m), np.asarray(params.g)
    with np.errstate(invalid="ignore"):
        return np.asarray(np.sqrt(2.0 * (np.asarray(energy) / m - g * np.asarray(y))))


def flight_energy(params: HopperParams, y: Real, xdot: Real, ydot: Real) -> Real:
    """Total mechanical energy [J] in flight (the massless leg holds none)."""
    return 0.5 * params.m * (xdot * xdot + ydot * ydot) + params.m * params.g * y


def ground_reaction_force(
    params: Hopper, r: Real, sin_t: Real, cos_t: Real, rdot: Real, tau: Real
) -> tuple[Real, Real]:
    """Force (F_x, F_y) [N] the ground exerts on the body through the leg in stance.

    F = f_leg e_r + (tau / r) e_theta, e_r = (-sin, cos) from toe to body, e_theta = (-cos, -sin):
    the hip torque acts on the body as a force normal to the leg with moment tau about the toe.
    """
    f_leg = leg_force(params, r, rdot)
    f_normal = tau / r
    return -f_leg * sin_t - f_normal * cos_t, f_leg * cos_t - f_normal * sin_t


def stance_hopper_state(
    params: HopperParams,
    t: float,
    stride: int,
    toe_x: float,
    r: float,
    theta: float,
    rdot: float,
    thetadot: float,
    tau: float,
    toe_y: float = 0.0,
    ground: Callable[[float], float] | None = None,
) -> HopperState:
    """Full state record in stance, toe at (toe_x, toe_y), hip torque tau; ground(x) gives the ground
    height under the body (None: flat ground)."""
    sin_t, cos_t = math.sin(theta), math.cos(theta)
    xdot, ydot = cartesian_velocity(r, sin_t, cos_t, rdot, thetadot)
    grf_x, grf_y = ground_reaction_force(params, r, sin_t, cos_t, rdot, tau)
    x = toe_x - r * sin_t
    return HopperState(
        t=t,
        stride=stride,
        phase=Phase.STANCE,
        x=x,
        y=toe_y + r * cos_t,
        xdot=xdot,
        ydot=ydot,
        toe_x=toe_x,
        toe_y=toe_y,
        r=r,
        theta=theta,
        rdot=rdot,
        thetadot=thetadot,
        hip_torque=tau,
        energy=stance_energy(params, r, cos_t, rdot, thetadot) + params.m * params.g * toe_y,
        grf_x=grf_x,
        grf_y=grf_y,
        ground_height=0.0 if ground is None else ground(x),
    )


def flight_hopper_state(
    params: HopperParams,
    t: float,
    stride: int,
    x: float,
    y: float,
    xdot: float,
    ydot: float,
    leg_angle: float,
    ground: Callable[[float], float] | None = None,
) -> HopperState:
    """Full state record in flight, the leg held at rest length and at leg_angle [rad]; ground(x) gives
    the ground height under the body (None: flat ground)."""
    return HopperState(
        t=t,
        stride=stride,
        phase=Phase.FLIGHT,
        x=x,
        y=y,
        xdot=xdot,
        ydot=ydot,
        toe_x=x + params.r0 * math.sin(leg_angle),
        toe_y=y - params.r0 * math.cos(leg_angle),
        r=params.r0,
        theta=leg_angle,
        rdot=0.0,
        thetadot=0.0,
        hip_torque=0.0,
        energy=flight_energy(params, y, xdot, ydot),
        grf_x=0.0,
        grf_y=0.0,
        ground_height=0.0 if ground is None else ground(x),
    )


# Failure rules shared by the integrators (the kinds are defined in :mod:`.events`).


def toe_stubbing(highest_y: float, y_touchdown: float) -> tuple[FailureKind, str] | None:
    """Touchdown is infeasible when the highest body height still ahead is below the touchdown height."""
    if highest_y < y_touchdown:
        return FailureKind.TOE_STUBBING, (
            f"apex height {highest_y:.6g} m is below the touchdown height "
            f"r0 cos(theta_td) = {y_touchdown:.6g} m"
        )
    return None


def toe_below_ground(
    y_apex: float, y_touchdown: float, toe_x: float, ground: float
) -> tuple[FailureKind, str]:
    """The toe_stubbing of uneven ground: placed at the apex y_apex [m, world frame], the toe at toe_x is
    below the ground under it (the body would have to be at ground + r0 cos(theta_td) = y_touchdown)."""
    return FailureKind.TOE_STUBBING, (
        f"apex height {y_apex:.6g} m is below the touchdown height {y_touchdown:.6g} m over the ground "
        f"under the placed toe (x = {toe_x:.6g} m, ground height {ground:.6g} m): the toe is "
        f"{y_touchdown - y_apex:.3g} m below the ground"
    )


def touchdown_reversal(thetadot_td: float) -> tuple[FailureKind, str] | None:
    """A touchdown with thetadot >= 0 sends the body back over its toe."""
    if thetadot_td >= 0.0:
        return (
            FailureKind.REVERSAL,
            f"thetadot = {thetadot_td:.6g} rad/s >= 0 at touchdown: the body swings back",
        )
    return None


def stance_failure(event_name: str, s: float) -> tuple[FailureKind, str]:
    """The failure a terminal stance event other than liftoff means, s [s] after touchdown."""
    if event_name == "reversal":
        return FailureKind.REVERSAL, f"thetadot reached 0 at {s:.6g} s into stance: the body swings back"
    if event_name == "fall":
        return FailureKind.FALL, f"body height reached 0 at {s:.6g} s into stance"
    raise ValueError(f"{event_name!r} is not a failure event")


def no_liftoff(limit: float) -> tuple[FailureKind, str]:
    return FailureKind.NO_LIFTOFF, f"no liftoff within {limit:.6g} s of stance (limits.max_stance_time)"


def takeoff_failure(xdot_lo: float, ydot_lo: float) -> tuple[FailureKind, str] | None:
    """Failure decided by the liftoff velocity: no apex ahead (fall) or a backward apex (reversal)."""
    if ydot_lo <= 0.0:
        return FailureKind.FALL, f"liftoff with ydot = {ydot_lo:.6g} m/s <= 0: the flight has no apex"
    if xdot_lo <= 0.0:
        return (
            FailureKind.REVERSAL,
            f"liftoff with xdot = {xdot_lo:.6g} m/s <= 0: the apex speed is not forward",
        )
    return None
