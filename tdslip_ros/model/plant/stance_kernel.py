"""The exact stance, compiled: the one DOP853 integrator of every exact engine that hops lanes (the batched
engine, :mod:`.batch`, and the compiled stride, :mod:`.stride_kernels`).

One lane's stance (eq. 2, :mod:`.dynamics`) is integrated from a state (s, y) by the DOP853 Runge-Kutta
pair (scipy's coefficients) with scipy's error norm and step-size rule, split at the kinks of the torque.
The torque is a :class:`LaneTorque`: the ramp of eq. 18 saturated at tau_max (kinks at the saturation's
end and at t_f), or a held torque (a ramp that never ends), until a ``stop`` instant. When a step crosses
a terminal event (liftoff, reversal, fall; :func:`.dynamics.stance_event_values`), the event is located
inside the step by safeguarded Newton iteration, each trial a DOP853 step of the trial length from the
step's start, to 1e-14 s. A lane ends at its first terminal event, at the time limit, when its step size
collapses (scipy's rule: below ten spacings of s) or at its stop instant, which it lands on exactly, as
on a kink: its caller changes the torque there (a stance law's sample, :mod:`.stance_laws`) and resumes it.

The right-hand side, torque, events and rates are :mod:`.dynamics`' own functions, compiled here for one
lane (numba compiles their Python source on their first use in a kernel); the hopper reaches them as
:class:`LaneHopper`.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable
from scipy.integrate._ivp import dop853_coefficients as _dop853

from tdslip_ros.model import dynamics
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

# How a lane's stance ends (integrate_stance's outcome); STANCE_STOP: at its stop instant, to be resumed.
STANCE_LIFTOFF, STANCE_REVERSAL, STANCE_FALL, STANCE_TIME_LIMIT, STANCE_STEP_COLLAPSE, STANCE_STOP = range(6)
STANCE_FAILURES = {
    STANCE_REVERSAL: FailureKind.REVERSAL,
    STANCE_FALL: FailureKind.FALL,
    STANCE_TIME_LIMIT: FailureKind.NO_LIFTOFF,
    STANCE_STEP_COLLAPSE: FailureKind.STATE_LIMIT,
}
"""The failure each end of a stance other than liftoff is (a collapsed step size: state_limit)."""
TERMINAL_OUTCOMES = np.array([STANCE_LIFTOFF, STANCE_REVERSAL, STANCE_FALL])
"""The stance outcome of each terminal event, in the order of terminal_values."""


class LaneHopper(NamedTuple):
    """The hopper's parameters as the compiled :mod:`.dynamics` reads them (SI)."""

    m: float
    k: float
    r0: float
    c: float
    g: float


@lru_cache(maxsize=16)
def hopper_row(params: HopperParams) -> Array:
    """The hopper as the lane loops take it: the fields of :class:`LaneHopper` in order; made once per
    hopper and shared (the kernels only read it)."""
    params.require_fixed_body("the compiled lane stride")
    return np.array([getattr(params, name) for name in LaneHopper._fields])


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


# The kernels of the step (the field, the sums, the step itself) are inlined: the calls, which pass named
# tuples, cost about as much as their arithmetic. The rest are not (compile time).
@inlined_kernel
def stance_field(hopper: LaneHopper, torque: LaneTorque, s: float, y: Array, out: Array) -> None:
    """The stance right-hand side at (s, y) into ``out`` (:func:`.dynamics.stance_derivatives`)."""
    theta = y[1]
    tau = dynamics.hip_torque(torque.tau0, torque.t_f, s, torque.tau_max)
    derivatives = dynamics.stance_derivatives(hopper, y[0], math.sin(theta), math.cos(theta), y[2], y[3], tau)
    for i in range(STATE_SIZE):
        out[i] = derivatives[i]


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
    hopper: LaneHopper, torque: LaneTorque, s: float, y: Array, h: float, k: Array, y_new: Array
) -> None:
    """One DOP853 step of length h into y_new (which holds each stage's state on the way); k[0] must hold
    the field at (s, y); fills k[1:12]."""
    for stage in range(1, STAGES):
        for i in range(STATE_SIZE):
            y_new[i] = y[i] + h * combined(A[stage, :stage], k, i)
        stance_field(hopper, torque, s + C[stage] * h, y_new, k[stage])
    for i in range(STATE_SIZE):
        y_new[i] = y[i] + h * combined(B, k, i)


@inlined_kernel
def terminal_values(hopper: LaneHopper, y: Array) -> tuple[float, float, float]:
    """The terminal events' values (liftoff, reversal, fall) of :func:`.dynamics.stance_event_values`."""
    values = dynamics.stance_event_values(hopper, y[0], math.cos(y[1]), y[2], y[3])
    return values[1], values[2], values[3]


@kernel
def terminal_rate(hopper: LaneHopper, y: Array, velocity: Array, event: int) -> float:
    """The rate of terminal event ``event`` (0 liftoff, 1 reversal, 2 fall) at y moving with ``velocity``."""
    theta = y[1]
    rates = dynamics.stance_event_rates(
        hopper, y[0], math.sin(theta), math.cos(theta), y[2], y[3], velocity[2], velocity[3]
    )
    rate: float = rates[event + 1]
    return rate


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
    hopper: LaneHopper,
    torque: LaneTorque,
    s0: float,
    y0: Array,
    h: float,
    k: Array,
    crossed: tuple[bool, bool, bool],
    g_start: tuple[float, float, float],
    g_end: tuple[float, float, float],
    y_event: Array,
) -> tuple[int, float]:
    """The earliest terminal event inside [s0, s0 + h]: its index (0 liftoff, 1 reversal, 2 fall) and time;
    its state into y_event. k[0] holds the field at (s0, y0).

    The function is the smallest of the crossed events' values after a DOP853 step of trial length sigma
    from the bracket start (positive at 0, non-positive at h); its slope is the event's rate at that state.
    A Newton step that leaves the shrinking bracket is replaced by bisection. Converges in 2-3 steps from
    the regula falsi start (the time a step costs)."""
    g_a, g_b = math.inf, math.inf
    for event in range(3):
        if crossed[event]:
            g_a, g_b = min(g_a, g_start[event]), min(g_b, g_end[event])
    a, b = 0.0, h
    sigma = min(max(g_a * h / (g_a - g_b), 0.0), h)
    velocity = np.empty(STATE_SIZE)
    active = 0
    located = sigma  # the trial length whose state y_event holds
    for _ in range(MAX_ROOT_ITERATIONS):
        located = sigma
        dop853_step(hopper, torque, s0, y0, sigma, k, y_event)
        values = terminal_values(hopper, y_event)
        g = math.inf
        for event in range(3):  # the first smallest
            if crossed[event] and values[event] < g:
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
    hopper: LaneHopper,
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
    k = np.empty((STAGES + 1, STATE_SIZE))
    y_new = np.empty(STATE_SIZE)
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
        for i in range(STATE_SIZE):
            scale = atol + max(abs(y[i]), abs(y_new[i])) * rtol
            q5, q3 = combined(E5, k, i) / scale, combined(E3, k, i) / scale
            err5 += q5 * q5
            err3 += q3 * q3
            finite = finite and math.isfinite(y_new[i])
        denominator = err5 + 0.01 * err3
        error = h * err5 / math.sqrt(denominator * STATE_SIZE) if denominator > 0.0 else 0.0
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
        crossed = (
            accepted and g_before[0] > 0.0 and g_after[0] <= 0.0,
            accepted and g_before[1] > 0.0 and g_after[1] <= 0.0,
            accepted and g_before[2] > 0.0 and g_after[2] <= 0.0,
        )
        if crossed[0] or crossed[1] or crossed[2]:
            event, s_event = locate_event(hopper, torque, s, y, h, k, crossed, g_before, g_after, y_new)
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
    """:func:`integrate_stance` for each lane of ``lanes``, one after the other, in place: from its time s,
    step h and state y (a row of y) under its torque (:class:`LaneTorque`'s fields) to its outcome.
    ``hopper`` holds the fields of :class:`LaneHopper` in order (:func:`hopper_row`)."""
    lane_hopper = LaneHopper(hopper[0], hopper[1], hopper[2], hopper[3], hopper[4])
    for lane in lanes:
        torque = LaneTorque(tau0[lane], t_f[lane], tau_max[lane], stop[lane])
        outcome[lane], s[lane], h[lane] = integrate_stance(
            lane_hopper, torque, s[lane], h[lane], y[lane], t_limit, rtol, atol
        )
