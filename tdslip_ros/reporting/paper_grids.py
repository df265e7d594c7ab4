"""The grids of the paper's basin figures, declared once for ``tdslip figures`` (at its resolutions) and
``tdslip sweep`` (at any): the exact plant from initial apexes over fig. 7's (alpha, y0), fig. 10's (Ebar0,
y0) and fig. 11's (Ebar, y0) per varied parameter, for the paper's hopper; and the per-row median that
reduces a grid's fixed points reached to one curve."""

from __future__ import annotations

import math

import numpy as np

from tdslip_ros.model.arrays import Array
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.stability import analytic_fixed_points

BASIN_BETA_DEG = 26.0
"""Touchdown angle [deg] of figs 7 and 10."""
FIG11_STUDIES = {
    "beta_deg": (20.0, 22.0, 24.0, 26.0, 28.0, 30.0),
    "kbar": (20.0, 28.0, 36.0, 44.0, 52.0),
    "zeta0": (0.04, 0.08, 0.12, 0.16),
}
"""fig11's parameter values (the others at kbar = 36, zeta0 = 0.08, beta = 26 deg)."""


def fig07_grid(alphas: int, heights: int) -> tuple[Array, Array]:
    """fig07's touchdown powers alpha in [0.5, 2.5] and initial heights [m] from r0 cos(beta) + 5 mm to
    2.4 m (each start on the energy fixed point E*(y0) of eq. 27)."""
    beta = math.radians(BASIN_BETA_DEG)
    return np.linspace(0.5, 2.5, alphas), np.linspace(
        analytic_fixed_points.infeasible_height(PAPER_PARAMS, beta) + 0.005, 2.4, heights
    )


def fig10_grid(energies: int, heights: int) -> tuple[Array, Array]:
    """fig10's initial (= goal) energies Ebar in [2, 6] and initial heights [m] from r0 cos(beta) + 2 mm
    to 2.4 m."""
    beta = math.radians(BASIN_BETA_DEG)
    return np.linspace(2.0, 6.0, energies), np.linspace(
        analytic_fixed_points.infeasible_height(PAPER_PARAMS, beta) + 0.002, 2.4, heights
    )


def fig11_energies_bar(energies: int) -> Array:
    """fig11's goal energies Ebar in [0.8, 14]."""
    return np.linspace(0.8, 14.0, energies)


def row_median(values: Array) -> Array:
    """Median of the finite values of each row; NaN for rows without any."""
    sorted_rows = np.sort(values, axis=1)  # NaN last
    count = np.sum(np.isfinite(values), axis=1)
    low = np.take_along_axis(sorted_rows, np.maximum((count - 1) // 2, 0)[:, None], 1)[:, 0]
    high = np.take_along_axis(sorted_rows, np.maximum(count // 2, 0)[:, None], 1)[:, 0]
    return np.where(count > 0, 0.5 * (low + high), np.nan)
