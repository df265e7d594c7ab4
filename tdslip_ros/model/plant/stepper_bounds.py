"""What the 1 kHz stepper (:mod:`.stepper`) accepts, apart from its tick loop: a sub-step that resolves the
motion's fastest rate, a start it runs, and for a rigid body a leg that can be placed. Each refusal is a
:class:`~tdslip_ros.model.params.ParameterError` naming why. The node's run options ask the same questions
before a run starts (:func:`check_body`).

The sub-step must resolve the motion's fastest rate (:data:`MAX_RATE_STEP`, :func:`fastest_rate`): a stiff
or heavily damped leg that 1 kHz RK4 cannot follow is refused at construction rather than integrated into
nonsense.
"""

from __future__ import annotations

import math

from tdslip_ros.model import body_dynamics, dynamics
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody
from tdslip_ros.model.plant.flight_landing import FlightReference
from tdslip_ros.model.plant.perturbations import Perturbations

MAX_RATE_STEP = 0.5
"""Largest sub-step times the motion's fastest rate (see :func:`fastest_rate`) the stepper accepts: well
inside RK4's stability limit (2.8), where its local error is still ~1e-4 per sub-step. The paper's
hopper at 1 kHz with 4 sub-steps is at 0.012."""


def check_step(limits: PlausibilityLimits, pitch_rate: float, dt: float, substeps: int) -> None:
    """ParameterError for a tick ``dt`` [s] or a number of ``substeps`` that cannot resolve a motion within
    ``limits`` (its :func:`fastest_rate`, or a start's ``pitch_rate`` if that is faster)."""
    if not (math.isfinite(dt) and dt > 0.0):
        raise ParameterError(f"dt must be a positive finite number, got {dt!r}")
    if substeps < 1:
        raise ParameterError(f"substeps must be at least 1, got {substeps!r}")
    rate = max(fastest_rate(limits), abs(pitch_rate))
    if rate * dt / substeps > MAX_RATE_STEP:
        raise ParameterError(
            f"a sub-step of dt/substeps = {dt / substeps:.6g} s cannot resolve this hopper, whose "
            f"fastest rate is {rate:.6g} 1/s: at most {MAX_RATE_STEP / rate:.6g} s"
        )


def check_body(params: HopperParams, apex: ApexState, perturbations: Perturbations | None) -> None:
    """ParameterError for a start the stepper does not run: a pitch on the fixed body; for a rigid body, an
    apex pitched past its tip_limit and what it does not run for one yet, naming it: uneven terrain (a rigid
    body runs on flat ground at height 0, as on the exact map) and apex noise (its sensor reads no pitch).
    Saturation, pushes and placement errors run."""
    body = params.body
    if body is None:
        if apex.pitch != 0.0 or apex.pitch_rate != 0.0:
            raise ParameterError(
                f"the apex has a pitch ({apex.pitch!r} rad, {apex.pitch_rate!r} rad/s), but the hopper's "
                f"body is fixed: give HopperParams a RigidBody"
            )
        return
    if abs(apex.pitch) >= body.tip_limit:
        raise ParameterError(
            f"the apex pitch {apex.pitch!r} rad is past the body's tip_limit {body.tip_limit!r}"
        )
    if perturbations is None:
        return
    if not perturbations.terrain.is_flat:
        raise ParameterError(
            f"the 1 kHz stepper runs a rigid body on flat ground at height 0 for now, not on the "
            f"{perturbations.terrain.kind} terrain"
        )
    if perturbations.sensing.active:
        raise ParameterError(
            "the 1 kHz stepper has no sensor for a rigid body's apex yet (it would read no pitch): apex "
            "noise is refused"
        )


def fastest_rate(limits: PlausibilityLimits) -> float:
    """The fastest rate [1/s] of a TD-SLIP motion within ``limits``: the leg's fastest mode
    omega0 (zeta0 + sqrt(zeta0^2 - 1)) (omega0 when underdamped), or the swing rate about the toe at the
    highest speed the limits allow, sqrt(2 max_energy / m) / r0, whichever is larger.

    A rigid body moves the leg's mode to the hip's smallest effective mass m_h = 1 / (1/m + |d|^2 / J) along
    the leg (d the hip's offset, J the inertia), the hip's swing by the spin, and adds the spin
    sqrt(2 max_energy / J) of the whole energy bound put into the rotation."""
    params = limits.params
    zeta0 = params.zeta0
    leg = params.omega0 * (zeta0 + math.sqrt(max(zeta0 * zeta0 - 1.0, 0.0)))
    swing = math.sqrt(2.0 * limits.max_energy / params.m) / params.r0
    body = params.body
    if body is None:
        return max(leg, swing)
    reach = math.hypot(body.hip_x, body.hip_y)
    hip_mass = 1.0 / (1.0 / params.m + reach * reach / body.inertia)
    zeta = params.c / (2.0 * math.sqrt(hip_mass * params.k))
    leg = math.sqrt(params.k / hip_mass) * (zeta + math.sqrt(max(zeta * zeta - 1.0, 0.0)))
    spin = math.sqrt(2.0 * limits.max_energy / body.inertia)
    return max(leg, swing + spin * reach / params.r0, spin)


def check_rigid_placement(
    params: HopperParams,
    body: RigidBody,
    touchdown_angle: float,
    placed: float,
    flight: FlightReference,
    pitch: tuple[float, float],
    now: float,
    descending: bool,
) -> None:
    """A rigid body's command in flight at ``now``: ParameterError unless the leg commanded at
    ``touchdown_angle`` can be placed (:func:`.dynamics.can_place_leg`) from the hip's height at the apex of
    the flight from ``flight`` with ``pitch`` (pitch, rate) there (the planners' view,
    :mod:`.policies.posture`), and, in a ``descending`` flight, the touchdown of the leg ``placed`` at that
    angle (:func:`~.rigid_touchdown_time`) has not passed."""
    t_ref, _, y_ref, _, ydot_ref = flight
    rise = ydot_ref / params.g  # 0 when descending: the reference is the apex
    pitch_ref, pitch_rate = pitch
    pitch_apex = pitch_ref + pitch_rate * rise
    y_apex = y_ref + ydot_ref**2 / (2.0 * params.g)
    hip_apex = y_apex + body_dynamics.hip_offset(body, math.sin(pitch_apex), math.cos(pitch_apex))[1]
    cos_td = math.cos(touchdown_angle)
    if not dynamics.can_place_leg(params.r0, params.g, hip_apex, cos_td):
        raise ParameterError(
            f"touchdown_angle {touchdown_angle!r} rad needs the hip at "
            f"{dynamics.touchdown_height(params, cos_td):.6g} m, but it is at {hip_apex:.6g} m at this "
            f"flight's apex, and placement needs a fall of {dynamics.PLACEMENT_LEAD_TIME:g} s from the "
            f"apex to touchdown"
        )
    if descending:
        landing = body_dynamics.rigid_touchdown_time(
            params, body, y_ref, pitch_apex, pitch_rate, math.cos(placed)
        )
        if landing is not None and t_ref + landing < now:
            raise ParameterError(
                f"touchdown_angle {touchdown_angle!r} rad puts the toe on the ground at "
                f"t = {t_ref + landing:.6g} s, before the command arrived ({now:.6g} s)"
            )
