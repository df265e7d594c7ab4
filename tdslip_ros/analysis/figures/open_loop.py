"""The open-loop figures (section III): fig04 (energy map, height section, fixed points over alpha with their
saddle-nodes), fig05 (fixed points over alpha and beta) and fig06 (their eigenvalues), each analytic fixed
point checked on the exact plant with the paper's t_f."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure

from tdslip_ros.analysis.figures.common import (
    PARAMS,
    ExactCheck,
    FigureData,
    Reporter,
    Resolution,
    bar_energy,
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
from tdslip_ros.model.stability import analytic_fixed_points
from tdslip_ros.reporting.style import EXACT


def fig04(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    beta, alpha_a = math.radians(26.0), 1.5
    scale = units.energy_scale(PARAMS)
    figure = Figure(figsize=(13.5, 4.2))
    left, middle, right = figure.subplots(1, 3)

    heights_a = np.array([1.0, 1.2, 1.4, 1.6, 1.8, 2.0])
    energies = np.linspace(0.0, 12.0, 241)[None, :] + heights_a[:, None]
    _, next_energy = analytic_fixed_points.open_loop_energy_map(
        PARAMS, beta, alpha_a, heights_a[:, None], energies * scale, speed=speed
    )
    fixed_energy = analytic_fixed_points.energy_fixed_point(PARAMS, beta, alpha_a, heights_a, speed=speed)
    for y, e, e_next, e_star in zip(
        heights_a, energies, bar_energy(next_energy), bar_energy(fixed_energy), strict=True
    ):
        (line,) = left.plot(e, e_next, lw=1, label=f"ybar = {y:.1f}")
        left.plot(e_star, e_star, "o", color=EXACT, mfc="none")
    left.plot([0, 14], [0, 14], ":", color="0.6")
    left.set(
        xlabel="Ebar[k]",
        ylabel="Ebar[k+1]",
        title=f"(a) energy map, alpha = {alpha_a}",
        xlim=(0, 14),
        ylim=(0, 14),
    )
    left.legend(fontsize=7)

    reporter.stage("height sections (eq. 28)")
    alphas_b = np.array([1.0, 1.25, 1.5, 1.75, 2.0])
    heights = analytic_fixed_points.height_grid(PARAMS, beta, points=resolution.heights)
    section_energy, section_next = analytic_fixed_points.height_section(
        PARAMS, beta, alphas_b[:, None], heights[None, :], speed=speed
    )
    for alpha, y_next in zip(alphas_b, section_next, strict=True):
        thick = alpha == alpha_a
        middle.plot(
            bar_height(heights),
            bar_height(y_next),
            color=EXACT if thick else None,
            lw=2.5 if thick else 1,
            label=f"alpha = {alpha}",
        )
    middle.plot([0.8, 2.8], [0.8, 2.8], ":", color="0.6")
    middle.set(
        xlabel="ybar[k]",
        ylabel="ybar[k+1] on E*(y)",
        title="(b) height section",
        xlim=(0.85, 2.8),
        ylim=(0.85, 2.8),
    )
    middle.legend(fontsize=7)

    reporter.stage(f"fixed points over {resolution.alphas} alphas, saddle-nodes, the exact plant's")
    alphas, traced, bifurcations = open_loop_trace(26.0, resolution, speed)
    check = open_loop_exact(26.0, resolution, speed)
    plot_fixed_points(right, alphas[:, None], bar_height(traced.y), traced.stable, label="analytic")
    plot_exact_check(right, alphas[:, None], bar_height(traced.y), check, bar_height(check.exact.y))
    for alpha in bifurcations:
        right.axvline(alpha, ls=":", color="0.5")
    right.set(xlabel="alpha", ylabel="ybar*", title="(c) fixed points (open: unstable)")
    right.legend(fontsize=7)
    data = {
        "beta_deg": 26.0,
        "a": {
            "alpha": alpha_a,
            "ybar": heights_a.tolist(),
            "Ebar": energies.tolist(),
            "Ebar_next": bar_energy(next_energy).tolist(),
            "Ebar_fixed": bar_energy(fixed_energy).tolist(),
        },
        "b": {
            "alpha": alphas_b.tolist(),
            "ybar": bar_height(heights).tolist(),
            "Ebar_fixed": bar_energy(section_energy).tolist(),
            "ybar_next": bar_height(section_next).tolist(),
        },
        "c": fixed_points_json(traced, alphas)
        | {"saddle_node_alpha": bifurcations.tolist()}
        | check.json(alphas),
    }
    return figure, data


@SHARED.register
def open_loop_exact(beta_deg: float, resolution: Resolution, speed: SpeedSource) -> ExactCheck:
    """The open-loop analytic fixed points of open_loop_trace checked on the exact plant (paper's t_f)."""
    return exact_check(
        math.radians(beta_deg), "open_loop", open_loop_trace(beta_deg, resolution, speed)[1], resolution
    )


@SHARED.register
def open_loop_trace(
    beta_deg: float, resolution: Resolution, speed: SpeedSource
) -> tuple[Array, analytic_fixed_points.FixedPoints, Array]:
    beta = math.radians(beta_deg)
    alphas = np.linspace(0.5, 2.5, resolution.alphas)
    heights = analytic_fixed_points.height_grid(PARAMS, beta, points=resolution.heights)
    traced = analytic_fixed_points.open_loop_fixed_points(PARAMS, beta, alphas, heights, speed=speed)
    return alphas, traced, analytic_fixed_points.saddle_nodes(PARAMS, beta, traced, heights, speed=speed)


def fig05(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    betas = np.linspace(20.0, 32.0, resolution.betas)
    alphas = _fig05_alphas(resolution)
    radius = np.full((betas.size, alphas.size), np.nan)
    height, energy = np.full_like(radius, np.nan), np.full_like(radius, np.nan)
    count, stable_count, exact_count, exact_stable_count = (np.zeros(radius.shape, int) for _ in range(4))
    exists = np.zeros(radius.shape, dtype=bool)
    for row, beta_deg in enumerate(betas):
        reporter.stage(f"beta = {beta_deg:.1f} deg ({row + 1}/{betas.size}), analytic and exact plant")
        points, check = open_loop_row(float(beta_deg), resolution, speed)
        spectral = np.where(np.isfinite(points.spectral_radius), points.spectral_radius, np.inf)
        best = np.argmin(spectral, axis=1)[:, None]
        radius[row] = np.take_along_axis(points.spectral_radius, best, 1)[:, 0]
        height[row] = np.take_along_axis(bar_height(points.y), best, 1)[:, 0]
        energy[row] = np.take_along_axis(bar_energy(points.energy), best, 1)[:, 0]
        count[row] = points.count
        stable_count[row] = np.sum(points.stable, axis=1)
        exists[row] = np.take_along_axis(check.exists, best, 1)[:, 0]
        exact_count[row] = check.exact.count
        exact_stable_count[row] = np.sum(check.exact.stable, axis=1)
    figure = Figure(figsize=(15, 4.5))
    unstable = np.where(radius >= 1.0, 1.0, np.nan)
    panels = (
        (height, "viridis", "(a) ybar*"),
        (energy, "viridis", "(b) Ebar*"),
        (np.minimum(radius, 1.5), "Blues_r", "(c) max |lambda|"),
    )
    for axes, (values, colour_map, name) in zip(figure.subplots(1, 3), panels, strict=True):
        mesh = axes.pcolormesh(alphas, betas, values, cmap=colour_map, shading="nearest")
        figure.colorbar(mesh, ax=axes)
        axes.pcolormesh(
            alphas, betas, unstable, cmap=ListedColormap(["#005a32"]), alpha=0.55, shading="nearest"
        )
        axes.contourf(
            alphas, betas, (count >= 3).astype(float), levels=[0.5, 1.5], hatches=["//"], colors="none"
        )
        missing = np.isfinite(radius) & ~exists
        alpha_grid, beta_grid = np.meshgrid(alphas, betas)
        axes.plot(alpha_grid[missing], beta_grid[missing], "x", color=EXACT, markersize=5)
        axes.set(xlabel="alpha", ylabel="beta [deg]", title=f"{name}, most stable fixed point")
    figure.suptitle(
        "open loop: dark green = unstable, hatched = three fixed points, white = none found, "
        "red x = not on the exact plant"
    )
    data = {
        "beta_deg": betas.tolist(),
        "alpha": alphas.tolist(),
        "spectral_radius": radius.tolist(),
        "ybar": height.tolist(),
        "Ebar": energy.tolist(),
        "fixed_point_count": count.tolist(),
        "stable_fixed_point_count": stable_count.tolist(),
        "exact_fixed_point_count": exact_count.tolist(),
        "exact_stable_fixed_point_count": exact_stable_count.tolist(),
        "most_stable_exists_on_exact_plant": exists.tolist(),
    }
    return figure, data


def _fig05_alphas(resolution: Resolution) -> Array:
    return np.linspace(0.5, 2.5, max(resolution.alphas // 2, 11))


@SHARED.register
def open_loop_row(
    beta_deg: float, resolution: Resolution, speed: SpeedSource
) -> tuple[analytic_fixed_points.FixedPoints, ExactCheck]:
    """fig05's row at beta: the open-loop fixed points over its alphas, checked on the exact plant."""
    beta = math.radians(beta_deg)
    points = analytic_fixed_points.open_loop_fixed_points(
        PARAMS,
        beta,
        _fig05_alphas(resolution),
        analytic_fixed_points.height_grid(PARAMS, beta, points=resolution.heights),
        speed=speed,
    )
    return points, exact_check(beta, "open_loop", points, resolution)


def fig06(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    figure = Figure(figsize=(7, 6))
    data: dict[str, Any] = {}
    for axes, beta_deg, label in zip(figure.subplots(2, 1), (26.0, 32.0), "ab", strict=True):
        reporter.stage(f"beta = {beta_deg} deg")
        alphas, traced, bifurcations = open_loop_trace(beta_deg, resolution, speed)
        check = open_loop_exact(beta_deg, resolution, speed)
        plot_fixed_points(axes, alphas[:, None], traced.spectral_radius, traced.stable, label="analytic")
        plot_exact_check(axes, alphas[:, None], traced.spectral_radius, check, check.exact.spectral_radius)
        axes.legend(fontsize=7)
        axes.axhline(1.0, color="0.6", lw=0.8)
        for alpha in bifurcations:
            axes.axvline(alpha, ls=":", color="0.5")
        axes.set(
            xlabel="alpha", ylabel="max |lambda|", title=f"({label}) beta = {beta_deg:g} deg", ylim=(0, 2)
        )
        data[label] = {
            "beta_deg": beta_deg,
            **fixed_points_json(traced, alphas),
            "saddle_node_alpha": bifurcations.tolist(),
            **check.json(alphas),
        }
    return figure, data
