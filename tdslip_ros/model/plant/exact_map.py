"""The exact apex-to-apex return map P = P_a o P_s o P_d (paper eqs. 3-7), solved to high accuracy.

Descent (P_d) and ascent (P_a) are ballistic and taken in closed form. Stance (P_s, eq. 2 with the
ramp torque of eq. 18) is integrated by scipy's DOP853 with event location; the stance is split at
the ramp end s = t_f so that no step straddles the kink of the torque. A stance under feedback
(:class:`.stance_laws.StanceFeedback`) is split at its sample instants, where the law sets the torque
held until the next one; the apex's absolute time puts the stride on the sample grid.

Uneven ground, torque saturation, pushes and leg placement errors (:mod:`.perturbations`) enter as
keyword arguments; without them the map is the flat-ground map, bit for bit.

Inputs and states are held to the plausibility limits (:mod:`.limits`) exactly as the 1 kHz stepper and
the batched engine hold them, so the three report the same failure for the same input. An integration
that DOP853 cannot complete is never taken for a result: it ends as ``state_limit`` with scipy's reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from tdslip_ros.model import body_dynamics, dynamics
from tdslip_ros.model.events import FailureKind, HopperState, StrideEnergy
from tdslip_ros.model.limits import PlausibilityLimits, check_tolerances
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody, StanceCommand
from tdslip_ros.model.plant.perturbations import UNPERTURBED, StrideConditions, placed_angle
from tdslip_ros.model.plant.stance_laws import HeldTorque, StanceFeedback, TorqueStream, torque_limit
from tdslip_ros.model.plant.terrain import touchdown

Torque = Callable[[float], float]
"""The hip torque [N m] of one stance segment as a function of the time s since touchdown [s]."""


@dataclass(frozen=True)
class StrideResult:
    """Outcome of one stride from an apex at t = 0 (stride 0).

    apex is the next apex (None on failure) reached at apex_time [s], its height above ``ground`` [m],
    the stance's ground height (the toe's, world frame; None without a touchdown), at x = apex_x [m];
    touchdown, bottom (the first maximum compression) and liftoff are the event states (world frame),
    each with its time ``.t``, or None where the stride did not get there; edge tells a touchdown on a
    vertical face of the terrain. failure_state is the state at the failure. energy holds the stance's
    energy flows whenever the leg lifted off. stance_torques: under stance feedback, the held torques
    [N m] by sample instant [s, absolute], as a recording lists them (the zero hold from touchdown to
    the first sample is not listed); empty for a ramp.
    """

    apex: ApexState | None
    failure: FailureKind | None
    reason: str
    touchdown: HopperState | None
    bottom: HopperState | None
    liftoff: HopperState | None
    apex_time: float | None
    failure_state: HopperState | None
    energy: StrideEnergy | None
    ground: float | None = None
    apex_x: float | None = None
    edge: bool = False
    stance_torques: tuple[tuple[float, float], ...] = ()


def apex_return_map(
    params: HopperParams,
    apex: ApexState,
    command: StanceCommand | StanceFeedback,
    *,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    limits: PlausibilityLimits | None = None,
    conditions: StrideConditions = UNPERTURBED,
    apex_time: float = 0.0,
) -> StrideResult:
    """Next apex from ``apex`` under ``command``, or a named failure (see :mod:`.events`).

    rtol and atol are DOP853's relative and absolute tolerances on the stance state (r [m],
    theta [rad], rdot [m/s], thetadot [rad/s], hip work and damper loss [J]); the defaults give
    apex states and event times to about 1e-12 relative. Events are located by scipy's root finder
    on DOP853's 7th-order dense output. limits (default: the hopper's defaults) bound the motion;
    their max_stance_time [s] is the no_liftoff bound. Raises ParameterError for tolerances outside
    :func:`.limits.check_tolerances` and for an apex beyond the limits.

    ``conditions`` (:class:`.perturbations.StrideConditions`, floats; default flat ground and no
    perturbation): the apex's x and the ground its height ``apex.y`` is above, the terrain, the torque's
    saturation tau_max, a push after the apex and the leg's placement error.

    A rigid body (``params.body``, :class:`.params.RigidBody`) carries the apex's pitch and pitch rate through
    the stride, and fails ``tipped`` past its tip_limit; it runs on flat ground (with saturation, a push and a
    placement error) for now, and refuses other ``conditions`` with ParameterError. A law under stance
    feedback sees its pitch and pitch rate (:class:`.stance_laws.StanceSample`).

    Stance feedback (a :class:`.stance_laws.StanceFeedback` command): the apex is at apex_time [s] on the
    sample clock, whose sample instants are the multiples of the command's sample_period; the law's
    torques are clipped at tau_max and at the limits' max_torque. Times in the result (``.t`` of the
    states, apex_time) stay relative to the apex. ParameterError for a TorqueStream law or a non-finite
    apex_time.
    """
    check_tolerances(rtol, atol)
    if not math.isfinite(apex_time):  # the sample instants would be NaN: the integration would never end
        raise ParameterError(f"apex_time must be finite, got {apex_time!r}")
    if params.body is not None:
        return _rigid_body_stride(
            params, params.body, apex, command, rtol, atol, limits, conditions, apex_time
        )
    if apex.pitch != 0.0 or apex.pitch_rate != 0.0:
        raise ParameterError(
            f"the apex has a pitch ({apex.pitch!r} rad, {apex.pitch_rate!r} rad/s), but the hopper's body is "
            f"fixed: give HopperParams a RigidBody"
        )
    x, ground, terrain = conditions.x, conditions.ground, conditions.terrain
    tau_max, push, angle_error = conditions.tau_max, conditions.push, conditions.angle_error
    if isinstance(command, StanceFeedback) and isinstance(command.law, TorqueStream):
        raise ParameterError("the exact map cannot run a torque stream: replay it with RecordedTorques")
    limits = PlausibilityLimits.of(params, limits)
    limits.check_apex(apex)
    t_limit = limits.max_stance_time
    flat = terrain.is_flat
    if ground is None:
        ground = 0.0 if flat else terrain.height_at(x)
    height = None if flat else terrain.height_at
    y_apex = ground + apex.y
    xdot = apex.xdot + push
    angle = placed_angle(command.touchdown_angle, angle_error)
    sin_td, cos_td = math.sin(angle), math.cos(angle)
    y_td = dynamics.touchdown_height(params, cos_td)
    saturation = None if math.isinf(tau_max) else tau_max

    def result(
        failure: FailureKind | None,
        reason: str,
        failure_state: HopperState | None,
        touchdown: HopperState | None = None,
        bottom: HopperState | None = None,
        liftoff: HopperState | None = None,
        energy: StrideEnergy | None = None,
        next_apex: ApexState | None = None,
        apex_time: float | None = None,
        apex_x: float | None = None,
        stance_torques: tuple[tuple[float, float], ...] = (),
    ) -> StrideResult:
        stance_ground = None if touchdown is None else touchdown.toe_y
        return StrideResult(
            next_apex,
            failure,
            reason,
            touchdown,
            bottom,
            liftoff,
            apex_time,
            failure_state,
            energy,
            stance_ground,
            apex_x,
            edge,
            stance_torques,
        )

    def flight_state(t: float) -> HopperState:
        x_t, y_t, _, ydot_t = dynamics.ballistic(x, y_apex, xdot, 0.0, t, params.g)
        return dynamics.flight_hopper_state(params, t, 0, x_t, y_t, xdot, ydot_t, angle, height)

    edge = False
    pushed_out = None if push == 0.0 else limits.push_failure(apex.y, apex.xdot, push)
    if pushed_out is not None:
        return result(*pushed_out, flight_state(0.0))
    if flat:
        stubbing = dynamics.toe_stubbing(y_apex, y_td)
        if stubbing is not None:
            return result(*stubbing, flight_state(0.0))
        t_td = dynamics.fall_time(y_apex, 0.0, y_td, params.g)
        toe_y = 0.0
    else:
        x_a, y_a, xdot_a, sin_a, cos_a = (np.array([v]) for v in (x, y_apex, xdot, sin_td, cos_td))
        landing = touchdown(terrain, x_a, y_a, xdot_a, sin_a, cos_a, params.r0, params.g)
        if landing.stubbed[0]:
            toe_x0 = x + params.r0 * sin_td
            ground0 = float(landing.placement_ground[0])
            return result(
                *dynamics.toe_below_ground(y_apex, ground0 + y_td, toe_x0, ground0), flight_state(0.0)
            )
        t_td, toe_y, edge = float(landing.t[0]), float(landing.toe_y[0]), bool(landing.edge[0])
    x_td, y_fall, _, ydot_td = dynamics.ballistic(x, y_apex, xdot, 0.0, t_td, params.g)
    if isinstance(command, StanceCommand):
        beyond_limits = limits.torque_failure(command.tau0)
        if beyond_limits is not None:  # the hip cannot act: the stride ends as the leg meets the ground
            state = dynamics.flight_hopper_state(params, t_td, 0, x_td, y_fall, xdot, ydot_td, angle, height)
            return result(*beyond_limits, state)
    toe_x = x_td + params.r0 * sin_td if flat else float(landing.toe_x[0])
    rdot_td, thetadot_td = dynamics.polar_velocity(params.r0, sin_td, cos_td, xdot, ydot_td)

    def stance_state(s: float, y: np.ndarray, tau: float) -> HopperState:
        return dynamics.stance_hopper_state(
            params,
            t_td + s,
            0,
            toe_x,
            float(y[0]),
            float(y[1]),
            float(y[2]),
            float(y[3]),
            float(tau),
            toe_y,
            height,
        )

    y0 = np.array([params.r0, angle, rdot_td, thetadot_td, 0.0, 0.0])
    segments = _stance_segments(command, saturation, limits, t_limit, apex_time + t_td, y0)
    touchdown_state = stance_state(0.0, y0, segments.torque_at_touchdown)
    reversal = dynamics.touchdown_reversal(thetadot_td)
    if reversal is not None:
        return result(*reversal, touchdown_state, touchdown_state)

    outcome = _integrate_stance(params, segments, y0, t_limit, rtol, atol)
    bottom = None if outcome.bottom is None else stance_state(*outcome.bottom)
    end_state = stance_state(outcome.s_end, outcome.y_end, outcome.tau_end)
    torques = segments.record if isinstance(segments, _SampledSegments) else ()
    if outcome.terminal == "failed":
        return result(
            FailureKind.STATE_LIMIT,
            f"the stance integration failed at {outcome.s_end:.6g} s into stance: {outcome.message}",
            end_state,
            touchdown_state,
            bottom,
            stance_torques=torques,
        )
    if outcome.terminal is None:
        return result(
            *dynamics.no_liftoff(t_limit), end_state, touchdown_state, bottom, stance_torques=torques
        )
    if outcome.terminal != "liftoff":
        ended = dynamics.stance_failure(outcome.terminal, outcome.s_end)
        return result(*ended, end_state, touchdown_state, bottom, stance_torques=torques)

    r_lo = float(outcome.y_end[0])
    energy = StrideEnergy(
        hip_work=float(outcome.y_end[4]),
        damping_loss=float(outcome.y_end[5]),
        spring_loss=dynamics.spring_energy(params, r_lo),
    )
    liftoff = end_state
    failure = dynamics.takeoff_failure(liftoff.xdot, liftoff.ydot)
    if failure is not None:
        return result(*failure, liftoff, touchdown_state, bottom, liftoff, energy, stance_torques=torques)
    t_rise = liftoff.ydot / params.g
    # The next apex above the stance's ground: from the liftoff height above the toe.
    y_liftoff = r_lo * math.cos(float(outcome.y_end[1]))
    apex_x, y_next, _, _ = dynamics.ballistic(
        liftoff.x, y_liftoff, liftoff.xdot, liftoff.ydot, t_rise, params.g
    )
    failure = limits.apex_failure(y_next, liftoff.xdot)
    if failure is not None:
        return result(*failure, liftoff, touchdown_state, bottom, liftoff, energy, stance_torques=torques)
    next_apex = ApexState(y=y_next, xdot=liftoff.xdot)
    return result(
        None,
        "",
        None,
        touchdown_state,
        bottom,
        liftoff,
        energy,
        next_apex,
        liftoff.t + t_rise,
        apex_x,
        torques,
    )


@dataclass(frozen=True)
class _StanceEvent:
    """One of dynamics.stance_event_values in solve_ivp's event protocol (crossing from > 0 to <= 0)."""

    params: HopperParams
    index: int
    terminal: bool
    direction: float = -1.0

    def __call__(self, s: float, y: np.ndarray) -> float:
        r, theta, rdot, thetadot = float(y[0]), float(y[1]), float(y[2]), float(y[3])
        if self.index == len(dynamics.STANCE_EVENT_NAMES):  # "tipped": only a rigid body's state has a pitch
            assert self.params.body is not None
            return body_dynamics.tip_margin(self.params.body, float(y[6]))
        return dynamics.stance_event_values(self.params, r, math.cos(theta), rdot, thetadot)[self.index]


@dataclass(frozen=True)
class _StanceOutcome:
    s_end: float
    y_end: np.ndarray
    terminal: (
        str | None
    )  # "liftoff", "reversal", "fall", "tipped", "failed" (DOP853 gave up), None at the limit
    bottom: tuple[float, np.ndarray, float] | None  # s, state, torque
    tau_end: float
    message: str = ""  # scipy's reason when the integration failed


class _RampSegments:
    """The ramp of eq. 18, saturated at tau_max (None: not): segments end at its kinks, fixed in advance."""

    def __init__(self, command: StanceCommand, tau_max: float | None, t_limit: float) -> None:
        tau0, t_f = command.tau0, command.t_f

        def ramp(s: float) -> float:
            return float(dynamics.hip_torque(tau0, t_f, s, tau_max))

        self._torque: Torque = ramp
        self.torque_at_touchdown = ramp(0.0)
        # The ramp and the torque-free rest of the stance are separate segments, and so is a saturated
        # start of the ramp: a kink would otherwise cost DOP853 its order there.
        kinks = [t_f] if tau_max is None else [float(dynamics.saturation_end(tau0, t_f, tau_max)), t_f]
        self._ends = [*sorted({kink for kink in kinks if 0.0 < kink < t_limit}), t_limit]

    def next(self, s: float, y: np.ndarray) -> tuple[float, Torque]:
        """The segment from s (a kink or touchdown): its end and its torque."""
        return next(end for end in self._ends if end > s), self._torque


class _SampledSegments:
    """A stance under feedback (:mod:`.stance_laws`): zero torque from touchdown to the first sample,
    then one segment per sample period, with the torque the law decides at its start."""

    def __init__(
        self, command: StanceFeedback, t_touchdown: float, limit: float, tau_max: float | None, y: np.ndarray
    ) -> None:
        self._hold = HeldTorque(command, t_touchdown, limit, tau_max, tuple(float(v) for v in y))
        self.torque_at_touchdown = self._hold.held

    @property
    def record(self) -> tuple[tuple[float, float], ...]:
        return tuple(self._hold.record)

    def next(self, s: float, y: np.ndarray) -> tuple[float, Torque]:
        """The segment from s (touchdown or a sample instant, sampled here): its end and held torque."""
        if s > 0.0 and s == self._hold.next_sample():
            self._hold.sample(tuple(float(v) for v in y))
        held = self._hold.held
        return self._hold.next_sample(), lambda _: held


def _stance_segments(
    command: StanceCommand | StanceFeedback,
    saturation: float | None,
    limits: PlausibilityLimits,
    t_limit: float,
    t_touchdown: float,
    y0: np.ndarray,
) -> _RampSegments | _SampledSegments:
    """The stance's torque segments: the ramp's, or a law's sampled from the touchdown at t_touchdown [s, the
    sample clock] in the state y0."""
    if isinstance(command, StanceCommand):
        return _RampSegments(command, saturation, t_limit)
    limit = torque_limit(saturation, limits.max_torque)
    return _SampledSegments(command, t_touchdown, limit, saturation, y0)


def _integrate_stance(
    params: HopperParams,
    segments: _RampSegments | _SampledSegments,
    y0: np.ndarray,
    t_limit: float,
    rtol: float,
    atol: float,
) -> _StanceOutcome:
    body = params.body

    def rhs(torque: Torque) -> Callable[[float, np.ndarray], np.ndarray]:
        def field(s: float, y: np.ndarray) -> np.ndarray:
            r, theta, rdot, thetadot = float(y[0]), float(y[1]), float(y[2]), float(y[3])
            if body is None:
                return np.array(
                    dynamics.stance_derivatives(
                        params, r, math.sin(theta), math.cos(theta), rdot, thetadot, torque(s)
                    )
                )
            pitch, pitch_rate = float(y[6]), float(y[7])
            return np.array(
                body_dynamics.rigid_stance_derivatives(
                    params,
                    body,
                    r,
                    math.sin(theta),
                    math.cos(theta),
                    rdot,
                    thetadot,
                    math.sin(pitch),
                    math.cos(pitch),
                    pitch_rate,
                    torque(s),
                )
            )

        return field

    names = dynamics.STANCE_EVENT_NAMES if body is None else body_dynamics.RIGID_STANCE_EVENT_NAMES
    events = [_StanceEvent(params, index, terminal=name != "bottom") for index, name in enumerate(names)]
    bottom: tuple[float, np.ndarray, float] | None = None
    s_start, y = 0.0, y0
    while s_start < t_limit:
        s_stop, torque = segments.next(s_start, y)
        s_stop = min(s_stop, t_limit)
        sol = solve_ivp(
            rhs(torque), (s_start, s_stop), y, method="DOP853", rtol=rtol, atol=atol, events=events
        )
        if bottom is None and sol.t_events[0].size:
            s_bottom = float(sol.t_events[0][0])
            bottom = (s_bottom, sol.y_events[0][0], torque(s_bottom))
        if sol.status == -1:  # the last accepted state is where it gave up
            s_end = float(sol.t[-1])
            return _StanceOutcome(s_end, sol.y[:, -1], "failed", bottom, torque(s_end), sol.message)
        for index, name in enumerate(names[1:], start=1):
            if sol.t_events[index].size:
                s_end = float(sol.t_events[index][0])
                return _StanceOutcome(s_end, sol.y_events[index][0], name, bottom, torque(s_end))
        s_start, y = s_stop, sol.y[:, -1]
    return _StanceOutcome(t_limit, y, None, bottom, torque(t_limit))


def _rigid_body_stride(
    params: HopperParams,
    body: RigidBody,
    apex: ApexState,
    command: StanceCommand | StanceFeedback,
    rtol: float,
    atol: float,
    limits: PlausibilityLimits | None,
    conditions: StrideConditions,
    apex_time: float,
) -> StrideResult:
    """:func:`apex_return_map` for a rigid body: the centre of mass is ballistic in flight and the pitch turns
    at its constant rate; the stance adds (phi, phidot) to the fixed body's state
    (:func:`.body_dynamics.rigid_stance_derivatives`)."""
    if isinstance(command, StanceFeedback) and isinstance(command.law, TorqueStream):
        raise ParameterError("the exact map cannot run a torque stream: replay it with RecordedTorques")
    if not conditions.terrain.is_flat or conditions.ground not in (None, 0.0):
        raise ParameterError("a rigid body runs on flat ground at height 0 for now")
    limits = PlausibilityLimits.of(params, limits)
    limits.check_apex(apex)
    if abs(apex.pitch) >= body.tip_limit:
        raise ParameterError(
            f"the apex pitch {apex.pitch!r} rad is past the body's tip_limit {body.tip_limit!r}"
        )
    t_limit = limits.max_stance_time
    x, xdot, g = conditions.x, apex.xdot + conditions.push, params.g
    pitch0, pitch_rate = apex.pitch, apex.pitch_rate
    angle = placed_angle(command.touchdown_angle, conditions.angle_error)
    sin_td, cos_td = math.sin(angle), math.cos(angle)
    saturation = None if math.isinf(conditions.tau_max) else conditions.tau_max

    def flight_state(t: float) -> HopperState:
        x_t, y_t, _, ydot_t = dynamics.ballistic(x, apex.y, xdot, 0.0, t, g)
        pitch = pitch0 + pitch_rate * t
        return body_dynamics.rigid_flight_hopper_state(
            params, body, t, 0, x_t, y_t, xdot, ydot_t, pitch, pitch_rate, angle
        )

    segments: _RampSegments | _SampledSegments | None = None

    def stance_torques() -> tuple[tuple[float, float], ...]:
        return segments.record if isinstance(segments, _SampledSegments) else ()

    def failed(
        failure: tuple[FailureKind, str],
        state: HopperState,
        touchdown: HopperState | None = None,
        bottom: HopperState | None = None,
        liftoff: HopperState | None = None,
        energy: StrideEnergy | None = None,
    ) -> StrideResult:
        ground = None if touchdown is None else 0.0
        return StrideResult(
            None,
            failure[0],
            failure[1],
            touchdown,
            bottom,
            liftoff,
            None,
            state,
            energy,
            ground,
            stance_torques=stance_torques(),
        )

    if conditions.push != 0.0:
        pushed_out = limits.push_failure(apex.y, apex.xdot, conditions.push)
        if pushed_out is not None:
            return failed(pushed_out, flight_state(0.0))
    t_td = body_dynamics.rigid_touchdown_time(params, body, apex.y, pitch0, pitch_rate, cos_td)
    if t_td is None:
        hip_y = apex.y + body_dynamics.hip_offset(body, math.sin(pitch0), math.cos(pitch0))[1]
        stubbing = dynamics.toe_stubbing(hip_y, dynamics.touchdown_height(params, cos_td))
        assert stubbing is not None
        return failed(stubbing, flight_state(0.0))
    t_tip = body_dynamics.pitch_limit_time(body, pitch0, pitch_rate)
    if t_tip <= t_td:
        state = flight_state(t_tip)
        return failed(
            body_dynamics.tipped(state.pitch, body.tip_limit, "in the flight before touchdown"), state
        )
    if isinstance(command, StanceCommand):
        beyond_limits = limits.torque_failure(command.tau0)
        if beyond_limits is not None:
            return failed(beyond_limits, flight_state(t_td))
    x_td, _, _, ydot_td = dynamics.ballistic(x, apex.y, xdot, 0.0, t_td, g)
    pitch_td = pitch0 + pitch_rate * t_td
    sin_p, cos_p = math.sin(pitch_td), math.cos(pitch_td)
    offset_x = body_dynamics.hip_offset(body, sin_p, cos_p)[0]
    relative_vx, relative_vy = body_dynamics.pitch_velocity_offset(body, sin_p, cos_p, pitch_rate)
    toe_x = x_td + offset_x + params.r0 * sin_td
    rdot_td, thetadot_td = dynamics.polar_velocity(
        params.r0, sin_td, cos_td, xdot + relative_vx, ydot_td + relative_vy
    )

    def stance_state(s: float, y: np.ndarray, tau: float) -> HopperState:
        r, theta, rdot, thetadot, pitch, rate = (float(y[index]) for index in (0, 1, 2, 3, 6, 7))
        return body_dynamics.rigid_stance_hopper_state(
            params, body, t_td + s, 0, toe_x, r, theta, rdot, thetadot, pitch, rate, float(tau)
        )

    y0 = np.array([params.r0, angle, rdot_td, thetadot_td, 0.0, 0.0, pitch_td, pitch_rate])
    segments = _stance_segments(command, saturation, limits, t_limit, apex_time + t_td, y0)
    touchdown_state = stance_state(0.0, y0, segments.torque_at_touchdown)
    reversal = dynamics.touchdown_reversal(thetadot_td)
    if reversal is not None:
        return failed(reversal, touchdown_state, touchdown_state)
    outcome = _integrate_stance(params, segments, y0, t_limit, rtol, atol)
    bottom = None if outcome.bottom is None else stance_state(*outcome.bottom)
    end_state = stance_state(outcome.s_end, outcome.y_end, outcome.tau_end)
    if outcome.terminal == "failed":
        reason = f"the stance integration failed at {outcome.s_end:.6g} s into stance: {outcome.message}"
        return failed((FailureKind.STATE_LIMIT, reason), end_state, touchdown_state, bottom)
    if outcome.terminal is None:
        return failed(dynamics.no_liftoff(t_limit), end_state, touchdown_state, bottom)
    if outcome.terminal == "tipped":
        when = f"{outcome.s_end:.6g} s into stance"
        return failed(
            body_dynamics.tipped(end_state.pitch, body.tip_limit, when), end_state, touchdown_state, bottom
        )
    if outcome.terminal != "liftoff":
        return failed(
            dynamics.stance_failure(outcome.terminal, outcome.s_end), end_state, touchdown_state, bottom
        )
    liftoff = end_state
    energy = StrideEnergy(
        hip_work=float(outcome.y_end[4]),
        damping_loss=float(outcome.y_end[5]),
        spring_loss=dynamics.spring_energy(params, liftoff.r),
    )
    failure = dynamics.takeoff_failure(liftoff.xdot, liftoff.ydot)
    if failure is not None:
        return failed(failure, liftoff, touchdown_state, bottom, liftoff, energy)
    t_rise = liftoff.ydot / g
    t_tip = body_dynamics.pitch_limit_time(body, liftoff.pitch, liftoff.pitch_rate)
    if t_tip <= t_rise:
        x_t, y_t, _, ydot_t = dynamics.ballistic(liftoff.x, liftoff.y, liftoff.xdot, liftoff.ydot, t_tip, g)
        state = body_dynamics.rigid_flight_hopper_state(
            params,
            body,
            liftoff.t + t_tip,
            0,
            x_t,
            y_t,
            liftoff.xdot,
            ydot_t,
            liftoff.pitch + liftoff.pitch_rate * t_tip,
            liftoff.pitch_rate,
            angle,
        )
        tip = body_dynamics.tipped(state.pitch, body.tip_limit, "in the flight after liftoff")
        return failed(tip, state, touchdown_state, bottom, liftoff, energy)
    apex_x, y_next, _, _ = dynamics.ballistic(liftoff.x, liftoff.y, liftoff.xdot, liftoff.ydot, t_rise, g)
    failure = limits.apex_failure(y_next, liftoff.xdot)
    if failure is not None:
        return failed(failure, liftoff, touchdown_state, bottom, liftoff, energy)
    next_apex = ApexState(
        y=y_next,
        xdot=liftoff.xdot,
        pitch=liftoff.pitch + liftoff.pitch_rate * t_rise,
        pitch_rate=liftoff.pitch_rate,
    )
    return StrideResult(
        next_apex,
        None,
        "",
        touchdown_state,
        bottom,
        liftoff,
        liftoff.t + t_rise,
        None,
        energy,
        0.0,
        apex_x,
        stance_torques=stance_torques(),
    )
