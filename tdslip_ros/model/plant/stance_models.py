"""What the 1 kHz stepper (:mod:`.stepper`) integrates in stance, one model per kind of body: the point mass's
six values (:class:`PointMassStance`) or the rigid body's eight (:class:`RigidBodyStance`). A model holds what
differs between them (the RK4 step of its derivative, its event values and their rates, its events' names
and failures, the HopperState of a stance vector and the vector at touchdown); the stepper's one stance loop
drives either, and :meth:`StanceModel.locate` finds an event inside a step for both. The physics is
:mod:`.dynamics`' (its one source): a model only unpacks its state vector for it.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any

from tdslip_ros.model import body_dynamics, dynamics
from tdslip_ros.model.events import FailureKind, HopperState
from tdslip_ros.model.params import HopperParams, RigidBody

StanceVector = tuple[float, ...]
"""(r, theta, rdot, thetadot, hip work, damper loss) in stance; a rigid body's adds (phi, phidot)
(:func:`.body_dynamics.rigid_stance_derivatives`)."""
Torque = Callable[[float], float]
"""The hip torque [N m] at time s [s] since touchdown (the stepper's ramp or held sample)."""
Step = Callable[[float, StanceVector, float], StanceVector]
"""One RK4 step: (s, y, h) -> y after h."""

_EVENT_TIME_TOLERANCE = 1e-14  # s, Newton's tolerance on the event time inside a sub-step
_MAX_ROOT_ITERATIONS = 100


def unrolled_rk4(size: int, fed: tuple[int, ...]) -> Callable[[Callable[..., StanceVector]], Step]:
    """Classical RK4 for a stance vector of ``size`` values, the derivative f(s, *y[fed]) taking the values at
    the indices ``fed`` (the others, hip work and damper loss, feed nothing back): a function of f that
    returns the step (s, y, h) -> y(s + h).

    The step is written out term by term from this one template (as collections.namedtuple writes its
    class): a stance tick's cost is mostly this step, and on bench/bench_stepper.py a loop over the values
    costs the point mass's stance tick ~40 % more, the rigid body's eight values with the pitch held at 0
    ~7 % more, than its own six written out."""

    def stage(k: str, step: str) -> str:
        return ", ".join(f"y[{i}] + {step} * {k}[{i}]" for i in fed)

    combined = ", ".join(
        f"y[{i}] + sixth * (k1[{i}] + 2.0 * (k2[{i}] + k3[{i}]) + k4[{i}])" for i in range(size)
    )
    source = "\n".join(
        [
            "def bind(f):",
            "    def rk4(s, y, h):",
            f"        k1 = f(s, {', '.join(f'y[{i}]' for i in fed)})",
            "        half = 0.5 * h",
            f"        k2 = f(s + half, {stage('k1', 'half')})",
            f"        k3 = f(s + half, {stage('k2', 'half')})",
            f"        k4 = f(s + h, {stage('k3', 'h')})",
            "        sixth = h / 6.0",
            f"        return ({combined},)",
            "    return rk4",
        ]
    )
    namespace: dict[str, Any] = {}
    exec(compile(source, f"<rk4 of {size} values>", "exec"), namespace)
    bind: Callable[[Callable[..., StanceVector]], Step] = namespace["bind"]
    return bind


_POINT_MASS_RK4 = unrolled_rk4(6, (0, 1, 2, 3))
_RIGID_BODY_RK4 = unrolled_rk4(body_dynamics.RIGID_STANCE_STATE_SIZE, (0, 1, 2, 3, 6, 7))


class StanceModel(ABC):
    """A kind of body's stance on the stepper's grid under the stepper's hip torque ``torque(s)``.

    ``rk4(s, y, h)`` is classical RK4 of the model's derivative; ``event_names`` name the event values in
    order (each event happens where its value crosses from > 0 to <= 0)."""

    event_names: tuple[str, ...]
    rk4: Step

    def __init__(self, params: HopperParams, torque: Torque) -> None:
        self.params, self._torque = params, torque

    @abstractmethod
    def event_values(self, y: StanceVector) -> tuple[float, ...]:
        """The event values of the stance vector y, in the order of ``event_names``."""

    @abstractmethod
    def event_rate(self, s: float, y: StanceVector, index: int) -> float:
        """The time derivative of event value ``index`` along the motion at (s, y), for Newton's method."""

    @abstractmethod
    def state(
        self, t: float, stride: int, toe_x: float, toe_y: float, y: StanceVector, tau: float
    ) -> HopperState:
        """The HopperState of the stance vector y at time t [s], the toe at (toe_x, toe_y), hip torque tau."""

    @abstractmethod
    def failure(self, name: str, s: float, state: HopperState) -> tuple[FailureKind, str]:
        """The failure that the terminal event ``name`` (not liftoff) at state, s [s] into stance, is."""

    @abstractmethod
    def touchdown(
        self, angle: float, xdot: float, ydot: float, pitch: float, pitch_rate: float
    ) -> tuple[float, StanceVector]:
        """The hip's x offset [m] from the centre of mass and the stance vector at the touchdown of a leg at
        ``angle`` [rad], the centre of mass moving at (xdot, ydot) [m/s], the body at pitch, pitch_rate."""

    def locate(
        self, s: float, y: StanceVector, length: float, index: int, g_start: float, g_end: float
    ) -> float:
        """Time sigma into the piece [s, s + length] from y where event ``index`` happens, its value
        g_start > 0 at the start and g_end <= 0 at the end: the RK4 step from (s, y) is re-taken with length
        sigma, and sigma solved for the value's zero by safeguarded Newton (rate: :meth:`event_rate`), started
        by regula falsi and falling back to bisection when a step leaves the bracket; ~1e-14 s in 2-3
        iterations."""
        low, high = 0.0, length
        sigma = g_start * length / (g_start - g_end)
        for _ in range(_MAX_ROOT_ITERATIONS):
            y_sigma = self.rk4(s, y, sigma)
            value = self.event_values(y_sigma)[index]
            if value == 0.0:
                break
            if value > 0.0:
                low = sigma
            else:
                high = sigma
            rate = self.event_rate(s + sigma, y_sigma, index)
            newton_step = value / rate if rate != 0.0 else math.inf
            if abs(newton_step) <= _EVENT_TIME_TOLERANCE:
                break
            newton = sigma - newton_step
            sigma = newton if low < newton < high else 0.5 * (low + high)
        return sigma


class PointMassStance(StanceModel):
    """The fixed body's stance: :func:`.dynamics.stance_accelerations` and :func:`.dynamics.stance_powers`
    (:func:`.dynamics.stance_derivatives`' two parts, called here without it: one call fewer per stage of the
    hot loop), its events (:data:`.dynamics.STANCE_EVENT_NAMES`) and its state, on flat or uneven ground
    (``ground(x)`` the height under the body, None: flat)."""

    event_names = dynamics.STANCE_EVENT_NAMES

    def __init__(self, params: HopperParams, torque: Torque, ground: Callable[[float], float] | None) -> None:
        super().__init__(params, torque)
        self._ground = ground
        self.rk4 = _POINT_MASS_RK4(self.derivative)

    def derivative(self, s: float, r: float, theta: float, rdot: float, thetadot: float) -> StanceVector:
        params = self.params
        tau = self._torque(s)
        rddot, thetaddot = dynamics.stance_accelerations(
            params, r, math.sin(theta), math.cos(theta), rdot, thetadot, tau
        )
        hip_power, damper_power = dynamics.stance_powers(params, rdot, thetadot, tau)
        return rdot, thetadot, rddot, thetaddot, hip_power, damper_power

    def event_values(self, y: StanceVector) -> tuple[float, ...]:
        return dynamics.stance_event_values(self.params, y[0], math.cos(y[1]), y[2], y[3])

    def event_rate(self, s: float, y: StanceVector, index: int) -> float:
        r, theta, rdot, thetadot = y[0], y[1], y[2], y[3]
        _, _, rddot, thetaddot, _, _ = self.derivative(s, r, theta, rdot, thetadot)
        return dynamics.stance_event_rates(
            self.params, r, math.sin(theta), math.cos(theta), rdot, thetadot, rddot, thetaddot
        )[index]

    def state(
        self, t: float, stride: int, toe_x: float, toe_y: float, y: StanceVector, tau: float
    ) -> HopperState:
        return dynamics.stance_hopper_state(
            self.params, t, stride, toe_x, y[0], y[1], y[2], y[3], tau, toe_y, self._ground
        )

    def failure(self, name: str, s: float, state: HopperState) -> tuple[FailureKind, str]:
        return dynamics.stance_failure(name, s)

    def touchdown(
        self, angle: float, xdot: float, ydot: float, pitch: float, pitch_rate: float
    ) -> tuple[float, StanceVector]:
        r0 = self.params.r0
        rdot, thetadot = dynamics.polar_velocity(r0, math.sin(angle), math.cos(angle), xdot, ydot)
        return 0.0, (r0, angle, rdot, thetadot, 0.0, 0.0)


class RigidBodyStance(StanceModel):
    """A rigid body's stance on flat ground: :func:`.body_dynamics.rigid_stance_derivatives`, its events
    (:data:`.body_dynamics.RIGID_STANCE_EVENT_NAMES`, the fixed body's and ``tipped``) and its state."""

    event_names = body_dynamics.RIGID_STANCE_EVENT_NAMES

    def __init__(self, params: HopperParams, body: RigidBody, torque: Torque) -> None:
        super().__init__(params, torque)
        self.body = body
        self.rk4 = _RIGID_BODY_RK4(self.derivative)

    def derivative(
        self, s: float, r: float, theta: float, rdot: float, thetadot: float, pitch: float, pitch_rate: float
    ) -> StanceVector:
        return body_dynamics.rigid_stance_derivatives(
            self.params,
            self.body,
            r,
            math.sin(theta),
            math.cos(theta),
            rdot,
            thetadot,
            math.sin(pitch),
            math.cos(pitch),
            pitch_rate,
            self._torque(s),
        )

    def event_values(self, y: StanceVector) -> tuple[float, ...]:
        return body_dynamics.rigid_stance_event_values(
            self.params, self.body, y[0], math.cos(y[1]), y[2], y[3], y[6]
        )

    def event_rate(self, s: float, y: StanceVector, index: int) -> float:
        r, theta, rdot, thetadot, pitch, pitch_rate = y[0], y[1], y[2], y[3], y[6], y[7]
        rates = self.derivative(s, r, theta, rdot, thetadot, pitch, pitch_rate)
        return body_dynamics.rigid_stance_event_rates(
            self.params,
            r,
            math.sin(theta),
            math.cos(theta),
            rdot,
            thetadot,
            rates[2],
            rates[3],
            pitch,
            pitch_rate,
        )[index]

    def state(
        self, t: float, stride: int, toe_x: float, toe_y: float, y: StanceVector, tau: float
    ) -> HopperState:
        """The state on flat ground (the toe at height toe_y = 0)."""
        return body_dynamics.rigid_stance_hopper_state(
            self.params, self.body, t, stride, toe_x, y[0], y[1], y[2], y[3], y[6], y[7], tau
        )

    def failure(self, name: str, s: float, state: HopperState) -> tuple[FailureKind, str]:
        if name == "tipped":
            return body_dynamics.tipped(state.pitch, self.body.tip_limit, f"{s:.6g} s into stance")
        return dynamics.stance_failure(name, s)

    def touchdown(
        self, angle: float, xdot: float, ydot: float, pitch: float, pitch_rate: float
    ) -> tuple[float, StanceVector]:
        """The hip moves with the centre of mass and the turning body (:func:`.body_dynamics.hip_offset`)."""
        r0, body = self.params.r0, self.body
        sin_p, cos_p = math.sin(pitch), math.cos(pitch)
        offset_x = body_dynamics.hip_offset(body, sin_p, cos_p)[0]
        relative_vx, relative_vy = body_dynamics.pitch_velocity_offset(body, sin_p, cos_p, pitch_rate)
        rdot, thetadot = dynamics.polar_velocity(
            r0, math.sin(angle), math.cos(angle), xdot + relative_vx, ydot + relative_vy
        )
        return offset_x, (r0, angle, rdot, thetadot, 0.0, 0.0, pitch, pitch_rate)
