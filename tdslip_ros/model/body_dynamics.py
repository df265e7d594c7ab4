"""The rigid body's equations of motion, events and energies (docs/rotating_body.md): a pitching body on the
paper's massless leg, beside :mod:`.dynamics`'s fixed body, whose leg force and ground force it uses."""

from __future__ import annotations

import math
from typing import Protocol

from tdslip_ros.model.dynamics import (
    STANCE_EVENT_NAMES,
    Hopper,
    Real,
    cartesian_velocity,
    fall_time,
    flight_energy,
    ground_reaction_force,
    spring_energy,
    stance_event_rates,
    stance_event_values,
    stance_powers,
    touchdown_height,
)
from tdslip_ros.model.events import FailureKind, HopperState, Phase
from tdslip_ros.model.params import HopperParams

# The rigid body (docs/rotating_body.md). The leg's polar coordinates (r, theta) are the hip's about the toe,
# and the body adds its pitch phi (counter-clockwise, as theta). The massless leg passes the ground's force F
# (ground_reaction_force: its moment about the hip is the motor's torque tau) to the body at the hip, and the
# motor turns the body by -tau: m com'' = F - m g y^, J phi'' = (R(phi) d) x F - tau, d the hip's offset from
# the centre of mass in the body's frame. A rigid stance state is the fixed body's six values and then
# (phi, phidot), so that the events and energy flows keep their places.


class Body(Protocol):
    """What the rigid body's arithmetic reads of a body: :class:`.params.RigidBody`."""

    @property
    def inertia(self) -> float: ...
    @property
    def hip_x(self) -> float: ...
    @property
    def hip_y(self) -> float: ...
    @property
    def tip_limit(self) -> float: ...


def hip_offset(body: Body, sin_p: Real, cos_p: Real) -> tuple[Real, Real]:
    """The hip's position [m] relative to the centre of mass at pitch phi (its sine and cosine): R(phi) d."""
    return body.hip_x * cos_p - body.hip_y * sin_p, body.hip_x * sin_p + body.hip_y * cos_p


def rigid_stance_accelerations(
    params: Hopper,
    body: Body,
    r: Real,
    sin_t: Real,
    cos_t: Real,
    rdot: Real,
    thetadot: Real,
    sin_p: Real,
    cos_p: Real,
    pitch_rate: Real,
    tau: Real,
) -> tuple[Real, Real, Real]:
    """(rddot, thetaddot, phiddot) of the rigid body in stance under hip torque tau [N m].

    phiddot follows from the moment of F about the centre of mass and the motor's -tau; the hip's acceleration
    is the centre of mass's, (F/m - g y^), plus the rotation's phiddot z^ x o - phidot^2 o (o = R(phi) d);
    rddot and thetaddot are its polar components, as in eq. 2."""
    force_x, force_y = ground_reaction_force(params, r, sin_t, cos_t, rdot, tau)
    offset_x, offset_y = hip_offset(body, sin_p, cos_p)
    pitchddot = (offset_x * force_y - offset_y * force_x - tau) / body.inertia
    spin = pitch_rate * pitch_rate
    hip_ax = force_x / params.m - pitchddot * offset_y - spin * offset_x
    hip_ay = force_y / params.m - params.g + pitchddot * offset_x - spin * offset_y
    rddot = -hip_ax * sin_t + hip_ay * cos_t + r * thetadot * thetadot
    thetaddot = (-hip_ax * cos_t - hip_ay * sin_t - 2.0 * rdot * thetadot) / r
    return rddot, thetaddot, pitchddot


def rigid_stance_derivatives(
    params: Hopper,
    body: Body,
    r: Real,
    sin_t: Real,
    cos_t: Real,
    rdot: Real,
    thetadot: Real,
    sin_p: Real,
    cos_p: Real,
    pitch_rate: Real,
    tau: Real,
) -> tuple[Real, Real, Real, Real, Real, Real, Real, Real]:
    """d/ds of the rigid stance state (r, theta, rdot, thetadot, hip work, damper loss, phi, phidot): the
    hip's power is tau (thetadot - phidot), the motor turning the leg against the body."""
    rddot, thetaddot, pitchddot = rigid_stance_accelerations(
        params, body, r, sin_t, cos_t, rdot, thetadot, sin_p, cos_p, pitch_rate, tau
    )
    hip_power, damper_power = stance_powers(params, rdot, thetadot - pitch_rate, tau)
    return rdot, thetadot, rddot, thetaddot, hip_power, params.c * rdot * rdot, pitch_rate, pitchddot


RIGID_STANCE_STATE_SIZE = 8
"""Values in a rigid stance state: (r, theta, rdot, thetadot, hip work, damper loss, phi, phidot)."""

RIGID_STANCE_EVENT_NAMES = (*STANCE_EVENT_NAMES, "tipped")
"""Stance events of a rigid body: the fixed body's, then the body pitching past its tip_limit."""


def tip_margin(body: Body, pitch: Real) -> Real:
    """tip_limit - |pitch| [rad]: the event value of ``tipped`` (it crosses from > 0 to <= 0)."""
    margin: Real = body.tip_limit - abs(pitch)
    return margin


def rigid_stance_event_values(
    params: Hopper, body: Body, r: float, cos_t: float, rdot: float, thetadot: float, pitch: float
) -> tuple[float, float, float, float, float]:
    """The rigid body's stance event values, in the order of RIGID_STANCE_EVENT_NAMES: the fixed body's
    (:func:`stance_event_values` of the leg from the toe to the hip), then :func:`tip_margin`. Each event
    happens when its value crosses from > 0 to <= 0."""
    bottom, liftoff, reversal, fall = stance_event_values(params, r, cos_t, rdot, thetadot)
    return bottom, liftoff, reversal, fall, tip_margin(body, pitch)


def rigid_stance_event_rates(
    params: Hopper,
    r: float,
    sin_t: float,
    cos_t: float,
    rdot: float,
    thetadot: float,
    rddot: float,
    thetaddot: float,
    pitch: float,
    pitch_rate: float,
) -> tuple[float, float, float, float, float]:
    """Time derivatives of :func:`rigid_stance_event_values` along the motion, for Newton's method: the fixed
    body's :func:`stance_event_rates`, then d/dt (tip_limit - |phi|) = -sign(phi) phidot (at pitch 0 the
    margin is the whole tip_limit, far from its event)."""
    bottom, liftoff, reversal, fall = stance_event_rates(
        params, r, sin_t, cos_t, rdot, thetadot, rddot, thetaddot
    )
    return bottom, liftoff, reversal, fall, -pitch_rate if pitch >= 0.0 else pitch_rate


def pitch_velocity_offset(body: Body, sin_p: Real, cos_p: Real, pitch_rate: Real) -> tuple[Real, Real]:
    """The hip's velocity [m/s] relative to the centre of mass's: phidot z^ x R(phi) d."""
    offset_x, offset_y = hip_offset(body, sin_p, cos_p)
    return -pitch_rate * offset_y, pitch_rate * offset_x


def rigid_stance_energy(
    params: HopperParams,
    body: Body,
    r: float,
    sin_t: float,
    cos_t: float,
    rdot: float,
    thetadot: float,
    sin_p: float,
    cos_p: float,
    pitch_rate: float,
) -> float:
    """Total mechanical energy [J] of the rigid body in stance, the toe at height 0: the centre of mass's
    kinetic and gravitational energy, the rotation's J phidot^2 / 2 and the spring's."""
    hip_vx, hip_vy = cartesian_velocity(r, sin_t, cos_t, rdot, thetadot)
    relative_vx, relative_vy = pitch_velocity_offset(body, sin_p, cos_p, pitch_rate)
    com_vx, com_vy = hip_vx - relative_vx, hip_vy - relative_vy
    com_y = r * cos_t - hip_offset(body, sin_p, cos_p)[1]
    kinetic = 0.5 * params.m * (com_vx * com_vx + com_vy * com_vy) + 0.5 * body.inertia * pitch_rate**2
    return kinetic + params.m * params.g * com_y + spring_energy(params, r)


def rigid_stance_hopper_state(
    params: HopperParams,
    body: Body,
    t: float,
    stride: int,
    toe_x: float,
    r: float,
    theta: float,
    rdot: float,
    thetadot: float,
    pitch: float,
    pitch_rate: float,
    tau: float,
) -> HopperState:
    """Full state record of the rigid body in stance on flat ground, the toe at (toe_x, 0): (x, y) and its
    rates are the centre of mass's."""
    sin_t, cos_t = math.sin(theta), math.cos(theta)
    sin_p, cos_p = math.sin(pitch), math.cos(pitch)
    hip_vx, hip_vy = cartesian_velocity(r, sin_t, cos_t, rdot, thetadot)
    relative_vx, relative_vy = pitch_velocity_offset(body, sin_p, cos_p, pitch_rate)
    offset_x, offset_y = hip_offset(body, sin_p, cos_p)
    grf_x, grf_y = ground_reaction_force(params, r, sin_t, cos_t, rdot, tau)
    return HopperState(
        t=t,
        stride=stride,
        phase=Phase.STANCE,
        x=toe_x - r * sin_t - offset_x,
        y=r * cos_t - offset_y,
        xdot=hip_vx - relative_vx,
        ydot=hip_vy - relative_vy,
        toe_x=toe_x,
        toe_y=0.0,
        r=r,
        theta=theta,
        rdot=rdot,
        thetadot=thetadot,
        hip_torque=tau,
        energy=rigid_stance_energy(params, body, r, sin_t, cos_t, rdot, thetadot, sin_p, cos_p, pitch_rate),
        grf_x=grf_x,
        grf_y=grf_y,
        pitch=pitch,
        pitch_rate=pitch_rate,
    )


def rigid_flight_hopper_state(
    params: HopperParams,
    body: Body,
    t: float,
    stride: int,
    x: float,
    y: float,
    xdot: float,
    ydot: float,
    pitch: float,
    pitch_rate: float,
    leg_angle: float,
) -> HopperState:
    """Full state record of the rigid body in flight, (x, y) its centre of mass, the leg held at rest length
    and at leg_angle [rad] from its hip."""
    offset_x, offset_y = hip_offset(body, math.sin(pitch), math.cos(pitch))
    return HopperState(
        t=t,
        stride=stride,
        phase=Phase.FLIGHT,
        x=x,
        y=y,
        xdot=xdot,
        ydot=ydot,
        toe_x=x + offset_x + params.r0 * math.sin(leg_angle),
        toe_y=y + offset_y - params.r0 * math.cos(leg_angle),
        r=params.r0,
        theta=leg_angle,
        rdot=0.0,
        thetadot=0.0,
        hip_torque=0.0,
        energy=flight_energy(params, y, xdot, ydot) + 0.5 * body.inertia * pitch_rate**2,
        grf_x=0.0,
        grf_y=0.0,
        pitch=pitch,
        pitch_rate=pitch_rate,
    )


def rigid_touchdown_time(
    params: HopperParams, body: Body, y_apex: float, pitch: float, pitch_rate: float, cos_touchdown: float
) -> float | None:
    """Time [s] from an apex (centre of mass at y_apex [m], pitch, pitch_rate) to the first touchdown of a leg
    held at rest length at the touchdown angle (its cosine) on flat ground; None if the toe is below the
    ground already at the apex (toe_stubbing).

    The hip's height h(t) = y_apex - g t^2 / 2 + (R(phi0 + phidot t) d)_y - r0 cos(theta_td) is a parabola
    plus a rotation. Steps that h's fastest fall, g t + |phidot| |d|, cannot overshoot approach its first root
    from above (a graze that does not touch is passed), and Newton's step ends them at rounding.
    """
    g = params.g
    height = y_apex - touchdown_height(params, cos_touchdown)

    def gap(t: float) -> float:
        phi = pitch + pitch_rate * t
        return height - 0.5 * g * t * t + hip_offset(body, math.sin(phi), math.cos(phi))[1]

    start = gap(0.0)
    if start < 0.0:
        return None
    reach = abs(pitch_rate) * math.hypot(body.hip_x, body.hip_y)
    if reach == 0.0:
        return fall_time(start, 0.0, 0.0, g)
    t, value = 0.0, start
    tolerance = 1e-15 * max(1.0, params.r0)
    for _ in range(10_000):
        if value <= tolerance:
            break
        rate = g * t + reach
        t += (math.sqrt(rate * rate + 2.0 * g * value) - rate) / g
        value = gap(t)
    phi = pitch + pitch_rate * t
    offset_x = hip_offset(body, math.sin(phi), math.cos(phi))[0]
    slope = -g * t + pitch_rate * offset_x
    return t - value / slope if slope < 0.0 else t


def pitch_limit_time(body: Body, pitch: float, pitch_rate: float) -> float:
    """Time [s] at which a body turning at a constant pitch_rate (in flight) reaches its tip_limit (inf if
    never)."""
    if pitch_rate == 0.0:
        return math.inf
    return (math.copysign(body.tip_limit, pitch_rate) - pitch) / pitch_rate


def tipped(pitch: float, limit: float, when: str) -> tuple[FailureKind, str]:
    return (
        FailureKind.TIPPED,
        f"the body pitched to {pitch:.6g} rad {when}, past its tip_limit {limit:.6g} rad",
    )
