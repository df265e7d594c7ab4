"""A rigid body in the batched engine's lanes (:mod:`.batch`, docs/rotating_body.md): what the engine runs
for one (:func:`rigid_lanes`), and its flight: per lane the time to touchdown and to tipping past the
tip_limit, and where the hip is beside the centre of mass, by :mod:`.body_dynamics`' own functions (those of
the exact map and the 1 kHz stepper).

The two times are iterations and branches of one lane each, run lane by lane here; the hip's offset is plain
arithmetic on the lanes' arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tdslip_ros.model import body_dynamics
from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.limits import check_lanes
from tdslip_ros.model.params import HopperParams, ParameterError, RigidBody
from tdslip_ros.model.plant.perturbations import StrideConditions


@dataclass(frozen=True)
class RigidLanes:
    """A rigid body's lanes of one stride: the body and the apexes' pitch [rad] and pitch_rate [rad/s]."""

    body: RigidBody
    pitch: FloatArray
    pitch_rate: FloatArray


def rigid_lanes(
    params: HopperParams, pitch: FloatArray, pitch_rate: FloatArray, conditions: StrideConditions
) -> RigidLanes | None:
    """The lanes' rigid body, None for the fixed body. ParameterError, naming the lane, for a pitch on the
    fixed body, and for a rigid body an apex pitched past its tip_limit or what the batched engine does not
    run for one yet: ground other than flat at height 0 (as on the exact map and the stepper)."""
    body = params.body
    if body is None:
        fixed = "0 on the fixed body (give HopperParams a RigidBody)"
        check_lanes(
            (
                ("apex pitch", pitch, pitch == 0.0, fixed),
                ("apex pitch_rate", pitch_rate, pitch_rate == 0.0, fixed),
            )
        )
        return None
    inside = f"inside the body's tip_limit {body.tip_limit!r} rad"
    check_lanes(
        (
            ("apex pitch", pitch, np.abs(pitch) < body.tip_limit, inside),
            ("apex pitch_rate", pitch_rate, np.isfinite(pitch_rate), "finite"),
        )
    )
    ground = conditions.ground
    if not conditions.terrain.is_flat or not (ground is None or np.all(np.asarray(ground) == 0.0)):
        raise ParameterError(
            f"the batched engine runs a rigid body on flat ground at height 0 for now, not on the "
            f"{conditions.terrain.kind} terrain at ground {ground!r}"
        )
    return RigidLanes(body, pitch, pitch_rate)


def touchdown_times(
    params: HopperParams,
    body: RigidBody,
    y: FloatArray,
    pitch: FloatArray,
    pitch_rate: FloatArray,
    cos_touchdown: FloatArray,
) -> FloatArray:
    """Per lane, the time [s] from its apex (centre of mass at y [m], pitch, pitch_rate) to touchdown, the leg
    at the angle whose cosine is cos_touchdown (:func:`.body_dynamics.rigid_touchdown_time`); NaN where the
    toe is below the ground at the apex already (toe_stubbing)."""
    lanes = zip(y.tolist(), pitch.tolist(), pitch_rate.tolist(), cos_touchdown.tolist(), strict=True)
    times = (body_dynamics.rigid_touchdown_time(params, body, *lane) for lane in lanes)
    return np.array([math.nan if t is None else t for t in times], dtype=np.float64)


def tip_times(body: RigidBody, pitch: FloatArray, pitch_rate: FloatArray) -> FloatArray:
    """Per lane, the time [s] at which the body, turning at its constant pitch_rate from pitch (in flight),
    reaches its tip_limit (:func:`.body_dynamics.pitch_limit_time`; inf if never)."""
    lanes = zip(pitch.tolist(), pitch_rate.tolist(), strict=True)
    return np.array([body_dynamics.pitch_limit_time(body, *lane) for lane in lanes], dtype=np.float64)


def hip_beside_centre_of_mass(
    body: RigidBody, pitch: FloatArray, pitch_rate: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The hip's position [m] and velocity [m/s] relative to the centre of mass, (x, y, xdot, ydot), at pitch
    and pitch_rate: :func:`.body_dynamics.hip_offset` and :func:`.body_dynamics.pitch_velocity_offset`."""
    sin_p, cos_p = np.sin(pitch), np.cos(pitch)
    offset_x, offset_y = body_dynamics.hip_offset(body, sin_p, cos_p)
    relative_vx, relative_vy = body_dynamics.pitch_velocity_offset(body, sin_p, cos_p, pitch_rate)
    return offset_x, offset_y, relative_vx, relative_vy
