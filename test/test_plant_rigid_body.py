"""The rigid body on the exact map (issue 36): its fixed-body limits, its invariants and its symmetry.

Independent truth here: the fixed body's own strides (a hip at the centre of mass leaves the centre of mass's
motion the point mass's for any inertia; an infinite inertia holds the pitch), the energy balance with the
rotational energy, conservation without torque and damping, flight's ballistic centre of mass and constant
spin, and the mirror symmetry of the equations. test_model_rigid_body_reference.py integrates the stride
separately in Cartesian coordinates.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tdslip_ros.model import body_dynamics
from tdslip_ros.model.events import FailureKind
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map

PAPER_HOPPER = HopperParams.from_dimensionless(36.0, 0.08)  # figs 8-10: kbar 36, zeta0 0.08, m 80 kg, r0 1 m
COMMAND = StanceCommand(math.radians(22.0), -40.0, 0.15)
HIP_APEX = ApexState(1.1, 3.0)  # the hip's apex: the centre of mass's is hip_y lower


def with_body(body: RigidBody, params: HopperParams = PAPER_HOPPER) -> HopperParams:
    return HopperParams(params.m, params.k, params.r0, params.c, params.g, body)


def com_apex(body: RigidBody, pitch: float = 0.0, pitch_rate: float = 0.0) -> ApexState:
    """The apex whose hip is at HIP_APEX at pitch 0."""
    return ApexState(HIP_APEX.y - body.hip_y, HIP_APEX.xdot, pitch, pitch_rate)


@pytest.mark.parametrize("inertia", [2.0, 7.2, 1e6])
def test_a_hip_at_the_centre_of_mass_leaves_the_point_masss_stride_and_spins_the_body_by_the_torque(inertia):
    fixed = apex_return_map(PAPER_HOPPER, HIP_APEX, COMMAND)
    body = RigidBody(inertia, tip_limit=math.pi)
    rigid = apex_return_map(with_body(body), ApexState(1.1, 3.0, 0.1, -0.2), COMMAND)
    assert fixed.failure is None and rigid.failure is None
    assert (rigid.apex.y, rigid.apex.xdot, rigid.apex_time) == pytest.approx(
        (fixed.apex.y, fixed.apex.xdot, fixed.apex_time), abs=1e-9
    )
    assert rigid.liftoff.r == pytest.approx(fixed.liftoff.r, abs=1e-9)
    # J phidot changes by -int(tau) over the stance (the ramp's integral tau0 t_f / 2), nothing else turns it.
    spin = -COMMAND.tau0 * COMMAND.t_f / 2.0 / inertia
    assert rigid.apex.pitch_rate == pytest.approx(-0.2 + spin, abs=1e-9 * max(1.0, spin))
    # The pitch turns at -0.2 rad/s all along, and by the torque's double integral: tau0 t_f^2 / 3 over the
    # ramp, then its full spin from the ramp's end to the apex.
    after_ramp = rigid.apex_time - rigid.touchdown.t - COMMAND.t_f
    turned = -COMMAND.tau0 * COMMAND.t_f**2 / 3.0 / inertia + spin * after_ramp
    assert rigid.apex.pitch == pytest.approx(0.1 - 0.2 * rigid.apex_time + turned, abs=1e-9)


def test_an_infinite_inertia_holds_the_pitch_and_the_stride_is_the_fixed_bodys_moved_by_the_offset():
    body = RigidBody(1e15, hip_x=0.1, hip_y=-0.2)
    fixed = apex_return_map(PAPER_HOPPER, HIP_APEX, COMMAND)
    rigid = apex_return_map(with_body(body), com_apex(body), COMMAND)
    assert rigid.failure is None
    assert rigid.apex.y == pytest.approx(fixed.apex.y - body.hip_y, abs=1e-9)
    assert (rigid.apex.xdot, rigid.apex_time) == pytest.approx((fixed.apex.xdot, fixed.apex_time), abs=1e-9)
    assert rigid.liftoff.toe_x - rigid.liftoff.x == pytest.approx(fixed.liftoff.toe_x - fixed.liftoff.x + 0.1)
    assert abs(rigid.apex.pitch) < 1e-9 and abs(rigid.apex.pitch_rate) < 1e-9
    assert rigid.energy.hip_work == pytest.approx(fixed.energy.hip_work, rel=1e-9)


BODIES = [
    RigidBody.from_gyration(80.0, 0.3, hip_y=-0.3),  # an upright trunk, the hip below the centre of mass
    RigidBody(10.0, hip_x=-0.1, hip_y=-0.2),
    RigidBody(40.0, hip_x=0.05, hip_y=0.1),
]


@pytest.mark.parametrize("body", BODIES, ids=["trunk", "behind", "above"])
def test_the_energy_balance_holds_with_the_rotation(body):
    """Hip work minus damper loss equals the stance's change of the total energy, J phidot^2 / 2 included;
    minus the spring's loss at liftoff, the apexes' change."""
    params = with_body(body)
    apex = com_apex(body, 0.03, -0.2)
    result = apex_return_map(params, apex, COMMAND)
    assert result.failure is None, result.reason
    flows = result.energy
    assert abs(result.apex.pitch_rate - apex.pitch_rate) > 0.05  # the hip's torque turned the body
    scale = apex.energy(params)
    stance_change = result.liftoff.energy - result.touchdown.energy
    assert stance_change == pytest.approx(flows.hip_work - flows.damping_loss, abs=1e-10 * scale)
    assert result.apex.energy(params) - apex.energy(params) == pytest.approx(
        flows.net_gain, abs=1e-10 * scale
    )
    rotation = 0.5 * body.inertia * (result.apex.pitch_rate**2 - apex.pitch_rate**2)
    translation = (result.apex.energy(params) - 0.5 * body.inertia * result.apex.pitch_rate**2) - (
        apex.energy(params) - 0.5 * body.inertia * apex.pitch_rate**2
    )
    assert abs(rotation) > 1e-3 * abs(translation)  # the rotation's share is not negligible


@pytest.mark.parametrize("body", BODIES, ids=["trunk", "behind", "above"])
def test_without_torque_and_damping_a_stance_conserves_the_total_energy(body):
    params = with_body(body, HopperParams.from_dimensionless(36.0, 0.0))
    apex = com_apex(body, -0.02, 0.1)
    result = apex_return_map(params, apex, StanceCommand(math.radians(22.0), 0.0, 0.1))
    assert result.liftoff is not None, result.reason
    assert result.liftoff.energy == pytest.approx(result.touchdown.energy, rel=1e-10)
    assert result.liftoff.r == pytest.approx(params.r0, abs=1e-9)  # the undamped leg lifts off at rest length
    assert result.bottom.energy == pytest.approx(result.touchdown.energy, rel=1e-10)


def test_in_flight_the_centre_of_mass_is_ballistic_and_the_spin_constant():
    body = BODIES[1]
    params = with_body(body)
    apex = com_apex(body, 0.02, 0.3)
    result = apex_return_map(params, apex, COMMAND)
    touchdown, liftoff = result.touchdown, result.liftoff
    t = touchdown.t
    assert (touchdown.x, touchdown.y, touchdown.xdot, touchdown.ydot) == pytest.approx(
        (t * apex.xdot, apex.y - 0.5 * params.g * t * t, apex.xdot, -params.g * t), abs=1e-12
    )
    assert (touchdown.pitch, touchdown.pitch_rate) == pytest.approx((0.02 + 0.3 * t, 0.3), abs=1e-12)
    # The hip's toe touches the ground at touchdown: the hip at r0 cos(theta_td) above it.
    hip_y = (
        touchdown.y + body_dynamics.hip_offset(body, math.sin(touchdown.pitch), math.cos(touchdown.pitch))[1]
    )
    assert hip_y == pytest.approx(params.r0 * math.cos(COMMAND.touchdown_angle), abs=1e-12)
    rise = result.apex_time - liftoff.t
    assert liftoff.ydot - params.g * rise == pytest.approx(0.0, abs=1e-12)
    assert result.apex.pitch == pytest.approx(liftoff.pitch + liftoff.pitch_rate * rise, abs=1e-12)
    assert result.apex.pitch_rate == liftoff.pitch_rate


def test_the_equations_are_mirror_symmetric():
    """Mirrored about the vertical (x, theta, phi, tau and the hip's forward offset change sign), the stance's
    accelerations mirror: rddot stays, thetaddot and phiddot change sign."""
    rng = np.random.default_rng(7)
    for _ in range(50):
        r, theta, rdot, thetadot, pitch, rate, tau, hip_x, hip_y = rng.uniform(
            [0.6, -0.6, -2.0, -3.0, -0.5, -2.0, -200.0, -0.3, -0.3],
            [1.0, 0.6, 2.0, 3.0, 0.5, 2.0, 200.0, 0.3, 0.3],
        )
        body, mirrored = RigidBody(5.0, hip_x, hip_y), RigidBody(5.0, -hip_x, hip_y)

        def accelerations(body, theta, thetadot, pitch, rate, tau, r=r, rdot=rdot):
            return body_dynamics.rigid_stance_accelerations(
                PAPER_HOPPER, body, r, math.sin(theta), math.cos(theta), rdot, thetadot, math.sin(pitch),
                math.cos(pitch), rate, tau,
            )  # fmt: skip

        forward = accelerations(body, theta, thetadot, pitch, rate, tau)
        backward = accelerations(mirrored, -theta, -thetadot, -pitch, -rate, -tau)
        assert backward == pytest.approx((forward[0], -forward[1], -forward[2]), rel=1e-12, abs=1e-9)


def test_a_body_that_pitches_past_its_limit_fails_tipped_where_it_crosses():
    body = RigidBody(2.0, tip_limit=0.05)
    result = apex_return_map(with_body(body), com_apex(body), COMMAND)
    assert result.failure is FailureKind.TIPPED and "into stance" in result.reason, result.reason
    assert result.failure_state.pitch == pytest.approx(0.05, abs=1e-9)
    spinning = apex_return_map(with_body(body), com_apex(body, 0.04, -1.0), COMMAND)
    assert spinning.failure is FailureKind.TIPPED and "before touchdown" in spinning.reason
    assert (spinning.failure_state.t, spinning.failure_state.pitch) == pytest.approx((0.09, -0.05))


def test_the_touchdown_of_a_spinning_body_is_the_first_one():
    """The hip's height is a parabola plus the rotation: its first root, found against a fine scan."""
    body = RigidBody(3.0, hip_x=0.25, hip_y=-0.1)
    params = with_body(body)
    cos_td = math.cos(math.radians(20.0))
    for pitch_rate in (-6.0, -1.0, 2.0, 9.0):
        t = body_dynamics.rigid_touchdown_time(params, body, 1.2, 0.1, pitch_rate, cos_td)
        times = np.linspace(0.0, 1.0, 2_000_001)
        phi = 0.1 + pitch_rate * times
        gap = 1.2 - 0.5 * params.g * times**2 + 0.25 * np.sin(phi) - 0.1 * np.cos(phi) - params.r0 * cos_td
        first = times[np.argmax(gap <= 0.0)]
        assert t == pytest.approx(first, abs=1e-6)
        phi_t = 0.1 + pitch_rate * t
        assert 1.2 - 0.5 * params.g * t * t + 0.25 * math.sin(phi_t) - 0.1 * math.cos(phi_t) == pytest.approx(
            params.r0 * cos_td, abs=1e-13
        )


def test_a_pitch_on_a_fixed_body_and_bad_bodies_are_refused():
    with pytest.raises(ParameterError, match="fixed"):
        apex_return_map(PAPER_HOPPER, ApexState(1.1, 3.0, 0.1), COMMAND)
    for bad in ({"inertia": 0.0}, {"inertia": 1.0, "hip_y": math.nan}, {"inertia": 1.0, "tip_limit": 4.0}):
        with pytest.raises(ParameterError, match="body"):
            RigidBody(**bad)
    with pytest.raises(ParameterError, match="tip_limit"):
        apex_return_map(with_body(RigidBody(1.0, tip_limit=0.2)), ApexState(1.1, 3.0, 0.25), COMMAND)
