"""The energy-regulated figures (section IV): fig08 (height maps and fixed points over Ebar), fig09 (their
eigenvalues), each checked on the exact plant held at each energy, and the stable Ebar ranges (the paper's,
the analytic map's and the exact plant's under two regulators)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from tdslip_ros.analysis.figures.common import (
    PARAMS,
    ExactCheck,
    FigureData,
    Reporter,
    Resolution,
    bar_height,
    exact_check,
    fixed_points_json,
    plot_exact_check,
    plot_fixed_points,
)
from tdslip_ros.analysis.figures.shared import SHARED
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import SpeedSource
from tdslip_ros.model.arrays import Array
from tdslip_ros.model.paper import PAPER_KBAR, PAPER_ZETA0
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.stability import analytic_fixed_points, exact_fixed_points
from tdslip_ros.reporting.style import EXACT, STABLE


@SHARED.register
def regulated_with_exact_check(
    beta_deg: float, resolution: Resolution, speed: SpeedSource
) -> tuple[Array, analytic_fixed_points.FixedPoints, ExactCheck]:
    """Regulated fixed points over Ebar in [1, 8] (figs 8, 9), checked on the exact plant held at each
    energy exactly (energy_exact, the exact counterpart of the map's energy conservation)."""
    energies_bar = np.linspace(1.0, 8.0, resolution.energies)
    beta = math.radians(beta_deg)
    energies = units.energy_from_bar(PARAMS, energies_bar)
    points = analytic_fixed_points.regulated_fixed_points(PARAMS, beta, energies, speed=speed)
    return energies_bar, points, exact_check(beta, "energy_exact", points, resolution)


def _shade_infeasible(axes: Axes, bottom: float, horizontal: bool = True, vertical: bool = False) -> None:
    if horizontal:
        axes.axhspan(0.0, bottom, color="0.85", zorder=0)
    if vertical:
        axes.axvspan(0.0, bottom, color="0.85", zorder=0)


def fig08(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    figure = Figure(figsize=(11, 8))
    rows = figure.subplots(2, 2)
    data: dict[str, Any] = {}
    for (left, right), beta_deg in zip(rows, (22.0, 30.0), strict=True):
        reporter.stage(f"beta = {beta_deg} deg, analytic and exact plant (energy_exact)")
        beta = math.radians(beta_deg)
        bottom = analytic_fixed_points.infeasible_height(PARAMS, beta)
        curves: dict[str, Any] = {}
        for energy_bar in range(1, 9):
            heights = np.linspace(bottom * (1 + 1e-6), energy_bar, 200)
            y_next = analytic_fixed_points.regulated_height_map(
                PARAMS, beta, units.energy_from_bar(PARAMS, energy_bar), heights, speed=speed
            )
            left.plot(heights, y_next, lw=1, label=f"Ebar = {energy_bar}")
            curves[str(energy_bar)] = {"ybar": heights.tolist(), "ybar_next": y_next.tolist()}
        left.plot([0, 8], [0, 8], ":", color="0.6")
        _shade_infeasible(left, bottom, horizontal=True, vertical=True)
        left.set(
            xlabel="ybar[k]",
            ylabel="ybar[k+1]",
            title=f"height map, beta = {beta_deg:g} deg",
            xlim=(0.7, 3.0),
            ylim=(0.7, 3.0),
        )
        left.legend(fontsize=7, ncol=2)
        energies_bar, points, check = regulated_with_exact_check(beta_deg, resolution, speed)
        analytic_y = bar_height(points.y)
        plot_fixed_points(right, energies_bar[:, None], analytic_y, points.stable, label="analytic")
        plot_exact_check(right, energies_bar[:, None], analytic_y, check, bar_height(check.exact.y))
        _shade_infeasible(right, bottom)
        right.set(xlabel="Ebar", ylabel="ybar*", title="fixed points (open: unstable)", ylim=(0.7, 3.0))
        right.legend(fontsize=7)
        data[f"beta_{beta_deg:g}"] = {
            "infeasible_below_ybar": bottom,
            "maps": curves,
            "fixed_points": fixed_points_json(points, energies_bar) | check.json(energies_bar),
        }
    return figure, data


def fig09(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    figure = Figure(figsize=(7, 6))
    data: dict[str, Any] = {}
    for axes, beta_deg, label in zip(figure.subplots(2, 1), (22.0, 30.0), "ab", strict=True):
        reporter.stage(f"beta = {beta_deg} deg, analytic and exact plant (energy_exact)")
        energies_bar, points, check = regulated_with_exact_check(beta_deg, resolution, speed)
        eigenvalue = np.real(points.eigenvalues[..., 0])
        plot_fixed_points(axes, energies_bar[:, None], eigenvalue, points.stable, label="analytic")
        exact_eigenvalue = np.real(check.exact.eigenvalues[..., 0])
        plot_exact_check(axes, energies_bar[:, None], eigenvalue, check, exact_eigenvalue)
        axes.legend(fontsize=7)
        for level in (-1.0, 1.0):
            axes.axhline(level, color="0.6", lw=0.8)
        axes.set(
            xlabel="Ebar", ylabel="lambda = dy'/dy", title=f"({label}) beta = {beta_deg:g} deg", ylim=(-3, 2)
        )
        data[label] = {
            "beta_deg": beta_deg,
            **fixed_points_json(points, energies_bar),
            **check.json(energies_bar),
        }
    return figure, data


RANGE_EBAR = (0.8, 22.0)
"""Goal energies Ebar scanned for the stable ranges (at beta = 30 deg the exact plant's reaches ~17)."""
RANGE_BETAS = (20.0, 22.0, 26.0, 30.0)
"""Touchdown angles [deg] of the ranges figure."""
PAPER_RANGES = {20.0: (1.1, 3.4), 30.0: (3.45, 11.9)}
"""The paper's stable Ebar ranges (section IV.C)."""
RANGE_SOURCES = ("analytic", "energy", "energy_exact")
"""analytic: the analytic regulated map; energy, energy_exact: the exact plant, planned on the analytic
map (the paper's goal regulator) or on the exact map (the ideal regulator)."""


@SHARED.register
def stable_range(
    kbar: float, zeta0: float, beta_deg: float, source: str, resolution: Resolution, speed: SpeedSource
) -> tuple[float, float]:
    """Stable Ebar range of ``source`` (RANGE_SOURCES) for the hopper (kbar, zeta0) at beta [deg]: the
    analytic map's (its next-apex ``speed``) from its fixed points
    (analytic_fixed_points.stable_energy_range), the exact plant's from its fixed points and eigenvalues
    (exact_fixed_points.stable_energy_range, planned on the
    default map); (NaN, NaN) where none is stable."""
    params = HopperParams.from_dimensionless(kbar, zeta0)
    beta = math.radians(beta_deg)
    energies = units.energy_from_bar(params, np.linspace(*RANGE_EBAR, resolution.exact_energies))
    if source == "analytic":
        ends = analytic_fixed_points.stable_energy_range(
            params, beta, energies, bisections=resolution.bisections + 6, speed=speed
        )
    else:
        heights = analytic_fixed_points.height_grid(params, beta, points=resolution.exact_heights)
        regulator: exact_fixed_points.Regulator = "energy" if source == "energy" else "energy_exact"
        ends = exact_fixed_points.stable_energy_range(
            params, beta, regulator, energies, resolution.bisections, heights
        )
    low, high = (float(units.energy_to_bar(params, end)) for end in ends)
    return low, high


def ranges(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    """Stable Ebar ranges at beta = 20, 22, 26, 30 deg: the paper's, the analytic map's, and the exact
    plant's under the paper's goal regulator (energy) and the ideal one (energy_exact)."""
    betas = RANGE_BETAS
    figure = Figure(figsize=(8, 4.5))
    axes = figure.subplots()
    styles = {"paper": "0.6", "analytic": STABLE, "energy": "tab:orange", "energy_exact": EXACT}
    data: dict[str, Any] = {"beta_deg": list(betas), "paper": {}, **{source: {} for source in RANGE_SOURCES}}
    for row, beta_deg in enumerate(betas):
        found = {"paper": PAPER_RANGES.get(beta_deg)}
        for source in RANGE_SOURCES:
            reporter.stage(f"beta = {beta_deg:g} deg: stable range of {source}")
            found[source] = stable_range(PAPER_KBAR, PAPER_ZETA0, beta_deg, source, resolution, speed)
        for offset, (source, ends) in enumerate(found.items()):
            data[source][f"{beta_deg:g}"] = ends
            if ends is None:
                continue
            level = beta_deg + 0.35 * (offset - 1.5)
            axes.plot(
                ends, [level, level], "-", color=styles[source], lw=4, label=source if row == 0 else None
            )
    axes.set(xlabel="Ebar", ylabel="beta [deg] (bars offset per source)", title="stable energy ranges")
    axes.set_yticks(betas)
    axes.legend(fontsize=8)
    return figure, data
