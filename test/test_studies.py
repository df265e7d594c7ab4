"""Study designs and chunks, in one process: what each trajectory runs, and its row.

Truth used: the closed-loop runs of :mod:`tdslip_ros.model.stability.basins` (the goal regulator of fig. 10,
the open-loop basin of fig. 7), fig. 13's deadbeat runs (analysis.figures.tracking.deadbeat_runs) and apex
foot placement's on basins.basin, called directly on the same lanes; numpy's SeedSequence for the draws.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from tdslip_ros.analysis.figures import tracking
from tdslip_ros.model import units
from tdslip_ros.model.arrays import CommandArrays
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.perturbations import StrideConditions
from tdslip_ros.model.policies import controllers
from tdslip_ros.model.policies.registry import PolicySpec
from tdslip_ros.model.stability import analytic_fixed_points, basins
from tdslip_ros.studies import chunk, perturbed, table
from tdslip_ros.studies.design import DESIGN_STREAM, Study, StudyError, Uniform

PARAMS = PAPER_PARAMS
BETA = math.radians(26.0)


def _column(rows, name: str) -> np.ndarray:
    return rows[name].to_numpy(zero_copy_only=False)


def test_a_grid_runs_every_combination_with_the_first_axis_outermost() -> None:
    study = Study.of(
        grid={"policy": ["energy", "deadbeat"], "y0": [1.0, 1.1, 1.2]}, fixed={"xdot0": 4.0}, start="speed"
    )
    assert (study.size, study.cells) == (6, 6)
    lanes = study.lanes(0, 6)
    assert list(lanes["policy"]) == ["energy"] * 3 + ["deadbeat"] * 3
    np.testing.assert_array_equal(lanes["y0"], [1.0, 1.1, 1.2] * 2)
    # Derived: the energy of the start, and the goal regulator's target (NaN target: the initial energy).
    energy = PARAMS.m * (PARAMS.g * lanes["y0"] + 0.5 * 4.0**2)
    np.testing.assert_allclose(lanes["energy0"], energy, rtol=1e-15)
    np.testing.assert_array_equal(lanes["target_energy"], lanes["energy0"])
    assert lanes["kbar"][0] == 36.0 and lanes["touchdown_angle"][0] == pytest.approx(BETA)


def test_monte_carlo_draws_come_from_the_seed_and_the_trajectory_index_only() -> None:
    study = Study.of(
        grid={"energy0": [3000.0, 3500.0]},
        draws={"y0": Uniform(0.95, 1.6), "target_speed": Uniform(3.0, 4.0)},
        samples=50,
        seed=7,
        chunk_size=13,
    )
    whole = study.lanes(0, study.size)
    pieces = [study.lanes(*study.chunk_range(index)) for index in range(study.chunks)]
    for name in ("y0", "target_speed", "energy0", "xdot0"):
        np.testing.assert_array_equal(whole[name], np.concatenate([piece[name] for piece in pieces]))
    # Trajectory 61: cell 1, its own stream.
    generator = np.random.default_rng(np.random.SeedSequence(7, spawn_key=(61, DESIGN_STREAM)))
    assert whole["y0"][61] == generator.uniform(0.95, 1.6)
    assert whole["target_speed"][61] == generator.uniform(3.0, 4.0)
    assert whole["energy0"][61] == 3500.0 and whole["energy0"][49] == 3000.0
    assert np.all((whole["y0"] >= 0.95) & (whole["y0"] <= 1.6))
    assert len(set(whole["y0"])) == study.size
    other_seed = Study.of(
        grid={"energy0": [3000.0, 3500.0]}, draws={"y0": Uniform(0.95, 1.6)}, samples=50, seed=8
    )
    assert not np.any(other_seed.lanes(0, 100)["y0"] == whole["y0"])


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"grid": {"mass": [1.0]}}, "unknown study parameter 'mass'"),
        (
            {"grid": {"policy": ["energy", "raibert"]}, "fixed": {"y0": 1.0, "energy0": 3000.0}},
            "unknown policy 'raibert'",
        ),
        (
            {"draws": {"kbar": Uniform(20, 40)}, "fixed": {"y0": 1.0, "energy0": 3000.0}},
            "kbar is a grid axis or fixed",
        ),
        ({"fixed": {"y0": 1.0}}, "the start rule 'energy' needs energy0"),
        ({"fixed": {"y0": 1.0, "energy0": 3000.0, "xdot0": 3.0}}, "derives xdot0"),
        ({"grid": {"y0": [1.0]}, "fixed": {"y0": 1.1, "energy0": 3000.0}}, "'y0' is given more than once"),
        ({"draws": {"y0": Uniform(1.2, 1.0)}, "fixed": {"energy0": 3000.0}}, "the range of y0 is empty"),
        ({"grid": {"zeta0": [0.5, 1.2]}, "fixed": {"y0": 1.0, "energy0": 3000.0}}, "zeta0 must be in [0, 1)"),
        ({"fixed": {"y0": 1.0, "energy0": 3000.0}, "chunk_size": 0}, "chunk_size must be at least 1"),
        ({"fixed": {"y0": math.inf, "energy0": 3000.0}}, "y0 must be a finite number"),
        (
            {"grid": {"analytic_map": ["ours", "papr"]}, "fixed": {"y0": 1.0, "energy0": 3000.0}},
            "unknown analytic_map 'papr'; one of ours, paper",
        ),
        (
            {"draws": {"analytic_map": Uniform(0, 1)}, "fixed": {"y0": 1.0, "energy0": 3000.0}},
            "analytic_map is a grid axis or fixed",
        ),
        ({"fixed": {"y0": 1.0, "energy0": 3000.0, "analytic_map": 1.0}}, "unknown analytic_map 1.0"),
    ],
)
def test_an_inconsistent_design_is_refused_with_the_reason(settings: dict, message: str) -> None:
    with pytest.raises(StudyError, match=re.escape(message)):
        Study.of(**settings)


def test_a_study_plans_on_either_analytic_map() -> None:
    """An analytic_map axis: each lane's policy plans on its map, so its first stride is the exact map's
    stride under the command of the policy function with that map's next apex speed."""
    apex, target = ApexState(1.05, 4.8), (1.0, 5.0)
    study = Study.of(
        grid={"analytic_map": ["ours", "paper"], "policy": ["deadbeat", "energy"]},
        fixed={"y0": apex.y, "xdot0": apex.xdot, "target_height": target[0], "target_speed": target[1]},
        start="speed",
        strides=1,
    )
    rows = chunk.run_chunk(study, 0)
    assert list(_column(rows, "analytic_map")) == ["ours", "ours", "paper", "paper"]
    energy = apex.energy(PARAMS)
    ends = []
    for name, policy in zip(_column(rows, "analytic_map"), _column(rows, "policy"), strict=True):
        speed = {"ours": "energy", "paper": "liftoff"}[name]
        if policy == "deadbeat":
            command = controllers.deadbeat(PARAMS, apex.y, apex.xdot, *target, speed=speed)
        else:
            command = controllers.energy_regulation(PARAMS, apex.y, apex.xdot, BETA, energy, speed=speed)
        after = apex_return_map(
            PARAMS, apex, command.command(), rtol=basins.EXACT_TOLERANCE, atol=basins.EXACT_TOLERANCE
        ).apex
        assert after is not None
        ends.append((after.y, after.xdot))
    np.testing.assert_allclose(
        np.column_stack([_column(rows, "y_end"), _column(rows, "xdot_end")]), ends, rtol=1e-9
    )
    # deadbeat aims by the next apex speed, so the maps part; energy regulation plans alike on both here.
    assert abs(ends[0][1] - ends[2][1]) > 0.05 and ends[1] == ends[3]


def test_a_chunk_of_the_goal_regulator_is_fig10_s_basin_row_for_row() -> None:
    energies = units.energy_from_bar(PARAMS, np.array([2.0, 3.5, 5.0, 6.0]))
    heights = np.array([0.85, 0.95, 1.2, 1.6, 2.2, 3.5])  # 0.85: toe stubbing; 3.5 m: above y_max at low E
    study = Study.of(grid={"energy0": energies, "y0": heights}, strides=25, chunk_size=100)
    rows = chunk.run_chunk(study, 0)
    expected = basins.regulated_basin(PARAMS, BETA, *np.meshgrid(heights, energies), strides=25)
    outcome = np.asarray(basins.OUTCOMES)[expected.outcome.ravel()]
    np.testing.assert_array_equal(_column(rows, "outcome"), outcome)
    assert {"converged", "toe_stubbing", "impossible"} <= set(outcome)
    np.testing.assert_array_equal(_column(rows, "convergence_stride"), expected.convergence_stride.ravel())
    np.testing.assert_array_equal(_column(rows, "y_fixed"), expected.y.ravel())
    np.testing.assert_array_equal(_column(rows, "xdot_fixed"), expected.xdot.ravel())
    failure = expected.history.failure_stride.ravel()
    np.testing.assert_array_equal(_column(rows, "failure_stride"), failure)
    # Survived: every stride but the failing one; the last apex is the one before the failure.
    survived = _column(rows, "strides_survived")
    failed = (failure >= 0) & (outcome != "impossible")
    np.testing.assert_array_equal(survived[failed], failure[failed])
    assert np.all(survived[outcome == "converged"] == 25) and np.all(survived[outcome == "impossible"] == 0)
    last = expected.history.y.reshape(26, -1)[survived, np.arange(survived.size)]
    possible = outcome != "impossible"
    np.testing.assert_array_equal(_column(rows, "y_end")[possible], last[possible])
    assert np.all(np.isnan(_column(rows, "y_end")[~possible]))
    converged = outcome == "converged"
    assert np.all(_column(rows, "y_std")[converged] > 0.0)
    assert rows.schema.field("y_end").metadata == {b"unit": b"m"}
    assert rows.schema.metadata[b"tdslip.study"] == study.digest.encode()


def test_a_chunk_of_the_open_loop_starts_on_the_energy_fixed_point_as_fig7_does() -> None:
    alphas = np.array([1.0, 1.5])
    heights = np.array([1.0, 1.6, 2.0])
    study = Study.of(
        grid={"touchdown_power": units.power_from_alpha(PARAMS, alphas), "y0": heights},
        fixed={"policy": "open_loop"},
        start="open_loop_fixed_point",
        strides=20,
    )
    rows = chunk.run_chunk(study, 0)
    alpha_grid, height_grid = (a.ravel() for a in np.meshgrid(alphas, heights, indexing="ij"))
    energy = analytic_fixed_points.energy_fixed_point(PARAMS, BETA, alpha_grid, height_grid)
    np.testing.assert_allclose(_column(rows, "energy0"), energy, rtol=1e-12)
    expected = basins.open_loop_basin(PARAMS, BETA, alpha_grid, height_grid, energy, strides=20)
    np.testing.assert_array_equal(_column(rows, "outcome"), np.asarray(basins.OUTCOMES)[expected.outcome])
    np.testing.assert_allclose(_column(rows, "y_end"), expected.history.y[-1], rtol=1e-12)


def test_the_open_loop_starts_on_the_energy_fixed_point_of_its_own_analytic_map() -> None:
    alpha, heights = 1.5, np.array([1.0, 1.6])
    study = Study.of(
        grid={"analytic_map": ["paper", "ours"], "y0": heights},
        fixed={"policy": "open_loop", "touchdown_power": units.power_from_alpha(PARAMS, alpha)},
        start="open_loop_fixed_point",
    )
    lanes = study.lanes(0, study.size)
    paper, ours = (
        analytic_fixed_points.energy_fixed_point(PARAMS, BETA, alpha, heights, speed=s)
        for s in ("liftoff", "energy")
    )
    np.testing.assert_allclose(lanes["energy0"], np.concatenate([paper, ours]), rtol=1e-12)
    assert np.all(np.abs(paper - ours) > 1.0)  # J: the maps' fixed points differ


def test_deadbeat_and_foot_placement_lanes_run_as_the_basins_run_them() -> None:
    """apex_foot_placement keeps each lane's previous apex speed: lanes of one call must not share it."""
    speeds = units.speed_from_bar(PARAMS, np.array([1.0, 1.75, 2.5]))
    study = Study.of(
        grid={"policy": ["deadbeat", "apex_foot_placement"], "target_speed": speeds},
        fixed={"y0": 1.0, "xdot0": 5.0, "target_height": 1.0},
        start="speed",
        strides=20,
    )
    rows = chunk.run_chunk(study, 0)
    previous = np.full(speeds.shape, 5.0)

    def foot_placement(stride: int, y: np.ndarray, xdot: np.ndarray, lanes: np.ndarray) -> CommandArrays:
        command = controllers.apex_foot_placement(PARAMS, y, xdot, previous[lanes], 1.0, speeds[lanes])
        previous[lanes] = xdot
        return command

    runs = (
        tracking.deadbeat_runs(PARAMS, 1.0, speeds, (1.0, 5.0), 20),
        basins.basin(PARAMS, np.ones(3), PARAMS.m * (PARAMS.g + 0.5 * 5.0**2), foot_placement, 20),
    )
    for position, run in enumerate(runs):
        lanes = slice(3 * position, 3 * position + 3)
        outcome = np.asarray(basins.OUTCOMES)[run.outcome]
        np.testing.assert_array_equal(_column(rows, "outcome")[lanes], outcome)
        survived = _column(rows, "strides_survived")[lanes]
        np.testing.assert_array_equal(_column(rows, "xdot_end")[lanes], run.history.xdot[survived, [0, 1, 2]])
    assert list(_column(rows, "outcome")) == ["converged"] * 3 + ["no_command", "converged", "no_command"]


def test_an_apex_beyond_the_plausibility_limits_is_an_impossible_start_not_an_error() -> None:
    study = Study.of(grid={"y0": [1.1, 1e6]}, fixed={"xdot0": 4.0}, start="speed", strides=3)
    outcome = list(_column(chunk.run_chunk(study, 0), "outcome"))
    assert outcome[1] == "impossible" and outcome[0] != "impossible"


def test_the_directory_takes_one_study_and_resumes_only_that_one(tmp_path) -> None:
    study = Study.of(grid={"y0": [1.0, 1.1]}, fixed={"xdot0": 4.0}, start="speed", strides=2)
    table.prepare(tmp_path, study, resume=False)
    with pytest.raises(table.StudyDirectoryError, match="already holds this study; add --resume"):
        table.prepare(tmp_path, study, resume=False)
    table.prepare(tmp_path, study, resume=True)
    other = Study.of(grid={"y0": [1.0, 1.2]}, fixed={"xdot0": 4.0}, start="speed", strides=2)
    with pytest.raises(table.StudyDirectoryError, match="holds another study"):
        table.prepare(tmp_path, other, resume=True)
    with pytest.raises(table.StudyDirectoryError, match="nothing to resume"):
        (tmp_path / "empty" / table.PARTS).mkdir(parents=True)
        table.prepare(tmp_path / "empty", study, resume=True)


# --- perturbed studies ------------------------------------------------------------------------------------


def test_perturbations_need_the_closed_loop_that_holds_commands_and_one_terrain() -> None:
    start = {"y0": 1.0, "energy0": 3000.0}
    with pytest.raises(StudyError, match="need hold_commands"):
        Study.of(grid={"terrain_sigma": [0.0, 0.02]}, fixed=start)
    with pytest.raises(StudyError, match="random blocks \\(terrain_sigma\\) or a step, not both"):
        Study.of(
            grid={"terrain_sigma": [0.02]},
            draws={"step_height": Uniform(-0.1, 0.0)},
            fixed=start,
            hold_commands=True,
        )
    with pytest.raises(StudyError, match="mismatch_mass is a grid axis or fixed, not drawn"):
        Study.of(draws={"mismatch_mass": Uniform(0.9, 1.1)}, fixed=start, hold_commands=True)
    with pytest.raises(StudyError, match="terrain_sigma must be non-negative, got -0.01"):
        Study.of(draws={"terrain_sigma": Uniform(-0.01, 0.02)}, fixed=start, hold_commands=True)
    with pytest.raises(StudyError, match="push_rate must be in \\[0, 1\\], got 1.5"):
        Study.of(fixed=start | {"push_rate": 1.5}, hold_commands=True)
    with pytest.raises(
        StudyError, match="the values of the linked axis noise_height,noise_speed must be 2-tuples"
    ):
        Study.of(grid={"noise_height,noise_speed": [0.01, 0.02]}, fixed=start, hold_commands=True)


def test_a_linked_axis_takes_its_parameters_together() -> None:
    study = Study.of(
        grid={
            "policy": ["energy", "apex_foot_placement"],
            "noise_height,noise_speed": [(0.0, 0.0), (0.01, 0.03), (0.02, 0.06)],
        },
        fixed={"y0": 1.0, "energy0": 3000.0},
        hold_commands=True,
    )
    lanes = study.lanes(0, study.size)
    np.testing.assert_array_equal(lanes["noise_height"], [0.0, 0.01, 0.02] * 2)
    np.testing.assert_array_equal(lanes["noise_speed"], [0.0, 0.03, 0.06] * 2)
    assert study.values_of("noise_speed") == (0.0, 0.03, 0.06)


OPERATING = {"touchdown_angle": math.radians(26.0), "target_energy": units.energy_from_bar(PARAMS, 3.5)}


def test_on_flat_ground_the_held_closed_loop_is_the_basin_loop_to_the_bit() -> None:
    """Where the policy always has a command, holding commands changes nothing: the perturbed runner with no
    perturbation gives basins.run_strides' rows (another engine call path, the same numbers)."""
    grid = {"y0": [0.95, 1.1, 1.4], "energy0": units.energy_from_bar(PARAMS, np.array([3.0, 3.5]))}
    basin = chunk.run_chunk(Study.of(grid=grid, fixed=OPERATING | {"target_energy": math.nan}, strides=20), 0)
    held = chunk.run_chunk(
        Study.of(grid=grid, fixed=OPERATING | {"target_energy": math.nan}, strides=20, hold_commands=True), 0
    )
    assert set(_column(basin, "outcome")) == {"converged"}
    for name in ("outcome", "strides_survived", "convergence_stride", "y_end", "xdot_end", "y_std"):
        np.testing.assert_array_equal(_column(held, name), _column(basin, name))
    assert list(_column(held, "strides_held")) == [0] * 6 and np.all(_column(held, "x_end") > 0.0)


def test_a_perturbed_trajectory_is_the_exact_map_s_stride_by_stride() -> None:
    """Random blocks and sensor noise, energy regulation holding its command: each lane of a chunk against
    the single-trajectory exact map (solve_ivp with events) in a closed loop written out here, with the
    draws of the trajectory's index."""
    study = Study.of(
        grid={"terrain_sigma": [0.03, 0.06]},
        samples=2,
        fixed=OPERATING
        | {"policy": "energy", "y0": 1.0126, "xdot0": 6.994, "noise_height": 0.01, "noise_speed": 0.03},
        start="speed",
        strides=12,
        seed=5,
        hold_commands=True,
    )
    rows = chunk.run_chunk(study, 0)
    lanes = study.lanes(0, study.size)
    spec = PolicySpec.of(
        "energy", {k: lanes[k][0] for k in PolicySpec.settings() if k != "corrections"} | {"corrections": 1}
    )
    for lane in range(study.size):
        one = {name: values[lane : lane + 1] for name, values in lanes.items()}
        perturbations = perturbed.perturbations_of(one, study.seed, "blocks").take(0)
        draws = perturbations.draws(one["trajectory"], 0, study.strides)
        apex, x, ground = ApexState(1.0126, 6.994), 0.0, 0.0
        in_force = spec.commands(PARAMS, apex.y, apex.xdot, apex.xdot).command()
        survived = study.strides
        for stride in range(study.strides):
            seen_y, seen_xdot = (
                apex.y + draws.height_error[stride, 0],
                apex.xdot + draws.speed_error[stride, 0],
            )
            plan = spec.commands(PARAMS, seen_y, seen_xdot, seen_xdot)
            if plan.reason() is None:
                in_force = plan.command()
            result = apex_return_map(
                PARAMS,
                apex,
                in_force,
                rtol=1e-10,
                atol=1e-10,
                conditions=StrideConditions(x=x, ground=ground, terrain=perturbations.terrain),
            )
            if result.apex is None:
                survived = stride
                assert _column(rows, "outcome")[lane] == result.failure.value
                break
            apex, x, ground = result.apex, result.apex_x, result.ground
        assert _column(rows, "strides_survived")[lane] == survived
        if survived == study.strides:
            assert _column(rows, "y_end")[lane] == pytest.approx(apex.y, abs=1e-7)
            assert _column(rows, "x_end")[lane] == pytest.approx(x, abs=1e-7)
    assert set(_column(rows, "outcome")) >= {"toe_stubbing"} and max(_column(rows, "strides_survived")) == 12
