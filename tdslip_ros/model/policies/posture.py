"""Posture for a hopper with a rigid body (:class:`tdslip_ros.model.params.RigidBody`, docs/rotating_body.md):
the paper's energy regulation planned on the hip, and the lean that lets the same hip torque hold the body.

**Energy regulation on the hip** (:class:`HipEnergyRegulation`). The paper plans on a point mass at the hip.
The planner (section IV.A, :func:`.controllers.energy_regulation`, on the analytic map) is fed what the hip
sees at the apex: its height and the centre of mass's speed. It plans the paper's ramp with the touchdown
angle beta fixed.

**The balancing lean** (:func:`balance_lean`), the paper's suggestion (section VI): the body receives the
reaction -tau of every thrusting torque, an angular impulse -tau0 t_f / 2 over the ramp. Over a periodic
stride the leg's force, about m g T upwards on average over the stride's time T, must return it through its
moment about the centre of mass: o_x m g T = tau0 t_f / 2, o_x the hip's forward offset from the centre of
mass, R(phi) d's first component. The lean phi solves that; of its two solutions (the hip above or below
the line of the force) the one nearer the apex's pitch is taken, so the law never turns the body over. A
hip closer to the centre of mass than |o_x| has none. T is taken as the planned stance t_f (the ramp ends at
liftoff) and a flight from the apex's hip height to the touchdown height and back.

**Holding the lean in stance** (:class:`BalancedPosture`, a sampled stance law on the 1 kHz torque interface):
the planned ramp plus k_p (phi - lean) + k_d phidot, k_p = J omega^2 and k_d = 2 zeta J omega. A body pitched
back from the lean (phi > lean) gets less thrust and so less of its reaction. :class:`PostureRegulation`
puts the three together at each apex. Where it holds the body and where it does not, with the numbers:
docs/rotating_body.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from tdslip_ros.model import body_dynamics, dynamics
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody, StanceCommand
from tdslip_ros.model.plant.stance_laws import StanceFeedback, StanceSample, finite_field
from tdslip_ros.model.policies.controllers import energy_regulation

DEFAULT_NATURAL_FREQUENCY = 60.0
"""rad/s: omega of the stance PD; with DEFAULT_DAMPING_RATIO, the hip 0.1-0.3 m below the centre of mass is
held (docs/rotating_body.md)."""
DEFAULT_DAMPING_RATIO = 1.0
"""zeta of the stance PD."""


def _rigid_body(params: HopperParams) -> RigidBody:
    if params.body is None:
        raise ParameterError("posture needs a hopper with a rigid body (HopperParams.body)")
    return params.body


def hip_height(body: RigidBody, apex: ApexState) -> float:
    """The hip's height [m] at the apex."""
    return apex.y + body_dynamics.hip_offset(body, math.sin(apex.pitch), math.cos(apex.pitch))[1]


@dataclass(frozen=True)
class HipEnergyRegulation:
    """Energy regulation planned on the hip (module docstring): touchdown angle ``beta`` [rad], the hip's
    point-mass energy m g y_hip + m xdot^2 / 2 held at ``target_energy`` [J]. Called with the hopper (a rigid
    body's) and an apex, it returns the stride's ramp."""

    beta: float
    target_energy: float

    def __post_init__(self) -> None:
        for name in ("beta", "target_energy"):
            object.__setattr__(self, name, finite_field(name, getattr(self, name)))

    def __call__(self, params: HopperParams, apex: ApexState) -> StanceCommand:
        hip_y = hip_height(_rigid_body(params), apex)
        planned = energy_regulation(
            replace(params, body=None), hip_y, apex.xdot, self.beta, self.target_energy
        )
        if not math.isfinite(float(planned.tau0)):
            raise ParameterError(
                f"energy regulation has no command from the hip at {hip_y!r} m, {apex.xdot!r} m/s"
            )
        return StanceCommand(float(planned.touchdown_angle), float(planned.tau0), float(planned.t_f))


def balance_lean(params: HopperParams, apex: ApexState, ramp: StanceCommand) -> float:
    """The pitch [rad] at which the leg's force returns the ramp's reaction over a stride (module docstring);
    ParameterError when the hip is too close to the centre of mass for any lean to."""
    body = _rigid_body(params)
    fall = max(hip_height(body, apex) - params.r0 * math.cos(ramp.touchdown_angle), 0.0)
    stride_time = ramp.t_f + 2.0 * math.sqrt(2.0 * fall / params.g)
    needed = ramp.tau0 * ramp.t_f / (2.0 * params.m * params.g * stride_time)
    # hip_x cos(phi) - hip_y sin(phi) = |d| cos(phi + a), tan(a) = hip_y / hip_x
    reach = math.hypot(body.hip_x, body.hip_y)
    if abs(needed) >= reach:
        raise ParameterError(
            f"no lean balances the thrust: the hip must sit {abs(needed):.3g} m ahead of or behind the "
            f"centre of mass, and it is {reach:.3g} m from it"
        )
    offset = math.atan2(body.hip_y, body.hip_x)
    turns = (math.acos(needed / reach) - offset, -math.acos(needed / reach) - offset)
    return min(
        (apex.pitch + math.remainder(turn - apex.pitch, 2.0 * math.pi) for turn in turns),
        key=lambda turn: abs(turn - apex.pitch),
    )


@dataclass(frozen=True)
class BalancedPosture:
    """The stance law of :class:`PostureRegulation`: the ``ramp``'s torque plus ``pitch_gain`` [N m/rad]
    (phi - ``lean`` [rad]) plus ``pitch_rate_gain`` [N m s/rad] phidot."""

    ramp: StanceCommand
    lean: float
    pitch_gain: float
    pitch_rate_gain: float

    def torque(self, sample: StanceSample, lanes: npt.NDArray[np.int64] | None = None) -> Any:
        planned = dynamics.ramp_torque(self.ramp.tau0, self.ramp.t_f, sample.s)
        return (
            planned + self.pitch_gain * (sample.pitch - self.lean) + self.pitch_rate_gain * sample.pitch_rate
        )


@dataclass(frozen=True)
class PostureRegulation:
    """Energy regulation on the hip (``beta`` [rad], ``target_energy`` [J]) with the balancing lean held in
    stance by a PD of ``natural_frequency`` omega [rad/s] and ``damping_ratio`` zeta (module docstring).
    Called with the hopper and an apex, it returns the stride's :class:`.stance_laws.StanceFeedback`."""

    beta: float
    target_energy: float
    natural_frequency: float = DEFAULT_NATURAL_FREQUENCY
    damping_ratio: float = DEFAULT_DAMPING_RATIO

    def __post_init__(self) -> None:
        for name in ("beta", "target_energy", "natural_frequency", "damping_ratio"):
            object.__setattr__(self, name, finite_field(name, getattr(self, name)))

    def __call__(self, params: HopperParams, apex: ApexState) -> StanceFeedback:
        inertia = _rigid_body(params).inertia
        ramp = HipEnergyRegulation(self.beta, self.target_energy)(params, apex)
        omega = self.natural_frequency
        law = BalancedPosture(
            ramp,
            balance_lean(params, apex, ramp),
            inertia * omega * omega,
            2.0 * self.damping_ratio * inertia * omega,
        )
        return StanceFeedback(ramp.touchdown_angle, law)
