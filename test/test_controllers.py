"""The paper's policies: their promises on the analytic map; deadbeat and PD control of the exact plant."""

from __future__ import annotations

import numpy as np
import pytest

from tdslip_ros.model import units
from tdslip_ros.model.analytic import ParamArrays, approximate_map
from tdslip_ros.model.controllers import (
    admissible_angles,
    deadbeat,
    energy_regulation,
    fixed_power,
    neutral_angle,
    pd_speed_energy_height,
    ramp_to_liftoff,
)
from tdslip_ros.model.exact_map import apex_return_map
from tdslip_ros.model.params import ApexState, HopperParams

PARAMS = HopperParams.from_dimensionless(36.0, 0.08)
Y, XDOT = np.meshgrid([1.0, 1.05, 1.15, 1.3], [2.5, 4.0, 5.5, 7.0], indexing="ij")
ANGLES = np.radians([[[20.0]], [[26.0]], [[32.0]]])  # broadcasts against the (4, 4) states


def _energy(y: np.ndarray, xdot: np.ndarray) -> np.ndarray:
    return PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)


@pytest.mark.parametrize("corrections", [0, 1, 3])
def test_energy_regulation_keeps_the_map_energy_to_solver_precision(corrections: int) -> None:
    command = energy_regulation(PARAMS, Y, XDOT, ANGLES, corrections=corrections)
    stride = approximate_map(PARAMS, Y, XDOT, command, corrections)
    assert stride.ok.sum() > 0.8 * stride.ok.size
    np.testing.assert_allclose(
        stride.energy[stride.ok], np.broadcast_to(_energy(Y, XDOT), stride.ok.shape)[stride.ok], rtol=1e-12
    )
    # The ramp ends at the predicted liftoff of the very stance it produces.
    np.testing.assert_allclose(command.t_f[stride.ok], stride.stance.t_lo[stride.ok], rtol=1e-12)
    # E_tau = E_loss, eq. 32, from the closed forms of the stance.
    stance = stride.stance
    np.testing.assert_allclose(stance.hip_energy[stride.ok], stance.energy_loss[stride.ok], rtol=1e-10)
    assert np.all(command.tau0[stride.ok] < 0.0)  # losses are paid by forward thrust


def test_energy_regulation_with_a_target_energy_reaches_it_in_one_stride() -> None:
    target = _energy(Y, XDOT) * 1.05
    command = energy_regulation(PARAMS, Y, XDOT, np.radians(26.0), target_energy=target)
    stride = approximate_map(PARAMS, Y, XDOT, command)
    assert stride.ok.sum() > 10
    np.testing.assert_allclose(stride.energy[stride.ok], target[stride.ok], rtol=1e-12)


def test_energy_regulation_broadcasts_over_parameter_sets() -> None:
    lanes = ParamArrays.from_dimensionless(np.array([20.0, 36.0, 50.0]), np.array([0.05, 0.08, 0.12]))
    command = energy_regulation(lanes, 1.1, 4.5, np.radians(26.0))
    stride = approximate_map(lanes, 1.1, 4.5, command)
    np.testing.assert_allclose(stride.energy, lanes.m * (lanes.g * 1.1 + 0.5 * 4.5**2), rtol=1e-12)
    for i, (kbar, zeta0) in enumerate([(20.0, 0.05), (36.0, 0.08), (50.0, 0.12)]):
        single = energy_regulation(HopperParams.from_dimensionless(kbar, zeta0), 1.1, 4.5, np.radians(26.0))
        assert float(single.tau0) == pytest.approx(float(command.tau0[i]), rel=1e-11)


def test_fixed_power_puts_the_requested_power_in_at_touchdown() -> None:
    alpha = np.array([0.5, 1.5, 2.5])[:, None, None]
    command = fixed_power(PARAMS, Y, XDOT, np.radians(26.0), alpha)
    stride = approximate_map(PARAMS, Y, XDOT, command)
    ok = stride.ok
    power = command.tau0 * stride.touchdown.thetadot
    expected = np.broadcast_to(units.power_from_alpha(PARAMS, alpha), ok.shape)
    np.testing.assert_allclose(power[ok], expected[ok], rtol=1e-13)
    np.testing.assert_allclose(command.t_f[ok], stride.stance.t_lo[ok], rtol=1e-12)


def test_ramp_to_liftoff_keeps_the_torque_and_ends_the_ramp_at_liftoff() -> None:
    command = ramp_to_liftoff(PARAMS, Y, XDOT, np.radians(24.0), -500.0)
    stride = approximate_map(PARAMS, Y, XDOT, command)
    assert np.all(command.tau0[stride.ok] == -500.0)
    np.testing.assert_allclose(command.t_f[stride.ok], stride.stance.t_lo[stride.ok], rtol=1e-12)


def test_commands_are_nan_where_the_leg_cannot_be_placed() -> None:
    command = energy_regulation(PARAMS, np.array([0.8, 1.1]), np.array([4.0, 4.0]), np.radians(30.0))
    assert np.isnan(command.tau0[0]) and np.isnan(command.t_f[0])
    assert np.isfinite(command.tau0[1]) and np.isfinite(command.t_f[1])


def test_deadbeat_inverts_the_analytic_map_in_one_stride() -> None:
    y, xdot = np.array([1.0, 1.1, 1.2]), np.array([3.0, 4.0, 5.5])
    target_y, target_xdot = np.array([1.1, 1.05, 1.0]), np.array([5.0, 4.7, 3.5])
    command = deadbeat(PARAMS, y, xdot, target_y, target_xdot)
    lower, upper = admissible_angles(PARAMS, y)
    assert np.all((command.touchdown_angle > lower) & (command.touchdown_angle < upper))
    stride = approximate_map(PARAMS, y, xdot, command)
    np.testing.assert_allclose(stride.xdot, target_xdot, rtol=1e-7)
    np.testing.assert_allclose(stride.y, target_y, rtol=1e-6)


@pytest.mark.parametrize(
    ("start", "target"),
    [
        ((1.1, 4.0), (1.05, 4.7)),
        ((1.0, 3.0), (1.1, 5.0)),
        ((1.2, 5.5), (1.0, 3.5)),
        ((1.1, 4.0), (1.02, 2.5)),
    ],
)
def test_deadbeat_brings_the_exact_plant_to_the_target_within_one_percent_in_three_strides(
    start: tuple[float, float], target: tuple[float, float]
) -> None:
    apex = ApexState(*start)
    for _ in range(3):
        result = apex_return_map(PARAMS, apex, deadbeat(PARAMS, apex.y, apex.xdot, *target).command())
        assert result.apex is not None, result.reason
        apex = result.apex
    assert apex.y == pytest.approx(target[0], rel=0.01)
    assert apex.xdot == pytest.approx(target[1], rel=0.01)


def test_pd_baseline_is_the_documented_foot_placement_rule() -> None:
    y, xdot, target = 1.2, np.array([4.0, 4.5, 5.0]), 4.5
    command = pd_speed_energy_height(
        PARAMS, y, xdot, np.array([4.2, 4.5, 4.6]), 1.1, target, kp=0.05, kd=0.02
    )
    expected = (
        neutral_angle(PARAMS, xdot) + 0.05 * (xdot - target) + 0.02 * (xdot - np.array([4.2, 4.5, 4.6]))
    )
    np.testing.assert_allclose(command.touchdown_angle, expected, rtol=1e-15)
    stride = approximate_map(PARAMS, y, xdot, command)
    np.testing.assert_allclose(stride.energy, _energy(np.asarray(1.1), np.asarray(target)), rtol=1e-12)
    # Stance time pi sqrt(m/k): the toe lands half the distance covered in stance ahead of the body.
    stance_time = np.pi * np.sqrt(PARAMS.m / PARAMS.k)
    np.testing.assert_allclose(np.sin(neutral_angle(PARAMS, xdot)), xdot * stance_time / 2.0, rtol=1e-15)
    # Too low to place the leg at the rule's angle: clipped into the admissible interval.
    low = pd_speed_energy_height(PARAMS, 0.9, 2.0, 2.0, 1.1, 3.0)
    assert float(low.touchdown_angle) == pytest.approx(float(admissible_angles(PARAMS, 0.9)[0]), rel=1e-15)


def test_pd_baseline_runs_the_exact_plant_towards_the_target() -> None:
    target_y, target_xdot = 1.05, 4.7
    apex, previous = ApexState(1.1, 4.0), 4.0
    for _ in range(20):
        command = pd_speed_energy_height(
            PARAMS, apex.y, apex.xdot, previous, target_y, target_xdot, kp=0.15, kd=0.05
        )
        result = apex_return_map(PARAMS, apex, command.command())
        assert result.apex is not None, result.reason
        previous, apex = apex.xdot, result.apex
    # A proportional rule without the map keeps a steady error, but far below the initial 15 % in speed.
    assert abs(apex.xdot / target_xdot - 1.0) < 0.03
    assert abs(apex.y / target_y - 1.0) < 0.05
