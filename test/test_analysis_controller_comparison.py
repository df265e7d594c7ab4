"""``tdslip compare``: deadbeat vs apex foot placement from recorded lockstep runs, checked against the
model's simulation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tdslip_ros.analysis import controller_comparison as cc
from tdslip_ros.commands import compare
from tdslip_ros.model import controllers, units
from tdslip_ros.model.batch import simulate_strides
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.policies import DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED

SPEEDS = (0.75, 1.5)  # from the default apex, foot placement cannot plan for 0.75
STRIDES = 8
HEIGHT = 1.0

pytestmark = pytest.mark.nodes  # tdslip compare records its runs with the node suite


@pytest.fixture(scope="module")
def sweep(compare_sweep: Path) -> Path:
    """tdslip compare --out DIR --speeds SPEEDS --strides STRIDES, recorded in the background (conftest)."""
    return compare_sweep


def _model_final_apex(controller: str, speed: float) -> tuple[float, float] | None:
    """The final apex the model's batched exact engine reaches under the same policy, or None if the
    policy finds no command (as the controller node then does not answer)."""
    previous: list[float] = []

    def policy(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[np.ndarray, ...]:
        if controller == "deadbeat":
            command = controllers.deadbeat(PAPER_PARAMS, y, xdot, HEIGHT, speed)
        else:
            before = previous[-1] if previous else xdot
            command = controllers.apex_foot_placement(PAPER_PARAMS, y, xdot, before, HEIGHT, speed)
        previous.append(xdot)
        if not np.all(np.isfinite(command.tau0)):
            raise LookupError("no command")
        return tuple(command)

    try:
        result = simulate_strides(PAPER_PARAMS, DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED, policy, STRIDES)
    except LookupError:
        return None
    return float(result.y[-1]), float(result.xdot[-1])


def test_recorded_sweep_matches_the_model_and_marks_lost_stability(sweep: Path) -> None:
    results = json.loads((sweep / "comparison.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert [(r["controller"], r["target_speed_bar"]) for r in results] == [
        (c, s) for c in cc.CONTROLLERS for s in SPEEDS
    ]
    for row in results:
        speed = float(units.speed_from_bar(PAPER_PARAMS, row["target_speed_bar"]))
        model = _model_final_apex(row["controller"], speed)
        if model is None:
            assert not row["stable"] and row["outcome"] == "command_timeout"
            assert row["speed_error_percent"] is None  # NaN in the results, null in JSON
            continue
        # The recorded final apex is the model's (1 kHz RK4 plant vs DOP853), and so are the errors.
        assert (row["final_height"], row["final_speed"]) == pytest.approx(model, rel=1e-8)
        assert row["stable"] and row["outcome"] == "run_complete"
        assert row["speed_error_percent"] == pytest.approx(100.0 * (model[1] - speed) / speed, abs=1e-6)
        assert row["height_error_percent"] == pytest.approx(100.0 * (model[0] - HEIGHT) / HEIGHT, abs=1e-6)
    stable = {(r["controller"], r["target_speed_bar"]): r["stable"] for r in results}
    assert stable == {
        ("deadbeat", 0.75): True,
        ("deadbeat", 1.5): True,
        ("apex_foot_placement", 0.75): False,
        ("apex_foot_placement", 1.5): True,
    }
    # Deadbeat tracks to a fraction of a percent (the map's error), foot placement to several percent.
    by_key = {(r["controller"], r["target_speed_bar"]): r for r in results}
    assert abs(by_key["deadbeat", 1.5]["speed_error_percent"]) < 0.5
    assert abs(by_key["apex_foot_placement", 1.5]["speed_error_percent"]) > 1.0


def test_figure_marks_where_a_controller_loses_stability(sweep: Path, tmp_path: Path) -> None:
    results = [cc.analyse_run(sweep, entry) for entry in cc.load_sweep(sweep)]
    assert cc.stable_range(results, "deadbeat") == (0.75, 1.5)
    assert cc.stable_range(results, "apex_foot_placement") == (1.5, 1.5)
    figure = cc.plot_tracking(results, tmp_path / "tracking.png")
    assert (tmp_path / "tracking.png").read_bytes()[:4] == b"\x89PNG"
    for axes in figure.axes:
        lines = {line.get_label(): line for line in axes.get_lines()}
        assert set(lines) == {"deadbeat", "apex_foot_placement", "apex_foot_placement loses stability"}
        assert list(lines["apex_foot_placement loses stability"].get_xdata()) == [0.75]
        assert list(lines["deadbeat"].get_xdata()) == [0.75, 1.5]
        placement_errors = np.asarray(lines["apex_foot_placement"].get_ydata())
        assert (
            np.isnan(placement_errors[0]) and placement_errors[1] > 0.0
        )  # no error drawn where foot placement is lost


def test_analyse_only_redoes_the_analysis_from_the_manifest(
    sweep: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = (sweep / "comparison.json").read_text()
    assert compare.main(["--out", str(sweep), "--analyse-only"]) == 0
    assert (sweep / "comparison.json").read_text() == before
    assert "deadbeat: tracks its target xdotbar* in [0.750, 1.500]" in capsys.readouterr().out
