"""Where one flight of the 1 kHz stepper (:mod:`.stepper`) lands: the leg placed at its apex on uneven
ground (:func:`.terrain.touchdown` for one hopper), and a rigid body's toe stubbing, judged at the hip."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tdslip_ros.model import body_dynamics, dynamics
from tdslip_ros.model.events import FailureKind
from tdslip_ros.model.params import HopperParams, RigidBody
from tdslip_ros.model.plant.terrain import Terrain, touchdown

FlightReference = tuple[float, float, float, float, float]
"""A flight's reference state (t, x, y, xdot, ydot): its apex, or its liftoff while it still rises."""


class Landing(NamedTuple):
    """Where the leg placed at a flight's apex lands on uneven ground: (stubbed, time from the apex to
    touchdown, toe position) and the ground under the toe at placement."""

    stubbed: bool
    t: float
    toe_x: float
    toe_y: float
    placement_ground: float


def plan_landing(params: HopperParams, terrain: Terrain, flight: FlightReference, angle: float) -> Landing:
    """Where a leg placed at ``angle`` at the apex of the flight from ``flight`` lands on ``terrain``."""
    _, x, y, xdot, _ = flight
    x_a, y_a, xdot_a, sin_a, cos_a = (np.array([v]) for v in (x, y, xdot, math.sin(angle), math.cos(angle)))
    landing = touchdown(terrain, x_a, y_a, xdot_a, sin_a, cos_a, params.r0, params.g)
    return Landing(
        bool(landing.stubbed[0]),
        float(landing.t[0]),
        float(landing.toe_x[0]),
        float(landing.toe_y[0]),
        float(landing.placement_ground[0]),
    )


def rigid_stubbing(
    params: HopperParams, body: RigidBody, y_apex: float, pitch: float, angle: float
) -> tuple[FailureKind, str] | None:
    """The exact map's toe stubbing of a rigid body at an apex of height ``y_apex`` and ``pitch`` whose leg,
    placed at ``angle``, :func:`~.rigid_touchdown_time` found with the hip below the touchdown height."""
    hip_y = y_apex + body_dynamics.hip_offset(body, math.sin(pitch), math.cos(pitch))[1]
    y_td = dynamics.touchdown_height(params, math.cos(angle))
    # rigid_touchdown_time found the hip below y_td at the apex; a rounding apart, so does this.
    return dynamics.toe_stubbing(min(hip_y, math.nextafter(y_td, -math.inf)), y_td)
