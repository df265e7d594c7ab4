"""A recorded run against the analytic map: ground truth from the model itself, convergence, fixed points."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from support.analysis_runs import as_if_from_ones_own_controller

from tdslip_ros.analysis.compare import (
    analytic_fixed_point,
    compare_run,
    convergence,
    convergence_stride,
    dimensionless,
    policy_for_run,
    recorded_fixed_point,
)
from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.analysis.records import Run
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import approximate_return_map
from tdslip_ros.model.analytic.closed_loop import closed_loop_map, eigenvalues, map_jacobian
from tdslip_ros.model.arrays import CommandArrays, ParamArrays
from tdslip_ros.model.events import EventKind
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.model.policies import controllers
from tdslip_ros.model.policies.registry import (
    LEARNED,
    POSTURE,
    STANCE_PD_SPEED_ENERGY,
    PolicyError,
    PolicySpec,
    settings_of,
)
from tdslip_ros.model.stability import analytic_fixed_points
from tdslip_ros.nodes.runner import RunReport


@pytest.fixture(scope="module")
def run(energy: RunReport) -> Run:
    # The plant's own parameters, so that the model below computes with bit-identical inputs.
    return read_run(energy.bag, energy.params)


def _replay_on_the_model(run: Run) -> tuple[list[tuple[int, float, float, float]], list[tuple[float, ...]]]:
    """The model's 1 kHz stepper driven by the commands the plant applied: apexes and energy flows."""
    first = run.strides[0]
    assert first.command is not None
    stepper = FixedStepStepper(run.params, ApexState(first.y, first.xdot), first.command, dt=1e-3)
    apexes = [(0, 0.0, first.y, first.xdot)]
    flows = []
    while len(apexes) < len(run.strides):
        for event in stepper.step():
            assert event.kind is not EventKind.FAILURE, event.reason
            if event.kind is EventKind.APEX:
                apexes.append((event.stride, event.t, event.state.y, event.state.xdot))
                energy = stepper.last_stride_energy
                assert energy is not None
                flows.append((energy.hip_work, energy.damping_loss, energy.spring_loss))
                command = run.strides[event.stride].command
                if command is not None:
                    stepper.set_command(command)
    return apexes, flows


def test_the_analysis_recovers_the_plants_own_apex_sequence_exactly(run: Run) -> None:
    apexes, flows = _replay_on_the_model(run)
    assert [(s.stride, s.t, s.y, s.xdot) for s in run.strides] == apexes
    assert [(s.hip_work, s.damping_loss, s.spring_loss) for s in run.strides[:-1]] == flows


def test_prediction_errors_agree_with_the_models_own(run: Run) -> None:
    apexes, _ = _replay_on_the_model(run)
    comparison = compare_run(run)
    predictions = comparison.predictions
    assert list(predictions.stride) == [s.stride for s in run.strides[:-1]]
    for corrections in (0, 1):
        direct_errors = []
        for k, stride in enumerate(run.strides[:-1]):
            assert stride.command is not None
            predicted, failure = approximate_return_map(
                run.params, ApexState(apexes[k][2], apexes[k][3]), stride.command, corrections
            )
            assert failure is None and predicted is not None
            direct_errors.append((predicted.y - apexes[k + 1][2], predicted.xdot - apexes[k + 1][3]))
        errors = predictions.analytic[corrections] - predictions.recorded
        np.testing.assert_allclose(errors, direct_errors, rtol=1e-9, atol=1e-13)
        worst = np.max(np.abs(dimensionless(run.params, np.array(direct_errors))), axis=0)
        stats = comparison.errors[corrections]
        assert (stats.max_height, stats.max_speed) == pytest.approx(tuple(worst), rel=1e-9)
        assert stats.failures == 0 and stats.strides == len(run.strides) - 1
    # The correction makes the map more accurate, as the paper says.
    assert comparison.errors[1].max_height < comparison.errors[0].max_height


def test_the_1khz_plant_agrees_with_the_high_accuracy_exact_map(run: Run) -> None:
    comparison = compare_run(run)
    for k, stride in enumerate(run.strides[:-1]):
        assert stride.command is not None
        exact = apex_return_map(run.params, ApexState(stride.y, stride.xdot), stride.command)
        assert exact.apex is not None
        np.testing.assert_allclose(
            comparison.predictions.exact[k], (exact.apex.y, exact.apex.xdot), rtol=1e-10
        )
    # The issue-2 accuracy target of the plant against a high-accuracy solve.
    assert comparison.exact_errors.max_height < 1e-9 and comparison.exact_errors.max_speed < 1e-9


def test_the_recorded_energy_balance_holds(run: Run) -> None:
    assert compare_run(run).energy_balance_residual < 1e-9


def test_the_policy_replay_reproduces_the_applied_commands(run: Run) -> None:
    policy = policy_for_run(run)
    assert policy.name == "energy" and policy.target_energy == run.strides[0].energy
    comparison = compare_run(run, policy)
    assert comparison.policy_reproduced and comparison.command_deviation < 1e-9
    wrong = compare_run(run, policy_for_run(run, target_energy=0.99 * policy.target_energy))
    assert not wrong.policy_reproduced


def test_the_policy_settings_come_from_the_parameters_stored_in_the_bag(
    deadbeat: RunReport, tmp_path_factory: pytest.TempPathFactory
) -> None:
    run = read_run(deadbeat.bag)
    assert run.custom_data["tdslip_ros.controller.target_speed"] == "4.0"
    assert run.custom_data["tdslip_ros.plant.max_strides"] == "4"
    policy = policy_for_run(run)
    assert policy.source == "the controller parameters stored in the recording"
    assert (policy.name, policy.target) == ("deadbeat", (1.0, 4.0))  # not the installed default 5 m/s
    assert compare_run(run, policy).policy_reproduced
    # A bare copy of the .mcap keeps them: they are in its rosbag2 metadata record.
    bare = tmp_path_factory.mktemp("bare") / "run.mcap"
    shutil.copyfile(run.path / f"{run.path.name}_0.mcap", bare)
    assert read_run(bare).custom_data == run.custom_data


def test_energy_exact_holds_the_1khz_plant_at_its_target_energy(energy_exact: RunReport) -> None:
    """The ideal regulator in the node suite: every recorded apex has the target energy (the initial
    one) to the 1 kHz plant's own accuracy (~1e-11), and the analysis replays its commands."""
    run = read_run(energy_exact.bag)
    policy = policy_for_run(run)
    assert policy.name == "energy_exact" and policy.target_energy == run.strides[0].energy
    energies = np.array([stride.energy for stride in run.strides])
    assert len(energies) == 7
    np.testing.assert_allclose(energies, policy.target_energy, rtol=1e-10)
    assert compare_run(run, policy).policy_reproduced


def test_a_run_of_an_unknown_policy_is_analysed_without_replaying_it(
    energy: RunReport, run: Run, tmp_path: Path
) -> None:
    own = read_run(as_if_from_ones_own_controller(energy, tmp_path / "own.mcap"), energy.params)
    assert own.policies == ("my_controller",) and own.custom_data
    assert policy_for_run(own) is None
    comparison, known = compare_run(own), compare_run(run)
    # What needs the policy is skipped ...
    assert comparison.policy is None and comparison.policy_name == "my_controller"
    assert comparison.command_deviation is None and not comparison.policy_reproduced
    assert comparison.analytic_fixed_point is None
    # ... the rest needs only the recorded apexes and applied commands: the same as the known policy's
    # analysis of the same strides (checked against the model above), to the plant's accuracy.
    predictions = comparison.predictions
    np.testing.assert_array_equal(predictions.stride, known.predictions.stride)
    np.testing.assert_array_equal(predictions.recorded, known.predictions.recorded)
    np.testing.assert_array_equal(predictions.exact, known.predictions.exact)
    for corrections in (0, 1):
        np.testing.assert_array_equal(
            predictions.analytic[corrections], known.predictions.analytic[corrections]
        )
        assert comparison.errors[corrections] == known.errors[corrections]
    assert comparison.exact_errors.max_height < 1e-9 and comparison.exact_errors.max_speed < 1e-9
    assert comparison.converged_at == known.converged_at is not None
    assert comparison.recorded_fixed_point == known.recorded_fixed_point
    # Naming a known policy compares with it as before, its settings from the recording and the defaults.
    named = compare_run(own, policy_for_run(own, name="energy"))
    assert named.policy_reproduced and named.analytic_fixed_point == known.analytic_fixed_point
    with pytest.raises(PolicyError, match="unknown policy 'my_controller'"):
        policy_for_run(own, name="my_controller")


def test_a_converged_run_has_its_fixed_point_near_the_analytic_one(run: Run) -> None:
    comparison = compare_run(run)
    assert comparison.converged_at is not None and comparison.converged_at < 8  # the paper's "at most 8"
    recorded, analytic = comparison.recorded_fixed_point, comparison.analytic_fixed_point
    assert recorded is not None and analytic is not None
    last = run.strides[-1]
    assert (recorded.y, recorded.xdot) == pytest.approx((last.y, last.xdot), rel=1e-9)
    # The analytic map is accurate to ~1e-3 here, and so is its fixed point.
    assert (
        np.max(np.abs(dimensionless(run.params, (recorded.y - analytic.y, recorded.xdot - analytic.xdot))))
        < 5e-3
    )
    assert abs(recorded.dominant) < 1.0 and abs(analytic.dominant) < 1.0
    assert abs(abs(recorded.dominant) - abs(analytic.dominant)) < 0.1


def test_a_failed_run_is_reported_by_stride(fall: RunReport) -> None:
    report = fall
    run = read_run(report.bag)
    assert run.outcome is not None and run.outcome.fatal and run.outcome.kind == report.outcome.kind
    failed = [s for s in run.strides if s.failure is not None]
    assert [(s.stride, s.failure) for s in failed] == [(run.outcome.stride, "fall")]
    assert failed[0].failure_reason == run.outcome.reason
    comparison = compare_run(run)
    assert comparison.converged_at is None and comparison.recorded_fixed_point is None
    # The failing stride is predicted too (no recorded next apex): the exact map fails there as well.
    predictions = comparison.predictions
    assert predictions.stride[-1] == failed[0].stride
    assert np.all(np.isnan(predictions.recorded[-1])) and np.all(np.isnan(predictions.exact[-1]))
    for corrections in (0, 1):
        named = np.array([name is not None for name in predictions.analytic_failures[corrections]])
        assert np.array_equal(named, np.isnan(predictions.analytic[corrections][:, 0]))
        assert comparison.errors[corrections].strides == len(predictions.stride) - 1


# --- convergence and the fitted dynamics, on sequences with known answers ----------------------------


def _sequence(
    params: HopperParams, matrix: np.ndarray, start: np.ndarray, fixed: np.ndarray, n: int
) -> np.ndarray:
    """n + 1 apexes (SI) of the linear stride map s_{k+1} = s* + A (s_k - s*), A in dimensionless units."""
    bar = [fixed + start]
    for _ in range(n):
        bar.append(fixed + matrix @ (bar[-1] - fixed))
    bar_array = np.array(bar)
    return np.stack(
        [units.height_from_bar(params, bar_array[:, 0]), units.speed_from_bar(params, bar_array[:, 1])],
        axis=-1,
    )


FIXED = np.array([0.97, 1.62])
BASIS = np.array([[1.0, 0.4], [-0.3, 1.0]])


@pytest.mark.parametrize(
    "values",
    [np.array([0.6, -0.3]), np.array([0.5 + 0.4j, 0.5 - 0.4j]), np.array([0.05, 0.0])],
    ids=["real", "complex", "fast"],
)
def test_the_fit_recovers_fixed_point_and_eigenvalues(values: np.ndarray) -> None:
    if np.iscomplexobj(values):
        matrix = abs(values[0]) * np.array(
            [
                [np.cos(np.angle(values[0])), -np.sin(np.angle(values[0]))],
                [np.sin(np.angle(values[0])), np.cos(np.angle(values[0]))],
            ]
        )
    else:
        matrix = BASIS @ np.diag(values) @ np.linalg.inv(BASIS)
    apexes = _sequence(PAPER_PARAMS, matrix, np.array([2e-3, -1e-3]), FIXED, 14)
    fitted = recorded_fixed_point(PAPER_PARAMS, apexes)
    assert fitted is not None
    fixed_bar = dimensionless(PAPER_PARAMS, (fitted.y, fitted.xdot))
    # The last apex is still far (up to ~1e-7) from s*; the extrapolation is not.
    assert np.max(np.abs(fixed_bar - FIXED)) < 1e-11
    expected = sorted(values, key=lambda v: -abs(v))
    np.testing.assert_allclose(
        sorted(fitted.eigenvalues, key=lambda v: (-abs(v), v.imag)),
        sorted(expected, key=lambda v: (-abs(v), v.imag)),
        atol=1e-6,
    )


def test_convergence_is_the_first_stride_from_which_every_change_is_small() -> None:
    # Changes (dimensionless, in height) that dip below the tolerance at stride 1 and rise above it again.
    changes = [5e-3, 5e-5, 2e-4, 5e-5, 1e-5, 2e-6, 4e-7]
    bar = np.array([FIXED + (total, 0.0) for total in np.concatenate([[0.0], np.cumsum(changes)])])
    apexes = np.stack(
        [units.height_from_bar(PAPER_PARAMS, bar[:, 0]), units.speed_from_bar(PAPER_PARAMS, bar[:, 1])],
        axis=-1,
    )
    assert convergence_stride(PAPER_PARAMS, apexes) == 3
    converged_at, fitted = convergence(PAPER_PARAMS, apexes)
    assert converged_at == 3 and fitted is not None
    assert abs(fitted.dominant) == pytest.approx(0.2, rel=1e-6)  # the last changes shrink fivefold


def test_small_but_growing_changes_are_a_drift_not_convergence() -> None:
    apexes = _sequence(PAPER_PARAMS, np.diag([1.004, 0.3]), np.array([1e-6, 1e-6]), FIXED, 30)
    assert convergence_stride(PAPER_PARAMS, apexes) == 0  # every change is below the tolerance ...
    converged_at, fitted = convergence(PAPER_PARAMS, apexes)
    assert converged_at is None  # ... but they grow
    assert fitted is not None and fitted.dominant == pytest.approx(1.004, abs=1e-6)


def test_no_convergence_while_the_last_change_is_large() -> None:
    apexes = _sequence(PAPER_PARAMS, np.diag([0.9, 0.5]), np.array([0.5, 0.0]), FIXED, 10)
    assert convergence(PAPER_PARAMS, apexes) == (None, None)
    assert convergence(PAPER_PARAMS, apexes[:1]) == (None, None)


# --- analytic fixed points -----------------------------------------------------------------------------


def _spec(name: str, **values: float) -> PolicySpec:
    defaults = {
        "touchdown_angle": math.radians(20.0),
        "touchdown_power": 925.0,
        "target_energy": 1784.8,
        "target_height": 1.0,
        "target_speed": 5.0,
        "foot_placement_kp": 0.06,
        "foot_placement_kd": 0.03,
        "corrections": 1,
        "analytic_map": "ours",
        # The stance-feedback policies' and the learned one's, which these policies do not read.
        **{setting.name: setting.default for setting in settings_of(STANCE_PD_SPEED_ENERGY)},
        **{setting.name: setting.default for setting in settings_of(POSTURE)},
        **{setting.name: setting.default for setting in settings_of(LEARNED)},
    }
    return PolicySpec(name=name, **{**defaults, **values})  # type: ignore[arg-type]


def test_energy_regulation_fixed_point_and_eigenvalues_match_the_models_jacobian() -> None:
    spec = _spec("energy")
    fixed = analytic_fixed_point(PAPER_PARAMS, spec, (1.0, 5.0))
    assert fixed is not None

    def policy(params: ParamArrays, y: np.ndarray, xdot: np.ndarray) -> CommandArrays:
        return controllers.energy_regulation(params, y, xdot, spec.touchdown_angle, spec.target_energy)

    after = closed_loop_map(PAPER_PARAMS, fixed.y, fixed.xdot, policy)
    assert (float(after.y), float(after.xdot)) == pytest.approx((fixed.y, fixed.xdot), rel=1e-10)
    assert ApexState(fixed.y, fixed.xdot).energy(PAPER_PARAMS) == pytest.approx(spec.target_energy, rel=1e-10)
    # Complex-step Jacobian of the model (independent of the central differences used here).
    reference = eigenvalues(map_jacobian(PAPER_PARAMS, fixed.y, fixed.xdot, policy))
    assert abs(fixed.dominant) == pytest.approx(abs(reference[0]), abs=1e-6)
    assert abs(fixed.dominant) < 1.0
    # The model's bracketed search over the whole energy-regulated height map finds it too.
    found = analytic_fixed_points.regulated_fixed_points(
        PAPER_PARAMS, spec.touchdown_angle, [spec.target_energy]
    )
    nearest = int(np.nanargmin(np.abs(found.y[0] - fixed.y)))
    assert found.y[0, nearest] == pytest.approx(fixed.y, rel=1e-9)
    assert found.spectral_radius[0, nearest] == pytest.approx(abs(fixed.dominant), abs=1e-6)


def test_the_deadbeat_fixed_point_is_its_target() -> None:
    fixed = analytic_fixed_point(
        PAPER_PARAMS, _spec("deadbeat", target_height=1.05, target_speed=4.0), (0.9, 5.0)
    )
    assert fixed is not None
    assert (fixed.y, fixed.xdot) == pytest.approx((1.05, 4.0), rel=1e-9)
    assert abs(fixed.dominant) < 1e-4  # deadbeat: the analytic map reaches the target in one stride


def test_the_foot_placement_fixed_point_is_a_fixed_point_of_the_model_policy() -> None:
    spec = _spec("apex_foot_placement")
    fixed = analytic_fixed_point(PAPER_PARAMS, spec, (1.0, 5.0))
    assert fixed is not None
    command = controllers.apex_foot_placement(
        PAPER_PARAMS,
        fixed.y,
        fixed.xdot,
        fixed.xdot,
        spec.target_height,
        spec.target_speed,
        kp=spec.foot_placement_kp,
        kd=spec.foot_placement_kd,
    ).command()
    after, failure = approximate_return_map(PAPER_PARAMS, ApexState(fixed.y, fixed.xdot), command)
    assert failure is None and after is not None
    assert (after.y, after.xdot) == pytest.approx((fixed.y, fixed.xdot), rel=1e-10)
    assert len(fixed.eigenvalues) == 3  # (y, xdot, previous xdot): the derivative term remembers a stride


def test_no_fixed_point_where_the_map_fails() -> None:
    # Apex 0.5 m cannot place the leg at 20 deg (toe stubbing): Newton has nowhere to start.
    assert analytic_fixed_point(PAPER_PARAMS, _spec("energy"), (0.5, 5.0)) is None
