"""Perturbed runs of the node suite, recorded and analysed: random blocks, sensing noise, placement errors,
a saturating hip, pushes and a mismatched controller at once, in lockstep, then ``tdslip analyze``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_rgb
from matplotlib.image import imread
from matplotlib.lines import Line2D
from support.analysis_runs import RUNS
from support.helpers import assert_png, drawn_line

from tdslip_ros.analysis import plots
from tdslip_ros.analysis.compare import compare_run, dimensionless
from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.analysis.records import Run
from tdslip_ros.commands import run as run_command
from tdslip_ros.commands import terrain as terrain_command
from tdslip_ros.commands.analyze import main as analyze
from tdslip_ros.interfaces import PERTURBATION_PARAMETERS, perturbation_parameters, stored_parameters
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.nodes import run_options
from tdslip_ros.nodes.parameters import PERTURBATIONS
from tdslip_ros.nodes.runner import RunReport
from tdslip_ros.reporting.style import DPI, POLICY_COLOURS


@pytest.fixture(scope="module")
def rough_run(rough: RunReport) -> Run:
    return read_run(rough.bag)


def test_the_recording_says_how_to_reproduce_the_run(rough: RunReport, rough_run: Run) -> None:
    """The plant's perturbation parameters and the controller's (mismatched) hopper are in custom_data."""
    given = RUNS["rough"]["perturbations"]
    assert isinstance(given, Perturbations)
    stored = stored_parameters(rough_run.custom_data, "plant")
    assert {name: stored[name] for name in PERTURBATION_PARAMETERS.values()} == {
        name: run_options._ros_value(value) for name, value in perturbation_parameters(given).items()
    }
    assert perturbation_parameters(rough_run.perturbations) == perturbation_parameters(given)
    planner = given.mismatch.controller_params(PAPER_PARAMS)
    assert rough_run.controller_params == planner and rough_run.params == PAPER_PARAMS
    assert tuple(spec.name for spec in PERTURBATIONS) == tuple(PERTURBATION_PARAMETERS.values())


def test_recorded_ground_heights_are_the_terrain(rough_run: Run) -> None:
    terrain = rough_run.perturbations.terrain
    samples = rough_run.samples
    assert np.array_equal(samples.ground_height, terrain.height(samples.x))
    touchdowns = [c for c in rough_run.contacts if c.kind == "touchdown"]
    assert len(touchdowns) == len(rough_run.strides) - 1
    for touchdown in touchdowns:
        assert touchdown.ground == touchdown.state.toe_y  # the stance stands where its toe is
        levels = terrain.height(touchdown.state.toe_x + np.array([-1e-9, 0.0]))
        if touchdown.ground != levels[1]:  # landed on a face: between the levels on either side
            assert min(levels) < touchdown.ground < max(levels)
        for contact in (c for c in rough_run.contacts if c.stride == touchdown.stride):
            assert contact.ground == touchdown.ground
    grounds = [s.ground for s in rough_run.strides]
    assert grounds[0] == terrain.height_at(0.0)
    assert grounds[1:] == [t.ground for t in touchdowns]
    assert len(set(grounds)) == len(grounds)  # every stance on another block


def test_every_stride_is_predicted_at_the_flat_ground_level(rough_run: Run) -> None:
    """From each recorded apex and applied command, with the run's terrain, torque limit, push and placement
    error, the exact map predicts the plant's next apex to the 1 kHz plant's own accuracy (~1e-11)."""
    comparison = compare_run(rough_run)
    predictions = comparison.predictions
    assert len(predictions.stride) == len(rough_run.strides) - 1
    error = np.abs(dimensionless(rough_run.params, predictions.exact - predictions.recorded))
    assert np.all(error < 1e-10), error.max()
    assert comparison.energy_balance_residual < 1e-10  # with the pushes' work
    # The controller is replayed on the measured apexes with its own (mismatched) model.
    assert comparison.policy_reproduced, comparison.command_deviation


def test_sensor_placement_pushes_and_saturation_are_as_drawn(rough_run: Run) -> None:
    perturbations = rough_run.perturbations
    draws = perturbations.draws([0], 0, len(rough_run.strides))
    strides = rough_run.strides
    assert [s.measured_y for s in strides] == [
        s.y + e for s, e in zip(strides, draws.height_error[:, 0], strict=True)
    ]
    assert [s.measured_xdot for s in strides] == [
        s.xdot + e for s, e in zip(strides, draws.speed_error[:, 0], strict=True)
    ]
    assert [s.push for s in strides] == draws.push[:, 0].tolist() and strides[5].push != 0.0
    applied = [s for s in strides if s.command is not None]
    assert len(applied) == len(strides) - 1  # every touchdown matched its command
    tau_max = float(perturbations.tau_max)
    touchdowns = {c.stride: c for c in rough_run.contacts if c.kind == "touchdown"}
    for stride in applied:
        state = touchdowns[stride.stride].state
        assert state.theta == stride.placed_angle != stride.command.touchdown_angle  # type: ignore[union-attr]
        assert stride.saturated == (abs(state.hip_torque) == tau_max)
    assert 0 < rough_run.saturated_strides < len(applied)
    # A push shows in the flight after its apex: the touchdown's speed.
    pushed = strides[5]
    assert touchdowns[5].state.xdot == pytest.approx(pushed.xdot + pushed.push, abs=1e-12)


def test_analyze_reports_the_perturbations(
    rough: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert analyze([str(rough.bag), "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "perturbations: terrain blocks:sigma=0.02" in printed and "mismatch mass=1.05" in printed
    summary = json.loads((tmp_path / "summary.json").read_text())
    saturated = summary["run"]["perturbations"]["saturated_strides"]
    assert f"the hip saturated (|tau0| > tau_max) in {saturated} stride(s)" in printed
    assert summary["run"]["perturbations"]["mismatch"] == pytest.approx(
        {"mass_factor": 1.05, "stiffness_factor": 1.0, "damping_factor": 0.9, "rest_length_factor": 1.0}
    )
    assert {"terrain_path", "measured_apex"} <= set(summary["figures"])  # what they draw: the test below
    for name in ("terrain_path.png", "measured_apex.png"):
        assert_png(tmp_path / name)
    rows = summary["strides"]
    assert [row["ground_m"] for row in rows] == [s.ground for s in read_run(rough.bag).strides]
    assert sum(row["saturated"] for row in rows) == saturated


def _drawn(line: Line2D) -> tuple[np.ndarray, np.ndarray]:
    x, y = line.get_data()
    return np.asarray(x, dtype=float), np.asarray(y, dtype=float)


def test_the_perturbation_figures_draw_the_terrain_and_the_true_and_measured_apexes(
    rough_run: Run, tmp_path: Path
) -> None:
    """terrain_path draws the run's terrain (its blocks, in both panels) under the centre of mass, the ground
    height the plant recorded under the body, and the toe's touchdowns on the ground; measured_apex draws,
    per stride, the true apex (above the ground of the last stance) and apart from it the apex the sensor
    reported, in the paper's units (eq. 24), and shades the saturated strides. Truths: the terrain's own
    heights and the recorded strides and samples."""
    run, params = rough_run, rough_run.params
    terrain = run.perturbations.terrain
    figure = plots.terrain_path(run, tmp_path / "terrain_path.png")
    body, ground = figure.axes
    for axes in (body, ground):
        x, y = _drawn(drawn_line(axes, f"ground ({terrain.kind})"))
        np.testing.assert_array_equal(y, terrain.height(x))
        assert x.min() <= run.samples.x.min() and run.samples.x.max() <= x.max()
    assert np.ptp(y) > 0.02  # the blocks of sigma 2 cm: not flat
    x, y = _drawn(drawn_line(body, "centre of mass"))
    np.testing.assert_array_equal(x, run.samples.x)
    np.testing.assert_array_equal(y, run.samples.y)
    x, y = _drawn(drawn_line(ground, "recorded under the body"))
    np.testing.assert_array_equal(y, run.samples.ground_height)
    np.testing.assert_array_equal(y, terrain.height(x))
    touchdowns = [c.state for c in run.contacts if c.kind == "touchdown"]
    x, y = _drawn(drawn_line(ground, "toe at touchdown"))
    assert x.tolist() == [state.toe_x for state in touchdowns] and y.tolist() == [s.toe_y for s in touchdowns]
    assert len(set(y.tolist())) == len(touchdowns) > 5  # each on another block

    figure = plots.measured_apex(compare_run(run), tmp_path / "measured_apex.png")
    strides = [s.stride for s in run.strides]
    scale = (params.r0, math.sqrt(params.g * params.r0))
    true = [[(s.y - s.ground) / scale[0] for s in run.strides], [s.xdot / scale[1] for s in run.strides]]
    measured = [
        [(s.measured_y - s.ground) / scale[0] for s in run.strides],
        [s.measured_xdot / scale[1] for s in run.strides],
    ]
    for column, axes in enumerate(figure.axes):
        x, y = _drawn(drawn_line(axes, "true"))
        assert x.tolist() == strides
        np.testing.assert_allclose(y, true[column], rtol=1e-12)
        x, y = _drawn(drawn_line(axes, "measured (the controller's)"))
        assert x.tolist() == strides
        np.testing.assert_allclose(y, measured[column], rtol=1e-12)
        assert np.all(np.array(measured[column]) != np.array(true[column]))  # the sensing noise shows
        saturated = [patch for patch in axes.patches if patch.get_facecolor()[:3] == to_rgb(plots.SATURATED)]
        assert len(saturated) == run.saturated_strides > 0


def test_a_run_that_fails_on_the_terrain_says_where_and_why(
    wall: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A 30 cm wall at 8 m: the toe cannot clear it."""
    report = wall
    assert not report.outcome.ok and report.recording_complete
    assert analyze([str(report.bag), "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    line = next(line for line in printed.splitlines() if line.startswith("failed on the terrain"))
    assert report.outcome.kind in line and report.outcome.reason in line
    x = float(line.split("x = ")[1].split(" m")[0])
    assert 6.0 < x < 8.5  # at the wall
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["run"]["failure_location"]["x_m"] == pytest.approx(x, abs=1e-3)


@pytest.mark.parametrize(
    ("arguments", "phrase"),
    [
        (["--terrain", "hills"], "terrain 'hills' is not one of: flat"),
        (["--terrain", "blocks:sigma=0.02,length=0.5"], "missing seed=..."),
        (["--apex-noise", "height=-0.1"], "height noise must be finite and >= 0"),
        (["--angle-noise", "sigma=one"], "sigma='one' is not a valid float"),
        (["--mismatch", "mass=0"], "mass mismatch factor must be finite and > 0"),
        (["--tau-max", "-5"], "tau_max must be > 0 N m"),
        (["--push", "3:fast"], "neither STRIDE:DV"),
        # Refused as the run builds its plant node and the controller's model: in the run's rclpy context.
        pytest.param(
            ["--push", "random:size=40,rate=0.5"], "exceeds max_apex_speed", marks=pytest.mark.nodes
        ),
        pytest.param(["--mismatch", "damping=20"], "underdamped leg", marks=pytest.mark.nodes),
    ],
)
def test_malformed_perturbations_stop_tdslip_run_with_one_line(
    arguments: list[str], phrase: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run_command.main(["--out", str(tmp_path / "bag"), *arguments]) == 2  # a usage error
    error = capsys.readouterr().err.strip()
    assert error.startswith("tdslip run: ") and phrase in error and "\n" not in error
    assert not (tmp_path / "bag").exists()


def _energy_spans(printed: str) -> dict[str, float]:
    """The span of the apex energy above ground, per policy, from ``tdslip terrain``'s summary lines."""
    return {
        line.split()[0]: float(line.split("spans ")[1].split()[0])
        for line in printed.splitlines()
        if "spans" in line
    }


def test_the_readme_figure_starts_both_policies_at_one_fixed_point(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``tdslip terrain`` on flat ground: from energy regulation's fixed point, open loop with the hip power
    applied there hops on identically, at one apex energy: any difference over blocks is the terrain's."""
    assert terrain_command.main(["--out", str(tmp_path / "flat.png"), "--sigma", "0", "--strides", "5"]) == 0
    assert _energy_spans(capsys.readouterr().out) == {"energy": 0.0, "open": 0.0}


def _pixels_of(panel: np.ndarray, colour: str) -> int:
    """How many pixels of an RGB image ``panel`` have the matplotlib ``colour`` (to rounding)."""
    return int(np.count_nonzero(np.all(np.abs(panel - np.array(to_rgb(colour))) < 0.01, axis=-1)))


def test_the_readme_figure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The README's figure: over 3 cm blocks energy regulation holds the apex energy above the ground
    closer than open loop, whose energy wanders. The PNG is the 10 x 6.5 in figure: both policies' paths
    over the ground above, their apex energies below."""
    out = tmp_path / "rough.png"
    # 22 deg as the README draws it: at the default 20 deg the toe stubs on 3 cm blocks.
    assert terrain_command.main(["--out", str(out), "--strides", "25", "--touchdown-angle-deg", "22"]) == 0
    spans = _energy_spans(capsys.readouterr().out)
    assert 0.0 < spans["energy"] < 0.75 * spans["open"]
    pixels = imread(out)[..., :3]
    assert pixels.shape == (round(6.5 * DPI), round(10 * DPI), 3)
    split = round(0.6 * len(pixels))  # the panels' height ratio is 3:2
    paths, energies = pixels[:split], pixels[split:]
    # A legend entry is some 40 pixels of its colour: hundreds are a drawn path or energy series.
    for colour in (POLICY_COLOURS["open_loop"], POLICY_COLOURS["energy"]):
        assert _pixels_of(paths, colour) > 200 and _pixels_of(energies, colour) > 200, colour
    assert _pixels_of(paths, "saddlebrown") > 200 and _pixels_of(energies, "saddlebrown") == 0  # the ground
