"""``tdslip compare``: deadbeat vs the baseline of ref. 36 from recorded lockstep runs, checked stride by
stride against the model's fig. 13 runs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from support.helpers import assert_png, strict_json

from tdslip_ros.analysis import controller_comparison as cc
from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.analysis.figures.tracking import BASELINE, baseline_law, baseline_touchdown_angles
from tdslip_ros.commands import compare
from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.plant.batch import simulate_strides
from tdslip_ros.model.policies import controllers
from tdslip_ros.model.policies.registry import DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED
from tdslip_ros.model.stability import basins

SPEEDS = (0.75, 1.5)  # in 8 strides the baseline converges towards 1.5 but not yet towards 0.75
STRIDES = 8
HEIGHT = 1.0
RECORDED_VS_MODEL = 1e-9
"""m, m/s: a recorded apex against the model's. The plant (RK4, 4 sub-steps per 1 ms tick) and the model's
DOP853 differ by the plant's integration error, some 1e-12 m and m/s over these strides (measured 2.5e-12)."""

pytestmark = pytest.mark.nodes  # tdslip compare records its runs with the node suite


@pytest.fixture(scope="module")
def sweep(compare_sweep: Path) -> Path:
    """tdslip compare --out DIR --speeds SPEEDS --strides STRIDES, recorded in the background (conftest)."""
    return compare_sweep


def _deadbeat_final_apex(speed: float) -> tuple[float, float]:
    """The final apex the model's batched exact engine reaches under deadbeat towards (HEIGHT, speed)."""

    def policy(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[np.ndarray, ...]:
        return tuple(controllers.deadbeat(PAPER_PARAMS, y, xdot, HEIGHT, speed))

    result = simulate_strides(PAPER_PARAMS, DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED, policy, STRIDES)
    return float(result.y[-1]), float(result.xdot[-1])


def _baseline_model_runs() -> tuple[np.ndarray, basins.Basin]:
    """The model's fig. 13 runs of the baseline towards SPEEDS (one lane each): the touchdown angle of each
    target speed [rad], and the batched engine's runs from the node suite's initial apex at those angles,
    the law sampled at 1 kHz."""
    speeds = np.asarray(units.speed_from_bar(PAPER_PARAMS, np.array(SPEEDS)))
    angles = baseline_touchdown_angles(PAPER_PARAMS, HEIGHT, speeds)
    law_of = baseline_law(PAPER_PARAMS, HEIGHT, speeds)
    runs = basins.feedback_basin(
        PAPER_PARAMS, DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED, angles, law_of, STRIDES
    )
    return angles, runs


def test_recorded_sweep_matches_the_model_and_marks_lost_stability(sweep: Path) -> None:
    results = strict_json(sweep / "comparison.json")
    assert [(r["controller"], r["target_speed_bar"]) for r in results] == [
        (c, s) for c in cc.DEFAULT_CONTROLLERS for s in SPEEDS
    ]
    for row in results:
        if row["controller"] != "deadbeat" or not row["stable"]:
            continue
        speed = float(units.speed_from_bar(PAPER_PARAMS, row["target_speed_bar"]))
        model = _deadbeat_final_apex(speed)
        # The recorded final apex is the model's (1 kHz RK4 plant vs DOP853), and so are the errors.
        assert (row["final_height"], row["final_speed"]) == pytest.approx(model, rel=1e-8)
        assert row["speed_error_percent"] == pytest.approx(100.0 * (model[1] - speed) / speed, abs=1e-6)
        assert row["height_error_percent"] == pytest.approx(100.0 * (model[0] - HEIGHT) / HEIGHT, abs=1e-6)
    stable = {(r["controller"], r["target_speed_bar"]): r["stable"] for r in results}
    assert stable == {
        ("deadbeat", 0.75): True,
        ("deadbeat", 1.5): True,
        (BASELINE, 0.75): False,
        (BASELINE, 1.5): True,
    }
    by_key = {(r["controller"], r["target_speed_bar"]): r for r in results}
    lost = by_key[BASELINE, 0.75]
    assert lost["outcome"] == "run_complete" and lost["speed_error_percent"] is None  # NaN: null in JSON
    assert abs(by_key["deadbeat", 1.5]["speed_error_percent"]) < 0.5
    assert abs(by_key[BASELINE, 1.5]["speed_error_percent"]) < 0.5


def test_recorded_baseline_runs_are_the_models_fig13_runs_stride_by_stride(sweep: Path) -> None:
    """Each baseline run landed at the model's angle of its target speed, and every recorded apex is the
    batched engine's under the same sampled law; converged (stable) where the model's run converged."""
    angles, model = _baseline_model_runs()
    entries = [e for e in cc.load_sweep(sweep) if e.controller == BASELINE]
    assert [e.target_speed_bar for e in entries] == list(SPEEDS)
    results = {r.target_speed_bar: r for r in (cc.analyse_run(sweep, e) for e in entries)}
    for lane, entry in enumerate(entries):
        assert entry.bag is not None and entry.stance_touchdown_angle is not None
        assert entry.stance_touchdown_angle == angles[lane]
        recorded = read_run(sweep / entry.bag, entry.params).apex_array()
        expected = np.stack([model.history.y[:, lane], model.history.xdot[:, lane]], axis=1)
        np.testing.assert_allclose(recorded, expected, rtol=0.0, atol=RECORDED_VS_MODEL)
        assert results[entry.target_speed_bar].stable == (model.outcome[lane] == basins.CONVERGED)


def test_figure_marks_where_a_controller_loses_stability(sweep: Path, tmp_path: Path) -> None:
    results = [cc.analyse_run(sweep, entry) for entry in cc.load_sweep(sweep)]
    assert cc.stable_range(results, "deadbeat") == (0.75, 1.5)
    assert cc.stable_range(results, BASELINE) == (1.5, 1.5)
    figure = cc.plot_tracking(results, tmp_path / "tracking.png")
    assert_png(tmp_path / "tracking.png")
    for axes in figure.axes:
        lines = {line.get_label(): line for line in axes.get_lines()}
        assert set(lines) == {"deadbeat", BASELINE, f"{BASELINE} loses stability"}
        assert list(lines[f"{BASELINE} loses stability"].get_xdata()) == [0.75]
        assert list(lines["deadbeat"].get_xdata()) == [0.75, 1.5]
        baseline_errors = np.asarray(lines[BASELINE].get_ydata())
        assert np.isnan(baseline_errors[0]) and baseline_errors[1] > 0.0  # no error drawn where it is lost


def test_a_target_speed_without_a_touchdown_angle_is_lost_without_a_run(tmp_path: Path) -> None:
    entry = cc.SweepRun(BASELINE, HEIGHT, 1.0, 0.3, None, PAPER_PARAMS)
    cc.save_sweep(tmp_path, [entry])
    (result,) = [cc.analyse_run(tmp_path, e) for e in cc.load_sweep(tmp_path)]
    assert (result.outcome, result.stable, result.bag) == (cc.NO_TOUCHDOWN_ANGLE, False, None)
    assert math.isnan(result.speed_error_percent) and math.isnan(result.final_speed)
    assert cc.stable_range([result], BASELINE) is None


def test_analyse_only_redoes_the_analysis_from_the_manifest(
    sweep: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = (sweep / "comparison.json").read_text()
    assert compare.main(["--out", str(sweep), "--analyse-only"]) == 0
    assert (sweep / "comparison.json").read_text() == before
    out = capsys.readouterr().out
    assert "deadbeat: tracks its target xdotbar* in [0.750, 1.500]" in out
    assert f"{BASELINE}: tracks its target xdotbar* in [1.500, 1.500]" in out
