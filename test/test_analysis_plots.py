"""The figures, checked by what they draw (data, ranges, strides), not by pixels."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from support.helpers import assert_png, drawn_line

from tdslip_ros.analysis import plots
from tdslip_ros.analysis.compare import Comparison, compare_run, dimensionless
from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.analysis.records import Run
from tdslip_ros.model import units
from tdslip_ros.nodes.runner import RunReport


@pytest.fixture(scope="module")
def comparison(energy: RunReport) -> Comparison:
    return compare_run(read_run(energy.bag))


@pytest.fixture(scope="module")
def run(comparison: Comparison) -> Run:
    return comparison.run


def test_apex_sequence(comparison: Comparison, tmp_path: Path) -> None:
    figure = plots.apex_sequence(comparison, tmp_path / "apex.png")
    assert_png(tmp_path / "apex.png")
    run, predictions = comparison.run, comparison.predictions
    recorded = dimensionless(run.params, run.apex_array())
    for axes, column in ((0, 0), (1, 1)):
        line = drawn_line(figure.axes[axes], "recorded")
        assert list(line.get_xdata()) == [s.stride for s in run.strides]
        np.testing.assert_array_equal(line.get_ydata(), recorded[:, column])
        for corrections, label in ((0, "analytic map, 0 corrections"), (1, "analytic map, 1 correction")):
            predicted = drawn_line(figure.axes[axes], label)
            assert list(predicted.get_xdata()) == [k + 1 for k in predictions.stride]
            np.testing.assert_array_equal(
                predicted.get_ydata(), dimensionless(run.params, predictions.analytic[corrections])[:, column]
            )
        fixed = comparison.analytic_fixed_point
        assert fixed is not None
        expected = dimensionless(run.params, (fixed.y, fixed.xdot))[column]
        assert drawn_line(figure.axes[axes], "analytic fixed point").get_ydata()[0] == pytest.approx(expected)
        assert drawn_line(figure.axes[axes], "converged (1e-4)").get_xdata()[0] == comparison.converged_at
        low, high = figure.axes[axes].get_ylim()
        assert low <= recorded[:, column].min() and recorded[:, column].max() <= high


def test_return_map_cobweb(comparison: Comparison, tmp_path: Path) -> None:
    figure = plots.return_map(comparison, tmp_path / "map.png")
    assert_png(tmp_path / "map.png")
    heights = comparison.run.apex_array()[:, 0] / comparison.run.params.r0
    cobweb = drawn_line(figure.axes[0], "recorded (cobweb)")
    x, y = np.asarray(cobweb.get_xdata()), np.asarray(cobweb.get_ydata())
    assert len(x) == 2 * (len(heights) - 1) + 1  # one vertical and one horizontal step per stride
    np.testing.assert_array_equal(x[1::2], heights[:-1])  # vertical steps stand on y_k ...
    np.testing.assert_array_equal(y[1::2], heights[1:])  # ... and reach y_{k+1}
    curves = [
        line for line in figure.axes[0].get_lines() if line.get_label().startswith("analytic map at Ebar")
    ]
    assert len(curves) == 1
    curve_x, curve_y = np.asarray(curves[0].get_xdata()), np.asarray(curves[0].get_ydata())
    assert curve_x.min() < heights.min() and heights.max() < curve_x.max()
    # The curve is drawn at the fixed point's energy, so it crosses the diagonal there.
    fixed = comparison.analytic_fixed_point
    assert fixed is not None
    ybar = fixed.y / comparison.run.params.r0
    assert np.interp(ybar, curve_x, curve_y) == pytest.approx(ybar, abs=1e-6)


def test_without_a_policy_the_figures_draw_what_the_recording_shows(
    comparison: Comparison, tmp_path: Path
) -> None:
    """A run of a controller of the user's own: no closed-loop curve, fixed point or target to draw."""
    unknown = dataclasses.replace(comparison, policy=None, command_deviation=None, analytic_fixed_point=None)
    sequence = plots.apex_sequence(unknown, tmp_path / "apex.png")
    assert_png(tmp_path / "apex.png")
    labels = {line.get_label() for line in sequence.axes[0].get_lines()}
    assert "recorded" in labels and "analytic map, 1 correction" in labels
    assert not labels & {"analytic fixed point", "target"}
    assert sequence.axes[0].get_title().endswith(f"({', '.join(comparison.run.policies)})")
    cobweb = plots.return_map(unknown, tmp_path / "map.png")
    assert_png(tmp_path / "map.png")
    labels = {line.get_label() for line in cobweb.axes[0].get_lines()}
    assert "recorded (cobweb)" in labels and not any(label.startswith("analytic map") for label in labels)


def test_com_trajectory_draws_one_stride_with_its_virtual_footfalls(run: Run, tmp_path: Path) -> None:
    stride = 5
    figure = plots.com_trajectory(run, tmp_path / "com.png", stride)
    assert_png(tmp_path / "com.png")
    samples = run.samples
    start, end = run.strides[stride].t, run.strides[stride + 1].t
    window = (samples.t >= start) & (samples.t <= end)
    stance = window & (samples.phase == 1)
    toe = samples.toe_x[stance][0]
    touchdown = next(c for c in run.contacts if c.kind == "touchdown" and c.stride == stride)
    assert toe == pytest.approx(touchdown.state.toe_x, abs=1e-12)
    com = drawn_line(figure.axes[0], "centre of mass")
    np.testing.assert_array_equal(com.get_xdata(), samples.x[window] - toe)
    assert com.get_xdata()[0] == pytest.approx(
        run.strides[stride].x - toe, abs=0.006
    )  # first tick after apex
    forces = [line for line in figure.axes[0].get_lines() if line.get_gid() == plots.GRF_LINE_ID]
    assert all(line.get_ydata()[1] == 0.0 for line in forces)  # each ends on the ground
    pushing = np.count_nonzero(samples.grf_y[np.isin(samples.grf_t, samples.t[stance])] > 0.0)
    assert len(forces) == math.ceil(pushing / plots.GRF_LINE_PERIOD) > 10
    starts = np.array([(line.get_xdata()[0], line.get_ydata()[0]) for line in forces])
    assert np.all(np.isin(starts[:, 0], samples.x[stance] - toe))
    footfalls = np.array([line.get_xdata()[1] for line in forces])
    # Paper, fig. 12: the ramp torque puts the early virtual footfalls behind the toe; as the torque
    # fades they close in on it.
    assert footfalls[0] < -0.05
    assert abs(footfalls[-1]) < abs(footfalls[0]) / 3
    assert list(drawn_line(figure.axes[0], "toe").get_xdata()) == [0.0]
    with pytest.raises(ValueError, match="not a complete recorded stride"):
        plots.com_trajectory(run, tmp_path / "none.png", len(run.strides) - 1)


def test_energy_flows(comparison: Comparison, tmp_path: Path) -> None:
    figure = plots.energy_flows(comparison, tmp_path / "energy.png")
    assert_png(tmp_path / "energy.png")
    run = comparison.run
    complete = run.strides[:-1]
    steps = {patch.get_label(): patch.get_data() for patch in figure.axes[0].patches}
    hip, damping, spring = (
        steps[label] for label in ("hip work (input)", "damping loss", "spring energy left at liftoff")
    )
    for values, edges, _ in (hip, damping, spring):
        assert len(values) == len(complete)  # one step per stride, centred on it
        np.testing.assert_array_equal(edges, np.arange(len(complete) + 1) - 0.5)
    params = run.params
    flows = {
        name: units.energy_to_bar(params, np.array([getattr(s, name) for s in complete]))
        for name in ("hip_work", "damping_loss", "spring_loss")
    }
    np.testing.assert_allclose(hip.values, flows["hip_work"])
    np.testing.assert_allclose(damping.values, -flows["damping_loss"])
    # The spring loss is stacked below the damping loss.
    np.testing.assert_allclose(spring.baseline, -flows["damping_loss"])
    np.testing.assert_allclose(spring.values - spring.baseline, -flows["spring_loss"])
    net = drawn_line(figure.axes[0], "net apex energy change").get_ydata()
    changes = units.energy_to_bar(params, np.diff([s.energy for s in run.strides]))
    np.testing.assert_allclose(net, changes, atol=1e-12)  # the recorded energy balance, drawn
    predicted = drawn_line(figure.axes[0], "analytic input").get_ydata()
    np.testing.assert_allclose(
        predicted, hip.values, rtol=0.05
    )  # the analytic map predicts the input to a few %
