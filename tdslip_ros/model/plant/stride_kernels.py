"""The exact stride of one lane under a torque ramp, compiled: the batched engine's stride without numpy's
cost per call, for callers that hop a few apexes at a time. :func:`apex_stride` hops one apex (the exact
map's arguments), :func:`compiled_apex_return_map` a few lanes (the batched engine's), and
:func:`lane_stride` is the kernel
that ``energy_exact``'s planner (:mod:`tdslip_ros.model.policies.exact_regulation_kernels`) iterates on.

The stride is the one of :func:`.batch.batch_apex_return_map` on flat ground: descent and ascent in closed
form; stance (eq. 2, the ramp of eq. 18 saturated at tau_max) by the batched engine's own integrator,
:func:`.stance_kernel.integrate_stance` (DOP853 split at the torque's kinks, terminal events located to
1e-14 s); the rules and their order are those of :mod:`.batch`, so the failure kinds are the same and the
states agree to rounding (the batched engine's flight is numpy's arithmetic, this one libm's).

One source. The stance's right-hand side, torque, event functions and rates, and the flight's closed forms
are :mod:`.dynamics`' own functions, compiled here for one lane (numba compiles the Python source of each
on its first use in a kernel): the numpy engines call the very same code on arrays. The hopper reaches them
as :class:`.stance_kernel.LaneHopper`, a named tuple with the fields of :class:`.params.HopperParams` they
read, and the limits' rules as :class:`LaneLimits`.
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
from tdslip_ros.model.arrays import Array
from tdslip_ros.model.compiled import kernel
from tdslip_ros.model.events import NO_FAILURE_CODE, FailureKind, failure_code, failure_from_code
from tdslip_ros.model.limits import (
    PlausibilityLimits,
    check_lanes,
    check_tolerances,
    ramp_checks,
    validate_lanes,
)
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.batch import BatchStrideResult
from tdslip_ros.model.plant.perturbations import UNPERTURBED, StrideConditions
from tdslip_ros.model.plant.stance_kernel import (
    STANCE_FAILURES,
    STANCE_LIFTOFF,
    LaneHopper,
    LaneTorque,
    first_step,
    hopper_row,
    integrate_stance,
)

# The flight's functions of dynamics (the stance's are stance_kernel's) and the limits' rules made callable
# from kernels as they are: numba compiles their Python source where a kernel calls them, while Python
# callers keep the plain functions (numpy, floats).
for _shared in (
    dynamics.fall_time,
    dynamics.ballistic,
    dynamics.polar_velocity,
    dynamics.cartesian_velocity,
    dynamics.touchdown_height,
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
"""The failure code of each stance outcome (stance_kernel.STANCE_FAILURES; none for liftoff)."""
PITCH_FIELDS = ("pitch", "pitch_rate")
"""The fields of :class:`.batch.BatchStrideResult` that a fixed body holds at 0 (NaN on failure): not in a
block."""
ROW = {
    name: row
    for row, name in enumerate(
        field.name for field in fields(BatchStrideResult) if field.name not in PITCH_FIELDS
    )
}
"""The row of each other field of :class:`.batch.BatchStrideResult` in a block of strides."""
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


class LaneLimits(NamedTuple):
    """The plausibility limits as the compiled rules of :class:`.limits.PlausibilityLimits` read them."""

    max_torque: float
    max_apex_height: float
    max_apex_speed: float
    max_stance_time: float


@kernel
def lane_stride(
    hopper: LaneHopper,
    limits: LaneLimits,
    y: float,
    xdot: float,
    angle: float,
    ramp: LaneTorque,
    rtol: float,
    atol: float,
    out: Array,
    lane: int,
) -> None:
    """One lane's stride from the apex (y [m], xdot [m/s]) with the leg landing at ``angle`` [rad] under
    ``ramp`` (no stop) into column ``lane`` of ``out`` (STRIDE_ROWS rows): the rules of the batched
    engine's stride, in its order."""
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
    y_end = np.array([hopper.r0, angle, rdot_td, thetadot_td, 0.0, 0.0])
    outcome, s_end, _ = integrate_stance(
        hopper, ramp, 0.0, first_step(hopper), y_end, limits.max_stance_time, rtol, atol
    )
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
        ramp = LaneTorque(tau0[lane], t_f[lane], tau_max[lane], math.inf)
        lane_stride(lane_hopper, lane_limits, y[lane], xdot[lane], angle[lane], ramp, rtol, atol, out, lane)


def flat_ground_saturation(conditions: StrideConditions) -> Any:
    """The conditions' tau_max; ParameterError for any other condition than the defaults, which the compiled
    stride does not run (the batched engine does)."""
    defaults = {
        "x": bool(np.all(np.asarray(conditions.x) == 0.0)),
        "ground": conditions.ground is None,
        "terrain": conditions.terrain.is_flat,
        "push": bool(np.all(np.asarray(conditions.push) == 0.0)),
        "angle_error": bool(np.all(np.asarray(conditions.angle_error) == 0.0)),
    }
    others = [name for name, is_default in defaults.items() if not is_default]
    if others:
        raise ParameterError(
            f"the compiled stride runs flat ground with tau_max alone; got {', '.join(others)}: "
            "use the batched engine (batch_apex_return_map)"
        )
    return conditions.tau_max


@lru_cache(maxsize=16)
def default_limits(params: HopperParams) -> PlausibilityLimits:
    """PlausibilityLimits.for_hopper(params), made once per hopper: building it costs a sizeable part of a
    compiled stride (bench/bench_exact_stride.py)."""
    return PlausibilityLimits.for_hopper(params)


@lru_cache(maxsize=16)
def kernel_rows(limits: PlausibilityLimits) -> tuple[Array, Array]:
    """The hopper (m, k, r0, c, g) and the limits (the fields of :class:`LaneLimits`) as the lane loops
    take them; made once per limits and shared (the kernels only read them). ParameterError for a rigid
    body, which the compiled stride does not run yet."""
    limits.params.require_fixed_body("the compiled lane stride (stride_kernels)")
    return hopper_row(limits.params), np.array([getattr(limits, name) for name in LaneLimits._fields])


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
    conditions: StrideConditions = UNPERTURBED,
) -> BatchStrideResult:
    """:func:`.batch.batch_apex_return_map` on flat ground, without pushes or placement errors (the same
    arguments, checks and ParameterError; of the conditions only tau_max), one lane after the other in
    compiled code: for a few lanes per call, where the batched engine spends its time in numpy's overhead
    per call (its descent, ascent and checks are array operations)."""
    check_tolerances(rtol, atol)
    tau_max = flat_ground_saturation(conditions)
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
    rows: dict[str, Any] = {name: out[row].reshape(shape) for name, row in ROW.items()}
    rows["failure"] = rows["failure"].astype(np.int64)
    rows["saturated"] = rows["saturated"] != 0.0
    for name in PITCH_FIELDS:
        rows[name] = np.where(np.isnan(rows["y"]), np.nan, 0.0)
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
    conditions: StrideConditions = UNPERTURBED,
) -> LaneStrideResult:
    """The next apex of :func:`.exact_map.apex_return_map` on flat ground from one apex, compiled (the
    states and commands are validated on construction; ParameterError for tolerances, an apex beyond the
    limits or tau_max <= 0): the exact map at about a fiftieth of its cost, for callers that hop one apex
    at a time."""
    check_tolerances(rtol, atol)
    tau_max = float(flat_ground_saturation(conditions))
    limits = default_limits(params) if limits is None else PlausibilityLimits.of(params, limits)
    limits.check_apex(apex)
    if not tau_max > 0.0:
        raise ParameterError(f"tau_max must be > 0 N m (inf: no saturation), got {tau_max!r}")
    # One-lane arrays, not named tuples: numba types arrays in C on each call, tuples in Python.
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
