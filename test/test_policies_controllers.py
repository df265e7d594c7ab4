"""The paper's policies: their promises on the analytic map; deadbeat and apex foot placement on the exact
plant; the ideal regulator energy_exact on the exact plant; commands near the edges of the policies' ranges.

Truth used: the analytic map itself (a command's stride, evaluated independently of the policy's solver),
a brute-force scan of the torque (with t_f = t_lo by plain fixed-point iteration) for whether a valid
command exists, the scalar exact map (solve_ivp DOP853) for energy_exact, the 1 kHz stepper for leg
placement.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.learned_policy import learned_file

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.analytic.apex_map import ANALYTIC_MAPS, approximate_map
from tdslip_ros.model.arrays import CommandArrays, NoCommand, NoCommandError, ParamArrays
from tdslip_ros.model.dynamics import speed_from_energy
from tdslip_ros.model.events import EventKind
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.model.policies.controllers import (
    admissible_angles,
    apex_foot_placement,
    deadbeat,
    energy_regulation,
    exact_energy_regulation,
    fixed_power,
    neutral_angle,
    ramp_to_liftoff,
)
from tdslip_ros.model.policies.registry import POLICIES, PolicySpec

PARAMS = PAPER_PARAMS
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


def test_commands_are_nan_and_named_where_the_leg_cannot_be_placed() -> None:
    command = energy_regulation(PARAMS, np.array([0.8, 1.1]), np.array([4.0, 4.0]), np.radians(30.0))
    assert np.isnan(command.tau0[0]) and np.isnan(command.t_f[0])
    assert np.isfinite(command.tau0[1]) and np.isfinite(command.t_f[1])
    assert command.reason(0) is NoCommand.LEG_PLACEMENT and command.reason(1) is None
    with pytest.raises(NoCommandError, match="leg_placement"):
        command.command(0)
    assert command.command(1).tau0 == float(command.tau0[1])


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
    command = apex_foot_placement(PARAMS, y, xdot, np.array([4.2, 4.5, 4.6]), 1.1, target, kp=0.05, kd=0.02)
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
    low = apex_foot_placement(PARAMS, 0.9, 2.0, 2.0, 1.1, 3.0)
    assert float(low.touchdown_angle) == pytest.approx(float(admissible_angles(PARAMS, 0.9)[0]), rel=1e-15)


def test_pd_baseline_runs_the_exact_plant_towards_the_target() -> None:
    target_y, target_xdot = 1.05, 4.7
    apex, previous = ApexState(1.1, 4.0), 4.0
    for _ in range(20):
        command = apex_foot_placement(
            PARAMS, apex.y, apex.xdot, previous, target_y, target_xdot, kp=0.15, kd=0.05
        )
        result = apex_return_map(PARAMS, apex, command.command())
        assert result.apex is not None, result.reason
        previous, apex = apex.xdot, result.apex
    # A proportional rule without the map keeps a steady error, but far below the initial 15 % in speed.
    assert abs(apex.xdot / target_xdot - 1.0) < 0.03
    assert abs(apex.y / target_y - 1.0) < 0.05


# --- the edges of the policies' ranges ---------------------------------------------------------------


def _near_highest_forward_apex(
    betas_deg: list[float], energies_bar: list[float], drops: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Apexes (y, xdot, E) just below y_max(E, beta), the highest apex from which the leg placed at beta
    still swings forward (thetadot_td = 0 there: xdot cos(beta) = |ydot_td| sin(beta)), and beta, as
    broadcast (beta, E, drop) grids; ybar_max = Ebar cos^2(beta) + cos(beta) sin^2(beta)."""
    beta = np.radians(betas_deg)[:, None, None]
    energy_bar = np.asarray(energies_bar)[None, :, None]
    top = energy_bar * np.cos(beta) ** 2 + np.cos(beta) * np.sin(beta) ** 2
    y = units.height_from_bar(PARAMS, top - drops[None, None, :])
    energy = units.energy_from_bar(PARAMS, energy_bar)
    return y, speed_from_energy(PARAMS, y, energy), energy, beta


def _valid_torque_exists(y: np.ndarray, xdot: np.ndarray, beta: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Brute force: some tau0 (on a grid of +-15 m g r0, t_f = t_lo by plain fixed-point iteration) whose
    stride the analytic map accepts brackets a root of E' = target between two accepted neighbours."""
    taus = np.linspace(-15.0, 15.0, 241) * PARAMS.m * PARAMS.g * PARAMS.r0
    y_, xdot_, beta_, target_ = (np.asarray(v)[..., None] for v in np.broadcast_arrays(y, xdot, beta, target))
    t_f = np.full(np.broadcast_shapes(y_.shape, taus.shape), 0.15)
    for _ in range(15):  # t_lo depends weakly on t_f (through p_hat): a strong contraction
        stride = approximate_map(PARAMS, y_, xdot_, CommandArrays(beta_, taus, t_f))
        t_f = np.where(stride.stance.t_lo > 0.0, stride.stance.t_lo, 0.15)
    stride = approximate_map(PARAMS, y_, xdot_, CommandArrays(beta_, taus, t_f))
    gap = np.sign(stride.energy - target_)
    both = stride.ok[..., 1:] & stride.ok[..., :-1]
    return np.asarray(np.any(both & (gap[..., 1:] != gap[..., :-1]), axis=-1))


def test_energy_regulation_takes_the_forward_root_near_the_top_of_its_range() -> None:
    """The issue's example: beta = 26 deg, Ebar = 2.1, ybar = 1.8647. Its backward root (tau0 ~ +2.57 m g r0)
    drives the body backward; the forward root near tau0 = -3.18 m g r0 is the one to return."""
    y = units.height_from_bar(PARAMS, 1.8647)
    xdot = speed_from_energy(PARAMS, y, units.energy_from_bar(PARAMS, 2.1))
    command = energy_regulation(PARAMS, y, xdot, np.radians(26.0))
    assert units.torque_to_bar(PARAMS, float(command.tau0)) == pytest.approx(-3.18, abs=0.02)
    stride = approximate_map(PARAMS, y, xdot, command)
    assert bool(stride.ok) and float(stride.stance.momentum) < 0.0
    assert float(stride.energy) == pytest.approx(units.energy_from_bar(PARAMS, 2.1), rel=1e-12)


def test_no_policy_returns_a_command_its_map_rejects_when_a_valid_one_exists() -> None:
    """Near y_max(E) for beta 20-30 deg: every returned command gives a stride the analytic map accepts
    (with the energy the policy aimed at); where a brute-force torque scan finds a valid command, energy
    regulation and apex foot placement (energy regulation at the rule's angle) return one, and deadbeat does
    wherever energy regulation has one at one of 6 admissible angles; lanes without a command are named."""
    y, xdot, energy, beta = _near_highest_forward_apex(
        [20.0, 23.0, 26.0, 30.0], [1.3, 2.1, 3.5, 6.0], np.array([1e-3, 1e-2, 0.04, 0.1, 0.25])
    )
    y, xdot, energy, beta = np.broadcast_arrays(y, xdot, energy, beta)
    target_y, target_xdot = 1.0, 4.0
    target_energy = units.energy_from_bar(PARAMS, 1.0 + 0.5 * units.speed_to_bar(PARAMS, 4.0) ** 2)
    commands = {
        "energy": (energy_regulation(PARAMS, y, xdot, beta), energy),
        "energy to a target": (energy_regulation(PARAMS, y, xdot, beta, 1.1 * energy), 1.1 * energy),
        "open_loop": (fixed_power(PARAMS, y, xdot, beta, 1.5), None),
        "apex_foot_placement": (
            apex_foot_placement(PARAMS, y, xdot, xdot, target_y, target_xdot),
            target_energy,
        ),
        "deadbeat": (deadbeat(PARAMS, y, xdot, target_y, target_xdot), target_energy),
    }
    for name, (command, aimed) in commands.items():
        stride = approximate_map(PARAMS, y, xdot, command)
        has = np.isfinite(command.tau0)
        assert command.no_command is not None
        assert np.array_equal(has, command.no_command == -1), name
        assert np.all(stride.ok[has]), name
        if aimed is not None:
            np.testing.assert_allclose(stride.energy[has], np.broadcast_to(aimed, has.shape)[has], rtol=1e-10)
    for name, angle in (
        ("energy", beta),
        ("energy to a target", beta),
        ("apex_foot_placement", commands["apex_foot_placement"][0].touchdown_angle),
    ):
        command, aimed = commands[name]
        placed = np.isfinite(angle) & np.asarray(
            dynamics.can_place_leg(PARAMS.r0, PARAMS.g, y, np.cos(np.nan_to_num(angle)))
        )
        exists = placed & _valid_torque_exists(y, xdot, np.nan_to_num(angle, nan=0.3), aimed)
        assert exists.sum() >= 20, name  # the scan is not vacuous (80 lanes)
        assert np.all(np.isfinite(command.tau0[exists])), name
    lower, upper = admissible_angles(PARAMS, y)
    some_angle = np.zeros(y.shape, dtype=bool)
    for fraction in np.linspace(0.05, 0.8, 6):
        trial = energy_regulation(PARAMS, y, xdot, lower + fraction * (upper - lower), target_energy)
        some_angle |= np.isfinite(trial.tau0)
    assert some_angle.sum() >= 20
    assert np.all(np.isfinite(commands["deadbeat"][0].tau0[some_angle]))


def test_the_open_loop_policy_has_no_command_where_its_map_predicts_a_failure() -> None:
    """Its rule fixes tau0 and t_f: where the map rejects them, there is no valid command, and it says so."""
    y, xdot = np.meshgrid(np.linspace(0.95, 1.9, 12), np.linspace(0.3, 6.0, 12), indexing="ij")
    command = fixed_power(PARAMS, y, xdot, np.radians(26.0), 1.0)
    assert command.no_command is not None
    named = command.no_command != -1
    assert 0 < named.sum() < named.size
    # The same rule without the check: tau0 = C/thetadot_td, t_f its predicted liftoff time.
    power = units.power_from_alpha(PARAMS, 1.0)
    free = np.isfinite(command.tau0)
    thetadot = approximate_map(PARAMS, y, xdot, command).touchdown.thetadot
    np.testing.assert_allclose(command.tau0[free] * thetadot[free], power, rtol=1e-13)
    reasons = {command.reason(index) for index in zip(*np.nonzero(named), strict=True)}
    assert reasons <= {NoCommand.PREDICTED_REVERSAL, NoCommand.PREDICTED_FALL, NoCommand.LEG_PLACEMENT}


@pytest.mark.parametrize("corrections", [0, 2])
def test_policies_plan_every_lane_on_its_own_with_any_number_of_corrections(corrections: int) -> None:
    """Issue 9: with corrections = 0 an array input used lane 0's liftoff for every lane, a scalar one
    raised IndexError, and deadbeat returned NaN."""
    y, xdot = np.array([1.0, 0.9, 1.2, 1.05]), np.array([5.0, 4.0, 2.0, 3.0])
    together = energy_regulation(PARAMS, y, xdot, np.radians(20.0), corrections=corrections)
    for lane in range(y.size):
        alone = energy_regulation(PARAMS, y[lane], xdot[lane], np.radians(20.0), corrections=corrections)
        assert alone.reason() == together.reason(lane)
        np.testing.assert_allclose(float(alone.tau0), together.tau0[lane], rtol=1e-12)
    assert together.reason(1) is NoCommand.LEG_PLACEMENT and together.reason(0) is None
    command = deadbeat(PARAMS, 1.1, 4.0, 1.05, 4.7, corrections=corrections)
    stride = approximate_map(PARAMS, 1.1, 4.0, command, corrections)
    assert float(stride.y) == pytest.approx(1.05, rel=1e-6) and float(stride.xdot) == pytest.approx(
        4.7, rel=1e-7
    )


def test_iteration_and_grid_bounds_are_checked_with_a_clear_message() -> None:
    with pytest.raises(ParameterError, match="max_iterations must be at least 1, got 0"):
        energy_regulation(PARAMS, 1.0, 5.0, 0.35, max_iterations=0)
    for grid in (0, 1):
        with pytest.raises(ParameterError, match=f"grid must be at least 2, got {grid}"):
            deadbeat(PARAMS, 1.0, 5.0, 1.0, 4.0, grid=grid)


def test_energy_exact_holds_the_exact_plant_at_its_target_energy_to_1e_10_every_stride() -> None:
    """On the scalar exact map (solve_ivp, independent of the compiled exact stride the policy plans on): the
    next apex energy equals the target to 1e-10 m g r0 at every stride, the ramp ends at the exact liftoff,
    and the run converges."""
    beta, goal = np.radians(26.0), units.energy_from_bar(PARAMS, 3.0)
    apex = ApexState(1.2, 1.05 * float(speed_from_energy(PARAMS, 1.2, goal)))
    heights = []
    for _ in range(12):
        command = exact_energy_regulation(PARAMS, apex.y, apex.xdot, beta, goal).command()
        result = apex_return_map(PARAMS, apex, command)
        assert result.apex is not None and result.liftoff is not None and result.touchdown is not None
        assert abs(units.energy_to_bar(PARAMS, result.apex.energy(PARAMS) - goal)) < 1e-10
        assert command.t_f == pytest.approx(result.liftoff.t - result.touchdown.t, abs=1e-9)
        apex = result.apex
        heights.append(apex.y)
    assert abs(units.height_to_bar(PARAMS, heights[-1] - heights[-2])) < 1e-4  # converged (paper's 1e-4)
    # Without a target it holds the apex energy; where the analytic plan has none, it has none either.
    held = exact_energy_regulation(PARAMS, np.array([1.1, 0.8]), np.array([4.5, 4.5]), beta)
    assert held.reason(1) is NoCommand.LEG_PLACEMENT
    result = apex_return_map(PARAMS, ApexState(1.1, 4.5), held.command(0))
    assert result.apex is not None
    assert result.apex.energy(PARAMS) == pytest.approx(ApexState(1.1, 4.5).energy(PARAMS), rel=1e-11)


def test_every_policy_is_served_by_its_spec(tmp_path: Path) -> None:
    values = dict.fromkeys(PolicySpec.settings(), 1.0) | {
        "touchdown_angle": np.radians(24.0),
        "touchdown_power": float(units.power_from_alpha(PARAMS, 1.2)),
        "target_energy": ApexState(1.1, 4.5).energy(PARAMS),
        "target_height": 1.05,
        "target_speed": 4.6,
        "foot_placement_kp": 0.06,
        "foot_placement_kd": 0.03,
        "policy_file": learned_file(tmp_path / "learned.json"),
    }
    for name in POLICIES:
        for analytic_map in ANALYTIC_MAPS:  # on either analytic map
            spec = PolicySpec.of(name, values | {"analytic_map": analytic_map})
            command = spec.commands(PARAMS, 1.1, 4.5, 4.5).command()
            assert 0.0 < command.touchdown_angle < np.pi / 2 and command.t_f > 0.0


# --- leg placement: one test, shared by the policies and the plant ------------------------------------


def test_the_deadbeat_edge_command_is_accepted_by_the_plant_and_the_hopper_keeps_running() -> None:
    """Issue 9, item 11: towards y* = 0.95 m (below r0) deadbeat places the leg as steeply as it may.
    The stepper judged that against the body height at the end of the apex tick, already below the apex,
    while the controller kept 1e-6 rad: refused. Now both use dynamics.can_place_leg, and deadbeat keeps a
    margin from the map's fall edge: 8 strides at each speed on the 1 kHz plant, no refusal, no fall."""
    for speed in (2.0, 2.5, 3.0, 3.5):
        start = ApexState(1.0, 5.0)
        stepper = FixedStepStepper(
            PARAMS, start, deadbeat(PARAMS, start.y, start.xdot, 0.95, speed).command()
        )
        edge = 0
        while stepper.stride < 8 and stepper.failed is None:
            for event in stepper.step():
                if event.kind is EventKind.APEX:
                    y, xdot = event.state.y, event.state.xdot
                    command = deadbeat(PARAMS, y, xdot, 0.95, speed).command()
                    lowest = float(admissible_angles(PARAMS, y)[0])
                    edge += command.touchdown_angle < lowest + 1e-6
                    stepper.set_command(command)  # raises ParameterError if refused
        assert stepper.failed is None and stepper.stride == 8
        assert edge >= 1  # the edge was used: what used to be refused


def test_the_plant_refuses_a_placement_the_controllers_would_not_plan() -> None:
    stepper = FixedStepStepper(PARAMS, ApexState(0.95, 3.0), StanceCommand(np.radians(25.0), -100.0, 0.15))
    clearance = dynamics.placement_clearance(PARAMS.g)
    lowest, _ = admissible_angles(PARAMS, 0.95)
    stepper.set_command(StanceCommand(float(lowest), -100.0, 0.15))  # the controllers' steepest angle
    steep = float(np.arccos((0.95 - 0.5 * clearance) / PARAMS.r0))  # placeable, but within the lead time
    assert dynamics.can_place_leg(PARAMS.r0, PARAMS.g, 0.95, np.cos(steep)) is np.False_
    with pytest.raises(ParameterError, match="reaches at most"):
        stepper.set_command(StanceCommand(steep, -100.0, 0.15))
    # Late: 10 ms after the apex the body is 0.5 mm lower, below the touchdown height of the angle asked.
    stepper = FixedStepStepper(PARAMS, ApexState(0.95, 3.0), StanceCommand(np.radians(25.0), -100.0, 0.15))
    for _ in range(10):
        stepper.step()
    late = float(np.arccos((0.95 - 2.0 * clearance) / PARAMS.r0))
    with pytest.raises(ParameterError, match="already below"):
        stepper.set_command(StanceCommand(late, -100.0, 0.15))
