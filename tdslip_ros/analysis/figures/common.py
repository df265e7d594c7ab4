"""What the paper's figures share: their resolutions, progress on stderr, the paper's hopper and its
dimensionless units, and how analytic fixed points and their check on the exact plant are drawn and stored."""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import SpeedSource
from tdslip_ros.model.arrays import Array
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.stability import analytic_fixed_points, basins, exact_fixed_points
from tdslip_ros.reporting.style import EXACT, STABLE, UNSTABLE

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


def bar_height(y: Array) -> Array:
    return np.asarray(units.height_to_bar(PARAMS, y))


def bar_energy(energy: Array) -> Array:
    return np.asarray(units.energy_to_bar(PARAMS, energy))


def bar_speed(xdot: Array) -> Array:
    return np.asarray(units.speed_to_bar(PARAMS, xdot))


def plot_fixed_points(axes: Axes, x: Array, values: Array, stable: Array, label: str | None = None) -> None:
    """Fixed points as markers: filled where stable, open where unstable."""
    x_, values_, stable_ = np.broadcast_arrays(x, values, stable)
    axes.plot(x_[stable_], values_[stable_], "o", color=STABLE, markersize=3, label=label)
    unstable = ~stable_ & np.isfinite(values_)
    axes.plot(x_[unstable], values_[unstable], "o", color=UNSTABLE, markersize=3, mfc="none")


def fixed_points_json(points: analytic_fixed_points.FixedPoints, parameter: Array) -> dict[str, Any]:
    return {
        "parameter": parameter.tolist(),
        "ybar": bar_height(points.y).tolist(),
        "xdotbar": bar_speed(points.xdot).tolist(),
        "Ebar": bar_energy(points.energy).tolist(),
        "eigenvalues": points.eigenvalues.tolist(),
        "spectral_radius": points.spectral_radius.tolist(),
        "stable": points.stable.tolist(),
    }


@dataclass(frozen=True)
class ExactCheck:
    """The exact plant's fixed points for the members of an analytic trace, and per analytic fixed point
    whether the exact plant has it (exact_fixed_points.exists_on_exact_plant)."""

    exact: analytic_fixed_points.FixedPoints
    exists: Array

    def json(self, parameter: Array) -> dict[str, Any]:
        return {
            "exact": fixed_points_json(self.exact, parameter),
            "analytic_exists_on_exact_plant": self.exists.tolist(),
        }


def exact_check(
    beta: float,
    regulator: exact_fixed_points.Regulator,
    analytic: analytic_fixed_points.FixedPoints,
    resolution: Resolution,
) -> ExactCheck:
    """Every analytic fixed point of ``analytic`` (members: its parameter, alpha or the energy [J])
    checked on the exact plant under ``regulator``."""
    loop = exact_fixed_points.ExactLoop.of(PARAMS, beta, regulator, analytic.parameter)
    heights = analytic_fixed_points.height_grid(PARAMS, beta, points=resolution.exact_heights)
    exact = exact_fixed_points.fixed_points(loop, heights)
    return ExactCheck(exact, exact_fixed_points.exists_on_exact_plant(analytic, exact))


def plot_exact_check(
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


FigureData = tuple[Figure, dict[str, Any]]
"""A drawn figure and the numbers drawn (dimensionless, eq. 24), as its JSON document holds them."""
FigureFunction = Callable[[Resolution, Reporter, SpeedSource], FigureData]
"""What computes and draws one figure at a resolution with the analytic map of a next-apex speed (ours or
the paper's, :data:`~tdslip_ros.model.analytic.apex_map.SpeedSource`), reporting its progress."""
