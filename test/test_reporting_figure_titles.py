"""Titles fit their figures: every figure the commands draw, laid out as they save it
(:func:`tdslip_ros.reporting.style.save_figure`), has its titles, suptitle and axis labels inside the figure.

Truth used: matplotlib's renderer (``figure.canvas.draw()``, then each text's window extent against the
figure's bounding box), on each figure function at a tiny resolution; the recorded run's figures
(``tdslip analyze``) on a recorded run of the node tier.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.text import Text
from test_cli_figures import TINY, quiet

from tdslip_ros.analysis import controller_comparison, plots, rough_terrain
from tdslip_ros.analysis.compare import compare_run
from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.analysis.figures.catalogue import FIGURES
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.terrain import Blocks
from tdslip_ros.model.policies.registry import LEARNED, POLICIES
from tdslip_ros.model.stability.viability import viable_set
from tdslip_ros.model.stability.viability_spaces import ApexSpace, EnergySpace, q_map
from tdslip_ros.nodes.runner import RunReport
from tdslip_ros.reporting.style import lay_out, titles
from tdslip_ros.studies import chunk, robustness, viability_outputs
from tdslip_ros.studies.sweep import SWEEPS

MINI = dataclasses.replace(
    TINY,
    heights=8,
    alphas=5,
    energies=4,
    exact_heights=6,
    exact_energies=3,
    bisections=1,
    basin_alphas=2,
    basin_heights=2,
    basin_energies=2,
    speed_step=2.5,
)
"""Smaller than test_cli_figures.TINY: a figure's titles do not depend on its resolution."""
ANGLES = np.radians([15.0, 20.0, 25.0])


def texts(figure: Figure) -> list[Text]:
    """The titles and axis labels the figure shows."""
    labels = [label for axes in figure.axes for label in (axes.xaxis.label, axes.yaxis.label)]
    return titles(figure) + [label for label in labels if label.get_text() and label.get_visible()]


def outside(figure: Figure) -> list[str]:
    """The texts of ``figure``, laid out as the commands lay it out, that reach beyond its edges."""
    lay_out(figure)
    FigureCanvasAgg(figure).draw()
    box = figure.bbox
    found = []
    for text in texts(figure):
        extent = text.get_window_extent()
        if extent.x0 < box.x0 - 0.5 or extent.x1 > box.x1 + 0.5 or extent.y0 < box.y0 or extent.y1 > box.y1:
            found.append(f"{text.get_text()!r}: x {extent.x0:.0f}-{extent.x1:.0f} of {box.x1:.0f}")
    return found


def test_a_title_longer_than_its_figure_is_found_and_the_layout_wraps_it() -> None:
    """The check itself, on a title twice as wide as its figure: beyond both edges drawn as it is, inside
    once laid out."""
    figure = Figure(figsize=(4, 3))
    figure.subplots().set_title("a title far longer than the four inches of its figure, " * 2)
    FigureCanvasAgg(figure).draw()
    extent = texts(figure)[0].get_window_extent()
    assert extent.x0 < 0 and extent.x1 > figure.bbox.x1
    assert outside(figure) == []


@pytest.mark.parametrize("name", list(FIGURES))
def test_the_paper_s_figures_fit_their_titles(name: str) -> None:
    figure, _ = FIGURES[name](MINI, quiet(), "energy")
    assert outside(figure) == []


@pytest.mark.parametrize("name", list(SWEEPS))
def test_the_sweeps_fit_their_titles(name: str) -> None:
    sweep = SWEEPS[name]
    studies = sweep.studies((2, 2), 2, None, "ours")
    tables = {
        key: pa.concat_tables([chunk.run_chunk(study, index) for index in range(study.chunks)])
        for key, study in studies.items()
    }
    figure, _ = sweep.draw(studies, tables)
    assert outside(figure) == []


def test_the_robustness_figures_fit_their_titles() -> None:
    policies = [policy for policy in POLICIES if policy != LEARNED]
    kinds = robustness.KINDS
    summary = [
        {
            "kind": kind,
            "size": size,
            "policy": policy,
            "surviving": 1.0,
            "median_strides": 50.0,
            "apex_height_spread": 0.01,
            **dict.fromkeys(robustness.FAILURES, 1),
        }
        for kind in kinds
        for policy in policies
        for size in robustness.KINDS[kind].sizes
    ]
    figure = robustness.draw(
        summary, kinds, policies, "surviving", "fraction surviving 50 strides", "survival"
    )
    assert outside(figure) == []
    assert outside(robustness.draw_failures(summary, list(kinds), policies)) == []


@pytest.mark.parametrize("space", ["energy", "apex"])
def test_the_viability_figures_fit_their_titles(space: str) -> None:
    """Both layouts: a pair space (one state, one action) and a 2-D state space."""
    if space == "energy":
        slip = dataclasses.replace(PAPER_PARAMS, c=0.0)
        grid = EnergySpace(slip, 3.0 * slip.m * slip.g, np.linspace(0.3, 0.9, 4), ANGLES)
    else:
        grid = ApexSpace(
            PAPER_PARAMS, np.linspace(1.0, 1.3, 3), np.linspace(3.0, 5.0, 3), ANGLES, np.zeros(1), 0.2
        )
    qmap = q_map(grid)
    drawn = viability_outputs.figures(qmap, viable_set(qmap))
    assert sorted(drawn) == ["kernel.png", "measure.png", "qmap.png"]
    for name, figure in drawn.items():
        assert outside(figure) == [], name


def test_the_terrain_figure_fits_its_titles(tmp_path: Path) -> None:
    apex = ApexState(1.0, 5.0)
    start, specs = rough_terrain.policies(PAPER_PARAMS, apex, math.radians(rough_terrain.TOUCHDOWN_ANGLE_DEG))
    blocks = Blocks(0.03, 0.5, 1, 2.0)
    hops = [
        rough_terrain.hop(PAPER_PARAMS, spec, start, Perturbations(terrain=blocks), 3)
        for spec in specs.values()
    ]
    figure = rough_terrain.draw(PAPER_PARAMS, blocks, hops, tmp_path / "terrain.png")
    assert outside(figure) == []


def test_the_tracking_figure_fits_its_titles(tmp_path: Path) -> None:
    results = [
        controller_comparison.Tracking(
            controller, 1.0, speed, speed, "converged", True, 10, 1.0, speed, 0.1, 0.1, None, None
        )
        for controller in controller_comparison.CONTROLLERS
        for speed in (0.5, 1.0, 1.5)
    ]
    figure = controller_comparison.plot_tracking(results, tmp_path / "tracking.png")
    assert outside(figure) == []


def test_the_recorded_run_s_figures_fit_their_titles(rough: RunReport, tmp_path: Path) -> None:
    """Every figure of ``tdslip analyze`` on the run with every perturbation (all of them are drawn), under
    the longest directory name ``tdslip run`` gives by default (<policy>-<mode>-<time>), which their titles
    carry."""
    bag = tmp_path / "stance_pd_speed_energy-realtime-20261205-074455"
    shutil.copytree(rough.bag, bag)
    run = read_run(bag)
    comparison = compare_run(run)
    drawn = [
        plots.apex_sequence(comparison, tmp_path / "apex_sequence.png"),
        plots.return_map(comparison, tmp_path / "return_map.png"),
        plots.com_trajectory(run, tmp_path / "com_trajectory.png"),
        plots.energy_flows(comparison, tmp_path / "energy_flows.png"),
        plots.terrain_path(run, tmp_path / "terrain_path.png"),
        plots.measured_apex(comparison, tmp_path / "measured_apex.png"),
    ]
    for figure in drawn:
        assert outside(figure) == []
