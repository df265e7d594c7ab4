"""Posture at the apex: the paper's energy regulation for a hopper with a rigid body
(:class:`tdslip_ros.model.params.RigidBody`, docs/rotating_body.md), with an optional lean law.

The paper plans on a point mass at the hip. :class:`HipEnergyRegulation` keeps that planner (section IV.A,
:func:`.controllers.energy_regulation`, on the analytic map) and feeds it what the hip sees at the apex: its
height and the centre of mass's speed, the body being still at the apex for the planner. What it plans is
the paper's ramp with the touchdown angle beta fixed.

The lean law is the paper's suggestion for sharing the one actuator (section VI): the ramp's tau0 moves by
k_phi (phi - lean) + k_phidot phidot, so that a body pitched back from ``lean`` gets less of the thrust's
reaction (a thrusting tau0 is negative, and the body receives -tau). With both gains 0 it is the paper's
regulator alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from tdslip_ros.model import dynamics
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.stance_laws import finite_field
from tdslip_ros.model.policies.controllers import energy_regulation


@dataclass(frozen=True)
class HipEnergyRegulation:
    """Energy regulation planned on the hip (module docstring): touchdown angle ``beta`` [rad], the hip's
    point-mass energy m g y_hip + m xdot^2 / 2 held at ``target_energy`` [J]; the lean law's ``lean`` [rad],
    ``pitch_gain`` [N m/rad] and ``pitch_rate_gain`` [N m s/rad]. Called with the hopper (a rigid body's) and
    an apex, it returns the stride's command."""

    beta: float
    target_energy: float
    lean: float = 0.0
    pitch_gain: float = 0.0
    pitch_rate_gain: float = 0.0

    def __post_init__(self) -> None:
        for name in ("beta", "target_energy", "lean", "pitch_gain", "pitch_rate_gain"):
            object.__setattr__(self, name, finite_field(name, getattr(self, name)))

    def __call__(self, params: HopperParams, apex: ApexState) -> StanceCommand:
        body = params.body
        if body is None:
            raise ParameterError("HipEnergyRegulation plans for a rigid body (HopperParams.body)")
        hip_y = apex.y + dynamics.hip_offset(body, math.sin(apex.pitch), math.cos(apex.pitch))[1]
        planned = energy_regulation(
            replace(params, body=None), hip_y, apex.xdot, self.beta, self.target_energy
        )
        tau0 = float(planned.tau0)
        if not math.isfinite(tau0):
            raise ParameterError(
                f"energy regulation has no command from the hip at {hip_y!r} m, {apex.xdot!r} m/s"
            )
        tau0 += self.pitch_gain * (apex.pitch - self.lean) + self.pitch_rate_gain * apex.pitch_rate
        return StanceCommand(float(planned.touchdown_angle), tau0, float(planned.t_f))
