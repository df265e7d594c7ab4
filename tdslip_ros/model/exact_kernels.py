"""The exact stride of one lane under a torque ramp, compiled: the batched engine's algorithm without numpy's
cost per step, for callers that hop a few apexes at a time. :func:`apex_stride` hops one apex (the exact
map's arguments), :func:`compiled_apex_return_map` a few lanes (the batched engine's), and
:func:`exact_regulation_lanes` is ``energy_exact``'s whole Newton iteration on it.

The stride is the one of :func:`.batch.batch_apex_return_map` on flat ground: descent and ascent in closed
form; stance (eq. 2, the ramp of eq. 18 saturated at tau_max) by DOP853 with scipy's coefficients, error
norm and step-size rule, split at the kinks of the torque; a step that crosses a terminal event (liftoff,
reversal, fall) is cut back to the event by safeguarded Newton iteration on trial steps from the step's
start, to 1e-14 s. The constants are :mod:`.batch_stance`'s and the rules and their order those of
:mod:`.batch`, so the failure kinds are the same and the states agree to rounding (1e-14 relative:
numpy's pow and libm's differ in the last bit, and so do the step sizes).

One source. The stance's right-hand side, torque, event functions and rates, and the flight's closed forms
are :mod:`.dynamics`' own functions, compiled here for one lane (numba compiles the Python source of each
on its first use in a kernel): the numpy engines call the very same code on arrays. The hopper reaches them
as :class:`LaneHopper`, a named tuple with the fields of :class:`.params.HopperParams` they read, and the
limits' rules as :class:`LaneLimits`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import fields
from functools import lru_cache
from typing import Any, NamedTuple, cast

import numpy as np
import numpy.typing as npt
from numba.extending import register_jitable

from tdslip_ros.model import dynamics
from tdslip_ros.model.arrays import HAS_COMMAND, REASON_OF_FAILURE, Array
from tdslip_ros.model.batch import BatchStrideResult, check_lanes, ramp_checks, validate_lanes
from tdslip_ros.model.batch_stance import (
    E3,
    E5,
    ERROR_EXPONENT,
    EVENT_TIME_TOLERANCE,
    INITIAL_STEP_PERIODS,
    MAX_FACTOR,
    MAX_ROOT_ITERATIONS,
    MIN_FACTOR,
    SAFETY,
    STAGES,
    STANCE_FAILURES,
    STANCE_FALL,
    STANCE_LIFTOFF,
    STANCE_REVERSAL,
    STANCE_STEP_COLLAPSE,
    STANCE_TIME_LIMIT,
    STATE_SIZE,
    A,
    B,
    C,
)
from tdslip_ros.model.compiled import inlined_kernel, kernel
from tdslip_ros.model.controller_kernels import NO_SOLUTION_REASON, solve2, torque_scales
from tdslip_ros.model.events import NO_FAILURE_CODE, FailureKind, failure_code, failure_from_code
from tdslip_ros.model.limits import PlausibilityLimits, check_tolerances
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand

# dynamics' functions (and the limits' rules) made callable from kernels as they are: numba compiles their
# Python source where a kernel calls them, while Python callers keep the plain functions (numpy, floats).
for _shared in (
    dynamics.fall_time,
    dynamics.ballistic,
    dynamics.polar_velocity,
    dynamics.cartesian_velocity,
    dynamics.touchdown_height,
    dynamics.ramp_torque,
    dynamics.hip_torque,
    dynamics.saturation_time,
    dynamics.leg_force,
    dynamics.stance_accelerations,
    dynamics.stance_powers,
    dynamics.stance_derivatives,
    dynamics.stance_event_values,
    dynamics.stance_event_rates,
    dynamics.spring_energy,
    PlausibilityLimits.torque_exceeded,
    PlausibilityLimits.apex_exceeded,
):
    register_jitable(_shared)
# The limits' own rules, called on LaneLimits: their arithmetic reads only the fields LaneLimits has.
_torque_exceeded = cast(Callable[["LaneLimits", float], bool], PlausibilityLimits.torque_exceeded)
_apex_exceeded = cast(Callable[["LaneLimits", float, float], bool], PlausibilityLimits.apex_exceeded)

TOE_STUBBING = failure_code(FailureKind.TOE_STUBBING)
FALL = failure_code(FailureKind.FALL)
REVERSAL = failure_code(FailureKind.REVERSAL)
STATE_LIMIT = failure_code(FailureKind.STATE_LIMIT)
STANCE_FAILURE_CODES = np.array(
    [failure_code(STANCE_FAILURES.get(outcome)) for outcome in range(max(STANCE_FAILURES) + 1)]
)
"""The failure code of each stance outcome (batch_stance.STANCE_FAILURES; none for liftoff)."""
TERMINAL_OUTCOMES = np.array([STANCE_LIFTOFF, STANCE_REVERSAL, STANCE_FALL])
"""The stance outcome of each terminal event, in the order of terminal_values."""
ROW = {field.name: row for row, field in enumerate(fields(BatchStrideResult))}
"""The row of each field of :class:`.batch.BatchStrideResult` in a block of strides."""
STRIDE_ROWS = len(ROW)
Y_ROW, XDOT_ROW, FAILURE_ROW, X_ROW, GROUND_ROW = (
    ROW["y"],
    ROW["xdot"],
    ROW["failure"],
    ROW["x"],
    ROW["ground"],
)
HIP_WORK_ROW, DAMPING_LOSS_ROW, SPRING_LOSS_ROW = ROW["hip_work"], ROW["damping_loss"], ROW["spring_loss"]
STANCE_TIME_ROW, STRIDE_TIME_ROW, SATURATED_ROW = ROW["stance_time"], ROW["stride_time"], ROW["saturated"]


class LaneHopper(NamedTuple):
    """The hopper's parameters as the compiled :mod:`.dynamics` reads them (SI)."""

    m: float
    k: float
    r0: float
    c: float
    g: float


class LaneLimits(NamedTuple):
    """The plausibility limits as the compiled rules of :class:`.limits.PlausibilityLimits` read them."""

    max_torque: float
    max_apex_height: float
    max_apex_speed: float
    max_stance_time: float


class LaneRamp(NamedTuple):
    """One lane's ramp of eq. 18 (tau0 [N m], t_f [s]) saturated at tau_max [N m] (inf: never)."""

    tau0: float
    t_f: float
    tau_max: float


# The small kernels of the stage loop are inlined (a third off a stride), the rest are not (compile time).
@inlined_kernel
def stance_field(hopper: LaneHopper, ramp: LaneRamp, s: float, y: Array, out: Array) -> None:
    """The stance right-hand side at (s, y) into ``out`` (:func:`.dynamics.stance_derivatives`)."""
    theta = y[1]
    tau = dynamics.hip_torque(ramp.tau0, ramp.t_f, s, ramp.tau_max)
    derivatives = dynamics.stance_derivatives(hopper, y[0], math.sin(theta), math.cos(theta), y[2], y[3], tau)
    for i in range(STATE_SIZE):
        out[i] = derivatives[i]


@inlined_kernel
def combined(weights: Array, k: Array, i: int) -> float:
    """sum_j weights[j] k[j, i] over the tableau's non-zero weights, in the order of j (as
    the batched engine's ``_combine`` sums each lane)."""
    total = 0.0
    for j in range(weights.size):
        if weights[j] != 0.0:
            total += weights[j] * k[j, i]
    return total


@kernel
def dop853_step(
    hopper: LaneHopper, ramp: LaneRamp, s: float, y: Array, h: float, k: Array, y_new: Array
) -> None:
    """One DOP853 step of length h into y_new; k[0] must hold the field at (s, y); fills k[1:12]."""
    stage_y = np.empty(STATE_SIZE)
    for stage in range(1, STAGES):
        for i in range(STATE_SIZE):
            stage_y[i] = y[i] + h * combined(A[stage, :stage], k, i)
        stance_field(hopper, ramp, s + C[stage] * h, stage_y, k[stage])
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
def kink(ramp: LaneRamp, s: float) -> float:
    """The next kink of the torque after s: the end of the saturation, else the ramp's end t_f."""
    if abs(ramp.tau0) > ramp.tau_max:
        end = dynamics.saturation_time(ramp.tau0, ramp.t_f, ramp.tau_max)
        if s < end:
            return end
    return ramp.t_f


@kernel
def locate_event(
    hopper: LaneHopper,
    ramp: LaneRamp,
    s0: float,
    y0: Array,
    h: float,
    k: Array,
    crossed: tuple[bool, bool, bool],
    g_start: tuple[float, float, float],
    g_end: tuple[float, float, float],
    y_event: Array,
) -> tuple[int, float]:
    """The earliest terminal event inside [s0, s0 + h] (the batched engine's ``_locate``): its index (0
    liftoff, 1 reversal, 2 fall) and time; its state into y_event. k[0] holds the field at (s0, y0)."""
    g_a, g_b = math.inf, math.inf
    for event in range(3):
        if crossed[event]:
            g_a, g_b = min(g_a, g_start[event]), min(g_b, g_end[event])
    a, b = 0.0, h
    sigma = min(max(g_a * h / (g_a - g_b), 0.0), h)
    velocity = np.empty(STATE_SIZE)
    active = 0
    for _ in range(MAX_ROOT_ITERATIONS):
        dop853_step(hopper, ramp, s0, y0, sigma, k, y_event)
        values = terminal_values(hopper, y_event)
        g = math.inf
        for event in range(3):  # the first smallest, as numpy's argmin
            if crossed[event] and values[event] < g:
                active, g = event, values[event]
        stance_field(hopper, ramp, s0 + sigma, y_event, velocity)
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
    return active, s0 + sigma


@kernel
def integrate_stance(
    hopper: LaneHopper, ramp: LaneRamp, y0: Array, t_limit: float, rtol: float, atol: float, y_end: Array
) -> tuple[int, float]:
    """One lane's stance from touchdown (s = 0) to its first terminal event or the time limit
    (:func:`.batch_stance.integrate_stance`): its outcome (batch_stance.STANCE_*) and time s; the state
    there into y_end (the last accepted one on a step collapse)."""
    k = np.empty((STAGES + 1, STATE_SIZE))
    y = y0.copy()
    y_new = np.empty(STATE_SIZE)
    s = 0.0
    stance_field(hopper, ramp, s, y, k[0])
    g_before = terminal_values(hopper, y)
    h = INITIAL_STEP_PERIODS * 2.0 * math.pi / math.sqrt(hopper.k / hopper.m)
    rejected = False
    while True:
        next_kink = kink(ramp, s)
        in_ramp = s < next_kink
        if in_ramp:
            h = min(h, next_kink - s)
        h = min(h, t_limit - s)
        dop853_step(hopper, ramp, s, y, h, k, y_new)
        stance_field(hopper, ramp, s + h, y_new, k[STAGES])
        err5, err3, finite = 0.0, 0.0, True
        for i in range(STATE_SIZE):
            scale = atol + max(abs(y[i]), abs(y_new[i])) * rtol
            q5, q3 = combined(E5, k, i) / scale, combined(E3, k, i) / scale
            err5 += q5 * q5
            err3 += q3 * q3
            finite = finite and math.isfinite(y_new[i])
        denominator = err5 + 0.01 * err3
        error = h * err5 / math.sqrt(denominator * STATE_SIZE) if denominator > 0.0 else 0.0
        # A step that left the floats (overflow, NaN) fails its error test and shrinks by MIN_FACTOR.
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
            event, s_event = locate_event(hopper, ramp, s, y, h, k, crossed, g_before, g_after, y_end)
            return TERMINAL_OUTCOMES[event], s_event
        if accepted:
            # Land exactly on the kink, so that the next segment (torque-free after t_f) starts there.
            s = next_kink if in_ramp and h == next_kink - s else s + h
            y[:] = y_new
            k[0] = k[STAGES]
            g_before = g_after
        rejected = not accepted
        h = h * factor
        if accepted and s >= t_limit:
            y_end[:] = y
            return STANCE_TIME_LIMIT, t_limit
        if rejected and h < 10.0 * (np.nextafter(s, math.inf) - s):  # scipy's smallest step
            y_end[:] = y
            return STANCE_STEP_COLLAPSE, s


@kernel
def lane_stride(
    hopper: LaneHopper,
    limits: LaneLimits,
    y: float,
    xdot: float,
    angle: float,
    ramp: LaneRamp,
    rtol: float,
    atol: float,
    out: Array,
    lane: int,
) -> None:
    """One lane's stride from the apex (y [m], xdot [m/s]) with the leg landing at ``angle`` [rad] into
    column ``lane`` of ``out`` (STRIDE_ROWS rows): the rules of the batched engine's stride, in its order."""
    for row in range(STRIDE_ROWS):
        out[row, lane] = math.nan
    failure = NO_FAILURE_CODE
    sin_td, cos_td = math.sin(angle), math.cos(angle)
    y_td = dynamics.touchdown_height(hopper, cos_td)
    if y < y_td:
        failure = TOE_STUBBING
    t_td = dynamics.fall_time(y, 0.0, min(y_td, y), hopper.g)
    toe_x = xdot * t_td + hopper.r0 * sin_td
    # The torque limit, then reversal at touchdown, as the exact map.
    if failure == NO_FAILURE_CODE and _torque_exceeded(limits, ramp.tau0):
        failure = STATE_LIMIT
    out[GROUND_ROW, lane] = 0.0 if failure == NO_FAILURE_CODE else math.nan  # the stance's ground
    out[SATURATED_ROW, lane] = abs(ramp.tau0) > ramp.tau_max
    ydot_td = -hopper.g * t_td
    rdot_td, thetadot_td = dynamics.polar_velocity(hopper.r0, sin_td, cos_td, xdot, ydot_td)
    if failure == NO_FAILURE_CODE and thetadot_td >= 0.0:
        failure = REVERSAL
    out[FAILURE_ROW, lane] = failure
    if failure != NO_FAILURE_CODE:
        return
    y0 = np.array([hopper.r0, angle, rdot_td, thetadot_td, 0.0, 0.0])
    y_end = np.empty(STATE_SIZE)
    outcome, s_end = integrate_stance(hopper, ramp, y0, limits.max_stance_time, rtol, atol, y_end)
    if outcome != STANCE_LIFTOFF:
        out[FAILURE_ROW, lane] = STANCE_FAILURE_CODES[outcome]
        return
    r, theta, rdot, thetadot = y_end[0], y_end[1], y_end[2], y_end[3]
    sin_lo, cos_lo = math.sin(theta), math.cos(theta)
    xdot_lo, ydot_lo = dynamics.cartesian_velocity(r, sin_lo, cos_lo, rdot, thetadot)
    out[HIP_WORK_ROW, lane], out[DAMPING_LOSS_ROW, lane] = y_end[4], y_end[5]
    out[SPRING_LOSS_ROW, lane] = dynamics.spring_energy(hopper, r)
    out[STANCE_TIME_ROW, lane] = s_end
    # The same rules, in the same order, as dynamics.takeoff_failure, then limits.apex_failure.
    if ydot_lo <= 0.0:
        out[FAILURE_ROW, lane] = FALL
        return
    if xdot_lo <= 0.0:
        out[FAILURE_ROW, lane] = REVERSAL
        return
    t_rise = ydot_lo / hopper.g
    x_lo = toe_x - r * sin_lo
    x_apex, y_apex, _, _ = dynamics.ballistic(x_lo, r * cos_lo, xdot_lo, ydot_lo, t_rise, hopper.g)
    if _apex_exceeded(limits, y_apex, xdot_lo):
        out[FAILURE_ROW, lane] = STATE_LIMIT
        return
    out[Y_ROW, lane], out[XDOT_ROW, lane], out[X_ROW, lane] = y_apex, xdot_lo, x_apex
    out[STRIDE_TIME_ROW, lane] = t_td + s_end + t_rise


@kernel
def stride_lanes(
    hopper: Array,
    limits: Array,
    y: Array,
    xdot: Array,
    angle: Array,
    tau0: Array,
    t_f: Array,
    tau_max: Array,
    rtol: float,
    atol: float,
    out: Array,
) -> None:
    """The stride of every lane into the block ``out``; hopper holds m, k, r0, c, g and limits the fields
    of :class:`LaneLimits`, in order."""
    lane_hopper = LaneHopper(hopper[0], hopper[1], hopper[2], hopper[3], hopper[4])
    lane_limits = LaneLimits(limits[0], limits[1], limits[2], limits[3])
    for lane in range(y.size):
        ramp = LaneRamp(tau0[lane], t_f[lane], tau_max[lane])
        lane_stride(lane_hopper, lane_limits, y[lane], xdot[lane], angle[lane], ramp, rtol, atol, out, lane)


@lru_cache(maxsize=16)
def default_limits(params: HopperParams) -> PlausibilityLimits:
    """PlausibilityLimits.for_hopper(params), made once per hopper (about 10 us, a third of a stride)."""
    return PlausibilityLimits.for_hopper(params)


@lru_cache(maxsize=16)
def kernel_rows(limits: PlausibilityLimits) -> tuple[Array, Array]:
    """The hopper (m, k, r0, c, g) and the limits (the fields of :class:`LaneLimits`) as the lane loops
    take them; made once per limits and shared (the kernels only read them)."""
    params = limits.params
    hopper = np.array([params.m, params.k, params.r0, params.c, params.g])
    return hopper, np.array([getattr(limits, name) for name in LaneLimits._fields])


def compiled_apex_return_map(
    params: HopperParams,
    y: npt.ArrayLike,
    xdot: npt.ArrayLike,
    touchdown_angle: npt.ArrayLike,
    tau0: npt.ArrayLike,
    t_f: npt.ArrayLike,
    *,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    limits: PlausibilityLimits | None = None,
    tau_max: npt.ArrayLike = math.inf,
) -> BatchStrideResult:
    """:func:`.batch.batch_apex_return_map` on flat ground, without pushes or placement errors (the same
    arguments, checks and ParameterError), one lane after the other in compiled code: for a few lanes per
    call, where the batched engine spends its time in numpy's overhead per step."""
    check_tolerances(rtol, atol)
    limits = PlausibilityLimits.of(params, limits)
    arrays = np.broadcast_arrays(
        *(np.asarray(v, dtype=np.float64) for v in (y, xdot, touchdown_angle, tau0, t_f, tau_max))
    )
    shape = arrays[0].shape
    # Fresh, writable, C-ordered copies: numba compiles the loop once for this one array type.
    y_a, xdot_a, angle, tau0_a, t_f_a, tau_max_a = (np.array(a, dtype=np.float64).ravel() for a in arrays)
    validate_lanes(limits, y_a, xdot_a, angle, ramp_checks(tau0_a, t_f_a))
    check_lanes((("tau_max", tau_max_a, tau_max_a > 0.0, "> 0 N m (inf: no saturation)"),))
    hopper, bounds = kernel_rows(limits)
    out = np.empty((STRIDE_ROWS, y_a.size))
    stride_lanes(hopper, bounds, y_a, xdot_a, angle, tau0_a, t_f_a, tau_max_a, float(rtol), float(atol), out)
    rows: dict[str, Any] = {
        f.name: row.reshape(shape) for f, row in zip(fields(BatchStrideResult), out, strict=True)
    }
    rows["failure"] = rows["failure"].astype(np.int64)
    rows["saturated"] = rows["saturated"] != 0.0
    return BatchStrideResult(**rows)


class LaneStrideResult(NamedTuple):
    """One stride of :func:`apex_stride`: the next apex (None on failure) and the failure; the stance's energy
    flows [J] and duration [s] (NaN where the leg did not lift off); the time to the next apex [s] and its
    position x [m] (NaN on failure); whether the hip saturated."""

    apex: ApexState | None
    failure: FailureKind | None
    hip_work: float
    damping_loss: float
    spring_loss: float
    stance_time: float
    stride_time: float
    x: float
    saturated: bool


def apex_stride(
    params: HopperParams,
    apex: ApexState,
    command: StanceCommand,
    *,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    limits: PlausibilityLimits | None = None,
    tau_max: float = math.inf,
) -> LaneStrideResult:
    """The next apex of :func:`.exact_map.apex_return_map` on flat ground from one apex, compiled (the
    states and commands are validated on construction; ParameterError for tolerances, an apex beyond the
    limits or tau_max <= 0): the exact map at about a fiftieth of its cost, for callers that hop one apex
    at a time."""
    check_tolerances(rtol, atol)
    limits = default_limits(params) if limits is None else PlausibilityLimits.of(params, limits)
    limits.check_apex(apex)
    if not tau_max > 0.0:
        raise ParameterError(f"tau_max must be > 0 N m (inf: no saturation), got {tau_max!r}")
    # One-lane arrays, not named tuples: numba types arrays in C on each call, tuples in Python (~10 us each).
    hopper, bounds = kernel_rows(limits)
    y, xdot, angle, tau0, t_f, saturation = np.array(
        [[apex.y], [apex.xdot], [command.touchdown_angle], [command.tau0], [command.t_f], [tau_max]]
    )
    out = np.empty((STRIDE_ROWS, 1))
    stride_lanes(hopper, bounds, y, xdot, angle, tau0, t_f, saturation, float(rtol), float(atol), out)
    row = out[:, 0].tolist()
    failure = failure_from_code(int(row[FAILURE_ROW]))
    return LaneStrideResult(
        None if failure is not None else ApexState(row[Y_ROW], row[XDOT_ROW]),
        failure,
        row[HIP_WORK_ROW],
        row[DAMPING_LOSS_ROW],
        row[SPRING_LOSS_ROW],
        row[STANCE_TIME_ROW],
        row[STRIDE_TIME_ROW],
        row[X_ROW],
        bool(row[SATURATED_ROW]),
    )


class Newton(NamedTuple):
    """energy_exact's Newton settings (controllers.EXACT_*): the tolerances on the scaled energy and stance
    residuals, the bound on the steps and the forward-difference step."""

    energy_tolerance: float
    stance_tolerance: float
    iterations: int
    jacobian_step: float


@kernel
def exact_regulation_lanes(
    hopper: Array,
    limits: Array,
    y: Array,
    xdot: Array,
    angle: Array,
    goal_bar: Array,
    tau0: Array,
    t_f: Array,
    tolerance: float,
    newton: Newton,
    reason: Array,
) -> None:
    """energy_exact's Newton iteration (:func:`.controllers.exact_energy_regulation`) for every lane, from
    the start (tau0 [N m], t_f [s]) of the lanes whose ``reason`` is HAS_COMMAND: the command into tau0 and
    t_f where it converged, else NaN, and the reason into ``reason``. goal_bar: the goal energy / (m g r0);
    tolerance: the exact map's rtol = atol. The steps and their rounding are those of the numpy version."""
    lane_hopper = LaneHopper(hopper[0], hopper[1], hopper[2], hopper[3], hopper[4])
    lane_limits = LaneLimits(limits[0], limits[1], limits[2], limits[3])
    m, g = lane_hopper.m, lane_hopper.g
    energy_scale = m * g * lane_hopper.r0
    torque_scale, time_scale = torque_scales(m, lane_hopper.k, lane_hopper.r0, g)
    block = np.empty((STRIDE_ROWS, 3))  # the point and its shifts along tau0 and t_f
    energy_residual, stance_residual = np.empty(3), np.empty(3)
    for lane in range(y.size):
        x0, x1 = tau0[lane] / torque_scale, t_f[lane] / time_scale
        solved = False
        for _ in range(newton.iterations if reason[lane] == HAS_COMMAND else 0):
            if not (math.isfinite(x0) and math.isfinite(x1) and x1 > 0.0):
                break
            for point in range(3):
                p0 = x0 + (newton.jacobian_step if point == 1 else 0.0)
                p1 = x1 + (newton.jacobian_step if point == 2 else 0.0)
                ramp = LaneRamp(p0 * torque_scale, p1 * time_scale, math.inf)
                lane_stride(
                    lane_hopper,
                    lane_limits,
                    y[lane],
                    xdot[lane],
                    angle[lane],
                    ramp,
                    tolerance,
                    tolerance,
                    block,
                    point,
                )
                energy = m * (g * block[Y_ROW, point] + 0.5 * block[XDOT_ROW, point] ** 2)
                energy_residual[point] = energy / energy_scale - goal_bar[lane]
                stance_residual[point] = block[STANCE_TIME_ROW, point] / time_scale - p1
            failure = int(block[FAILURE_ROW, 0])
            if failure != NO_FAILURE_CODE:
                reason[lane] = REASON_OF_FAILURE[failure]
                break
            if (
                abs(energy_residual[0]) <= newton.energy_tolerance
                and abs(stance_residual[0]) <= newton.stance_tolerance
            ):
                solved = True
                break
            step = newton.jacobian_step
            step0, step1 = solve2(
                (energy_residual[1] - energy_residual[0]) / step,
                (energy_residual[2] - energy_residual[0]) / step,
                (stance_residual[1] - stance_residual[0]) / step,
                (stance_residual[2] - stance_residual[0]) / step,
                energy_residual[0],
                stance_residual[0],
            )
            x0, x1 = x0 + -step0, x1 + -step1
        if not solved and reason[lane] == HAS_COMMAND:
            reason[lane] = NO_SOLUTION_REASON
        has_command = reason[lane] == HAS_COMMAND
        tau0[lane] = x0 * torque_scale if has_command else math.nan
        t_f[lane] = x1 * time_scale if has_command else math.nan
