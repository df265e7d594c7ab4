"""Fixed points of the 4-D apex map of a rigid body under the paper's energy regulation (issue 36).

Independent truth: the exact map iterated directly (a fixed point returns to itself; a perturbation along an
eigenvector grows by its eigenvalue in one stride; a stable point draws a perturbed start in), and the
body's frame, which is ours to choose: a hip above the centre of mass and the same body turned a quarter
turn (the hip behind it) are one hopper, whose fixed point differs by pi/2 in pitch only.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tdslip_ros.model.params import ApexState, HopperParams, RigidBody
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.policies.posture import HipEnergyRegulation
from tdslip_ros.model.stability.rigid_fixed_points import apex_vector, rigid_fixed_point

PAPER_HOPPER = HopperParams.from_dimensionless(36.0, 0.08)  # figs 8-10: kbar 36, zeta0 0.08, m 80 kg, r0 1 m
# registry.DEFAULT_TOUCHDOWN_ANGLE and DEFAULT_TARGET_ENERGY: the hip's apex 1 m at 5 m/s
REGULATION = HipEnergyRegulation(math.radians(20.0), 80.0 * (9.81 * 1.0 + 0.5 * 5.0**2))


def with_body(body: RigidBody) -> HopperParams:
    p = PAPER_HOPPER
    return HopperParams(p.m, p.k, p.r0, p.c, p.g, body)


def next_apex(params: HopperParams, apex: ApexState) -> np.ndarray:
    result = apex_return_map(params, apex, REGULATION(params, apex))
    assert result.failure is None, result.reason
    return apex_vector(result.apex)


def found(params: HopperParams, lean: float):
    hip_y = params.body.hip_x * math.sin(lean) + params.body.hip_y * math.cos(lean)
    point = rigid_fixed_point(params, REGULATION, ApexState(1.0 - hip_y, 5.07, lean, 0.0))
    assert point.success, point.message
    return point


def test_a_hip_below_the_centre_of_mass_leans_forward_and_its_fixed_point_is_unstable():
    params = with_body(RigidBody.from_gyration(80.0, 0.2, hip_y=-0.2))
    point = found(params, -0.3)
    assert np.max(np.abs(next_apex(params, point.apex) - apex_vector(point.apex))) < 1e-9
    assert point.apex.pitch < -0.1  # leaning forward: the leg's force turns it forward against the thrust
    assert not point.stable
    # The largest eigenvalue, against the map: a small step along its eigenvector grows by it in one stride.
    values, vectors = np.linalg.eig(point.jacobian)
    largest = int(np.argmax(np.abs(values)))
    assert abs(values[largest].imag) < 1e-9 and values[largest].real > 1.5
    direction = vectors[:, largest].real
    start = apex_vector(point.apex) + 1e-6 * direction
    grown = (next_apex(params, ApexState(*start)) - apex_vector(point.apex)) / 1e-6
    assert grown == pytest.approx(values[largest].real * direction, abs=1e-3 * values[largest].real)


def test_a_hip_above_the_centre_of_mass_hangs_the_body_back_and_draws_a_perturbed_start_in():
    params = with_body(RigidBody.from_gyration(80.0, 0.2, hip_y=0.2))
    point = found(params, 0.3)
    assert point.apex.pitch > 0.1 and point.stable
    fixed = apex_vector(point.apex)
    state = fixed + np.array([0.01, -0.05, 0.05, 0.1])
    for _ in range(40):
        state = next_apex(params, ApexState(*state))
    # |lambda|^40 is 2.5e-4; the eigenvectors are not orthogonal, so the distance shrinks less at first
    assert np.linalg.norm(state - fixed) < 0.01 * 0.12


def test_the_bodys_frame_is_a_choice_a_quarter_turn_changes_only_the_pitch():
    above = found(with_body(RigidBody.from_gyration(80.0, 0.2, hip_y=0.2)), 0.3)
    behind = found(with_body(RigidBody.from_gyration(80.0, 0.2, hip_x=-0.2)), 0.3 - math.pi / 2)
    assert apex_vector(behind.apex) == pytest.approx(
        apex_vector(above.apex) - np.array([0.0, 0.0, math.pi / 2, 0.0]), abs=1e-9
    )
    assert np.sort_complex(behind.eigenvalues) == pytest.approx(np.sort_complex(above.eigenvalues), abs=1e-5)


def test_where_there_is_no_fixed_point_it_says_so():
    # a hip 0.3 m above with a light body (radius 0.2 m): the regulator's thrust tips it before any lean holds
    point = rigid_fixed_point(
        with_body(RigidBody.from_gyration(80.0, 0.2, hip_y=0.3)), REGULATION, ApexState(0.7, 5.07, 0.3, 0.0)
    )
    assert not point.success and point.apex is None and "no fixed point" in point.message
    assert math.isnan(point.spectral_radius)
