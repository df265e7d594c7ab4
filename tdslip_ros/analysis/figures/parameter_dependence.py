"""fig11: the analytic regulated map's stable fixed points as beta, kbar or zeta0 vary, with each value's
stable Ebar range, analytic and on the exact plant."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from tdslip_ros.analysis.figures.common import FigureData, Reporter, Resolution
from tdslip_ros.analysis.figures.regulated import stable_range
from tdslip_ros.analysis.figures.shared import SHARED
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import SpeedSource
from tdslip_ros.model.arrays import Array
from tdslip_ros.model.paper import PAPER_KBAR, PAPER_ZETA0
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.stability import analytic_fixed_points
from tdslip_ros.reporting.paper_grids import FIG11_STUDIES, fig11_energies_bar


def fig11_hoppers() -> list[tuple[str, float, float, float, float]]:
    """(varied parameter, its value, kbar, zeta0, beta [deg]) of every curve of fig11."""
    return [
        (
            name,
            value,
            value if name == "kbar" else PAPER_KBAR,
            value if name == "zeta0" else PAPER_ZETA0,
            value if name == "beta_deg" else 26.0,
        )
        for name, values in FIG11_STUDIES.items()
        for value in values
    ]


def _fig11_energies_bar(resolution: Resolution) -> Array:
    return fig11_energies_bar(2 * resolution.energies)


@SHARED.register
def fig11_fixed_points(
    kbar: float, zeta0: float, beta_deg: float, resolution: Resolution, speed: SpeedSource
) -> analytic_fixed_points.FixedPoints:
    """The analytic regulated map's fixed points over fig11's energies for the hopper (kbar, zeta0)."""
    params = HopperParams.from_dimensionless(kbar, zeta0)
    energies = units.energy_from_bar(params, _fig11_energies_bar(resolution))
    return analytic_fixed_points.regulated_fixed_points(params, math.radians(beta_deg), energies, speed=speed)


def fig11(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    energies_bar = _fig11_energies_bar(resolution)
    figure = Figure(figsize=(14, 4.5))
    data: dict[str, Any] = {}
    for axes, name in zip(figure.subplots(1, 3), FIG11_STUDIES, strict=True):
        ends = []
        data[name] = []
        for _, value, kbar, zeta0, beta_deg in (hopper for hopper in fig11_hoppers() if hopper[0] == name):
            reporter.stage(f"varying {name}: {value:g}, analytic and exact plant (energy_exact)")
            params = HopperParams.from_dimensionless(kbar, zeta0)
            points = fig11_fixed_points(kbar, zeta0, beta_deg, resolution, speed)
            stable = points.stable
            keep = stable.any(axis=1)
            pick = np.argmax(stable, axis=1)[:, None]
            y = np.take_along_axis(units.height_to_bar(params, points.y), pick, 1)[:, 0]
            xdot = np.take_along_axis(units.speed_to_bar(params, points.xdot), pick, 1)[:, 0]
            y, xdot = np.where(keep, y, np.nan), np.where(keep, xdot, np.nan)
            analytic = stable_range(kbar, zeta0, beta_deg, "analytic", resolution, speed)
            exact = stable_range(kbar, zeta0, beta_deg, "energy_exact", resolution, speed)
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
