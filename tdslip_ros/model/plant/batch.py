"""Batched exact TD-SLIP engine: many apex-to-apex strides at once, their flights vectorised over lanes.

Each lane is one initial condition with its own command: a torque ramp (:func:`batch_apex_return_map`) or
a stance law (:func:`batch_feedback_return_map`, :mod:`.stance_laws`). Descent and ascent are closed-form,
as in :mod:`.exact_map`; stance is integrated lane by lane by the compiled DOP853 of
:mod:`.stance_kernel`, with per-lane step sizes and event location (:mod:`.batch_stance`).

Failures are per lane, as integer codes (:func:`.events.failure_code`, -1 for none), with the
same rules as the single-trajectory paths, plausibility limits (:mod:`.limits`) included. A lane whose step
size collapses (scipy's rule: below ten spacings of s) fails as ``state_limit`` rather than stall the batch.

A rigid body (``params.body``, docs/rotating_body.md) hops one stride a call, as the exact map's
``_rigid_body_stride`` does: the lanes carry its pitch and pitch rate, the flight is :mod:`.batch_body`'s,
the stance the compiled rigid stance (:mod:`.stance_kernel`, ``tipped`` located as the other events), on
flat ground with saturation, a push and a placement error; ramps and stance feedback. What the engine does
not run for a body is refused by name: other ground (:func:`.batch_body.rigid_lanes`),
:func:`simulate_strides`, and the compiled stride (:mod:`.stride_kernels`). What a rigid stride costs:
bench/bench_rigid_body.py.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from tdslip_ros.model import dynamics
from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.events import NO_FAILURE_CODE, FailureKind, failure_code
from tdslip_ros.model.limits import (
    Checks,
    PlausibilityLimits,
    check_lanes,
    check_tolerances,
    ramp_checks,
    validate_lanes,
)
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.plant.batch_body import (
    RigidLanes,
    hip_beside_centre_of_mass,
    rigid_lanes,
    tip_times,
    touchdown_times,
)
from tdslip_ros.model.plant.batch_stance import IntArray, feedback_stance, ramp_stance
from tdslip_ros.model.plant.perturbations import UNPERTURBED, Perturbations, StrideConditions, placed_angle
from tdslip_ros.model.plant.stance_kernel import RIGID_STATE_SIZE, STANCE_FAILURES, STANCE_LIFTOFF, STATE_SIZE
from tdslip_ros.model.plant.stance_laws import DEFAULT_SAMPLE_PERIOD, StanceLaw, TorqueStream, torque_limit
from tdslip_ros.model.plant.terrain import FLAT, Terrain, touchdown

Policy = Callable[..., tuple[Any, ...]]
"""policy(stride, y, xdot[, lanes]) -> (touchdown_angle, tau0, t_f) for ramps, or (touchdown_angle, law)
for stance feedback, arrays (and a law's per-lane fields) over the alive lanes."""


@dataclass(frozen=True)
class BatchStrideResult:
    """One stride for every lane (arrays of the broadcast input shape).

    y, xdot: next apex [m, m/s], y above ``ground``, NaN where the lane failed; failure: code per lane
    (-1 none); hip_work, damping_loss, spring_loss [J]: the stance's energy flows, and stance_time [s] its
    duration (touchdown to liftoff), NaN where the leg did not lift off; stride_time [s]: apex to
    next apex, NaN on failure; ground [m]: the stance's ground height (world frame, the toe's), NaN
    without a stance; x [m]: the next apex's position, NaN on failure; saturated: the hip saturated at
    tau_max (a ramp's |tau0| beyond it, a law's sample clipped); pitch [rad], pitch_rate [rad/s]: a rigid
    body's at the next apex (0 for the fixed body), NaN where the lane failed.
    """

    y: FloatArray
    xdot: FloatArray
    failure: IntArray
    hip_work: FloatArray
    damping_loss: FloatArray
    spring_loss: FloatArray
    stance_time: FloatArray
    stride_time: FloatArray
    ground: FloatArray
    x: FloatArray
    saturated: npt.NDArray[np.bool_]
    pitch: FloatArray
    pitch_rate: FloatArray


@dataclass(frozen=True)
class _Ramp:
    """The ramps of eq. 18 of the lanes of a stride: tau0 [N m], t_f [s]."""

    tau0: FloatArray
    t_f: FloatArray


@dataclass(frozen=True)
class _Feedback:
    """Stance feedback for the lanes of a stride: the law, its sample period [s] and the lanes' apex
    times [s] on the sample clock."""

    law: StanceLaw
    period: float
    apex_time: FloatArray


def batch_apex_return_map(
    params: HopperParams,
    y: npt.ArrayLike,
    xdot: npt.ArrayLike,
    touchdown_angle: npt.ArrayLike,
    tau0: npt.ArrayLike,
    t_f: npt.ArrayLike,
    *,
    pitch: npt.ArrayLike = 0.0,
    pitch_rate: npt.ArrayLike = 0.0,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    limits: PlausibilityLimits | None = None,
    conditions: StrideConditions = UNPERTURBED,
) -> BatchStrideResult:
    """The exact return map of :func:`.exact_map.apex_return_map` for broadcastable arrays of apex
    states (y [m], xdot [m/s]; with a rigid body also pitch [rad] and pitch_rate [rad/s], 0 for the fixed
    body) and commands (touchdown_angle [rad], tau0 [N m], t_f [s]).

    rtol/atol: per-lane DOP853 tolerances on the stance state, as in the exact map; the defaults
    give apex states within ~1e-12 (dimensionless) of it. limits: the plausibility limits (default:
    the hopper's), max_stance_time among them. ParameterError names the field and the first lane of
    an invalid input, an apex beyond the limits included, or the invalid tolerance.

    ``conditions`` as in the exact map, per lane: each field a float or an array broadcast with the lanes
    (the terrain's per-lane fields in the lanes' shape). A rigid body runs on flat ground at height 0
    (:func:`.batch_body.rigid_lanes`).
    """
    return _return_map(
        params,
        (y, xdot, touchdown_angle, pitch, pitch_rate),
        (tau0, t_f),
        None,
        rtol,
        atol,
        limits,
        conditions,
    )


def batch_feedback_return_map(
    params: HopperParams,
    y: npt.ArrayLike,
    xdot: npt.ArrayLike,
    touchdown_angle: npt.ArrayLike,
    law: StanceLaw,
    *,
    pitch: npt.ArrayLike = 0.0,
    pitch_rate: npt.ArrayLike = 0.0,
    sample_period: float = DEFAULT_SAMPLE_PERIOD,
    apex_time: npt.ArrayLike = 0.0,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    limits: PlausibilityLimits | None = None,
    conditions: StrideConditions = UNPERTURBED,
) -> BatchStrideResult:
    """The exact map of :func:`.exact_map.apex_return_map` under stance feedback
    (:class:`.stance_laws.StanceFeedback`), for broadcastable arrays of apex states, touchdown angles
    [rad] and apex times [s] on the sample clock, whose sample instants are the multiples of
    sample_period [s]. The law's per-lane fields are over the broadcast lanes, in flat order. The law's
    torques are clipped at tau_max and the limits' max_torque; a rigid body's law sees the lanes' pitch and
    pitch rate. The rest as in :func:`batch_apex_return_map`; ParameterError for a TorqueStream law.
    """
    if isinstance(law, TorqueStream):
        raise ParameterError("the batched engine cannot run a torque stream: replay it with RecordedTorques")
    if not (math.isfinite(sample_period) and sample_period > 0.0):
        raise ParameterError(f"sample_period must be a positive finite number, got {sample_period!r}")
    return _return_map(
        params,
        (y, xdot, touchdown_angle, pitch, pitch_rate),
        (apex_time,),
        (law, sample_period),
        rtol,
        atol,
        limits,
        conditions,
    )


def _return_map(
    params: HopperParams,
    inputs: tuple[npt.ArrayLike, ...],
    stance_inputs: tuple[npt.ArrayLike, ...],
    feedback: tuple[StanceLaw, float] | None,
    rtol: float,
    atol: float,
    limits: PlausibilityLimits | None,
    conditions: StrideConditions,
) -> BatchStrideResult:
    """One stride of broadcast lanes: inputs (y, xdot, touchdown_angle, pitch, pitch_rate), the conditions,
    and the stance's inputs: (tau0, t_f) of ramps, or (apex_time,) under the law and period of
    ``feedback``."""
    check_tolerances(rtol, atol)
    limits = PlausibilityLimits.of(params, limits)
    ground, terrain = conditions.ground, conditions.terrain
    per_lane = (conditions.x, conditions.tau_max, conditions.push, conditions.angle_error)
    arrays = np.broadcast_arrays(
        *(np.asarray(v, dtype=np.float64) for v in (*inputs, *per_lane, *stance_inputs))
    )
    shape = arrays[0].shape
    y_a, xdot_a, angle, pitch_a, pitch_rate_a, x_a, tau_max_a, push_a, error_a, *stance_a = (
        np.array(a, dtype=np.float64).ravel() for a in arrays
    )
    rigid = rigid_lanes(params, pitch_a, pitch_rate_a, conditions)
    if ground is None:
        ground_a = (
            np.zeros(y_a.size) if terrain.is_flat else np.broadcast_to(terrain.height(x_a), y_a.shape).copy()
        )
    else:
        ground_a = np.array(
            np.broadcast_to(np.asarray(ground, dtype=np.float64), shape), dtype=np.float64
        ).ravel()
    stance = _Ramp(*stance_a) if feedback is None else _Feedback(feedback[0], feedback[1], stance_a[0])
    validate_lanes(limits, y_a, xdot_a, angle, _stance_checks(stance))
    _validate_perturbations(x_a, ground_a, tau_max_a, push_a, error_a)
    result = _stride(
        limits,
        y_a,
        xdot_a,
        placed_angle(angle, error_a),
        stance,
        rtol,
        atol,
        _Perturbed.of(terrain, x_a, ground_a, tau_max_a, push_a),
        rigid,
    )
    return BatchStrideResult(**{f.name: getattr(result, f.name).reshape(shape) for f in fields(result)})


def _stance_checks(stance: _Ramp | _Feedback) -> Checks:
    if isinstance(stance, _Ramp):
        return ramp_checks(stance.tau0, stance.t_f)
    return (("apex_time", stance.apex_time, np.isfinite(stance.apex_time), "finite"),)


@dataclass(frozen=True)
class _Perturbed:
    """The perturbations of one stride of 1-D lanes, None where a kind is off (the flat-ground path)."""

    x: FloatArray
    ground: FloatArray
    terrain: Terrain | None
    tau_max: FloatArray | None
    push: FloatArray | None

    @classmethod
    def of(
        cls, terrain: Terrain, x: FloatArray, ground: FloatArray, tau_max: FloatArray, push: FloatArray
    ) -> _Perturbed:
        return cls(
            x,
            ground,
            None if terrain.is_flat else terrain,
            None if np.all(np.isinf(tau_max)) else tau_max,
            None if np.all(push == 0.0) else push,
        )


@dataclass(frozen=True)
class BatchRun:
    """Apex histories of simulate_strides, lanes in the shape of y0.

    y, xdot: (n_strides + 1, *shape) apex states, row k the apex of stride k (row 0 the initial
    one), y its height above ``ground``, NaN from a lane's failure on; failure: code per lane (-1 none);
    failure_stride: the stride k whose apex-to-apex flow failed (-1 none); hip_work, damping_loss,
    spring_loss: (n_strides, *shape) energy flows of stride k [J], NaN where not reached.

    Where the run was perturbed (:mod:`.perturbations`): x, ground: (n_strides + 1, *shape) the apex's
    position and the ground height [m, world frame] of the stance before it (row 0: under the body; the
    ground of a stance that failed after touchdown is kept, where the stance was);
    measured_y, measured_xdot: (n_strides, *shape) the apex the policy was given at stride k (height
    above ground, speed); push: (n_strides, *shape) the push at apex k [m/s]; saturated: (n_strides, *shape)
    stride k's hip saturated at tau_max (a ramp's |tau0| beyond it, a law's sample clipped). NaN (False)
    where not reached.

    t: (n_strides + 1, *shape) the apex times [s] on the sample clock of stance feedback (row 0: t0), NaN
    from a lane's failure on.
    """

    y: FloatArray
    xdot: FloatArray
    failure: IntArray
    failure_stride: IntArray
    hip_work: FloatArray
    damping_loss: FloatArray
    spring_loss: FloatArray
    x: FloatArray
    ground: FloatArray
    measured_y: FloatArray
    measured_xdot: FloatArray
    push: FloatArray
    saturated: npt.NDArray[np.bool_]
    t: FloatArray


def simulate_strides(
    params: HopperParams,
    y0: npt.ArrayLike,
    xdot0: npt.ArrayLike,
    policy: Policy,
    n_strides: int,
    *,
    pass_lanes: bool = False,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    limits: PlausibilityLimits | None = None,
    perturbations: Perturbations | None = None,
    trajectories: npt.ArrayLike | None = None,
    x0: npt.ArrayLike = 0.0,
    sample_period: float = DEFAULT_SAMPLE_PERIOD,
    t0: npt.ArrayLike = 0.0,
) -> BatchRun:
    """Run every lane for n_strides strides under ``policy``, stopping lanes at their failure.

    Before stride k the policy is called as policy(k, y, xdot) with the apex states of the lanes
    still alive (1-D arrays) and returns (touchdown_angle, tau0, t_f), each broadcastable to them.
    With pass_lanes=True it is called as policy(k, y, xdot, lanes), lanes being the alive lanes'
    flat indices into y0, for policies with per-lane memory (such as a per-lane energy goal).
    rtol, atol and limits as in :func:`batch_apex_return_map`.

    A policy may answer (touchdown_angle, law) instead: stance feedback (:mod:`.stance_laws`) under
    ``law``, whose per-lane fields are over the alive lanes, sampled every sample_period [s] on the clock
    on which the initial apexes are at t0 [s] (each lane's apex times are kept, :attr:`BatchRun.t`).

    ``perturbations`` (:class:`~.perturbations.Perturbations`, its per-lane fields in the lanes' flat
    order) perturb the plant and the sensor: the policy is given the *measured* apex (height above the
    ground of the last stance, speed) and, for a mismatched model, must plan with
    ``perturbations.mismatch.controller_params(params)`` itself. The random draws of lane i are those of
    trajectory ``trajectories[i]`` (default: i), so a study that splits its trajectories into several calls
    gets the same results. y0 is the initial apex height above the ground under the body at x0 [m].
    """
    check_tolerances(rtol, atol)
    if params.body is not None:
        raise ParameterError(
            "simulate_strides runs the paper's fixed body only (its policies see no pitch, its perturbations "
            "no body): a rigid body's lanes hop one stride a call on batch_apex_return_map"
        )
    limits = PlausibilityLimits.of(params, limits)
    if n_strides < 0:
        raise ParameterError(f"n_strides must be non-negative, got {n_strides!r}")
    y_init, xdot_init, x_init = np.broadcast_arrays(
        np.asarray(y0, dtype=np.float64),
        np.asarray(xdot0, dtype=np.float64),
        np.asarray(x0, dtype=np.float64),
    )
    shape = y_init.shape
    lanes_total = y_init.size
    perturbed = perturbations if perturbations is not None and perturbations.active else None
    trajectory = (
        np.arange(lanes_total) if trajectories is None else np.asarray(trajectories, dtype=np.int64).ravel()
    )
    if trajectory.shape != (lanes_total,):
        raise ParameterError(
            f"trajectories must hold one index per lane ({lanes_total}), got {trajectory.shape}"
        )
    drawn = perturbed is not None and (perturbed.random or perturbed.pushes.active)
    draws = perturbed.draws(trajectory, 0, n_strides) if perturbed is not None and drawn else None
    y_hist = np.full((n_strides + 1, lanes_total), np.nan)
    xdot_hist = np.full((n_strides + 1, lanes_total), np.nan)
    x_hist = np.full((n_strides + 1, lanes_total), np.nan)
    ground_hist = np.full((n_strides + 1, lanes_total), np.nan)
    measured = np.full((2, n_strides, lanes_total), np.nan)
    push_hist = np.full((n_strides, lanes_total), np.nan)
    saturated = np.zeros((n_strides, lanes_total), dtype=bool)
    energies = np.full((3, n_strides, lanes_total), np.nan)
    failure = np.full(lanes_total, NO_FAILURE_CODE, dtype=np.int64)
    failure_stride = np.full(lanes_total, -1, dtype=np.int64)
    t_hist = np.full((n_strides + 1, lanes_total), np.nan)
    y_hist[0], xdot_hist[0], x_hist[0] = y_init.ravel(), xdot_init.ravel(), x_init.ravel()
    t_hist[0] = np.broadcast_to(np.asarray(t0, dtype=np.float64), shape).ravel()
    if not np.all(np.isfinite(x_hist[0])):
        raise ParameterError("x0 must be finite")
    if not (np.all(np.isfinite(t_hist[0])) and math.isfinite(sample_period) and sample_period > 0.0):
        raise ParameterError("t0 must be finite and sample_period positive and finite")
    terrain = FLAT if perturbed is None else perturbed.terrain
    ground_hist[0] = 0.0 if terrain.is_flat else terrain.height(x_hist[0])
    alive = np.arange(lanes_total)
    for stride in range(n_strides):
        if alive.size == 0:
            break
        y_k, xdot_k = y_hist[stride, alive], xdot_hist[stride, alive]
        seen_y, seen_xdot = y_k, xdot_k
        if draws is not None:
            seen_y, seen_xdot = (
                y_k + draws.height_error[stride, alive],
                xdot_k + draws.speed_error[stride, alive],
            )
        measured[:, stride, alive] = seen_y, seen_xdot
        command = (
            policy(stride, seen_y, seen_xdot, alive) if pass_lanes else policy(stride, seen_y, seen_xdot)
        )
        angle = np.array(np.broadcast_to(np.asarray(command[0], dtype=np.float64), alive.shape))
        stance: _Ramp | _Feedback
        if len(command) == 2:
            stance = _Feedback(command[1], sample_period, t_hist[stride, alive])
        else:
            stance = _Ramp(
                *(
                    np.array(np.broadcast_to(np.asarray(c, dtype=np.float64), alive.shape))
                    for c in command[1:]
                )
            )
        validate_lanes(limits, y_k, xdot_k, angle, _stance_checks(stance))
        lanes = perturbed.take(alive) if perturbed is not None else None
        push = np.zeros(alive.size) if draws is None else draws.push[stride, alive]
        tau_max = (
            np.full(alive.size, math.inf) if lanes is None else np.broadcast_to(lanes.tau_max, alive.shape)
        )
        if draws is not None:
            angle = placed_angle(angle, draws.angle_error[stride, alive])
        step = _stride(
            limits,
            y_k,
            xdot_k,
            angle,
            stance,
            rtol,
            atol,
            _Perturbed.of(
                terrain if lanes is None else lanes.terrain,
                x_hist[stride, alive],
                ground_hist[stride, alive],
                tau_max,
                push,
            ),
        )
        push_hist[stride, alive] = push
        saturated[stride, alive] = step.saturated
        t_hist[stride + 1, alive] = t_hist[stride, alive] + step.stride_time
        y_hist[stride + 1, alive], xdot_hist[stride + 1, alive] = step.y, step.xdot
        x_hist[stride + 1, alive], ground_hist[stride + 1, alive] = step.x, step.ground
        energies[:, stride, alive] = step.hip_work, step.damping_loss, step.spring_loss
        failed = step.failure != NO_FAILURE_CODE
        failure[alive[failed]] = step.failure[failed]
        failure_stride[alive[failed]] = stride
        alive = alive[~failed]
    return BatchRun(
        y=y_hist.reshape(n_strides + 1, *shape),
        xdot=xdot_hist.reshape(n_strides + 1, *shape),
        failure=failure.reshape(shape),
        failure_stride=failure_stride.reshape(shape),
        hip_work=energies[0].reshape(n_strides, *shape),
        damping_loss=energies[1].reshape(n_strides, *shape),
        spring_loss=energies[2].reshape(n_strides, *shape),
        x=x_hist.reshape(n_strides + 1, *shape),
        ground=ground_hist.reshape(n_strides + 1, *shape),
        measured_y=measured[0].reshape(n_strides, *shape),
        measured_xdot=measured[1].reshape(n_strides, *shape),
        push=push_hist.reshape(n_strides, *shape),
        saturated=saturated.reshape(n_strides, *shape),
        t=t_hist.reshape(n_strides + 1, *shape),
    )


def _validate_perturbations(
    x: FloatArray, ground: FloatArray, tau_max: FloatArray, push: FloatArray, angle_error: FloatArray
) -> None:
    """The perturbation inputs per lane, as :func:`_validate` checks the states and commands."""
    check_lanes(
        (
            ("x", x, np.isfinite(x), "finite"),
            ("ground", ground, np.isfinite(ground), "finite"),
            ("tau_max", tau_max, tau_max > 0.0, "> 0 N m (inf: no saturation)"),
            ("push", push, np.isfinite(push), "finite"),
            ("angle_error", angle_error, np.isfinite(angle_error), "finite"),
        )
    )


def _stride(
    limits: PlausibilityLimits,
    y: FloatArray,
    xdot: FloatArray,
    angle: FloatArray,
    stance: _Ramp | _Feedback,
    rtol: float,
    atol: float,
    perturbed: _Perturbed,
    rigid: RigidLanes | None = None,
) -> BatchStrideResult:
    """One stride of 1-D lanes (the arrays are validated; angle is where the leg lands); ``rigid``: a rigid
    body's lanes (on flat ground), None for the fixed body."""
    params = limits.params
    lanes = y.size
    failure = np.full(lanes, NO_FAILURE_CODE, dtype=np.int64)
    out = {
        name: np.full(lanes, np.nan)
        for name in (
            *("y", "xdot", "hip_work", "damping_loss", "spring_loss", "stance", "t", "ground", "x"),
            *("pitch", "pitch_rate"),
        )
    }
    if perturbed.push is not None:  # as limits.push_failure
        pushed_out = (perturbed.push != 0.0) & limits.apex_exceeded(y, xdot + perturbed.push)
        failure[pushed_out] = failure_code(FailureKind.STATE_LIMIT)
        xdot = xdot + perturbed.push
    sin_td, cos_td = np.sin(angle), np.cos(angle)
    y_td = dynamics.touchdown_height(params, cos_td)
    # The hip's velocity beside the centre of mass's at touchdown (a rigid body's turning).
    relative_vx: FloatArray | float = 0.0
    relative_vy: FloatArray | float = 0.0
    if rigid is not None:  # as the exact map's _rigid_body_stride: the hip stubs the toe, then tipping
        t_td = touchdown_times(params, rigid.body, y, rigid.pitch, rigid.pitch_rate, cos_td)
        failure[(failure == NO_FAILURE_CODE) & np.isnan(t_td)] = failure_code(FailureKind.TOE_STUBBING)
        tipping = tip_times(rigid.body, rigid.pitch, rigid.pitch_rate)
        failure[(failure == NO_FAILURE_CODE) & (tipping <= t_td)] = failure_code(FailureKind.TIPPED)
        pitch_td = rigid.pitch + rigid.pitch_rate * t_td
        offset_x, _, relative_vx, relative_vy = hip_beside_centre_of_mass(
            rigid.body, pitch_td, rigid.pitch_rate
        )
        toe_x = perturbed.x + xdot * t_td + offset_x + params.r0 * sin_td
        toe_y = np.zeros(lanes)
    elif perturbed.terrain is None:
        failure[(failure == NO_FAILURE_CODE) & (y < y_td)] = failure_code(FailureKind.TOE_STUBBING)
        t_td = dynamics.fall_time(y, np.zeros(lanes), np.minimum(y_td, y), params.g)
        toe_x = perturbed.x + xdot * t_td + params.r0 * sin_td
        toe_y = np.zeros(lanes)
    else:
        landing = touchdown(
            perturbed.terrain, perturbed.x, perturbed.ground + y, xdot, sin_td, cos_td, params.r0, params.g
        )
        failure[(failure == NO_FAILURE_CODE) & landing.stubbed] = failure_code(FailureKind.TOE_STUBBING)
        t_td, toe_x, toe_y = landing.t, landing.toe_x, landing.toe_y
    # The same rules, in the same order, as the exact map: the torque limit, then reversal at touchdown.
    saturated = np.zeros(lanes, dtype=bool)
    if isinstance(stance, _Ramp):
        beyond_torque = (failure == NO_FAILURE_CODE) & limits.torque_exceeded(stance.tau0)
        failure[beyond_torque] = failure_code(FailureKind.STATE_LIMIT)
        if perturbed.tau_max is not None:
            saturated = np.abs(stance.tau0) > perturbed.tau_max
    touched = failure == NO_FAILURE_CODE
    out["ground"][touched] = toe_y[touched]
    ydot_td = -params.g * t_td
    rdot_td, thetadot_td = dynamics.polar_velocity(
        np.full(lanes, params.r0), sin_td, cos_td, xdot + relative_vx, ydot_td + relative_vy
    )
    failure[(failure == NO_FAILURE_CODE) & (thetadot_td >= 0.0)] = failure_code(FailureKind.REVERSAL)

    in_stance = np.flatnonzero(failure == NO_FAILURE_CODE)
    # The touchdown states, then the stances' ends; a rigid body's end with its pitch and rate.
    y_end = np.zeros((in_stance.size, STATE_SIZE if rigid is None else RIGID_STATE_SIZE))
    y_end[:, 0], y_end[:, 1] = params.r0, angle[in_stance]
    y_end[:, 2], y_end[:, 3] = rdot_td[in_stance], thetadot_td[in_stance]
    if rigid is not None:
        y_end[:, 6], y_end[:, 7] = pitch_td[in_stance], rigid.pitch_rate[in_stance]
    tau_max = None if perturbed.tau_max is None else perturbed.tau_max[in_stance]
    t_limit = limits.max_stance_time
    if isinstance(stance, _Ramp):
        outcome, s_end = ramp_stance(
            params,
            y_end,
            stance.tau0[in_stance],
            stance.t_f[in_stance],
            tau_max,
            t_limit,
            rtol,
            atol,
        )
    else:
        outcome, s_end = feedback_stance(
            params,
            y_end,
            stance.law,
            stance.period,
            stance.apex_time[in_stance] + t_td[in_stance],
            np.broadcast_to(torque_limit(tau_max, limits.max_torque), in_stance.shape),
            tau_max,
            in_stance,
            saturated,
            t_limit,
            rtol,
            atol,
        )
    for code, kind in STANCE_FAILURES.items():
        failure[in_stance[outcome == code]] = failure_code(kind)

    lifted = outcome == STANCE_LIFTOFF
    lanes_lo = in_stance[lifted]
    r, theta, rdot, thetadot = y_end[lifted, 0], y_end[lifted, 1], y_end[lifted, 2], y_end[lifted, 3]
    sin_lo, cos_lo = np.sin(theta), np.cos(theta)
    # The centre of mass at liftoff, above the stance's ground: the hip's, less a rigid body's offset.
    xdot_lo, ydot_lo = dynamics.cartesian_velocity(r, sin_lo, cos_lo, rdot, thetadot)
    x_lo, y_lo = toe_x[lanes_lo] - r * sin_lo, r * cos_lo
    pitch_lo, pitch_rate_lo = np.zeros(lanes_lo.size), np.zeros(lanes_lo.size)
    if rigid is not None:
        pitch_lo, pitch_rate_lo = y_end[lifted, 6], y_end[lifted, 7]
        offset_x, offset_y, hip_vx, hip_vy = hip_beside_centre_of_mass(rigid.body, pitch_lo, pitch_rate_lo)
        xdot_lo, ydot_lo, x_lo, y_lo = xdot_lo - hip_vx, ydot_lo - hip_vy, x_lo - offset_x, y_lo - offset_y
    out["hip_work"][lanes_lo] = y_end[lifted, 4]
    out["damping_loss"][lanes_lo] = y_end[lifted, 5]
    out["spring_loss"][lanes_lo] = dynamics.spring_energy(params, r)
    out["stance"][lanes_lo] = s_end[lifted]
    # The same rules, in the same order, as dynamics.takeoff_failure, then a rigid body's tipping in the rise.
    falls = ydot_lo <= 0.0
    reversals = ~falls & (xdot_lo <= 0.0)
    failure[lanes_lo[falls]] = failure_code(FailureKind.FALL)
    failure[lanes_lo[reversals]] = failure_code(FailureKind.REVERSAL)
    rising = ~falls & ~reversals
    t_rise = ydot_lo[rising] / params.g
    tips = np.zeros(t_rise.size, dtype=bool)
    if rigid is not None:
        tips = tip_times(rigid.body, pitch_lo[rising], pitch_rate_lo[rising]) <= t_rise
        failure[lanes_lo[rising][tips]] = failure_code(FailureKind.TIPPED)
    x_apex, y_apex, _, _ = dynamics.ballistic(
        x_lo[rising], y_lo[rising], xdot_lo[rising], ydot_lo[rising], t_rise, params.g
    )
    beyond = ~tips & limits.apex_exceeded(y_apex, xdot_lo[rising])  # as limits.apex_failure
    failure[lanes_lo[rising][beyond]] = failure_code(FailureKind.STATE_LIMIT)
    ok = ~tips & ~beyond
    lanes_ok = lanes_lo[rising][ok]
    out["y"][lanes_ok] = y_apex[ok]
    out["xdot"][lanes_ok] = xdot_lo[rising][ok]
    out["x"][lanes_ok] = x_apex[ok]
    out["t"][lanes_ok] = t_td[lanes_ok] + s_end[lifted][rising][ok] + t_rise[ok]
    out["pitch"][lanes_ok] = (pitch_lo[rising] + pitch_rate_lo[rising] * t_rise)[ok]
    out["pitch_rate"][lanes_ok] = pitch_rate_lo[rising][ok]
    return BatchStrideResult(
        y=out["y"],
        xdot=out["xdot"],
        failure=failure,
        hip_work=out["hip_work"],
        damping_loss=out["damping_loss"],
        spring_loss=out["spring_loss"],
        stance_time=out["stance"],
        stride_time=out["t"],
        ground=out["ground"],
        x=out["x"],
        saturated=saturated,
        pitch=out["pitch"],
        pitch_rate=out["pitch_rate"],
    )
