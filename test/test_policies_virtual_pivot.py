"""Stance feedback on a rigid body (issue 36): the virtual pivot point's law, and the exact map's sampled
stance with a body.

Independent truth: the pivot's geometry redone here in Cartesian coordinates (the ground's force must point
from the toe through the pivot), the mirror image of a state, the fixed body's own stride under the same
law (a hip at the centre of mass leaves the centre of mass's motion the point mass's), and the energy
balance with the rotation over strides whose torques the law decides.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tdslip_ros.model import dynamics
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stance_laws import StanceFeedback, StanceSample
from tdslip_ros.model.policies.stance_pd import StancePDSpeedEnergy
from tdslip_ros.model.policies.virtual_pivot import VirtualPivot, pivot_torque

PAPER_HOPPER = HopperParams.from_dimensionless(36.0, 0.08)  # figs 8-10: kbar 36, zeta0 0.08, m 80 kg, r0 1 m
TOUCHDOWN_ANGLE = math.radians(20.0)


def with_body(body: RigidBody) -> HopperParams:
    p = PAPER_HOPPER
    return HopperParams(p.m, p.k, p.r0, p.c, p.g, body)


def random_states(count: int, seed: int) -> list[tuple[StanceSample, RigidBody, float, float]]:
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(count):
        body = RigidBody(rng.uniform(1.0, 20.0), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), math.pi)
        sample = StanceSample(
            0.0,
            0.05,
            rng.uniform(0.8, 1.0),
            rng.uniform(-0.5, 0.5),
            rng.uniform(-2.0, 2.0),
            rng.uniform(-6.0, -1.0),
            0.0,
            rng.uniform(-0.8, 0.8),
            rng.uniform(-3.0, 3.0),
        )
        cases.append((sample, body, rng.uniform(0.0, 0.6), rng.uniform(-0.2, 0.2)))
    return cases


@pytest.mark.parametrize("case", random_states(40, 7))
def test_the_ground_force_points_from_the_toe_through_the_pivot(case):
    sample, body, above, forward = case
    params = with_body(body)
    tau = pivot_torque(params, sample, above, forward)
    # Cartesian, the hip at the origin: the toe r below it along the leg, the centre of mass at minus the
    # turned offset, the pivot at the turned (forward, above) from there.
    toe = np.array([sample.r * math.sin(sample.theta), -sample.r * math.cos(sample.theta)])
    turn = np.array(
        [[math.cos(sample.pitch), -math.sin(sample.pitch)], [math.sin(sample.pitch), math.cos(sample.pitch)]]
    )
    com = -turn @ np.array([body.hip_x, body.hip_y])
    pivot = com + turn @ np.array([forward, above])
    sin_t, cos_t = math.sin(sample.theta), math.cos(sample.theta)
    force = np.array(dynamics.ground_reaction_force(params, sample.r, sin_t, cos_t, sample.rdot, tau))
    to_pivot = pivot - toe
    cross = to_pivot[0] * force[1] - to_pivot[1] * force[0]
    assert abs(cross) <= 1e-12 * np.linalg.norm(to_pivot) * np.linalg.norm(force)
    assert float(force @ to_pivot) > 0.0  # through the pivot, not away from it


@pytest.mark.parametrize("case", random_states(10, 8))
def test_a_mirrored_state_gets_the_mirrored_torque(case):
    sample, body, above, forward = case
    mirrored_body = RigidBody(body.inertia, -body.hip_x, body.hip_y, body.tip_limit)
    mirrored = sample._replace(
        theta=-sample.theta, thetadot=-sample.thetadot, pitch=-sample.pitch, pitch_rate=-sample.pitch_rate
    )
    tau = pivot_torque(with_body(body), sample, above, forward)
    assert pivot_torque(with_body(mirrored_body), mirrored, above, -forward) == pytest.approx(-tau, rel=1e-12)


def test_the_law_needs_a_rigid_body():
    with pytest.raises(ParameterError, match="rigid body"):
        VirtualPivot(PAPER_HOPPER, 0.2)


def test_a_hip_at_the_centre_of_mass_runs_the_fixed_bodys_sampled_stride_under_the_same_law():
    """The law of ref. 36 ignores the pitch; with the hip at the centre of mass the centre of mass moves as
    the point mass does whatever the body turns, so the sampled strides agree to the integrator's accuracy."""
    law = StancePDSpeedEnergy(PAPER_HOPPER, 1.1, 4.5)
    command = StanceFeedback(TOUCHDOWN_ANGLE, law)
    fixed = apex_return_map(PAPER_HOPPER, ApexState(1.05, 4.2), command, apex_time=0.0123)
    rigid = apex_return_map(
        with_body(RigidBody(200.0, tip_limit=math.pi)),
        ApexState(1.05, 4.2, 0.1, 0.3),
        command,
        apex_time=0.0123,
    )
    assert fixed.failure is None and rigid.failure is None
    assert (rigid.apex.y, rigid.apex.xdot, rigid.apex_time) == pytest.approx(
        (fixed.apex.y, fixed.apex.xdot, fixed.apex_time), abs=1e-9
    )
    assert len(rigid.stance_torques) == len(fixed.stance_torques) > 100
    assert np.allclose(rigid.stance_torques, fixed.stance_torques, rtol=0.0, atol=1e-6)
    # the body only spins, by the held torques' integral J dphidot = -sum(tau dt) (the last cut at liftoff)
    times = [t for t, _ in rigid.stance_torques] + [rigid.liftoff.t + 0.0123]
    holds = zip(rigid.stance_torques, times[1:], strict=True)
    impulse = sum(tau * (after - before) for (before, tau), after in holds)
    assert rigid.apex.pitch_rate == pytest.approx(0.3 - impulse / 200.0, abs=1e-9)
    assert abs(impulse / 200.0) > 0.01


@pytest.mark.parametrize("hip_y, above", [(-0.2, 0.3), (0.0, 0.1), (0.2, 0.3)])
def test_the_energy_balance_holds_with_the_rotation_over_sampled_strides(hip_y, above):
    """Hip work minus damper loss is the stance's change of the total energy, J phidot^2 / 2 included."""
    body = RigidBody.from_gyration(80.0, 0.3, hip_y=hip_y)
    params = with_body(body)
    law = VirtualPivot(params, above, 0.03)
    apex = ApexState(1.0 - hip_y, 5.0)

    for _ in range(3):
        result = apex_return_map(params, apex, StanceFeedback(TOUCHDOWN_ANGLE, law), apex_time=0.0)
        assert result.failure is None, result.reason
        scale, flows = apex.energy(params), result.energy
        stance_change = result.liftoff.energy - result.touchdown.energy
        assert stance_change == pytest.approx(flows.hip_work - flows.damping_loss, abs=1e-10 * scale)
        assert result.apex.energy(params) - apex.energy(params) == pytest.approx(
            flows.net_gain, abs=1e-10 * scale
        )
        assert any(tau != 0.0 for _, tau in result.stance_torques)
        apex = result.apex


class SeenSamples:
    """A law that holds no torque and keeps what it sees."""

    def __init__(self) -> None:
        self.seen: list[StanceSample] = []

    def torque(self, sample: StanceSample, lanes=None) -> float:
        self.seen.append(sample)
        return 0.0


def test_a_law_sees_the_bodys_pitch_and_rate_at_every_sample():
    """With no torque and the hip at the centre of mass nothing turns the body: at every sample the pitch is
    the apex's turned at the apex's rate for the time since the apex."""
    law = SeenSamples()
    apex = ApexState(1.05, 4.2, 0.1, 0.3)
    result = apex_return_map(
        with_body(RigidBody(3.0)), apex, StanceFeedback(TOUCHDOWN_ANGLE, law), apex_time=0.0123
    )
    assert result.failure is None and len(law.seen) > 100
    for sample in law.seen:
        assert sample.pitch_rate == pytest.approx(0.3, abs=1e-12)
        assert sample.pitch == pytest.approx(0.1 + 0.3 * (sample.t - 0.0123), abs=1e-12)
