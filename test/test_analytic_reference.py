"""The analytic map and the policies give today the strides and commands they gave when the record was made.

test/data/analytic_reference.npz holds inputs and outputs written by the numpy implementation (commit 48c37ba,
test/data/make_analytic_reference.py) before the maths moved to compiled kernels: strides of the map on
wide ranges with per-lane parameters (every failure kind occurs), commands of every analytic policy with
their no-command reasons, and complex-step Jacobians of closed loops. Values must agree to 1e-12 (relative,
with the quantity's typical size as the floor near zero), failure codes and reasons exactly, with two
exceptions that the last bit of a transcendental function decides (numpy's SIMD loops and the C library
differ there), each allowed on at most 2 % of the lanes:

* A lane without a command may name no_liftoff where it named no_solution, or the reverse: Newton's
  method for a torque that does not exist wanders chaotically, and whether an iterate meets a stance
  without liftoff within the bound on the steps is then a matter of rounding.
* Deadbeat towards a target it cannot reach stops at the extremum of the next speed, where the speed is
  flat in the angle: its angle agrees to its own tolerance (1e-9 rad), and the next apexes the two
  commands give agree to 1e-12.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tdslip_ros.model.analytic.apex_map import approximate_map
from tdslip_ros.model.analytic.closed_loop import map_jacobian
from tdslip_ros.model.arrays import CommandArrays, NoCommand, ParamArrays, no_command_code
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.policies.controllers import (
    apex_foot_placement,
    deadbeat,
    energy_regulation,
    fixed_power,
    ramp_to_liftoff,
)

RECORD = np.load(Path(__file__).parent / "data" / "analytic_reference.npz")
PARAMS = PAPER_PARAMS
AGREEMENT = 1e-12


def _assert_agrees(name: str, new: np.ndarray, old: np.ndarray) -> None:
    new, old = np.broadcast_arrays(np.asarray(new), np.asarray(old))
    assert np.array_equal(np.isnan(new), np.isnan(old)), f"{name}: NaN lanes differ"
    finite = ~np.isnan(old)
    if not finite.any():
        return
    typical = float(np.median(np.abs(old[finite])))
    error = np.abs(new[finite] - old[finite]) / (np.abs(old[finite]) + typical)
    assert error.max() <= AGREEMENT, f"{name}: worst relative difference {error.max():.3g}"


@pytest.mark.parametrize(
    ("case", "corrections", "liftoff"),
    [("1_paper", 1, "paper"), ("0_paper", 0, "paper"), ("2_force_root", 2, "force_root")],
)
def test_the_map_gives_the_recorded_strides(case: str, corrections: int, liftoff: str) -> None:
    params = ParamArrays(*(RECORD[f"map_{name}"] for name in ("m", "k", "r0", "c", "g")))
    command = CommandArrays(RECORD["map_angle"], RECORD["map_tau0"], RECORD["map_t_f"])
    stride = approximate_map(params, RECORD["map_y"], RECORD["map_xdot"], command, corrections, liftoff)
    assert np.array_equal(stride.failure, RECORD[f"map{case}_failure"])
    assert 0.3 * stride.failure.size < stride.ok.sum() < stride.failure.size  # both outcomes are checked
    for name, value in (
        ("y", stride.y),
        ("xdot", stride.xdot),
        ("energy", stride.energy),
        ("t_lo", stride.stance.t_lo),
        ("momentum", stride.stance.momentum),
        ("hip_energy", stride.stance.hip_energy),
        ("energy_loss", stride.stance.energy_loss),
    ):
        recorded = RECORD[f"map{case}_{name}"]
        # Failed lanes of the stance keep whatever the closed forms gave; compare where the stride succeeded.
        _assert_agrees(name, np.where(stride.ok, value, np.nan), np.where(stride.ok, recorded, np.nan))


def _policy_commands() -> dict[str, CommandArrays]:
    y, xdot, beta = RECORD["policy_y"], RECORD["policy_xdot"], RECORD["policy_beta"]
    target = RECORD["policy_target_energy"]
    ty, txdot, previous = RECORD["target_y"], RECORD["target_xdot"], RECORD["target_previous_xdot"]
    goal_y, goal_xdot = RECORD["target_target_y"], RECORD["target_target_xdot"]
    return {
        "energy": energy_regulation(PARAMS, y, xdot, beta),
        "energy_target": energy_regulation(PARAMS, y, xdot, beta, target),
        "energy_target_0": energy_regulation(PARAMS, y, xdot, beta, target, corrections=0),
        "energy_target_2": energy_regulation(PARAMS, y, xdot, beta, target, corrections=2),
        "open_loop": fixed_power(PARAMS, y, xdot, beta, RECORD["policy_alpha"]),
        "ramp": ramp_to_liftoff(PARAMS, y, xdot, beta, RECORD["policy_tau0"]),
        "deadbeat": deadbeat(PARAMS, ty, txdot, goal_y, goal_xdot),
        "apex_foot_placement": apex_foot_placement(PARAMS, ty, txdot, previous, goal_y, goal_xdot),
    }


_WANDERING = {no_command_code(NoCommand.NO_LIFTOFF), no_command_code(NoCommand.NO_SOLUTION)}


def _flat_extremum_lanes(command: CommandArrays, recorded: CommandArrays) -> np.ndarray:
    """Deadbeat lanes whose commands differ by more than AGREEMENT but within the angle tolerance, giving
    the same next apex to 1e-12 (module docstring)."""
    differ = np.zeros(command.tau0.shape, dtype=bool)
    for new, old in zip(command, recorded, strict=True):
        differ |= np.abs(new - old) > AGREEMENT * (np.abs(old) + np.nanmedian(np.abs(old)))
    y, xdot = RECORD["target_y"][differ], RECORD["target_xdot"][differ]
    assert np.all(np.abs(command.touchdown_angle - recorded.touchdown_angle)[differ] <= 2e-9)
    new_apex = approximate_map(PARAMS, y, xdot, CommandArrays(*(field[differ] for field in command)))
    old_apex = approximate_map(PARAMS, y, xdot, CommandArrays(*(field[differ] for field in recorded)))
    _assert_agrees("deadbeat next height", new_apex.y, old_apex.y)
    _assert_agrees("deadbeat next speed", new_apex.xdot, old_apex.xdot)
    return differ


def test_the_policies_give_the_recorded_commands_and_reasons() -> None:
    for name, command in _policy_commands().items():
        assert command.no_command is not None
        reason = RECORD[f"command_{name}_reason"]
        swapped = command.no_command != reason
        assert all(
            {int(a), int(b)} <= _WANDERING
            for a, b in zip(command.no_command[swapped], reason[swapped], strict=True)
        )
        assert swapped.sum() <= 0.02 * reason.size, name
        assert (command.no_command == -1).sum() > 0.5 * command.no_command.size, name
        recorded = CommandArrays(*(RECORD[f"command_{name}_{field}"] for field in ("angle", "tau0", "t_f")))
        same = np.ones(reason.shape, dtype=bool)
        if name == "deadbeat":
            same = ~_flat_extremum_lanes(command, recorded)
            assert same.sum() >= 0.98 * same.size
        for field, new, old in zip(("angle", "tau0", "t_f"), command, recorded, strict=True):
            _assert_agrees(f"{name} {field}", new[same], old[same])


def test_complex_step_jacobians_of_the_closed_loops_are_the_recorded_ones() -> None:
    y, xdot, beta = RECORD["jacobian_y"], RECORD["jacobian_xdot"], np.radians(26.0)
    by_speed = map_jacobian(PARAMS, y, xdot, lambda p, y_, x_: energy_regulation(p, y_, x_, beta))
    energy = PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)
    by_energy = map_jacobian(
        PARAMS, y, energy, lambda p, y_, x_: fixed_power(PARAMS, y_, x_, beta, 1.5), "energy"
    )
    assert np.all(np.isfinite(by_speed)) and np.all(np.isfinite(by_energy))
    _assert_agrees("energy regulation, speed", by_speed, RECORD["jacobian_energy_speed"])
    _assert_agrees("open loop, energy", by_energy, RECORD["jacobian_open_loop_energy"])
