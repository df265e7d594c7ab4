"""The exact plant's basins: fig07 (open loop from E*(y0) over alpha and y0, with the fixed points it
reaches and those it has by eigenvalue) and fig10 (the goal regulator over Ebar0 and y0), on the grids of
:mod:`tdslip_ros.reporting.paper_grids`."""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure

from tdslip_ros.analysis.figures.common import (
    PARAMS,
    ExactCheck,
    FigureData,
    Reporter,
    Resolution,
    bar_energy,
    bar_height,
    bar_speed,
    fixed_points_json,
    plot_exact_check,
    plot_fixed_points,
)
from tdslip_ros.analysis.figures.open_loop import open_loop_trace
from tdslip_ros.analysis.figures.shared import SHARED
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import SpeedSource
from tdslip_ros.model.arrays import Array
from tdslip_ros.model.dynamics import speed_from_energy
from tdslip_ros.model.stability import analytic_fixed_points, basins, exact_fixed_points
from tdslip_ros.reporting.paper_grids import BASIN_BETA_DEG, fig07_grid, fig10_grid, row_median
from tdslip_ros.reporting.style import EXACT, START, basin_colour_map, basin_colours


def _settled_text(stride: int) -> str:
    return "not settled" if stride < 0 else f"settled from stride {stride}"


def _outcome_counts(basin: basins.Basin) -> dict[str, int]:
    return {name: int(np.sum(basin.outcome == index)) for index, name in enumerate(basins.OUTCOMES)}


FIG07_CROSSES = {1.0: 2.0, 1.5: 1.05}
"""(alpha, ybar0) of fig07's panels (b) and (c)."""
FIG07_REGULATORS: tuple[exact_fixed_points.Regulator, ...] = ("open_loop", "open_loop_stance_tf")


def _fig07_grid(resolution: Resolution) -> tuple[Array, Array]:
    """fig07's alphas and initial heights [m] at this resolution."""
    return fig07_grid(resolution.basin_alphas, resolution.basin_heights)


@SHARED.register
def fig07_basin(resolution: Resolution, speed: SpeedSource) -> basins.Basin:
    """The open-loop exact plant from the analytic map's E*(y0) (its next-apex ``speed``) over fig07's grid,
    then from its two crosses, as lanes of one basin."""
    beta = math.radians(BASIN_BETA_DEG)
    alphas, heights = _fig07_grid(resolution)
    alpha_grid, height_grid = (a.ravel() for a in np.meshgrid(alphas, heights, indexing="ij"))
    start_energy = analytic_fixed_points.energy_fixed_point(
        PARAMS, beta, alpha_grid, height_grid, speed=speed
    )
    cross_alpha, cross_height = np.array(list(FIG07_CROSSES)), np.array(list(FIG07_CROSSES.values()))
    cross_energy = analytic_fixed_points.energy_fixed_point(
        PARAMS, beta, cross_alpha, cross_height, speed=speed
    )
    return basins.open_loop_basin(
        PARAMS,
        beta,
        np.concatenate([alpha_grid, cross_alpha]),
        np.concatenate([height_grid, cross_height]),
        np.concatenate([start_energy, cross_energy]),
    )


@SHARED.register
def fig07_by_eigenvalue(
    regulator: exact_fixed_points.Regulator, resolution: Resolution
) -> analytic_fixed_points.FixedPoints:
    """The open-loop exact plant's fixed points and eigenvalues at fig07's alphas."""
    beta = math.radians(BASIN_BETA_DEG)
    return exact_fixed_points.fixed_points(
        exact_fixed_points.ExactLoop.of(PARAMS, beta, regulator, _fig07_grid(resolution)[0]),
        analytic_fixed_points.height_grid(PARAMS, beta, points=resolution.exact_heights),
    )


def fig07(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    alphas, heights = _fig07_grid(resolution)
    alpha_grid, height_grid = np.meshgrid(alphas, heights, indexing="ij")
    cross_alpha, cross_height = np.array(list(FIG07_CROSSES)), np.array(list(FIG07_CROSSES.values()))
    reporter.stage(f"{alpha_grid.size + cross_alpha.size} lanes, {basins.OPEN_LOOP_STRIDES} strides")
    everything = fig07_basin(resolution, speed)
    grid = slice(0, alpha_grid.size)
    start_energy = everything.energy0[grid].reshape(alpha_grid.shape)
    outcome = everything.outcome[grid].reshape(alpha_grid.shape)
    colour = basin_colours(everything.outcome, everything.convergence_stride, basins.OPEN_LOOP_STRIDES)[
        grid
    ].reshape(alpha_grid.shape)
    reporter.stage("analytic fixed points")
    analytic_alphas, traced, _ = open_loop_trace(BASIN_BETA_DEG, resolution, speed)
    by_eigenvalue = {}
    for regulator in FIG07_REGULATORS:
        reporter.stage(f"the exact plant's fixed points and eigenvalues, {regulator}")
        by_eigenvalue[regulator] = fig07_by_eigenvalue(regulator, resolution)

    figure = Figure(figsize=(12, 7.5))
    top = figure.add_subplot(2, 1, 1)
    top.pcolormesh(
        alphas,
        bar_height(heights),
        colour.T,
        cmap=basin_colour_map(basins.OPEN_LOOP_STRIDES),
        vmin=0,
        vmax=basins.OPEN_LOOP_STRIDES + 1,
        shading="nearest",
    )
    plot_fixed_points(top, analytic_alphas[:, None], bar_height(traced.y), traced.stable)
    exact_y = everything.y[grid].reshape(alpha_grid.shape)
    top.plot(alpha_grid.ravel(), bar_height(exact_y).ravel(), ".", color=EXACT, markersize=4)
    top.plot(cross_alpha, cross_height, "x", color=START, markersize=9, mew=2)
    for regulator, colour in (("open_loop", EXACT), ("open_loop_stance_tf", "tab:purple")):
        points = by_eigenvalue[regulator]
        x, y, stable = np.broadcast_arrays(alphas[:, None], bar_height(points.y), points.stable)
        top.plot(x[stable], y[stable], "s", color=colour, mfc="none", markersize=6, label=regulator)
        top.plot(
            x[~stable & np.isfinite(y)],
            y[~stable & np.isfinite(y)],
            "d",
            color=colour,
            mfc="none",
            markersize=5,
        )
    top.legend(fontsize=7, title="exact fixed points (square: stable)")
    top.set(
        xlabel="alpha",
        ylabel="ybar0 (E0 = E*(y0))",
        title="(a) exact plant, 150 strides (blue: converged, lighter later; pale: sustained; white: failed)",
    )
    cross_lanes = np.arange(alpha_grid.size, alpha_grid.size + cross_alpha.size)
    for index, (lane, alpha) in enumerate(zip(cross_lanes, cross_alpha, strict=True)):
        axes = figure.add_subplot(2, 2, 3 + index)
        history = everything.history
        y_bar, xdot_bar = bar_height(history.y[:, lane]), bar_speed(history.xdot[:, lane])
        axes.plot(y_bar, label="ybar")
        axes.plot(y_bar + 0.5 * xdot_bar**2, label="Ebar")
        axes.set(
            xlabel="stride",
            title=f"({'bc'[index]}) alpha = {alpha:g}: "
            + _settled_text(int(everything.convergence_stride[lane])),
        )
        axes.legend(fontsize=7)
    data = {
        "beta_deg": BASIN_BETA_DEG,
        "strides": basins.OPEN_LOOP_STRIDES,
        "alpha": alphas.tolist(),
        "ybar0": bar_height(heights).tolist(),
        "Ebar0": bar_energy(start_energy).tolist(),
        "outcome": [[basins.OUTCOMES[o] for o in row] for row in outcome],
        "convergence_stride": everything.convergence_stride[grid].reshape(alpha_grid.shape).tolist(),
        "exact_fixed_ybar": bar_height(exact_y).tolist(),
        "last_ybar": bar_height(everything.history.y[-1, grid].reshape(alpha_grid.shape)).tolist(),
        "exact_by_eigenvalue": {
            regulator: fixed_points_json(points, alphas) for regulator, points in by_eigenvalue.items()
        },
        "exact_fixed_Ebar": bar_energy(everything.energy[grid].reshape(alpha_grid.shape)).tolist(),
        "outcome_counts": _outcome_counts(everything),
        "analytic": fixed_points_json(traced, analytic_alphas),
        "runs": [
            {
                "alpha": float(alpha),
                "ybar": bar_height(everything.history.y[:, lane]).tolist(),
                "xdotbar": bar_speed(everything.history.xdot[:, lane]).tolist(),
                "convergence_stride": int(everything.convergence_stride[lane]),
            }
            for lane, alpha in zip(cross_lanes, cross_alpha, strict=True)
        ],
    }
    return figure, data


def _fig10_grid(resolution: Resolution) -> tuple[Array, Array]:
    """fig10's initial (= goal) energies Ebar and initial heights [m] at this resolution."""
    return fig10_grid(resolution.basin_energies, resolution.basin_heights)


@SHARED.register
def fig10_basin(resolution: Resolution) -> basins.Basin:
    """The goal regulator's exact plant over fig10's grid."""
    energies_bar, heights = _fig10_grid(resolution)
    return basins.exact_regulated_fixed_points(
        PARAMS, math.radians(BASIN_BETA_DEG), units.energy_from_bar(PARAMS, energies_bar), heights
    )


@SHARED.register
def fig10_by_eigenvalue(resolution: Resolution) -> analytic_fixed_points.FixedPoints:
    """The goal regulator's exact fixed points and eigenvalues at fig10's energies."""
    beta = math.radians(BASIN_BETA_DEG)
    energies = units.energy_from_bar(PARAMS, _fig10_grid(resolution)[0])
    return exact_fixed_points.fixed_points(
        exact_fixed_points.ExactLoop.of(PARAMS, beta, "energy", energies),
        analytic_fixed_points.height_grid(PARAMS, beta, points=resolution.exact_heights),
    )


def _failed_from(history: basins.StrideHistory) -> Array:
    """Per lane the apex height [m] of the stride that failed (NaN where none did)."""
    stride = np.maximum(history.failure_stride, 0)
    apex = np.take_along_axis(history.y, stride[None], axis=0)[0]
    return np.where(history.failure_stride >= 0, apex, np.nan)


def fig10(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    beta = math.radians(BASIN_BETA_DEG)
    energies_bar, heights = _fig10_grid(resolution)
    reporter.stage(f"{energies_bar.size * heights.size} lanes, {basins.REGULATED_STRIDES} strides")
    exact = fig10_basin(resolution)
    fine_energies = np.linspace(2.0, 6.0, 4 * resolution.energies)
    fine = units.energy_from_bar(PARAMS, fine_energies)
    analytic = analytic_fixed_points.regulated_fixed_points(PARAMS, beta, fine, speed=speed)
    reporter.stage("the exact plant's fixed points and eigenvalues")
    by_eigenvalue = fig10_by_eigenvalue(resolution)
    exact_y, exact_xdot, exact_energy = (row_median(values) for values in (exact.y, exact.xdot, exact.energy))
    colour = basin_colours(exact.outcome, exact.convergence_stride, basins.REGULATED_STRIDES)
    colour_map = basin_colour_map(basins.REGULATED_STRIDES)
    figure = Figure(figsize=(12, 4.8))
    left, right = figure.subplots(1, 2)
    left.pcolormesh(
        energies_bar,
        bar_height(heights),
        colour.T,
        cmap=colour_map,
        vmin=0,
        vmax=basins.REGULATED_STRIDES + 1,
        shading="nearest",
    )
    start_speed = bar_speed(speed_from_energy(PARAMS, exact.y0, exact.energy0))
    right.scatter(
        np.broadcast_to(energies_bar[:, None], colour.shape),
        start_speed,
        c=colour,
        cmap=colour_map,
        vmin=0,
        vmax=basins.REGULATED_STRIDES + 1,
        marker="s",
        s=12,
    )
    for axes, analytic_values, exact_values, name in (
        (left, bar_height(analytic.y), bar_height(exact_y), "ybar"),
        (right, bar_speed(analytic.xdot), bar_speed(exact_xdot), "xdotbar"),
    ):
        plot_fixed_points(axes, fine_energies[:, None], analytic_values, analytic.stable, label="analytic")
        axes.plot(
            bar_energy(exact_energy), exact_values, "-", color=EXACT, lw=2, label="exact plant, reached"
        )
        plot_exact_check(
            axes,
            bar_energy(by_eigenvalue.energy),
            np.full(by_eigenvalue.y.shape, np.nan),
            ExactCheck(by_eigenvalue, np.ones(by_eigenvalue.y.shape, dtype=bool)),
            bar_height(by_eigenvalue.y) if name == "ybar" else bar_speed(by_eigenvalue.xdot),
        )
        axes.set(xlabel="Ebar", ylabel=f"{name} (fixed points; basin: initial {name}0)", xlim=(2, 6))
        axes.legend(fontsize=7)
    left.set_title("(a) apex height, beta = 26 deg (blue: basin after 50 strides)")
    right.set_title("(b) apex speed")
    converged = exact.outcome == basins.CONVERGED
    data = {
        "beta_deg": BASIN_BETA_DEG,
        "strides": basins.REGULATED_STRIDES,
        "Ebar0": energies_bar.tolist(),
        "ybar0": bar_height(heights).tolist(),
        "outcome": [[basins.OUTCOMES[o] for o in row] for row in exact.outcome],
        "convergence_stride": exact.convergence_stride.tolist(),
        "failure_stride": exact.history.failure_stride.tolist(),
        "failed_from_ybar": bar_height(_failed_from(exact.history)).tolist(),
        "outcome_counts": _outcome_counts(exact),
        "converged_within_8_strides": int(np.sum(converged & (exact.convergence_stride <= 8))),
        "exact_fixed_points": {
            "Ebar_goal": energies_bar.tolist(),
            "Ebar": bar_energy(exact_energy).tolist(),
            "ybar": bar_height(exact_y).tolist(),
            "xdotbar": bar_speed(exact_xdot).tolist(),
        },
        "analytic": fixed_points_json(analytic, fine_energies),
        "exact_by_eigenvalue": fixed_points_json(by_eigenvalue, energies_bar),
    }
    return figure, data
