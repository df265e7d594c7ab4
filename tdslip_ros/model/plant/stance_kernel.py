"""The exact stance, compiled: the one DOP853 integrator of every exact engine that hops lanes (the batched
engine, :mod:`.batch`, and the compiled stride, :mod:`.stride_kernels`).

One lane's stance (eq. 2, :mod:`.dynamics`; a rigid body's, :mod:`.body_dynamics`) is integrated from a
state (s, y) by the DOP853 Runge-Kutta pair (scipy's coefficients) with scipy's error norm and step-size
rule, split at the kinks of the torque. The torque is a :class:`LaneTorque`: the ramp of eq. 18 saturated
at tau_max (kinks at the saturation's end and at t_f), or a held torque (a ramp that never ends), until a
``stop`` instant. When a step crosses a terminal event (liftoff, reversal, fall:
:func:`.dynamics.stance_event_values`; a rigid body's ``tipped`` too, :func:`.body_dynamics.tip_margin`),
the event is located inside the step by safeguarded Newton iteration, each trial a DOP853 step of the trial
length from the step's start, to 1e-14 s. A lane ends at its first terminal event, at the time limit, when
its step size collapses (scipy's rule: below ten spacings of s) or at its stop instant, which it lands on
exactly, as on a kink: its caller changes the torque there (a stance law's sample, :mod:`.stance_laws`) and
resumes it.

The right-hand side, torque, events and rates are :mod:`.dynamics`' own functions (a rigid body's
:mod:`.body_dynamics`'), compiled here for one lane (numba compiles their Python source on their first use in
a kernel); the hopper reaches them as :class:`LaneHopper`, a rigid body's as :class:`LaneRigidHopper`. The
integrator is written once for both: what differs (the field, the state's size, the terminal events) is
chosen by the hopper's type when numba compiles it (:func:`stance_field`, :func:`state_size`,
:func:`terminal_values`, :func:`terminal_rate`), so the point mass's compiled stance is the 6-value one it
always was.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np
from numba.extending import overload, register_jitable
from scipy.integrate._ivp import dop853_coefficients as _dop853

from tdslip_ros.model import body_dynamics, dynamics
from tdslip_ros.model.arrays import Array
from tdslip_ros.model.compiled import inlined_kernel, kernel
from tdslip_ros.model.events import FailureKind
from tdslip_ros.model.params import HopperParams

# The stance's functions of dynamics made callable from kernels as they are: numba compiles their Python
# source where a kernel calls them, while Python callers keep the plain functions (numpy, floats).
for _shared in (
    dynamics.ramp_torque,
    dynamics.hip_torque,
    dynamics.saturation_time,
    dynamics.leg_force,
    dynamics.stance_accelerations,
    dynamics.stance_powers,
    dynamics.stance_derivatives,
    dynamics.stance_event_values,
    dynamics.stance_event_rates,
    dynamics.ground_reaction_force,
    body_dynamics.hip_offset,
    body_dynamics.rigid_stance_accelerations,
    body_dynamics.rigid_stance_derivatives,
    body_dynamics.tip_margin,
    body_dynamics.rigid_stance_event_values,
    body_dynamics.rigid_stance_event_rates,
):
    register_jitable(_shared)

# DOP853 (Hairer, Norsett & Wanner), the tableau scipy's solve_ivp uses; stage 12 is the FSAL stage. Held
# C-contiguous: the kernels take them as constants, which numba caches only then.
STAGES = _dop853.N_STAGES
A: Array = np.ascontiguousarray(_dop853.A[:STAGES, :STAGES])
B: Array = np.ascontiguousarray(_dop853.B)
C: Array = np.ascontiguousarray(_dop853.C[:STAGES])
E3: Array = np.ascontiguousarray(_dop853.E3)
E5: Array = np.ascontiguousarray(_dop853.E5)
SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0  # scipy's step-size rule
ERROR_EXPONENT = -1.0 / 8.0
INITIAL_STEP_PERIODS = 0.01  # first step, in natural periods of the leg spring
EVENT_TIME_TOLERANCE = 1e-14  # s
MAX_ROOT_ITERATIONS = 100
STATE_SIZE = 6  # r, theta, rdot, thetadot, hip work, damper loss
RIGID_STATE_SIZE = body_dynamics.RIGID_STANCE_STATE_SIZE  # then pitch, pitch rate

# How a lane's stance ends (integrate_stance's outcome); STANCE_STOP: at its stop instant, to be resumed.
(
    STANCE_LIFTOFF,
    STANCE_REVERSAL,
    STANCE_FALL,
    STANCE_TIME_LIMIT,
    STANCE_STEP_COLLAPSE,
    STANCE_STOP,
    STANCE_TIPPED,
) = range(7)
STANCE_FAILURES = {
    STANCE_REVERSAL: FailureKind.REVERSAL,
    STANCE_FALL: FailureKind.FALL,
    STANCE_TIME_LIMIT: FailureKind.NO_LIFTOFF,
    STANCE_STEP_COLLAPSE: FailureKind.STATE_LIMIT,
    STANCE_TIPPED: FailureKind.TIPPED,
}
"""The failure each end of a stance other than liftoff is (a collapsed step size: state_limit)."""
TERMINAL_OUTCOMES = np.array([STANCE_LIFTOFF, STANCE_REVERSAL, STANCE_FALL, STANCE_TIPPED])
"""The stance outcome of each terminal event, in the order of terminal_values (the point mass has the first
three)."""


class LaneHopper(NamedTuple):
    """The hopper's parameters as the compiled :mod:`.dynamics` reads them (SI)."""

    m: float
    k: float
    r0: float
    c: float
    g: float


class LaneRigidHopper(NamedTuple):
    """A hopper with a rigid body (:class:`.params.RigidBody`) as the compiled :mod:`.body_dynamics` reads it
    (SI): its fields are both the hopper's and the body's."""

    m: float
    k: float
    r0: float
    c: float
    g: float
    inertia: float
    hip_x: float
    hip_y: float
    tip_limit: float


@lru_cache(maxsize=16)
def hopper_row(params: HopperParams) -> Array:
    """The hopper as the lane loops take it: the fields of :class:`LaneHopper` in order, of
    :class:`LaneRigidHopper` with a rigid body; made once per hopper and shared (the kernels only read it)."""
    if params.body is None:
        return np.array([getattr(params, name) for name in LaneHopper._fields])
    body_fields = LaneRigidHopper._fields[len(LaneHopper._fields) :]
    return np.array(
        [
            *(getattr(params, name) for name in LaneHopper._fields),
            *(getattr(params.body, f) for f in body_fields),
        ]
    )


def first_step(hopper: dynamics.Hopper) -> float:
    """The first trial step of a stance [s]: INITIAL_STEP_PERIODS natural periods of the leg spring."""
    return INITIAL_STEP_PERIODS * 2.0 * math.pi / math.sqrt(hopper.k / hopper.m)


register_jitable(first_step)  # kernels call it on a LaneHopper, Python on HopperParams


class LaneTorque(NamedTuple):
    """One lane's hip torque until its stop instant: the ramp of eq. 18 (tau0 [N m], t_f [s]) saturated at
    tau_max [N m] (inf: never); t_f = inf holds tau0. stop [s since touchdown]: where the integration
    halts (inf: never)."""

    tau0: float
    t_f: float
    tau_max: float
    stop: float


# What the two stances differ in, chosen by numba from the hopper's type when it compiles a kernel (an
# overload per function: the Python function picks by isinstance, for the interpreter). Inlined, as the step's
# kernels below. Their hopper is typed Any: numba requires an overload's implementations to be annotated as
# the overload is, and only the implementation chosen for a LaneRigidHopper reads a body.
LaneModel = LaneHopper | LaneRigidHopper


def _is_rigid(hopper: object) -> bool:
    """Whether numba's type ``hopper`` is that of a :class:`LaneRigidHopper`."""
    return getattr(hopper, "instance_class", None) is LaneRigidHopper


def _point_mass_size(hopper: Any) -> int:
    return STATE_SIZE


def _rigid_body_size(hopper: Any) -> int:
    return RIGID_STATE_SIZE


def state_size(hopper: Any) -> int:
    """Values in the hopper's stance state: STATE_SIZE, or RIGID_STATE_SIZE with a rigid body."""
    return _rigid_body_size(hopper) if isinstance(hopper, LaneRigidHopper) else _point_mass_size(hopper)


@overload(state_size, inline="always")
def _state_size_of(hopper: Any) -> object:
    return _rigid_body_size if _is_rigid(hopper) else _point_mass_size


def _point_mass_field(hopper: Any, torque: LaneTorque, s: float, y: Array, out: Array) -> None:
    theta = y[1]
    tau = dynamics.hip_torque(torque.tau0, torque.t_f, s, torque.tau_max)
    derivatives = dynamics.stance_derivatives(hopper, y[0], math.sin(theta), math.cos(theta), y[2], y[3], tau)
    for i in range(STATE_SIZE):
        out[i] = derivatives[i]


def _rigid_body_field(hopper: Any, torque: LaneTorque, s: float, y: Array, out: Array) -> None:
    theta, pitch = y[1], y[6]
    tau = dynamics.hip_torque(torque.tau0, torque.t_f, s, torque.tau_max)
    derivatives = body_dynamics.rigid_stance_derivatives(
        hopper,
        hopper,
        y[0],
        math.sin(theta),
        math.cos(theta),
        y[2],
        y[3],
        math.sin(pitch),
        math.cos(pitch),
        y[7],
        tau,
    )
    for i in range(RIGID_STATE_SIZE):
        out[i] = derivatives[i]


def stance_field(hopper: Any, torque: LaneTorque, s: float, y: Array, out: Array) -> None:
    """The stance right-hand side at (s, y) into ``out``: :func:`.dynamics.stance_derivatives`, or
    :func:`.body_dynamics.rigid_stance_derivatives` of a rigid body."""
    if isinstance(hopper, LaneRigidHopper):
        _rigid_body_field(hopper, torque, s, y, out)
    else:
        _point_mass_field(hopper, torque, s, y, out)


@overload(stance_field, inline="always")
def _stance_field_of(hopper: Any, torque: LaneTorque, s: float, y: Array, out: Array) -> object:
    return _rigid_body_field if _is_rigid(hopper) else _point_mass_field


def _point_mass_terminal_values(hopper: Any, y: Array) -> tuple[float, ...]:
    values = dynamics.stance_event_values(hopper, y[0], math.cos(y[1]), y[2], y[3])
    return values[1], values[2], values[3]


def _rigid_body_terminal_values(hopper: Any, y: Array) -> tuple[float, ...]:
    values = body_dynamics.rigid_stance_event_values(hopper, hopper, y[0], math.cos(y[1]), y[2], y[3], y[6])
    return values[1], values[2], values[3], values[4]


def terminal_values(hopper: Any, y: Array) -> tuple[float, ...]:
    """The terminal events' values (liftoff, reversal, fall; a rigid body's tipped after them), in the order
    of TERMINAL_OUTCOMES: :func:`.dynamics.stance_event_values`, or
    :func:`.body_dynamics.rigid_stance_event_values`."""
    if isinstance(hopper, LaneRigidHopper):
        return _rigid_body_terminal_values(hopper, y)
    return _point_mass_terminal_values(hopper, y)


@overload(terminal_values, inline="always")
def _terminal_values_of(hopper: Any, y: Array) -> object:
    return _rigid_body_terminal_values if _is_rigid(hopper) else _point_mass_terminal_values


def _point_mass_terminal_rate(hopper: Any, y: Array, velocity: Array, event: int) -> float:
    theta = y[1]
    rates = dynamics.stance_event_rates(
        hopper, y[0], math.sin(theta), math.cos(theta), y[2], y[3], velocity[2], velocity[3]
    )
    rate: float = rates[event + 1]
    return rate


def _rigid_body_terminal_rate(hopper: Any, y: Array, velocity: Array, event: int) -> float:
    theta = y[1]
    rates = body_dynamics.rigid_stance_event_rates(
        hopper, y[0], math.sin(theta), math.cos(theta), y[2], y[3], velocity[2], velocity[3], y[6], y[7]
    )
    rate: float = rates[event + 1]
    return rate


def terminal_rate(hopper: Any, y: Array, velocity: Array, event: int) -> float:
    """The rate of terminal event ``event`` (its index in terminal_values) at y moving with ``velocity``."""
    if isinstance(hopper, LaneRigidHopper):
        return _rigid_body_terminal_rate(hopper, y, velocity, event)
    return _point_mass_terminal_rate(hopper, y, velocity, event)


@overload(terminal_rate)
def _terminal_rate_of(hopper: Any, y: Array, velocity: Array, event: int) -> object:
    return _rigid_body_terminal_rate if _is_rigid(hopper) else _point_mass_terminal_rate


# The kernels of the step (the sums, the step itself) are inlined: the calls, which pass named tuples, cost
# about as much as their arithmetic. The rest are not (compile time).
@inlined_kernel
def combined(weights: Array, k: Array, i: int) -> float:
    """sum_j weights[j] k[j, i] over the tableau's non-zero weights, in the order of j."""
    total = 0.0
    for j in range(weights.size):
        if weights[j] != 0.0:
            total += weights[j] * k[j, i]
    return total


@inlined_kernel
def dop853_step(
    hopper: LaneModel, torque: LaneTorque, s: float, y: Array, h: float, k: Array, y_new: Array
) -> None:
    """One DOP853 step of length h into y_new (which holds each stage's state on the way); k[0] must hold
    the field at (s, y); fills k[1:12]."""
    size = state_size(hopper)
    for stage in range(1, STAGES):
        for i in range(size):
            y_new[i] = y[i] + h * combined(A[stage, :stage], k, i)
        stance_field(hopper, torque, s + C[stage] * h, y_new, k[stage])
    for i in range(size):
        y_new[i] = y[i] + h * combined(B, k, i)


@kernel
def kink(torque: LaneTorque, s: float) -> float:
    """The next kink of the torque after s: the end of the saturation, else the ramp's end t_f; the stop
    instant where it comes first (a stop at or before s is no kink: it has been served)."""
    end = torque.t_f
    if abs(torque.tau0) > torque.tau_max:
        saturation_end = dynamics.saturation_time(torque.tau0, torque.t_f, torque.tau_max)
        if s < saturation_end:
            end = saturation_end
    return min(end, torque.stop) if torque.stop > s else end


@kernel
def locate_event(
    hopper: LaneModel,
    torque: LaneTorque,
    s0: float,
    y0: Array,
    h: float,
    k: Array,
    g_start: tuple[float, ...],
    g_end: tuple[float, ...],
    y_event: Array,
) -> tuple[int, float]:
    """The earliest terminal event inside [s0, s0 + h]: its index in terminal_values (0 liftoff, 1 reversal,
    2 fall, 3 tipped) and time; its state into y_event. k[0] holds the field at (s0, y0); g_start and g_end
    are the events' values at the accepted step's ends, those crossed from > 0 to <= 0 the candidates.

    The function is the smallest of the crossed events' values after a DOP853 step of trial length sigma
    from the bracket start (positive at 0, non-positive at h); its slope is the event's rate at that state.
    A Newton step that leaves the shrinking bracket is replaced by bisection. Converges in 2-3 steps from
    the regula falsi start (the time a step costs)."""
    g_a, g_b = math.inf, math.inf
    for event in range(len(g_start)):
        if g_start[event] > 0.0 and g_end[event] <= 0.0:
            g_a, g_b = min(g_a, g_start[event]), min(g_b, g_end[event])
    a, b = 0.0, h
    sigma = min(max(g_a * h / (g_a - g_b), 0.0), h)
    velocity = np.empty(state_size(hopper))
    active = 0
    located = sigma  # the trial length whose state y_event holds
    for _ in range(MAX_ROOT_ITERATIONS):
        located = sigma
        dop853_step(hopper, torque, s0, y0, sigma, k, y_event)
        values = terminal_values(hopper, y_event)
        g = math.inf
        for event in range(len(g_start)):  # the first smallest of the crossed
            if g_start[event] > 0.0 and g_end[event] <= 0.0 and values[event] < g:
                active, g = event, values[event]
        stance_field(hopper, torque, s0 + sigma, y_event, velocity)
        rate = terminal_rate(hopper, y_event, velocity, active)
        if g > 0.0:
            a = sigma
        else:
            b = sigma
        newton_step = g / rate
        if abs(newton_step) <= EVENT_TIME_TOLERANCE or g == 0.0:
            break
        newton = sigma - newton_step
        sigma = newton if a < newton < b else 0.5 * (a + b)
    return active, s0 + located


@kernel
def integrate_stance(
    hopper: LaneModel,
    torque: LaneTorque,
    s: float,
    h: float,
    y: Array,
    t_limit: float,
    rtol: float,
    atol: float,
) -> tuple[int, float, float]:
    """One lane's stance from state y at time s since touchdown, h the first trial step, to its first
    terminal event, the time limit t_limit [s], a collapse of its step size or its torque's stop instant:
    the outcome (STANCE_*), the time s there and the step size to resume with; the state there into y (on
    a step collapse the last accepted one).

    A lane resumed at its stop goes on as if it had not stopped: the step before it was accepted, the
    event values are those of y, and the field at (s, y) is evaluated anew under the torque held from s."""
    if s >= t_limit:  # stopped on the time limit
        return STANCE_TIME_LIMIT, t_limit, h
    size = state_size(hopper)
    k = np.empty((STAGES + 1, size))
    y_new = np.empty(size)
    stance_field(hopper, torque, s, y, k[0])
    g_before = terminal_values(hopper, y)
    rejected = False
    while True:
        next_kink = kink(torque, s)
        in_ramp = s < next_kink
        if in_ramp:
            h = min(h, next_kink - s)
        h = min(h, t_limit - s)
        dop853_step(hopper, torque, s, y, h, k, y_new)
        stance_field(hopper, torque, s + h, y_new, k[STAGES])
        err5, err3, finite = 0.0, 0.0, True
        for i in range(size):
            scale = atol + max(abs(y[i]), abs(y_new[i])) * rtol
            q5, q3 = combined(E5, k, i) / scale, combined(E3, k, i) / scale
            err5 += q5 * q5
            err3 += q3 * q3
            finite = finite and math.isfinite(y_new[i])
        denominator = err5 + 0.01 * err3
        error = h * err5 / math.sqrt(denominator * size) if denominator > 0.0 else 0.0
        # A trial step may leave the floats (a stiff leg, a too long first step, a NaN torque): it then
        # fails its error test and shrinks by MIN_FACTOR.
        if math.isnan(denominator) or math.isnan(error) or not finite:
            error = math.inf
        growth = SAFETY * error**ERROR_EXPONENT
        accepted = error < 1.0
        if not accepted:
            factor = max(MIN_FACTOR, growth)
        elif rejected:
            factor = min(1.0, growth)
        else:
            factor = min(MAX_FACTOR, growth)
        g_after = terminal_values(hopper, y_new)
        crossed = False
        for event in range(len(g_after)):
            crossed = crossed or (g_before[event] > 0.0 and g_after[event] <= 0.0)
        if accepted and crossed:
            event, s_event = locate_event(hopper, torque, s, y, h, k, g_before, g_after, y_new)
            y[:] = y_new
            return TERMINAL_OUTCOMES[event], s_event, h
        on_kink = False
        if accepted:
            # Land exactly on the kink, so that the next segment (torque-free after t_f) starts there.
            on_kink = in_ramp and h == next_kink - s
            s = next_kink if on_kink else s + h
            y[:] = y_new
            k[0] = k[STAGES]
            g_before = g_after
        rejected = not accepted
        h = h * factor  # carried across kinks and stops: the next segment starts with it
        if on_kink and s == torque.stop:
            return STANCE_STOP, s, h
        if accepted and s >= t_limit:
            return STANCE_TIME_LIMIT, t_limit, h
        if rejected and h < 10.0 * (np.nextafter(s, math.inf) - s):  # scipy's smallest step
            return STANCE_STEP_COLLAPSE, s, h


@inlined_kernel
def integrate_each(
    hopper: LaneModel,
    tau0: Array,
    t_f: Array,
    tau_max: Array,
    stop: Array,
    lanes: Array,
    t_limit: float,
    rtol: float,
    atol: float,
    s: Array,
    h: Array,
    y: Array,
    outcome: Array,
) -> None:
    """:func:`integrate_stance` for each lane of ``lanes``, one after the other, in place: from its time s,
    step h and state y (a row of y) under its torque (:class:`LaneTorque`'s fields) to its outcome."""
    for lane in lanes:
        torque = LaneTorque(tau0[lane], t_f[lane], tau_max[lane], stop[lane])
        outcome[lane], s[lane], h[lane] = integrate_stance(
            hopper, torque, s[lane], h[lane], y[lane], t_limit, rtol, atol
        )


@kernel
def integrate_lanes(
    hopper: Array,
    tau0: Array,
    t_f: Array,
    tau_max: Array,
    stop: Array,
    lanes: Array,
    t_limit: float,
    rtol: float,
    atol: float,
    s: Array,
    h: Array,
    y: Array,
    outcome: Array,
) -> None:
    """:func:`integrate_each` of the point mass, ``hopper`` the fields of :class:`LaneHopper` in order
    (:func:`hopper_row`), y's rows its states (STATE_SIZE values)."""
    lane_hopper = LaneHopper(hopper[0], hopper[1], hopper[2], hopper[3], hopper[4])
    integrate_each(lane_hopper, tau0, t_f, tau_max, stop, lanes, t_limit, rtol, atol, s, h, y, outcome)


@kernel
def integrate_rigid_lanes(
    hopper: Array,
    tau0: Array,
    t_f: Array,
    tau_max: Array,
    stop: Array,
    lanes: Array,
    t_limit: float,
    rtol: float,
    atol: float,
    s: Array,
    h: Array,
    y: Array,
    outcome: Array,
) -> None:
    """:func:`integrate_each` of a rigid body, ``hopper`` the fields of :class:`LaneRigidHopper` in order
    (:func:`hopper_row`), y's rows its states (RIGID_STATE_SIZE values)."""
    lane_hopper = LaneRigidHopper(
        hopper[0], hopper[1], hopper[2], hopper[3], hopper[4], hopper[5], hopper[6], hopper[7], hopper[8]
    )
    integrate_each(lane_hopper, tau0, t_f, tau_max, stop, lanes, t_limit, rtol, atol, s, h, y, outcome)
