"""Fixed-step TD-SLIP plant for the 1 kHz ROS node: one call advances exactly one tick.

Flight is ballistic and taken in closed form, so apex and touchdown are exact. Stance is
integrated by classical RK4 (as in the paper) on a fixed grid of ``substeps`` equal sub-steps per
tick; a stance piece also ends at touchdown, at the ramp end s = t_f (the torque has a kink
there) and at the no_liftoff bound. A stance event (bottom, liftoff, reversal, fall) inside a piece
is located on the sub-step itself: the RK4 step from the piece start is re-taken with length
sigma, and sigma is solved for a zero of the event function by safeguarded Newton iteration, to
~1e-14 s (2-3 iterations). The phase switches at the event and the tick is finished from there;
events are never rounded to the tick. This module is the tick loop; what a stance integrates (the RK4 step,
the events, the state), per kind of body, is a model of :mod:`.stance_models`.

Why 4 sub-steps per 1 ms tick: RK4's error scales with (omega0 h)^4. Against a DOP853 solve at
rtol 1e-13 over 20 strides (kbar = 36, zeta0 = 0.08, energy-regulated, test_plant_stepper.py), the
worst event-time error is 2.1e-8 s with 1 sub-step, 1.3e-9 s with 2 and 8e-11 s with 4 (apex
states 1.4e-9, 9e-11, 5e-12 dimensionless): 1 ms RK4 alone misses the 1e-9 s target, 4 sub-steps
meet it with margin. What a stance tick costs: bench/bench_stepper.py (numbers in docs/benchmarks.md).

Plausibility limits (:mod:`.limits`): the stepper refuses to start from an apex beyond them; a touchdown
under a torque beyond the actuator limit, or a liftoff towards an apex beyond the limits, ends the run as
``state_limit``, so every state it reports is finite and every flight bounded. What else it refuses (a leg
too fast for its sub-step, a body it does not run, a rigid body's leg that cannot be placed) is
:mod:`.stepper_bounds`.

Stance feedback (:class:`.stance_laws.StanceFeedback`, its sample period the tick dt): the sample
instants are the tick boundaries, so they are grid points of the sub-steps already. At the start of each
tick in stance the stepper samples the law (a :class:`.stance_laws.TorqueStream` takes the torque last
given to :meth:`FixedStepStepper.hold_torque`, the plant node's stream), and the hip holds that torque
through the tick; from touchdown to the first tick boundary it holds zero (:mod:`.stance_laws`).

Toe stubbing: the command for the next touchdown may be changed until touchdown (set_command),
e.g. by a controller that answers the apex event. The stepper therefore declares toe_stubbing
at the start of the first tick, after the apex, that begins with the body below the touchdown
height of the command in force (the initial apex counts as passed at t = 0).

Perturbations (:mod:`.perturbations`, the same description the exact map and the batched engine take)
are realised per stride k from the draws of trajectory ``trajectory``: at each apex the sensor's reading
(:attr:`FixedStepStepper.measured_apex`) and the leg's placement error are drawn and the push is applied
right after the apex; the toe lands on the terrain (:func:`.terrain.touchdown`, planned once per flight and
command) and the hip torque saturates at tau_max (a further kink where the stance is split). On uneven
ground toe stubbing means the toe, placed at the apex, is below the ground under it; a command is too late
when its toe would have met the ground before it arrived.

A rigid body (``params.body``, docs/rotating_body.md) runs on flat ground with the exact map's behaviour
(``exact_map._rigid_body_stride``). In flight the centre of mass is ballistic and the pitch turns at its
constant rate; the leg touches down at :func:`~.rigid_touchdown_time` (planned once per flight and
angle), and the body tips at :func:`~.pitch_limit_time` if that comes first (after a liftoff: before
the apex). The leg hangs from the hip, so toe stubbing and set_command's tests judge the hip. The stance
takes the 8-value state of :func:`~.rigid_stance_derivatives` through the same RK4 on the same grid
(a stance law sees its pitch and rate) and locates ``tipped`` (:func:`~.tip_margin`) as the other
events. Against the exact map over 24 ramp strides of 5 bodies (test_plant_stepper_rigid_body.py), 4
sub-steps give apex states to 4e-11 (the pitch rate; 1 sub-step 1e-8, 2: 7e-10, 8: 3e-12), event times to
4e-12 s and the stance's energy balance to 4e-12 of the apex energy. Saturation, pushes and placement
errors run; uneven terrain and apex noise are refused (:func:`.check_body`). What a rigid stance tick costs:
bench/bench_rigid_body.py.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from tdslip_ros.model import body_dynamics, dynamics
from tdslip_ros.model.events import Event, EventKind, FailureKind, HopperState, Phase, StrideEnergy
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody, StanceCommand
from tdslip_ros.model.plant.flight_landing import FlightReference, Landing, plan_landing, rigid_stubbing
from tdslip_ros.model.plant.perturbations import Perturbations, placed_angle
from tdslip_ros.model.plant.stance_laws import HeldTorque, StanceFeedback, TorqueStream, torque_limit
from tdslip_ros.model.plant.stance_models import PointMassStance, RigidBodyStance, StanceModel, StanceVector
from tdslip_ros.model.plant.stepper_bounds import check_body, check_rigid_placement, check_step
from tdslip_ros.model.plant.terrain import Terrain

DEFAULT_SUBSTEPS = 4
_GRID_SLACK = 1e-6  # fraction of a sub-step below which the stepper does not stop short of a grid point


class FixedStepStepper:
    """TD-SLIP plant advanced one tick of dt seconds per :meth:`step`, from an apex at t = 0.

    Time is tick * dt, computed from the tick count so it does not drift. stride counts apexes
    (the initial apex is stride 0; each APEX event carries the new count). After a failure the
    stepper refuses to step.
    """

    def __init__(
        self,
        params: HopperParams,
        apex: ApexState,
        command: StanceCommand | StanceFeedback,
        dt: float = 1e-3,
        x0: float = 0.0,
        *,
        substeps: int = DEFAULT_SUBSTEPS,
        limits: PlausibilityLimits | None = None,
        perturbations: Perturbations | None = None,
        trajectory: int = 0,
    ) -> None:
        """Start at ``apex`` (ParameterError when beyond ``limits``, default: the hopper's defaults),
        apex.y above the ground under the body at x0.

        Raises ParameterError too for a dt or a number of substeps that cannot resolve the motion, and for
        perturbations with per-lane values. ``trajectory`` chooses the random draws (module docstring).
        A rigid body (``params.body``) starts at the apex's pitch and pitch rate; ParameterError for what the
        stepper does not run for it (:func:`.check_body`), and for a pitch on the fixed body.
        """
        self._limits = PlausibilityLimits.of(params, limits)
        check_step(self._limits, apex.pitch_rate, dt, substeps)
        self._limits.check_apex(apex)
        check_body(params, apex, perturbations)
        if not math.isfinite(x0):
            raise ParameterError(f"x0 must be a finite number, got {x0!r}")
        self._params = params
        self._dt = dt
        self._check_sample_period(command)
        self._command = command
        self._substeps = substeps
        self._stance_limit = self._limits.max_stance_time
        self._tick = 0
        self._stride = 0
        self._failed: FailureKind | None = None
        self._failure_state: HopperState | None = None
        self._last_energy: StrideEnergy | None = None
        self._pending_energy: StrideEnergy | None = None
        self._phase = Phase.FLIGHT
        # Flight: ballistic from the reference state (t, x, y, xdot, ydot), the last liftoff or apex.
        self._descending = True
        # Stance: toe position, touchdown time, time since touchdown and the stance vector (its model's).
        self._toe_x = 0.0
        self._t_touchdown = 0.0
        self._s = 0.0
        self._stance: StanceVector = ()
        self._stance_tau0, self._stance_t_f, self._stance_saturation_end = 0.0, math.inf, math.inf
        # Stance feedback: the hold of the current (or last) stance under a law, and the streamed torque.
        self._hold: HeldTorque | None = None
        self._streamed = 0.0
        # Perturbations: None where off (the flat-ground path, bit for bit).
        self._perturbations = perturbations if perturbations is not None and perturbations.active else None
        if self._perturbations is not None:
            self._perturbations.scalars()  # ParameterError for per-lane values
        self._trajectory = trajectory
        self._terrain: Terrain | None = None
        self._tau_max: float | None = None
        if self._perturbations is not None:
            terrain = self._perturbations.terrain
            self._terrain = None if terrain.is_flat else terrain
            self._tau_max = None if not self._perturbations.saturates else float(self._perturbations.tau_max)
        self._torque_limit = torque_limit(self._tau_max, self._limits.max_torque)
        self._ground = 0.0 if self._terrain is None else self._terrain.height_at(x0)
        self._toe_y = 0.0
        self._landing: Landing | None = None  # planned once per flight and touchdown angle
        self._angle_error = 0.0
        self._place_leg()
        self._saturated_strides = 0
        self._pending_failure: tuple[HopperState, FailureKind, str] | None = None
        self._flight_ref: FlightReference = (0.0, x0, self._ground + apex.y, apex.xdot, 0.0)
        # A rigid body (None: the fixed body): its (pitch, pitch rate) at the flight reference's time (0 for
        # the fixed body), and the touchdown time planned for a flight: (apex time, angle, time from the apex,
        # None when the toe stubs).
        self._body = params.body
        self._pitch_ref = (apex.pitch, apex.pitch_rate)
        self._rigid_landing: tuple[float, float, float | None] | None = None
        self._stance_model: StanceModel = (
            PointMassStance(params, self._torque, self._height)
            if self._body is None
            else RigidBodyStance(params, self._body, self._torque)
        )
        self._begin_stride(0.0)

    @property
    def limits(self) -> PlausibilityLimits:
        return self._limits

    @property
    def t(self) -> float:
        """Current simulated time [s] (the failure time after a failure)."""
        if self._failure_state is not None:
            return self._failure_state.t
        return self._tick * self._dt

    @property
    def stride(self) -> int:
        return self._stride

    @property
    def command(self) -> StanceCommand | StanceFeedback:
        return self._command

    @property
    def past_touchdown(self) -> bool:
        """True from this stride's touchdown until the next apex (in stance, or rising after it): a
        command set now is for the next stride's touchdown."""
        return self._phase is Phase.STANCE or not self._descending

    @property
    def failed(self) -> FailureKind | None:
        return self._failed

    @property
    def apex_state(self) -> HopperState:
        """The state at the latest apex, before its push (world frame)."""
        return self._apex_state

    @property
    def measured_apex(self) -> tuple[float, float]:
        """The latest apex as the sensor reports it: (height [m, world frame], forward speed [m/s])."""
        return self._measured

    @property
    def ground(self) -> float:
        """The ground height [m] of the last stance (at the initial apex: under the body)."""
        return self._ground

    @property
    def push(self) -> float:
        """The push [m/s] applied right after the latest apex."""
        return self._push

    @property
    def placed_angle(self) -> float:
        """The touchdown angle [rad] the leg lands at with the command in force (its error included)."""
        return self._placed_angle

    @property
    def saturated_strides(self) -> int:
        """Strides in which the hip saturated: touchdowns whose |tau0| exceeded the torque limit tau_max,
        and stances under feedback one of whose samples it clipped."""
        return self._saturated_strides + (self._hold is not None and self._hold.saturated)

    @property
    def stance_torques(self) -> tuple[tuple[float, float], ...]:
        """The samples of the current or last stance under feedback, (time [s], held torque [N m]) as a
        recording lists them (the zero hold from touchdown to the first sample is not listed); empty when
        that stance had a ramp."""
        return () if self._hold is None else tuple(self._hold.record)

    @property
    def torque_due(self) -> bool:
        """True when the next step starts at a sample instant of a :class:`.stance_laws.TorqueStream` stance:
        the torque to hold from there must be given (:meth:`hold_torque`) before that step."""
        hold = self._hold
        return (
            self._phase is Phase.STANCE
            and self._failed is None
            and hold is not None
            and self._s == hold.next_sample()
            and isinstance(self._command, StanceFeedback)
            and isinstance(self._command.law, TorqueStream)
        )

    @property
    def last_stride_energy(self) -> StrideEnergy | None:
        """Energy flows of the stance before the latest apex (None before the first such apex)."""
        return self._last_energy

    @property
    def state(self) -> HopperState:
        """State at the current time (at the failure, after a failure)."""
        if self._failure_state is not None:
            return self._failure_state
        if self._phase is Phase.STANCE:
            return self._stance_state(self._s, self._stance)
        return self._flight_state(self.t)

    def set_command(self, command: StanceCommand | StanceFeedback) -> None:
        """Use ``command`` for the next touchdown.

        Raises ParameterError in stance, when the angle fails the controllers' own admissibility test
        for this flight's apex (:func:`dynamics.can_place_leg`, touchdown at least
        PLACEMENT_LEAD_TIME after the apex, judged on the apex the controller was given: the measured one,
        above the ground of the last stance), and when the command comes too late: the body is already
        below the new touchdown height r0 cos(theta_td) (on uneven ground: the toe would already have met
        the ground). A toe placed below the ground at the apex is not refused: it is toe stubbing. Stance
        feedback must sample at the tick, dt. A rigid body's leg is judged from its hip
        (:func:`.check_rigid_placement`).
        """
        if self._phase is Phase.STANCE:
            raise ParameterError("the stance command cannot change during stance")
        self._check_sample_period(command)
        if self._body is not None:
            check_rigid_placement(
                self._params,
                self._body,
                command.touchdown_angle,
                float(placed_angle(command.touchdown_angle, self._angle_error)),
                self._flight_ref,
                self._pitch_ref,
                self.t,
                self._descending,
            )
            self._command = command
            self._place_leg()
            return
        _, _, y_ref, _, ydot_ref = self._flight_ref
        apex = y_ref + ydot_ref**2 / (2.0 * self._params.g)  # descending, the reference is the apex
        if self._perturbations is not None and self._descending:
            apex = self._measured[0]
        cos_td = math.cos(command.touchdown_angle)
        y_td = dynamics.touchdown_height(self._params, cos_td)
        if not dynamics.can_place_leg(self._params.r0, self._params.g, apex - self._ground, cos_td):
            raise ParameterError(
                f"touchdown_angle {command.touchdown_angle!r} rad needs the body at {y_td:.6g} m, but it "
                f"reaches at most {apex - self._ground:.6g} m in this flight, and placement needs a fall of "
                f"{dynamics.PLACEMENT_LEAD_TIME:g} s from the apex to touchdown"
            )
        if self._terrain is None:
            if self._descending and self._flight_state(self.t).y < y_td:
                raise ParameterError(
                    f"touchdown_angle {command.touchdown_angle!r} rad needs the body at {y_td:.6g} m, "
                    f"but it is already below, at {self._flight_state(self.t).y:.6g} m"
                )
        elif self._descending:
            landing = self._plan_landing_at(float(placed_angle(command.touchdown_angle, self._angle_error)))
            if not landing.stubbed and self._flight_ref[0] + landing.t < self.t:
                raise ParameterError(
                    f"touchdown_angle {command.touchdown_angle!r} rad puts the toe on the ground at "
                    f"t = {self._flight_ref[0] + landing.t:.6g} s, before the command arrived "
                    f"({self.t:.6g} s)"
                )
        self._command = command
        self._place_leg()

    def hold_torque(self, tau: float) -> None:
        """The torque [N m] a :class:`.stance_laws.TorqueStream` stance holds from the next sample instant
        (the next tick's start) on, until replaced or until liftoff: the plant node's stream, clipped like a
        law's output. ParameterError for a torque that is not a finite number."""
        if not math.isfinite(tau):
            raise ParameterError(f"a held torque must be finite, got {tau!r}")
        self._streamed = float(tau)

    def _check_sample_period(self, command: StanceCommand | StanceFeedback) -> None:
        if isinstance(command, StanceFeedback) and command.sample_period != self._dt:
            raise ParameterError(
                f"the stance feedback samples every {command.sample_period!r} s, but the stepper's tick is "
                f"{self._dt!r} s: the sample instants must be its tick boundaries"
            )

    def step(self) -> list[Event]:
        """Advance one tick; return the events inside it in time order."""
        if self._failed is not None:
            raise RuntimeError(f"the stepper has failed ({self._failed.value}) and cannot step")
        t_start, t_end = self._tick * self._dt, (self._tick + 1) * self._dt
        events: list[Event] = []
        if self._pending_failure is not None:  # a push at the initial apex beyond the limits
            self._fail(events, *self._pending_failure)
            return events
        if self._phase is Phase.FLIGHT and self._descending:
            stubbing = self._stubbing()
            if stubbing is not None:
                self._fail(events, self._flight_state(t_start), *stubbing)
                return events
        hold = self._hold
        if self._phase is Phase.STANCE and hold is not None and self._s == hold.next_sample():
            hold.sample(self._stance, self._streamed)
        t = t_start
        while t < t_end and self._failed is None:
            if self._phase is Phase.FLIGHT:
                t = self._advance_flight(t, t_end, events)
            else:
                t = self._advance_stance(t_start, t_end, events)
        self._tick += 1
        return events

    # --- flight -----------------------------------------------------------------------------

    def _flight_state(self, t: float) -> HopperState:
        t_ref, x, y, xdot, ydot = self._flight_ref
        x, y, xdot, ydot = dynamics.ballistic(x, y, xdot, ydot, t - t_ref, self._params.g)
        if self._body is not None:  # the centre of mass ballistic, the pitch turning at its constant rate
            pitch, pitch_rate = self._pitch_ref
            return body_dynamics.rigid_flight_hopper_state(
                self._params,
                self._body,
                t,
                self._stride,
                x,
                y,
                xdot,
                ydot,
                pitch + pitch_rate * (t - t_ref),
                pitch_rate,
                self.placed_angle,
            )
        return dynamics.flight_hopper_state(
            self._params, t, self._stride, x, y, xdot, ydot, self.placed_angle, self._height
        )

    @property
    def _height(self) -> Callable[[float], float] | None:
        return None if self._terrain is None else self._terrain.height_at

    def _begin_stride(self, t_apex: float) -> None:
        """At the apex in the flight reference (before its push): record it, draw this stride's
        perturbations, apply the push (a push beyond the limits fails the stride)."""
        self._apex_state = self._flight_state(t_apex)
        self._measured = (self._apex_state.y, self._apex_state.xdot)
        self._push = 0.0
        if self._perturbations is None:
            return
        draws = self._perturbations.draws([self._trajectory], self._stride, 1)
        height_error, speed_error = float(draws.height_error[0, 0]), float(draws.speed_error[0, 0])
        self._measured = (self._apex_state.y + height_error, self._apex_state.xdot + speed_error)
        self._angle_error = float(draws.angle_error[0, 0])
        self._place_leg()
        self._push = float(draws.push[0, 0])
        self._apex_state = self._flight_state(t_apex)  # the leg at this stride's placement
        if self._push != 0.0:
            t_ref, x, y, xdot, _ = self._flight_ref
            self._flight_ref = (t_ref, x, y, xdot + self._push, 0.0)
            failure = self._limits.push_failure(y - self._ground, xdot, self._push)
            if failure is not None:
                self._pending_failure = (self._flight_state(t_apex), *failure)

    def _place_leg(self) -> None:
        """The command or the placement error changed: where the leg lands is to be found again."""
        self._placed_angle = self._command.touchdown_angle
        if self._angle_error != 0.0:
            self._placed_angle = float(placed_angle(self._command.touchdown_angle, self._angle_error))
        self._landing = None

    def _plan_landing_at(self, angle: float) -> Landing:
        assert self._terrain is not None
        return plan_landing(self._params, self._terrain, self._flight_ref, angle)

    def _current_landing(self) -> Landing:
        if self._landing is None:
            self._landing = self._plan_landing_at(self.placed_angle)
        return self._landing

    def _stubbing(self) -> tuple[FailureKind, str] | None:
        """Toe stubbing of the command in force at the apex of this (descending) flight, or None."""
        if self._body is not None:
            return self._rigid_stubbing(self._body)
        y_apex = self._flight_ref[2]
        y_td = dynamics.touchdown_height(self._params, math.cos(self.placed_angle))
        if self._terrain is None:
            return dynamics.toe_stubbing(y_apex, y_td)
        landing = self._current_landing()
        if not landing.stubbed:
            return None
        toe_x = self._flight_ref[1] + self._params.r0 * math.sin(self.placed_angle)
        ground = landing.placement_ground
        return dynamics.toe_below_ground(y_apex, ground + y_td, toe_x, ground)

    def _advance_flight(self, t: float, t_end: float, events: list[Event]) -> float:
        """Advance in flight from t to t_end, to touchdown or to a rigid body's tipping; return where it
        stopped.

        A rigid body's flight is the exact map's (``_rigid_body_stride``): the centre of mass ballistic and
        the pitch turning at its constant rate; the body tips where :func:`~.pitch_limit_time` says,
        if that comes before the apex (after a liftoff) or before the touchdown (after an apex)."""
        params, body = self._params, self._body
        if not self._descending:
            t_ref, _, _, _, ydot = self._flight_ref
            t_apex = t_ref + ydot / params.g
            if body is not None:
                t_tip = self._tip_time(body)
                if t_tip <= t_apex:
                    return self._tip_in_flight(body, t_tip, t_end, "in the flight after liftoff", events)
            if t_apex > t_end:
                return t_end
            pitch, pitch_rate = self._pitch_ref
            self._pitch_ref = (pitch + pitch_rate * (t_apex - t_ref), pitch_rate)  # before the apex's state
            if self._reach_apex(t_apex, events):
                return t_apex
            t = t_apex
        t_apex, x_apex, y_apex, xdot, _ = self._flight_ref
        fall = self._fall_time()
        t_touchdown = math.inf if fall is None else max(t, t_apex + fall)
        if body is not None:
            t_tip = self._tip_time(body)
            # With a stubbed toe too (no touchdown): a tip in this tick comes before the next tick declares
            # the stubbing.
            if t_tip <= t_touchdown:
                return self._tip_in_flight(body, t_tip, t_end, "in the flight before touchdown", events)
        if t_touchdown > t_end:
            return t_end  # a stubbed toe is declared at the next tick, unless the command changes
        command = self._command
        beyond_limits = (
            None if isinstance(command, StanceFeedback) else self._limits.torque_failure(command.tau0)
        )
        if beyond_limits is not None:
            self._fail(events, self._flight_state(t_touchdown), *beyond_limits)
            return t_touchdown
        fall = t_touchdown - t_apex
        x_td, _, _, ydot_td = dynamics.ballistic(x_apex, y_apex, xdot, 0.0, fall, params.g)
        pitch_apex, pitch_rate = self._pitch_ref
        angle = self.placed_angle
        offset_x, stance = self._stance_model.touchdown(
            angle, xdot, ydot_td, pitch_apex + pitch_rate * fall, pitch_rate
        )
        self._phase = Phase.STANCE
        if self._terrain is None:
            self._toe_x, self._toe_y = x_td + offset_x + params.r0 * math.sin(angle), 0.0
        else:
            self._toe_x, self._toe_y = self._current_landing().toe_x, self._current_landing().toe_y
        self._t_touchdown = t_touchdown
        self._s = 0.0
        self._stance = stance
        self._begin_stance_torque(command, t_touchdown, stance)
        touchdown_state = self._stance_state(0.0, stance)
        events.append(Event(EventKind.TOUCHDOWN, t_touchdown, self._stride, touchdown_state))
        reversal = dynamics.touchdown_reversal(stance[3])
        if reversal is not None:
            self._fail(events, touchdown_state, *reversal)
        return t_touchdown

    def _fall_time(self) -> float | None:
        """Time [s] from this (descending) flight's apex to the touchdown of the leg placed now; None when its
        toe stubs (:meth:`_stubbing`)."""
        if self._body is not None:
            return self._rigid_landing_time(self._body)
        if self._terrain is not None:
            landing = self._current_landing()
            return None if landing.stubbed else landing.t
        y_apex = self._flight_ref[2]
        y_td = dynamics.touchdown_height(self._params, math.cos(self.placed_angle))
        return None if y_apex < y_td else dynamics.fall_time(y_apex, 0.0, y_td, self._params.g)

    def _reach_apex(self, t_apex: float, events: list[Event]) -> bool:
        """The rising flight reaches its apex at t_apex: the apex becomes the flight's reference, a stride
        begins and its APEX event is emitted. True when a push there ended the run."""
        t_ref, x, y, xdot, ydot = self._flight_ref
        x, y, xdot, _ = dynamics.ballistic(x, y, xdot, ydot, t_apex - t_ref, self._params.g)
        self._flight_ref = (t_apex, x, y, xdot, 0.0)
        self._descending = True
        self._stride += 1
        self._last_energy = self._pending_energy
        self._begin_stride(t_apex)
        events.append(Event(EventKind.APEX, t_apex, self._stride, self._apex_state))
        if self._pending_failure is not None:
            self._fail(events, *self._pending_failure)
            return True
        return False

    def _begin_stance_torque(
        self, command: StanceCommand | StanceFeedback, t_touchdown: float, y: tuple[float, ...]
    ) -> None:
        """The hip's torque for the stance beginning at t_touchdown in the state y: the hold of a law
        (sampled at once on a tick boundary) or the command's ramp, with its saturation."""
        if self._hold is not None:  # the last stance's, counted now that it is replaced
            self._saturated_strides += self._hold.saturated
            self._hold = None
        if isinstance(command, StanceFeedback):
            # No kinks but the tick boundaries, where the sub-step grid stops anyway.
            self._stance_t_f = self._stance_saturation_end = math.inf
            self._hold = HeldTorque(
                command, t_touchdown, self._torque_limit, self._tau_max, y, self._streamed
            )
        else:
            self._stance_tau0, self._stance_t_f = command.tau0, command.t_f
            self._stance_saturation_end = self._stance_t_f
            if self._tau_max is not None:
                self._stance_saturation_end = float(
                    dynamics.saturation_end(self._stance_tau0, self._stance_t_f, self._tau_max)
                )
                self._saturated_strides += abs(self._stance_tau0) > self._tau_max

    # --- the rigid body's flight ---------------------------------------------------------------

    def _tip_time(self, body: RigidBody) -> float:
        """When the body's pitch, turning at its constant rate in this flight, reaches the tip_limit [s]."""
        pitch, pitch_rate = self._pitch_ref
        return self._flight_ref[0] + body_dynamics.pitch_limit_time(body, pitch, pitch_rate)

    def _tip_in_flight(
        self, body: RigidBody, t_tip: float, t_end: float, when: str, events: list[Event]
    ) -> float:
        """The body tips at t_tip in flight if that is in this tick; return where the flight stopped."""
        if t_tip > t_end:
            return t_end
        state = self._flight_state(t_tip)
        self._fail(events, state, *body_dynamics.tipped(state.pitch, body.tip_limit, when))
        return t_tip

    def _rigid_landing_time(self, body: RigidBody) -> float | None:
        """Time [s] from this (descending) flight's apex to the touchdown of the leg placed now, or None when
        its toe is below the ground at the apex (:func:`~.rigid_touchdown_time`, once per flight and
        angle)."""
        t_apex, _, y_apex, _, _ = self._flight_ref
        angle = self.placed_angle
        planned = self._rigid_landing
        if planned is None or planned[0] != t_apex or planned[1] != angle:
            pitch, pitch_rate = self._pitch_ref
            landing = body_dynamics.rigid_touchdown_time(
                self._params, body, y_apex, pitch, pitch_rate, math.cos(angle)
            )
            planned = self._rigid_landing = (t_apex, angle, landing)
        return planned[2]

    def _rigid_stubbing(self, body: RigidBody) -> tuple[FailureKind, str] | None:
        """The exact map's toe stubbing of a rigid body: the hip below the touchdown height at the apex."""
        if self._rigid_landing_time(body) is not None:
            return None
        return rigid_stubbing(self._params, body, self._flight_ref[2], self._pitch_ref[0], self.placed_angle)

    # --- stance -----------------------------------------------------------------------------

    def _torque(self, s: float) -> float:
        if self._hold is not None:
            return self._hold.held
        if self._tau_max is None:
            return dynamics.ramp_torque(self._stance_tau0, self._stance_t_f, s)
        return float(dynamics.hip_torque(self._stance_tau0, self._stance_t_f, s, self._tau_max))

    def _stance_state(self, s: float, y: StanceVector) -> HopperState:
        return self._stance_model.state(
            self._t_touchdown + s, self._stride, self._toe_x, self._toe_y, y, self._torque(s)
        )

    def _advance_stance(self, t_tick: float, t_end: float, events: list[Event]) -> float:
        """Integrate the stance to t_end or to liftoff/failure; return where it stopped."""
        model = self._stance_model
        h_grid = self._dt / self._substeps
        t_touchdown = self._t_touchdown
        s_end_of_tick = t_end - t_touchdown
        while self._s < s_end_of_tick:
            s, y = self._s, self._stance
            # The next sub-step grid point (a piece that would end within a rounding error of its
            # start goes on to the following point), then the ramp end and the time limit.
            index = math.floor((t_touchdown + s - t_tick) / h_grid + _GRID_SLACK) + 1
            s_next = s_end_of_tick if index >= self._substeps else t_tick + index * h_grid - t_touchdown
            if s < self._stance_saturation_end < s_next:
                s_next = self._stance_saturation_end
            if s < self._stance_t_f < s_next:
                s_next = self._stance_t_f
            s_next = min(s_next, self._stance_limit)
            y_next = model.rk4(s, y, s_next - s)
            if self._handle_stance_events(model, s, y, s_next, y_next, events):
                return t_touchdown + self._s
            self._s, self._stance = s_next, y_next
            if s_next >= self._stance_limit:
                self._fail(
                    events, self._stance_state(s_next, y_next), *dynamics.no_liftoff(self._stance_limit)
                )
                return t_touchdown + s_next
        return t_end

    def _handle_stance_events(
        self,
        model: StanceModel,
        s: float,
        y: StanceVector,
        s_next: float,
        y_next: StanceVector,
        events: list[Event],
    ) -> bool:
        """Emit the stance events of the piece [s, s_next]; True when one of them ended the stance."""
        before, after = model.event_values(y), model.event_values(y_next)
        crossed = [i for i in range(len(before)) if before[i] > 0.0 and after[i] <= 0.0]
        if not crossed:
            return False
        located = sorted((model.locate(s, y, s_next - s, i, before[i], after[i]), i) for i in crossed)
        for sigma, index in located:
            name = model.event_names[index]
            s_event = s + sigma
            y_event = model.rk4(s, y, sigma)
            state = self._stance_state(s_event, y_event)
            if name == "bottom":
                events.append(Event(EventKind.BOTTOM, state.t, self._stride, state))
                continue
            self._s, self._stance = s_event, y_event
            if name == "liftoff":
                self._lift_off(state, y_event, events)
            else:
                self._fail(events, state, *model.failure(name, s_event, state))
            return True
        return False

    def _lift_off(self, liftoff: HopperState, y: StanceVector, events: list[Event]) -> None:
        """The flight from liftoff, in the exact map's order: no apex ahead; a rigid body tipping before the
        apex (the flight ends there, :meth:`_advance_flight`); an apex beyond the limits."""
        events.append(Event(EventKind.LIFTOFF, liftoff.t, self._stride, liftoff))
        self._pending_energy = StrideEnergy(
            hip_work=y[4], damping_loss=y[5], spring_loss=dynamics.spring_energy(self._params, y[0])
        )
        self._phase = Phase.FLIGHT
        self._streamed = 0.0  # a stance's streamed torque ends with it
        self._flight_ref = (liftoff.t, liftoff.x, liftoff.y, liftoff.xdot, liftoff.ydot)
        self._pitch_ref = (liftoff.pitch, liftoff.pitch_rate)
        self._descending = False
        self._ground = self._toe_y
        failure = dynamics.takeoff_failure(liftoff.xdot, liftoff.ydot)
        if failure is None:
            t_apex = liftoff.t + liftoff.ydot / self._params.g  # as _advance_flight reaches it
            if self._body is not None and self._tip_time(self._body) <= t_apex:
                return
            _, y_apex, _, _ = dynamics.ballistic(
                liftoff.x, liftoff.y, liftoff.xdot, liftoff.ydot, t_apex - liftoff.t, self._params.g
            )
            failure = self._limits.apex_failure(y_apex - self._ground, liftoff.xdot)
        if failure is not None:
            self._fail(events, liftoff, *failure)

    def _fail(self, events: list[Event], state: HopperState, kind: FailureKind, reason: str) -> None:
        self._failed = kind
        self._failure_state = state
        events.append(Event(EventKind.FAILURE, state.t, self._stride, state, kind, reason))
