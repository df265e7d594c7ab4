"""``tdslip figures``: the paper's figures 4-11 and 13 from the model core, as PNG plus the numbers as JSON.

    tdslip figures --out DIR [--only fig04 fig10 ranges ...] [--fine]
                   [--scheduler tcp://HOST:PORT | --workers N]

Each figure is named after the paper's (fig04.png with fig04.json, ...); the JSON holds the numbers drawn
(dimensionless, eq. 24; NaN as null) and the settings. Parameters: kbar = 36, zeta0 = 0.08, m = 80 kg,
r0 = 1 m (figs 8-11, 13 and the paper's section V); the open-loop figures 4-7 use them too.

Every analytic fixed point drawn (figs 4-6, 8, 9) is checked on the exact plant
(:mod:`tdslip_ros.model.exact_stability`, the open-loop rule with the paper's t_f, or the ideal regulator
energy_exact for the energy-regulated map): red markers are the exact plant's fixed points (filled where
stable, by their eigenvalues), a red cross marks an analytic fixed point the exact plant does not have.
At the end the command prints the paper's claims beside ours (:mod:`.paper_comparison`) and writes them to
DIR/comparison.md; docs/paper.md explains the differences.

* fig04: open loop, beta = 26 deg: (a) energy map E' vs E at alpha = 1.5 for several heights, with the
  energy fixed points E*(y) (eq. 27); (b) the height section y' vs y on E*(y) for several alpha (eq. 28);
  (c) the fixed points over alpha with the saddle-node bifurcations.
* fig05: open-loop fixed points over (alpha, beta): apex height (a), energy (b) and largest eigenvalue
  modulus (c) of the most stable fixed point; dark green where it is unstable, hatched where there are
  three.
* fig06: largest eigenvalue modulus at every open-loop fixed point over alpha, beta = 26 and 32 deg.
* fig07: exact plant, open loop, beta = 26 deg, up to 150 strides from initial heights y0 on the energy
  fixed point E*(y0) of eq. 27: outcome per (alpha, y0), analytic fixed points (black: solid stable,
  dashed unstable), the fixed points the exact plant reaches (red dots) and its fixed points by
  eigenvalue with the paper's t_f and with t_f = the stance it produces (squares); (b), (c) convergence
  at alpha = 1 and 1.5 from the green crosses.
* fig08: energy-regulated height map y' vs y for Ebar = 1..8 and its fixed points over Ebar, beta = 22
  and 30 deg; grey: kinematically infeasible heights (y < r0 cos beta).
* fig09: the eigenvalue dy'/dy at those fixed points.
* fig10: beta = 26 deg, Ebar in [2, 6]: fixed points of the analytic map (black) and of the exact plant
  under the paper's goal-energy regulator (red line: reached in the basin; markers: by eigenvalue) in apex
  height (a) and speed (b); blue: the exact plant's basin after 50 strides, lighter for slower
  convergence.
* fig11: stable regulated fixed points (xdotbar*, ybar*) as beta, kbar or zeta0 vary (one curve over Ebar
  per value, circles at its ends, the arrow from the smallest value to the largest); the legend gives each
  value's stable Ebar range, analytic and on the exact plant (energy_exact).
* ranges: the stable Ebar ranges at beta = 20, 22, 26, 30 deg: the paper's, the analytic map's, and the
  exact plant's under the paper's goal regulator (energy) and the ideal one (energy_exact).
* fig13: deadbeat against the PD baseline on the exact plant, 50 strides per desired speed from the apex
  (1 m, 5 m/s) towards (1 m, xdot*): final speed and height errors in percent; crosses where a controller
  loses stability (fails, or does not converge to 1e-4). The JSON adds deadbeat towards y* = 0.95 m.

The sweeps that take the time (the exact plant's stable ranges, fixed points and basins: the @shared
computations of :func:`shared_work`) run first, as tasks on the study engine
(:mod:`tdslip_ros.studies.engine`: a local cluster of one worker process per core, or ``--scheduler``), the
longest first; the figures then draw from their results. Each task is the very call the figure would make,
so the numbers do not depend on where it ran. Defaults take some ten minutes of CPU (the exact-plant checks
and ranges most of it); ``--fine`` uses the paper's resolutions. Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure

from tdslip_ros.analysis import paper_comparison
from tdslip_ros.model import basins, exact_stability, stability, units
from tdslip_ros.model.analytic import Array, CommandArrays, speed_from_energy
from tdslip_ros.model.controllers import deadbeat, pd_speed_energy_height
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import HopperParams
from tdslip_ros.reporting.output import OutputError, output_directory, to_json, write_failed
from tdslip_ros.reporting.paper_grids import FIG11_STUDIES, fig07_grid, fig10_grid, row_median
from tdslip_ros.reporting.style import (
    CONTROLLER_STYLE,
    DPI,
    EXACT,
    STABLE,
    START,
    UNSTABLE,
    basin_colour_map,
    basin_colours,
)
from tdslip_ros.studies import engine

PARAMS = PAPER_PARAMS


@dataclass(frozen=True)
class Resolution:
    """Grid sizes of the sweeps: the defaults and ``--fine`` (the paper's)."""

    heights: int  # open-loop height scan (eq. 28)
    alphas: int  # open-loop alpha trace
    betas: int  # fig05 touchdown angles in [20, 32] deg
    basin_alphas: int  # fig07
    basin_heights: int  # fig07 and fig10 initial heights
    energies: int  # regulated fixed points over Ebar
    basin_energies: int  # fig10 initial energies
    speed_step: float  # fig13 desired speeds
    exact_heights: int  # height grid of the exact plant's fixed points (sections of eq. 28)
    exact_energies: int  # goal energies of the exact stable ranges (ranges, fig11)
    bisections: int  # of each end of a stable range


DEFAULT = Resolution(80, 41, 7, 17, 20, 57, 21, 0.25, 40, 22, 5)
FINE = Resolution(160, 101, 13, 41, 60, 141, 81, 0.1, 80, 54, 8)


SharedKey = tuple[str, tuple[Any, ...]]
_COMPUTED: dict[SharedKey, Any] = {}
"""Results of the @shared computations by (name, arguments), filled here or by the engine's tasks."""


def shared(function: Callable[..., Any]) -> Callable[..., Any]:
    """A pure computation that several figures use: computed once per process and arguments (as
    functools.cache), and one that :func:`precompute` can run as a task on the study engine."""

    @functools.wraps(function)
    def cached(*args: Any) -> Any:
        key = (function.__name__, args)
        if key not in _COMPUTED:
            _COMPUTED[key] = function(*args)
        return _COMPUTED[key]

    return cached


def computed_by(name: str, args: tuple[Any, ...]) -> dict[SharedKey, Any]:
    """Run the @shared computation ``name`` (in a worker) and return every shared result it made, itself
    and the shared parts it used (fig04's exact check brings its analytic trace along)."""
    before = set(_COMPUTED)
    globals()[name](*args)
    return {key: value for key, value in _COMPUTED.items() if key not in before or key == (name, args)}


class Reporter:
    """Progress of one figure's long sweeps on stderr, at most every ``interval`` seconds."""

    def __init__(self, figure: str, interval: float = 5.0) -> None:
        self.figure, self.interval, self.last = figure, interval, -math.inf

    def stage(self, text: str) -> None:
        print(f"{self.figure}: {text}", file=sys.stderr, flush=True)

    def strides(self, what: str) -> basins.Progress:
        def report(done: int, total: int) -> None:
            now = time.monotonic()
            if done == total or now - self.last >= self.interval:
                self.last = now
                print(f"{self.figure}: {what}: stride {done}/{total}", file=sys.stderr, flush=True)

        return report


def _bar_height(y: Array) -> Array:
    return np.asarray(units.height_to_bar(PARAMS, y))


def _bar_energy(energy: Array) -> Array:
    return np.asarray(units.energy_to_bar(PARAMS, energy))


def _bar_speed(xdot: Array) -> Array:
    return np.asarray(units.speed_to_bar(PARAMS, xdot))


def _plot_fixed_points(axes: Axes, x: Array, values: Array, stable: Array, label: str | None = None) -> None:
    """Fixed points as markers: filled where stable, open where unstable."""
    x_, values_, stable_ = np.broadcast_arrays(x, values, stable)
    axes.plot(x_[stable_], values_[stable_], "o", color=STABLE, markersize=3, label=label)
    unstable = ~stable_ & np.isfinite(values_)
    axes.plot(x_[unstable], values_[unstable], "o", color=UNSTABLE, markersize=3, mfc="none")


def _fixed_points_json(points: stability.FixedPoints, parameter: Array) -> dict[str, Any]:
    return {
        "parameter": parameter.tolist(),
        "ybar": _bar_height(points.y).tolist(),
        "xdotbar": _bar_speed(points.xdot).tolist(),
        "Ebar": _bar_energy(points.energy).tolist(),
        "eigenvalues": points.eigenvalues.tolist(),
        "spectral_radius": points.spectral_radius.tolist(),
        "stable": points.stable.tolist(),
    }


@dataclass(frozen=True)
class ExactCheck:
    """The exact plant's fixed points for the members of an analytic trace, and per analytic fixed point
    whether the exact plant has it (exact_stability.exists_on_exact_plant)."""

    exact: stability.FixedPoints
    exists: Array

    def json(self, parameter: Array) -> dict[str, Any]:
        return {
            "exact": _fixed_points_json(self.exact, parameter),
            "analytic_exists_on_exact_plant": self.exists.tolist(),
        }


def _exact_check(
    beta: float, regulator: exact_stability.Regulator, analytic: stability.FixedPoints, resolution: Resolution
) -> ExactCheck:
    """Every analytic fixed point of ``analytic`` (members: its parameter, alpha or the energy [J])
    checked on the exact plant under ``regulator``."""
    loop = exact_stability.ExactLoop.of(PARAMS, beta, regulator, analytic.parameter)
    heights = stability.height_grid(PARAMS, beta, points=resolution.exact_heights)
    exact = exact_stability.fixed_points(loop, heights)
    return ExactCheck(exact, exact_stability.exists_on_exact_plant(analytic, exact))


def _plot_exact_check(
    axes: Axes, x: Array, analytic_values: Array, check: ExactCheck, exact_values: Array
) -> None:
    """The exact plant's fixed points in red (filled: stable), and a red cross on every analytic fixed point
    the exact plant does not have."""
    x_, exact_, stable_ = np.broadcast_arrays(x, exact_values, check.exact.stable)
    axes.plot(x_[stable_], exact_[stable_], "o", color=EXACT, markersize=3, label="exact plant")
    unstable = ~stable_ & np.isfinite(exact_)
    axes.plot(x_[unstable], exact_[unstable], "o", color=EXACT, markersize=3, mfc="none")
    x_, values_, exists_ = np.broadcast_arrays(x, analytic_values, check.exists)
    missing = ~exists_ & np.isfinite(values_)
    axes.plot(x_[missing], values_[missing], "x", color=EXACT, markersize=6, label="not on the exact plant")


# --- Open loop (section III) -----------------------------------------------------------------------------


def fig04(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
    beta, alpha_a = math.radians(26.0), 1.5
    scale = units.energy_scale(PARAMS)
    figure = Figure(figsize=(13.5, 4.2))
    left, middle, right = figure.subplots(1, 3)

    heights_a = np.array([1.0, 1.2, 1.4, 1.6, 1.8, 2.0])
    energies = np.linspace(0.0, 12.0, 241)[None, :] + heights_a[:, None]
    _, next_energy = stability.open_loop_energy_map(
        PARAMS, beta, alpha_a, heights_a[:, None], energies * scale
    )
    fixed_energy = stability.energy_fixed_point(PARAMS, beta, alpha_a, heights_a)
    for y, e, e_next, e_star in zip(
        heights_a, energies, _bar_energy(next_energy), _bar_energy(fixed_energy), strict=True
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
    heights = stability.height_grid(PARAMS, beta, points=resolution.heights)
    section_energy, section_next = stability.height_section(PARAMS, beta, alphas_b[:, None], heights[None, :])
    for alpha, y_next in zip(alphas_b, section_next, strict=True):
        thick = alpha == alpha_a
        middle.plot(
            _bar_height(heights),
            _bar_height(y_next),
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
    alphas, traced, bifurcations = _open_loop_trace(26.0, resolution)
    check = _open_loop_exact(26.0, resolution)
    _plot_fixed_points(right, alphas[:, None], _bar_height(traced.y), traced.stable, label="analytic")
    _plot_exact_check(right, alphas[:, None], _bar_height(traced.y), check, _bar_height(check.exact.y))
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
            "Ebar_next": _bar_energy(next_energy).tolist(),
            "Ebar_fixed": _bar_energy(fixed_energy).tolist(),
        },
        "b": {
            "alpha": alphas_b.tolist(),
            "ybar": _bar_height(heights).tolist(),
            "Ebar_fixed": _bar_energy(section_energy).tolist(),
            "ybar_next": _bar_height(section_next).tolist(),
        },
        "c": _fixed_points_json(traced, alphas)
        | {"saddle_node_alpha": bifurcations.tolist()}
        | check.json(alphas),
    }
    return figure, data


@shared
def _open_loop_exact(beta_deg: float, resolution: Resolution) -> ExactCheck:
    """The open-loop analytic fixed points of _open_loop_trace checked on the exact plant (paper's t_f)."""
    return _exact_check(
        math.radians(beta_deg), "open_loop", _open_loop_trace(beta_deg, resolution)[1], resolution
    )


@shared
def _open_loop_trace(beta_deg: float, resolution: Resolution) -> tuple[Array, stability.FixedPoints, Array]:
    beta = math.radians(beta_deg)
    alphas = np.linspace(0.5, 2.5, resolution.alphas)
    heights = stability.height_grid(PARAMS, beta, points=resolution.heights)
    traced = stability.open_loop_fixed_points(PARAMS, beta, alphas, heights)
    return alphas, traced, stability.saddle_nodes(PARAMS, beta, traced, heights)


def fig05(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
    betas = np.linspace(20.0, 32.0, resolution.betas)
    alphas = _fig05_alphas(resolution)
    radius = np.full((betas.size, alphas.size), np.nan)
    height, energy, count, exact_count = (
        np.full_like(radius, np.nan),
        np.full_like(radius, np.nan),
        np.zeros(radius.shape, int),
        np.zeros(radius.shape, int),
    )
    exists = np.zeros(radius.shape, dtype=bool)
    for row, beta_deg in enumerate(betas):
        reporter.stage(f"beta = {beta_deg:.1f} deg ({row + 1}/{betas.size}), analytic and exact plant")
        points, check = _open_loop_row(float(beta_deg), resolution)
        spectral = np.where(np.isfinite(points.spectral_radius), points.spectral_radius, np.inf)
        best = np.argmin(spectral, axis=1)[:, None]
        radius[row] = np.take_along_axis(points.spectral_radius, best, 1)[:, 0]
        height[row] = np.take_along_axis(_bar_height(points.y), best, 1)[:, 0]
        energy[row] = np.take_along_axis(_bar_energy(points.energy), best, 1)[:, 0]
        count[row] = points.count
        exists[row] = np.take_along_axis(check.exists, best, 1)[:, 0]
        exact_count[row] = check.exact.count
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
        "exact_fixed_point_count": exact_count.tolist(),
        "most_stable_exists_on_exact_plant": exists.tolist(),
    }
    return figure, data


def _fig05_alphas(resolution: Resolution) -> Array:
    return np.linspace(0.5, 2.5, max(resolution.alphas // 2, 11))


@shared
def _open_loop_row(beta_deg: float, resolution: Resolution) -> tuple[stability.FixedPoints, ExactCheck]:
    """fig05's row at beta: the open-loop fixed points over its alphas, checked on the exact plant."""
    beta = math.radians(beta_deg)
    points = stability.open_loop_fixed_points(
        PARAMS,
        beta,
        _fig05_alphas(resolution),
        stability.height_grid(PARAMS, beta, points=resolution.heights),
    )
    return points, _exact_check(beta, "open_loop", points, resolution)


def fig06(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
    figure = Figure(figsize=(7, 6))
    data: dict[str, Any] = {}
    for axes, beta_deg, label in zip(figure.subplots(2, 1), (26.0, 32.0), "ab", strict=True):
        reporter.stage(f"beta = {beta_deg} deg")
        alphas, traced, bifurcations = _open_loop_trace(beta_deg, resolution)
        check = _open_loop_exact(beta_deg, resolution)
        _plot_fixed_points(axes, alphas[:, None], traced.spectral_radius, traced.stable, label="analytic")
        _plot_exact_check(axes, alphas[:, None], traced.spectral_radius, check, check.exact.spectral_radius)
        axes.legend(fontsize=7)
        axes.axhline(1.0, color="0.6", lw=0.8)
        for alpha in bifurcations:
            axes.axvline(alpha, ls=":", color="0.5")
        axes.set(
            xlabel="alpha", ylabel="max |lambda|", title=f"({label}) beta = {beta_deg:g} deg", ylim=(0, 2)
        )
        data[label] = {
            "beta_deg": beta_deg,
            **_fixed_points_json(traced, alphas),
            "saddle_node_alpha": bifurcations.tolist(),
            **check.json(alphas),
        }
    return figure, data


def _settled_text(stride: int) -> str:
    return "not settled" if stride < 0 else f"settled from stride {stride}"


def _outcome_counts(basin: basins.Basin) -> dict[str, int]:
    return {name: int(np.sum(basin.outcome == index)) for index, name in enumerate(basins.OUTCOMES)}


FIG07_CROSSES = {1.0: 2.0, 1.5: 1.05}
"""(alpha, ybar0) of fig07's panels (b) and (c)."""
FIG07_REGULATORS: tuple[exact_stability.Regulator, ...] = ("open_loop", "open_loop_stance_tf")


def _fig07_grid(resolution: Resolution) -> tuple[Array, Array]:
    """fig07's alphas and initial heights [m]."""
    return fig07_grid(resolution.basin_alphas, resolution.basin_heights)


@shared
def _fig07_basin(resolution: Resolution) -> basins.Basin:
    """The open-loop exact plant from E*(y0) over fig07's grid, then from its two crosses, as lanes of one
    basin."""
    beta = math.radians(26.0)
    alphas, heights = _fig07_grid(resolution)
    alpha_grid, height_grid = (a.ravel() for a in np.meshgrid(alphas, heights, indexing="ij"))
    start_energy = stability.energy_fixed_point(PARAMS, beta, alpha_grid, height_grid)
    cross_alpha, cross_height = np.array(list(FIG07_CROSSES)), np.array(list(FIG07_CROSSES.values()))
    cross_energy = stability.energy_fixed_point(PARAMS, beta, cross_alpha, cross_height)
    return basins.open_loop_basin(
        PARAMS,
        beta,
        np.concatenate([alpha_grid, cross_alpha]),
        np.concatenate([height_grid, cross_height]),
        np.concatenate([start_energy, cross_energy]),
    )


@shared
def _fig07_by_eigenvalue(
    regulator: exact_stability.Regulator, resolution: Resolution
) -> stability.FixedPoints:
    """The open-loop exact plant's fixed points and eigenvalues at fig07's alphas."""
    beta = math.radians(26.0)
    return exact_stability.fixed_points(
        exact_stability.ExactLoop.of(PARAMS, beta, regulator, _fig07_grid(resolution)[0]),
        stability.height_grid(PARAMS, beta, points=resolution.exact_heights),
    )


def fig07(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
    alphas, heights = _fig07_grid(resolution)
    alpha_grid, height_grid = np.meshgrid(alphas, heights, indexing="ij")
    cross_alpha, cross_height = np.array(list(FIG07_CROSSES)), np.array(list(FIG07_CROSSES.values()))
    reporter.stage(f"{alpha_grid.size + cross_alpha.size} lanes, {basins.OPEN_LOOP_STRIDES} strides")
    everything = _fig07_basin(resolution)
    grid = slice(0, alpha_grid.size)
    start_energy = everything.energy0[grid].reshape(alpha_grid.shape)
    outcome = everything.outcome[grid].reshape(alpha_grid.shape)
    colour = basin_colours(everything.outcome, everything.convergence_stride, basins.OPEN_LOOP_STRIDES)[
        grid
    ].reshape(alpha_grid.shape)
    reporter.stage("analytic fixed points")
    analytic_alphas, traced, _ = _open_loop_trace(26.0, resolution)
    by_eigenvalue = {}
    for regulator in FIG07_REGULATORS:
        reporter.stage(f"the exact plant's fixed points and eigenvalues, {regulator}")
        by_eigenvalue[regulator] = _fig07_by_eigenvalue(regulator, resolution)

    figure = Figure(figsize=(12, 7.5))
    top = figure.add_subplot(2, 1, 1)
    top.pcolormesh(
        alphas,
        _bar_height(heights),
        colour.T,
        cmap=basin_colour_map(basins.OPEN_LOOP_STRIDES),
        vmin=0,
        vmax=basins.OPEN_LOOP_STRIDES + 1,
        shading="nearest",
    )
    _plot_fixed_points(top, analytic_alphas[:, None], _bar_height(traced.y), traced.stable)
    exact_y = everything.y[grid].reshape(alpha_grid.shape)
    top.plot(alpha_grid.ravel(), _bar_height(exact_y).ravel(), ".", color=EXACT, markersize=4)
    top.plot(cross_alpha, cross_height, "x", color=START, markersize=9, mew=2)
    for regulator, colour in (("open_loop", EXACT), ("open_loop_stance_tf", "tab:purple")):
        points = by_eigenvalue[regulator]
        x, y, stable = np.broadcast_arrays(alphas[:, None], _bar_height(points.y), points.stable)
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
        y_bar, xdot_bar = _bar_height(history.y[:, lane]), _bar_speed(history.xdot[:, lane])
        axes.plot(y_bar, label="ybar")
        axes.plot(y_bar + 0.5 * xdot_bar**2, label="Ebar")
        axes.set(
            xlabel="stride",
            title=f"({'bc'[index]}) alpha = {alpha:g}: "
            + _settled_text(int(everything.convergence_stride[lane])),
        )
        axes.legend(fontsize=7)
    data = {
        "beta_deg": 26.0,
        "strides": basins.OPEN_LOOP_STRIDES,
        "alpha": alphas.tolist(),
        "ybar0": _bar_height(heights).tolist(),
        "Ebar0": _bar_energy(start_energy).tolist(),
        "outcome": [[basins.OUTCOMES[o] for o in row] for row in outcome],
        "convergence_stride": everything.convergence_stride[grid].reshape(alpha_grid.shape).tolist(),
        "exact_fixed_ybar": _bar_height(exact_y).tolist(),
        "exact_by_eigenvalue": {
            regulator: _fixed_points_json(points, alphas) for regulator, points in by_eigenvalue.items()
        },
        "exact_fixed_Ebar": _bar_energy(everything.energy[grid].reshape(alpha_grid.shape)).tolist(),
        "outcome_counts": _outcome_counts(everything),
        "analytic": _fixed_points_json(traced, analytic_alphas),
        "runs": [
            {
                "alpha": float(alpha),
                "ybar": _bar_height(everything.history.y[:, lane]).tolist(),
                "xdotbar": _bar_speed(everything.history.xdot[:, lane]).tolist(),
                "convergence_stride": int(everything.convergence_stride[lane]),
            }
            for lane, alpha in zip(cross_lanes, cross_alpha, strict=True)
        ],
    }
    return figure, data


# --- Energy regulation (section IV) ----------------------------------------------------------------------


@shared
def _regulated(beta_deg: float, resolution: Resolution) -> tuple[Array, stability.FixedPoints, ExactCheck]:
    """Regulated fixed points over Ebar in [1, 8] (figs 8, 9), checked on the exact plant held at each
    energy exactly (energy_exact, the exact counterpart of the map's energy conservation)."""
    energies_bar = np.linspace(1.0, 8.0, resolution.energies)
    beta = math.radians(beta_deg)
    points = stability.regulated_fixed_points(PARAMS, beta, units.energy_from_bar(PARAMS, energies_bar))
    return energies_bar, points, _exact_check(beta, "energy_exact", points, resolution)


def _shade_infeasible(axes: Axes, bottom: float, horizontal: bool = True, vertical: bool = False) -> None:
    if horizontal:
        axes.axhspan(0.0, bottom, color="0.85", zorder=0)
    if vertical:
        axes.axvspan(0.0, bottom, color="0.85", zorder=0)


def fig08(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
    figure = Figure(figsize=(11, 8))
    rows = figure.subplots(2, 2)
    data: dict[str, Any] = {}
    for (left, right), beta_deg in zip(rows, (22.0, 30.0), strict=True):
        reporter.stage(f"beta = {beta_deg} deg, analytic and exact plant (energy_exact)")
        beta = math.radians(beta_deg)
        bottom = stability.infeasible_height(PARAMS, beta)
        curves: dict[str, Any] = {}
        for energy_bar in range(1, 9):
            heights = np.linspace(bottom * (1 + 1e-6), energy_bar, 200)
            y_next = stability.regulated_height_map(
                PARAMS, beta, units.energy_from_bar(PARAMS, energy_bar), heights
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
        energies_bar, points, check = _regulated(beta_deg, resolution)
        analytic_y = _bar_height(points.y)
        _plot_fixed_points(right, energies_bar[:, None], analytic_y, points.stable, label="analytic")
        _plot_exact_check(right, energies_bar[:, None], analytic_y, check, _bar_height(check.exact.y))
        _shade_infeasible(right, bottom)
        right.set(xlabel="Ebar", ylabel="ybar*", title="fixed points (open: unstable)", ylim=(0.7, 3.0))
        right.legend(fontsize=7)
        data[f"beta_{beta_deg:g}"] = {
            "infeasible_below_ybar": bottom,
            "maps": curves,
            "fixed_points": _fixed_points_json(points, energies_bar) | check.json(energies_bar),
        }
    return figure, data


def fig09(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
    figure = Figure(figsize=(7, 6))
    data: dict[str, Any] = {}
    for axes, beta_deg, label in zip(figure.subplots(2, 1), (22.0, 30.0), "ab", strict=True):
        reporter.stage(f"beta = {beta_deg} deg, analytic and exact plant (energy_exact)")
        energies_bar, points, check = _regulated(beta_deg, resolution)
        eigenvalue = np.real(points.eigenvalues[..., 0])
        _plot_fixed_points(axes, energies_bar[:, None], eigenvalue, points.stable, label="analytic")
        exact_eigenvalue = np.real(check.exact.eigenvalues[..., 0])
        _plot_exact_check(axes, energies_bar[:, None], eigenvalue, check, exact_eigenvalue)
        axes.legend(fontsize=7)
        for level in (-1.0, 1.0):
            axes.axhline(level, color="0.6", lw=0.8)
        axes.set(
            xlabel="Ebar", ylabel="lambda = dy'/dy", title=f"({label}) beta = {beta_deg:g} deg", ylim=(-3, 2)
        )
        data[label] = {
            "beta_deg": beta_deg,
            **_fixed_points_json(points, energies_bar),
            **check.json(energies_bar),
        }
    return figure, data


def _fig10_grid(resolution: Resolution) -> tuple[Array, Array]:
    """fig10's initial (= goal) energies Ebar and initial heights [m]."""
    return fig10_grid(resolution.basin_energies, resolution.basin_heights)


@shared
def _fig10_basin(resolution: Resolution) -> basins.Basin:
    """The goal regulator's exact plant over fig10's grid."""
    energies_bar, heights = _fig10_grid(resolution)
    return basins.exact_regulated_fixed_points(
        PARAMS, math.radians(26.0), units.energy_from_bar(PARAMS, energies_bar), heights
    )


@shared
def _fig10_by_eigenvalue(resolution: Resolution) -> stability.FixedPoints:
    """The goal regulator's exact fixed points and eigenvalues at fig10's energies."""
    beta = math.radians(26.0)
    energies = units.energy_from_bar(PARAMS, _fig10_grid(resolution)[0])
    return exact_stability.fixed_points(
        exact_stability.ExactLoop.of(PARAMS, beta, "energy", energies),
        stability.height_grid(PARAMS, beta, points=resolution.exact_heights),
    )


def fig10(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
    beta = math.radians(26.0)
    energies_bar, heights = _fig10_grid(resolution)
    reporter.stage(f"{energies_bar.size * heights.size} lanes, {basins.REGULATED_STRIDES} strides")
    exact = _fig10_basin(resolution)
    fine_energies = np.linspace(2.0, 6.0, 4 * resolution.energies)
    analytic = stability.regulated_fixed_points(PARAMS, beta, units.energy_from_bar(PARAMS, fine_energies))
    reporter.stage("the exact plant's fixed points and eigenvalues")
    by_eigenvalue = _fig10_by_eigenvalue(resolution)
    exact_y, exact_xdot, exact_energy = (row_median(values) for values in (exact.y, exact.xdot, exact.energy))
    colour = basin_colours(exact.outcome, exact.convergence_stride, basins.REGULATED_STRIDES)
    colour_map = basin_colour_map(basins.REGULATED_STRIDES)
    figure = Figure(figsize=(12, 4.8))
    left, right = figure.subplots(1, 2)
    left.pcolormesh(
        energies_bar,
        _bar_height(heights),
        colour.T,
        cmap=colour_map,
        vmin=0,
        vmax=basins.REGULATED_STRIDES + 1,
        shading="nearest",
    )
    start_speed = _bar_speed(speed_from_energy(PARAMS, exact.y0, exact.energy0))
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
        (left, _bar_height(analytic.y), _bar_height(exact_y), "ybar"),
        (right, _bar_speed(analytic.xdot), _bar_speed(exact_xdot), "xdotbar"),
    ):
        _plot_fixed_points(axes, fine_energies[:, None], analytic_values, analytic.stable, label="analytic")
        axes.plot(
            _bar_energy(exact_energy), exact_values, "-", color=EXACT, lw=2, label="exact plant, reached"
        )
        _plot_exact_check(
            axes,
            _bar_energy(by_eigenvalue.energy),
            np.full(by_eigenvalue.y.shape, np.nan),
            ExactCheck(by_eigenvalue, np.ones(by_eigenvalue.y.shape, dtype=bool)),
            _bar_height(by_eigenvalue.y) if name == "ybar" else _bar_speed(by_eigenvalue.xdot),
        )
        axes.set(xlabel="Ebar", ylabel=f"{name} (fixed points; basin: initial {name}0)", xlim=(2, 6))
        axes.legend(fontsize=7)
    left.set_title("(a) apex height, beta = 26 deg (blue: basin after 50 strides)")
    right.set_title("(b) apex speed")
    converged = exact.outcome == basins.CONVERGED
    data = {
        "beta_deg": 26.0,
        "strides": basins.REGULATED_STRIDES,
        "Ebar0": energies_bar.tolist(),
        "ybar0": _bar_height(heights).tolist(),
        "outcome": [[basins.OUTCOMES[o] for o in row] for row in exact.outcome],
        "convergence_stride": exact.convergence_stride.tolist(),
        "outcome_counts": _outcome_counts(exact),
        "converged_within_8_strides": int(np.sum(converged & (exact.convergence_stride <= 8))),
        "exact_fixed_points": {
            "Ebar_goal": energies_bar.tolist(),
            "Ebar": _bar_energy(exact_energy).tolist(),
            "ybar": _bar_height(exact_y).tolist(),
            "xdotbar": _bar_speed(exact_xdot).tolist(),
        },
        "analytic": _fixed_points_json(analytic, fine_energies),
        "exact_by_eigenvalue": _fixed_points_json(by_eigenvalue, energies_bar),
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


@shared
def stable_range(
    kbar: float, zeta0: float, beta_deg: float, source: str, resolution: Resolution
) -> tuple[float, float]:
    """Stable Ebar range of ``source`` (RANGE_SOURCES) for the hopper (kbar, zeta0) at beta [deg]: the
    analytic map's from its fixed points (stability.stable_energy_range), the exact plant's from its fixed
    points and eigenvalues (exact_stability.stable_energy_range); (NaN, NaN) where none is stable."""
    params = HopperParams.from_dimensionless(kbar, zeta0)
    beta = math.radians(beta_deg)
    energies = units.energy_from_bar(params, np.linspace(*RANGE_EBAR, resolution.exact_energies))
    if source == "analytic":
        ends = stability.stable_energy_range(params, beta, energies, bisections=resolution.bisections + 6)
    else:
        heights = stability.height_grid(params, beta, points=resolution.exact_heights)
        regulator: exact_stability.Regulator = "energy" if source == "energy" else "energy_exact"
        ends = exact_stability.stable_energy_range(
            params, beta, regulator, energies, resolution.bisections, heights
        )
    low, high = (float(units.energy_to_bar(params, end)) for end in ends)
    return low, high


def ranges(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
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
            found[source] = stable_range(36.0, 0.08, beta_deg, source, resolution)
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


def fig11_hoppers() -> list[tuple[str, float, float, float, float]]:
    """(varied parameter, its value, kbar, zeta0, beta [deg]) of every curve of fig11."""
    return [
        (
            name,
            value,
            value if name == "kbar" else 36.0,
            value if name == "zeta0" else 0.08,
            value if name == "beta_deg" else 26.0,
        )
        for name, values in FIG11_STUDIES.items()
        for value in values
    ]


def _fig11_energies_bar(resolution: Resolution) -> Array:
    return np.linspace(0.8, 14.0, 2 * resolution.energies)


@shared
def _regulated_points(
    kbar: float, zeta0: float, beta_deg: float, resolution: Resolution
) -> stability.FixedPoints:
    """The analytic regulated map's fixed points over fig11's energies for the hopper (kbar, zeta0)."""
    params = HopperParams.from_dimensionless(kbar, zeta0)
    return stability.regulated_fixed_points(
        params, math.radians(beta_deg), units.energy_from_bar(params, _fig11_energies_bar(resolution))
    )


def fig11(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
    energies_bar = _fig11_energies_bar(resolution)
    figure = Figure(figsize=(14, 4.5))
    data: dict[str, Any] = {}
    for axes, name in zip(figure.subplots(1, 3), FIG11_STUDIES, strict=True):
        ends = []
        data[name] = []
        for _, value, kbar, zeta0, beta_deg in (hopper for hopper in fig11_hoppers() if hopper[0] == name):
            reporter.stage(f"varying {name}: {value:g}, analytic and exact plant (energy_exact)")
            params = HopperParams.from_dimensionless(kbar, zeta0)
            points = _regulated_points(kbar, zeta0, beta_deg, resolution)
            stable = points.stable
            keep = stable.any(axis=1)
            pick = np.argmax(stable, axis=1)[:, None]
            y = np.take_along_axis(units.height_to_bar(params, points.y), pick, 1)[:, 0]
            xdot = np.take_along_axis(units.speed_to_bar(params, points.xdot), pick, 1)[:, 0]
            y, xdot = np.where(keep, y, np.nan), np.where(keep, xdot, np.nan)
            analytic = stable_range(kbar, zeta0, beta_deg, "analytic", resolution)
            exact = stable_range(kbar, zeta0, beta_deg, "energy_exact", resolution)
            label = (
                f"{name} = {value:g}: Ebar [{analytic[0]:.2f}, {analytic[1]:.2f}], "
                f"exact [{exact[0]:.2f}, {exact[1]:.2f}]"
            )
            (line,) = axes.plot(xdot, y, lw=1.2, label=label)
            finite = np.flatnonzero(np.isfinite(y))
            if finite.size:
                axes.plot(xdot[finite[[0, -1]]], y[finite[[0, -1]]], "o", color=line.get_color(), mfc="none")
                ends.append((float(np.mean(xdot[finite])), float(np.mean(y[finite]))))
            data[name].append(
                {
                    "value": value,
                    "Ebar": energies_bar.tolist(),
                    "ybar": y.tolist(),
                    "xdotbar": xdot.tolist(),
                    "stable_Ebar_range": list(analytic),
                    "exact_stable_Ebar_range": list(exact),
                }
            )
        if len(ends) >= 2:
            axes.annotate("", xy=ends[-1], xytext=ends[0], arrowprops={"arrowstyle": "->", "color": "0.3"})
        axes.set(xlabel="xdotbar*", ylabel="ybar*", title=f"stable fixed points, varying {name}")
        axes.legend(fontsize=6)
    figure.suptitle(
        "analytic map's stable fixed points; legend: stable Ebar ranges, analytic and exact plant"
    )
    return figure, data


# --- Deadbeat against PD (section V) ---------------------------------------------------------------------


def track_targets(
    params: HopperParams,
    controller: str,
    target_y: float,
    target_speeds: Array,
    start: tuple[float, float],
    strides: int,
    progress: basins.Progress | None = None,
) -> basins.Basin:
    """Exact-plant runs from ``start`` (y [m], xdot [m/s]) towards (target_y, each target speed) [m, m/s]
    under ``controller`` ("deadbeat" or "pd", its default gains), one lane per target speed."""
    speeds = np.asarray(target_speeds, dtype=float)
    previous = np.full(speeds.shape, start[1])

    def policy(stride: int, y: Array, xdot: Array, lanes: Array) -> CommandArrays:
        if controller == "deadbeat":
            return deadbeat(params, y, xdot, target_y, speeds[lanes])
        command = pd_speed_energy_height(params, y, xdot, previous[lanes], target_y, speeds[lanes])
        previous[lanes] = xdot
        return command

    y0 = np.full(speeds.shape, start[0])
    energy0 = params.m * (params.g * y0 + 0.5 * start[1] ** 2)
    return basins.basin(params, y0, energy0, policy, strides, progress)


EDGE_HEIGHT, EDGE_SPEEDS, EDGE_STRIDES = 0.95, (1.5, 2.0, 2.5, 3.0, 3.5), 20
"""Deadbeat towards an apex below r0 (m, m/s, strides): the edges of leg placement and of the fall."""


def fig13(resolution: Resolution, reporter: Reporter) -> tuple[Figure, dict[str, Any]]:
    speeds_bar = np.round(np.arange(0.5, 3.0 + 1e-9, resolution.speed_step), 3)
    target_y, start = 1.0, (1.0, 5.0)
    speeds = np.asarray(units.speed_from_bar(PARAMS, speeds_bar))
    figure = Figure(figsize=(7, 6.5))
    top, bottom = figure.subplots(2, 1, sharex=True)
    data: dict[str, Any] = {
        "target_ybar": target_y,
        "start": {"ybar": start[0], "xdotbar": float(units.speed_to_bar(PARAMS, start[1]))},
        "strides": basins.REGULATED_STRIDES,
        "xdotbar_target": speeds_bar.tolist(),
    }
    for controller, (colour, style) in CONTROLLER_STYLE.items():
        run = track_targets(
            PARAMS,
            controller,
            target_y,
            speeds,
            start,
            basins.REGULATED_STRIDES,
            reporter.strides(controller),
        )
        final_y, final_xdot = run.history.y[-1], run.history.xdot[-1]
        speed_error = 100.0 * (final_xdot - speeds) / speeds
        height_error = 100.0 * (final_y - target_y) / target_y
        stable = run.outcome == basins.CONVERGED
        for axes, error in ((top, speed_error), (bottom, height_error)):
            axes.plot(
                speeds_bar[stable], np.abs(error[stable]), style, color=colour, marker=".", label=controller
            )
            # Losses of stability as crosses along the bottom of the (log) axes.
            bottom_edge = np.full(np.sum(~stable), 0.04 if controller == "deadbeat" else 0.1)
            axes.plot(
                speeds_bar[~stable],
                bottom_edge,
                "x",
                color=colour,
                markersize=9,
                mew=2,
                transform=axes.get_xaxis_transform(),
            )
        data[controller] = {
            "outcome": [basins.OUTCOMES[o] for o in run.outcome],
            "stable": stable.tolist(),
            "convergence_stride": run.convergence_stride.tolist(),
            "speed_error_percent": speed_error.tolist(),
            "height_error_percent": height_error.tolist(),
            "stable_xdotbar_range": [float(speeds_bar[stable].min()), float(speeds_bar[stable].max())]
            if stable.any()
            else None,
        }
    reporter.stage(f"deadbeat towards y* = {EDGE_HEIGHT} m, below r0 (the edge of leg placement)")
    edge = track_targets(PARAMS, "deadbeat", EDGE_HEIGHT, np.array(EDGE_SPEEDS), start, EDGE_STRIDES)
    data["edge"] = {
        "target_y": EDGE_HEIGHT,
        "target_xdot": list(EDGE_SPEEDS),
        "strides": EDGE_STRIDES,
        "outcome": [basins.OUTCOMES[o] for o in edge.history.outcome],
        "failure_stride": edge.history.failure_stride.tolist(),
        "last_y": edge.history.y[-1].tolist(),
        "last_xdot": edge.history.xdot[-1].tolist(),
    }
    top.set(ylabel="|speed error| [%]", yscale="log", title="deadbeat vs PD, 50 strides (x: loses stability)")
    bottom.set(xlabel="xdotbar*", ylabel="|height error| [%]", yscale="log")
    top.legend(fontsize=8)
    return figure, data


FIGURES: dict[str, Callable[[Resolution, Reporter], tuple[Figure, dict[str, Any]]]] = {
    "fig04": fig04,
    "fig05": fig05,
    "fig06": fig06,
    "fig07": fig07,
    "fig08": fig08,
    "fig09": fig09,
    "fig10": fig10,
    "fig11": fig11,
    "ranges": ranges,
    "fig13": fig13,
}


def shared_work(names: Sequence[str], resolution: Resolution) -> list[tuple[str, tuple[Any, ...]]]:
    """The @shared computations (name, arguments) that the figures ``names`` make: the sweeps that take
    their time. The exact plant's stable ranges come first, as they take longest."""
    work: list[tuple[str, tuple[Any, ...]]] = []
    if "ranges" in names:
        work += [
            ("stable_range", (36.0, 0.08, beta, s, resolution)) for beta in RANGE_BETAS for s in RANGE_SOURCES
        ]
    if "fig11" in names:
        for _, _, kbar, zeta0, beta_deg in fig11_hoppers():
            work += [
                ("stable_range", (kbar, zeta0, beta_deg, s, resolution)) for s in ("energy_exact", "analytic")
            ]
            work.append(("_regulated_points", (kbar, zeta0, beta_deg, resolution)))
    if "fig05" in names:
        work += [
            ("_open_loop_row", (float(beta), resolution))
            for beta in np.linspace(20.0, 32.0, resolution.betas)
        ]
    for beta_deg in [26.0] * ("fig04" in names or "fig06" in names) + [32.0] * ("fig06" in names):
        work.append(("_open_loop_exact", (beta_deg, resolution)))  # brings _open_loop_trace along
    if "fig07" in names:
        work += [("_fig07_basin", (resolution,))]
        work += [("_fig07_by_eigenvalue", (regulator, resolution)) for regulator in FIG07_REGULATORS]
        if ("_open_loop_exact", (26.0, resolution)) not in work:
            work.append(("_open_loop_trace", (26.0, resolution)))
    if "fig08" in names or "fig09" in names:
        work += [("_regulated", (beta_deg, resolution)) for beta_deg in (22.0, 30.0)]
    if "fig10" in names:
        work += [("_fig10_basin", (resolution,)), ("_fig10_by_eigenvalue", (resolution,))]
    exact_ranges = [item for item in work if item[0] == "stable_range" and item[1][3] != "analytic"]
    return exact_ranges + [item for item in work if item not in exact_ranges]


def precompute(names: Sequence[str], resolution: Resolution, where: engine.Where) -> None:
    """Run the figures' sweeps (:func:`shared_work`) as tasks on the study engine, in parallel; the
    figures then draw from their results. Each task brings back every shared result it made."""
    work = shared_work(names, resolution)
    if not work:
        return
    calls: list[engine.Call] = [(name, computed_by, (name, args)) for name, args in work]
    with engine.connect(where) as client:
        for entries in engine.compute(client, calls, engine.Progress("figures", "sweeps")):
            _COMPUTED.update(entries)


def write_figure(name: str, out: Path, resolution: Resolution) -> dict[str, Any]:
    """Compute, draw and save one figure as OUT/<name>.png and OUT/<name>.json; returns its data."""
    reporter = Reporter(name)
    started = time.process_time()
    figure, data = FIGURES[name](resolution, reporter)
    figure.tight_layout()
    figure.savefig(out / f"{name}.png", dpi=DPI)
    document = {
        "figure": name,
        "params": {"kbar": PARAMS.kbar, "zeta0": PARAMS.zeta0, "m": PARAMS.m, "r0": PARAMS.r0, "g": PARAMS.g},
        "resolution": vars(resolution),
        **data,
    }
    (out / f"{name}.json").write_text(to_json(document))
    reporter.stage(f"done in {time.process_time() - started:.1f} s CPU")
    return document


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="tdslip figures", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="directory for the PNG and JSON files")
    parser.add_argument("--only", nargs="+", choices=list(FIGURES), help="just these figures")
    parser.add_argument("--fine", action="store_true", help="the paper's resolutions (much slower)")
    engine.add_arguments(parser, resume=False)
    args = parser.parse_args(argv)
    try:
        output_directory(args.out)
        resolution = FINE if args.fine else DEFAULT
        names = args.only or list(FIGURES)
        precompute(names, resolution, engine.where_of(args))
        documents = {name: write_figure(name, args.out, resolution) for name in names}
        table = paper_comparison.rows(documents, PARAMS)
        (args.out / "comparison.md").write_text(paper_comparison.markdown(table))
    except (OutputError, engine.EngineError) as error:
        print(f"tdslip figures: {error}", file=sys.stderr)
        return 1
    except OSError as error:
        print(f"tdslip figures: {write_failed(error)}", file=sys.stderr)
        return 1
    print(paper_comparison.text(table), end="")
    return 0
