"""The paper's figures by name, which shared computations each needs, and one figure written as PNG + JSON."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tdslip_ros.analysis.figures import (
    exact_basins,
    ground_reaction,
    open_loop,
    parameter_dependence,
    regulated,
    tracking,
)
from tdslip_ros.analysis.figures.common import PARAMS, FigureFunction, Reporter, Resolution
from tdslip_ros.analysis.figures.shared import SHARED, SharedKey
from tdslip_ros.model.analytic.apex_map import SpeedSource
from tdslip_ros.model.paper import PAPER_KBAR, PAPER_ZETA0
from tdslip_ros.reporting.output import to_json
from tdslip_ros.reporting.style import save_figure

FIGURES: dict[str, FigureFunction] = {
    "fig04": open_loop.fig04,
    "fig05": open_loop.fig05,
    "fig06": open_loop.fig06,
    "fig07": exact_basins.fig07,
    "fig08": regulated.fig08,
    "fig09": regulated.fig09,
    "fig10": exact_basins.fig10,
    "fig11": parameter_dependence.fig11,
    "ranges": regulated.ranges,
    "fig12": ground_reaction.fig12,
    "fig13": tracking.fig13,
}
"""Every figure by the name of its files (fig04.png, fig04.json, ...), in the order they are written."""


def shared_work(
    names: Sequence[str], resolution: Resolution, speed: SpeedSource = "energy"
) -> list[tuple[str, tuple[Any, ...]]]:
    """The shared computations (name, arguments; :data:`.shared.SHARED`) that the figures ``names`` make with
    the analytic map of next-apex ``speed``: the sweeps that take their time. The exact plant's stable ranges
    come first, as they take longest."""
    work: list[tuple[str, tuple[Any, ...]]] = []
    if "ranges" in names:
        work += [
            ("stable_range", (PAPER_KBAR, PAPER_ZETA0, beta, s, resolution, speed))
            for beta in regulated.RANGE_BETAS
            for s in regulated.RANGE_SOURCES
        ]
    if "fig11" in names:
        for _, _, kbar, zeta0, beta_deg in parameter_dependence.fig11_hoppers():
            work += [
                ("stable_range", (kbar, zeta0, beta_deg, s, resolution, speed))
                for s in ("energy_exact", "analytic")
            ]
            work.append(("fig11_fixed_points", (kbar, zeta0, beta_deg, resolution, speed)))
    if "fig05" in names:
        work += [
            ("open_loop_row", (float(beta), resolution, speed))
            for beta in np.linspace(20.0, 32.0, resolution.betas)
        ]
    for beta_deg in [26.0] * ("fig04" in names or "fig06" in names) + [32.0] * ("fig06" in names):
        work.append(("open_loop_exact", (beta_deg, resolution, speed)))  # brings open_loop_trace along
    if "fig07" in names:
        work += [("fig07_basin", (resolution, speed))]
        work += [
            ("fig07_by_eigenvalue", (regulator, resolution)) for regulator in exact_basins.FIG07_REGULATORS
        ]
        if ("open_loop_exact", (26.0, resolution, speed)) not in work:
            work.append(("open_loop_trace", (26.0, resolution, speed)))
    if "fig08" in names or "fig09" in names:
        work += [("regulated_with_exact_check", (beta_deg, resolution, speed)) for beta_deg in (22.0, 30.0)]
    if "fig10" in names:
        work += [("fig10_basin", (resolution,)), ("fig10_by_eigenvalue", (resolution,))]
    exact_ranges = [item for item in work if item[0] == "stable_range" and item[1][3] != "analytic"]
    return exact_ranges + [item for item in work if item not in exact_ranges]


def compute_shared(name: str, args: tuple[Any, ...]) -> dict[SharedKey, Any]:
    """Run the shared computation ``name`` (a task on a study engine's worker, which has every figure
    family registered by importing this module) and return every shared result it made."""
    return SHARED.run(name, args)


def write_figure(
    name: str, out: Path, resolution: Resolution, speed: SpeedSource = "energy"
) -> dict[str, Any]:
    """Compute, draw and save one figure as OUT/<name>.png and OUT/<name>.json, with the analytic map of
    next-apex ``speed`` (:data:`~tdslip_ros.model.analytic.apex_map.SpeedSource`); returns its data."""
    reporter = Reporter(name)
    started = time.process_time()
    figure, data = FIGURES[name](resolution, reporter, speed)
    save_figure(figure, out / f"{name}.png")
    document = {
        "figure": name,
        "params": {"kbar": PARAMS.kbar, "zeta0": PARAMS.zeta0, "m": PARAMS.m, "r0": PARAMS.r0, "g": PARAMS.g},
        "resolution": vars(resolution),
        "analytic_map_speed": speed,
        **data,
    }
    (out / f"{name}.json").write_text(to_json(document))
    reporter.stage(f"done in {time.process_time() - started:.1f} s CPU")
    return document
