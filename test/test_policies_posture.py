"""Posture for a rigid body (issue 36): the balancing lean and the stance PD that holds it, on the exact map.

Independent truth: the exact map's own fixed points (the lean the balance predicts against the pitch where
the regulated gait repeats), strides iterated directly (100 strides that keep the body up, against energy
regulation alone that tips it), the body's frame (a quarter turn of the offset turns the lean by as much),
and the sign of the stance PD seen in one stance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tdslip_ros.model.events import FailureKind
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stance_laws import StanceFeedback
from tdslip_ros.model.policies.posture import (
    BalancedPosture,
    HipEnergyRegulation,
    PostureRegulation,
    balance_lean,
)
from tdslip_ros.model.stability.rigid_fixed_points import closed_loop_stride, rigid_fixed_point

PAPER_HOPPER = HopperParams.from_dimensionless(36.0, 0.08)  # figs 8-10: kbar 36, zeta0 0.08, m 80 kg, r0 1 m
BETA = math.radians(20.0)  # registry.DEFAULT_TOUCHDOWN_ANGLE
TARGET = 80.0 * (9.81 * 1.0 + 0.5 * 5.0**2)  # registry.DEFAULT_TARGET_ENERGY: the hip's apex 1 m at 5 m/s
REGULATION = HipEnergyRegulation(BETA, TARGET)
POSTURE = PostureRegulation(BETA, TARGET)


def with_body(hip_y: float, radius: float = 0.3, hip_x: float = 0.0) -> HopperParams:
    p = PAPER_HOPPER
    return HopperParams(p.m, p.k, p.r0, p.c, p.g, RigidBody.from_gyration(p.m, radius, hip_x, hip_y))


def start(params: HopperParams, lean: float) -> ApexState:
    """The apex whose hip is at 1 m, pitched to ``lean``."""
    body = params.body
    return ApexState(1.0 - body.hip_x * math.sin(lean) - body.hip_y * math.cos(lean), 5.0, lean, 0.0)


@pytest.mark.parametrize("hip_y", [-0.3, -0.2, -0.1, 0.2])
def test_the_balancing_lean_is_where_energy_regulation_alone_repeats_its_stride(hip_y):
    """The lean comes from an average over the stride; the exact map's fixed point under the paper's regulator
    pitches within 0.04 rad of it (0.032 rad at -0.1 m, where the lean is steepest, 0.004 rad at -0.2 m)."""
    params = with_body(hip_y)
    guess = -0.3 if hip_y < 0 else 0.3
    point = rigid_fixed_point(params, REGULATION, start(params, guess))
    assert point.success, point.message
    lean = balance_lean(params, point.apex, REGULATION(params, point.apex))
    assert abs(point.apex.pitch) > 0.15
    assert point.apex.pitch == pytest.approx(lean, abs=0.04)


def test_a_quarter_turn_of_the_offset_turns_the_lean_by_as_much():
    apex, ramp = ApexState(1.2, 5.0), StanceCommand(BETA, -200.0, 0.12)
    above = balance_lean(with_body(0.2), apex, ramp)
    behind = balance_lean(with_body(0.0, hip_x=-0.2), ApexState(1.2, 5.0, -math.pi / 2), ramp)
    assert behind == pytest.approx(above - math.pi / 2, abs=1e-12)


def test_a_hip_too_close_to_the_centre_of_mass_has_no_lean():
    params = with_body(-0.03)
    with pytest.raises(ParameterError, match="no lean balances the thrust"):
        balance_lean(params, start(params, 0.0), StanceCommand(BETA, -200.0, 0.12))


def test_the_stance_pd_turns_a_body_pitched_back_towards_the_lean():
    """Hip at the centre of mass: only the hip's torque turns the body. Pitched back from the lean, the law
    takes thrust away, so the body ends the stance nearer the lean than the ramp alone leaves it (measured:
    0.0017 rad against 0.31)."""
    params = with_body(0.0)
    ramp = StanceCommand(BETA, -150.0, 0.12)
    apex = ApexState(1.0, 5.0, 0.2, 0.0)
    inertia = params.body.inertia
    law = BalancedPosture(ramp, 0.0, inertia * 60.0**2, 2.0 * inertia * 60.0)
    held = apex_return_map(params, apex, StanceFeedback(BETA, law), apex_time=0.0)
    free = apex_return_map(
        params, apex, StanceFeedback(BETA, BalancedPosture(ramp, 0.0, 0.0, 0.0)), apex_time=0.0
    )
    assert held.failure is None and free.failure is None
    assert abs(held.liftoff.pitch) < 0.01 and free.liftoff.pitch > 0.3


@pytest.mark.parametrize("hip_y", [-0.3, -0.2, -0.1])
def test_the_posture_law_makes_the_hip_below_the_centre_of_mass_stable_where_regulation_alone_is_not(hip_y):
    params = with_body(hip_y)
    alone = rigid_fixed_point(params, REGULATION, start(params, -0.3))
    held = rigid_fixed_point(params, POSTURE, start(params, -0.3))
    assert alone.success and held.success
    assert alone.spectral_radius > 1.5 and held.spectral_radius < 0.8
    # the same gait: the lean and the speed of the regulated point
    assert held.apex.pitch == pytest.approx(alone.apex.pitch, abs=0.02)
    assert held.apex.xdot == pytest.approx(alone.apex.xdot, abs=0.02)


def test_a_hundred_strides_keep_the_body_up_under_the_posture_law_and_not_without_it():
    params = with_body(-0.2)
    apex = ApexState(1.2, 4.8, -0.2, 0.3)  # off the gait in every coordinate
    pitches = []
    for _ in range(100):
        result = closed_loop_stride(params, POSTURE, apex)
        assert result.failure is None, result.reason
        apex = result.apex
        pitches.append(apex.pitch)
    assert max(abs(p) for p in pitches) < 1.0  # tip_limit pi / 2
    assert np.std(pitches[-20:]) < 1e-6  # settled
    apex, strides = ApexState(1.2, 4.8, -0.2, 0.3), 0
    result = closed_loop_stride(params, REGULATION, apex)
    while result.failure is None and strides < 100:
        apex, strides = result.apex, strides + 1
        result = closed_loop_stride(params, REGULATION, apex)
    assert result.failure is FailureKind.TIPPED and strides < 10
