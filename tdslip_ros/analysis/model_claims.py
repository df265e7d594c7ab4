"""The paper's claims the model alone answers, without a figure: the rows of :mod:`.paper_comparison` that
read none. The analytic map's prediction error on the accuracy grids and its accuracy domain, the convergence
of its corrections, the solutions of eq. 27, the speed scale; some five seconds of work, which the full
``tdslip figures`` does and a run of some figures (``--only``) does not.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from tdslip_ros.analysis.figure_claims import span
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import SpeedSource
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.stability import analytic_accuracy, analytic_fixed_points
from tdslip_ros.model.stability.analytic_accuracy import Quantity


def accuracy_domain(params: HopperParams) -> tuple[str, str]:
    """Per map and quantity, the compressions up to which every stride of the fine domain grid errs less
    than 5 %, over the touchdown angles where the least compressed stride does (docs/paper.md has 1 %)."""
    grid = analytic_accuracy.FINE_DOMAIN_GRID
    domain = analytic_accuracy.domain_errors(params, analytic_accuracy.exact_strides(params, grid))
    parts: list[str] = []
    columns: tuple[tuple[str, SpeedSource, Quantity], ...] = (
        ("height", "liftoff", "height"),
        ("speed, ours", "energy", "speed"),
        ("eq. 7 speed", "liftoff", "speed"),
    )
    for name, speed, quantity in columns:
        found = analytic_accuracy.boundaries(domain, speed, quantity, 0.05)
        below = [boundary.below for boundary in found if boundary.below is not None]
        where = f"{min(below):.2f}-{max(below):.2f}" if below else "none"
        parts.append(f"{where} ({name}, {len(below)} of {len(found)}{' angles' if not parts else ''})")
    compared = domain.compression[~np.isnan(domain.errors["liftoff", "height"])]
    degrees = np.degrees(grid.angles)
    return (
        "every stride within 5 % up to compression " + ", ".join(parts),
        f"truth: the exact plant, {compared.size} strides, {degrees.min():g}-{degrees.max():g} deg, "
        f"compression {compared.min():.2f}-{compared.max():.2f}",
    )


@functools.cache
def _operating_strides(params: HopperParams) -> analytic_accuracy.ExactStrides:
    """The exact plant on the operating grid (two rows read it)."""
    return analytic_accuracy.exact_strides(params, analytic_accuracy.OPERATING_GRID)


def prediction_error(params: HopperParams) -> tuple[str, str]:
    accuracy = analytic_accuracy.accuracy(params, _operating_strides(params), corrections=1)
    analytic = (
        f"mean {100 * accuracy.mean_height_error:.2f} % (height), "
        f"{100 * accuracy.mean_speed_error:.2f} % (speed); "
        f"max {100 * accuracy.max_height_error:.1f} %, {100 * accuracy.max_speed_error:.1f} %; "
        f"the paper's eq. 7 speed: mean {100 * accuracy.mean_liftoff_speed_error:.2f} %, "
        f"max {100 * accuracy.max_liftoff_speed_error:.1f} %"
    )
    return analytic, f"truth: the exact plant, {accuracy.lanes} strides of the operating grid"


def corrections(params: HopperParams) -> tuple[str, str]:
    """II.D: the corrections iterated to convergence on the operating grid (and the fine domain grid): the
    iterations, and how far one correction's next apex lies from the converged one's; then each against the
    exact plant."""
    operating = analytic_accuracy.correction_convergence(params, analytic_accuracy.OPERATING_GRID)
    domain = analytic_accuracy.correction_convergence(params, analytic_accuracy.FINE_DOMAIN_GRID)

    def iterations(found: analytic_accuracy.CorrectionConvergence) -> str:
        done = found.iterations[found.iterations > 0]
        span = f" in {done.min()}-{done.max()}" if done.size else ""
        return f"{done.size} of {found.iterations.size}{span}"

    analytic = (
        f"converge: {iterations(operating)} iterations (operating grid), {iterations(domain)} (domain grid); "
        f"1 vs converged: height {100 * np.nanmax(operating.height_change):.2f} %, "
        f"speed {100 * np.nanmax(operating.speed_change):.2f} % at most"
    )
    errors = [
        analytic_accuracy.accuracy(params, _operating_strides(params), corrections)
        for corrections in (0, 1, analytic_accuracy.CORRECTION_LIMIT)
    ]
    exact = "mean error, height / speed: " + "; ".join(
        f"{name} {100 * found.mean_height_error:.2f} / {100 * found.mean_speed_error:.2f} %"
        for name, found in zip(("none", "1 correction", "converged"), errors, strict=True)
    )
    return analytic, exact


EQ27_BETAS_DEG = (20.0, 22.0, 24.0, 26.0, 28.0, 30.0, 32.0)
EQ27_ALPHAS = tuple(float(alpha) for alpha in np.linspace(0.5, 2.5, 11))
EQ27_HEIGHTS = 20
"""The grid on which the solutions of eq. 27 are counted: fig. 5's angles and powers, EQ27_HEIGHTS apex
heights per angle (analytic_fixed_points.height_grid), energies analytic_fixed_points.EQ27_SCAN."""


def eq27_solutions(params: HopperParams) -> tuple[str, str]:
    counts, falls, betas = [], 0, []
    for beta_deg in EQ27_BETAS_DEG:
        beta = math.radians(beta_deg)
        count, last = analytic_fixed_points.energy_fixed_point_count(
            params,
            beta,
            np.array(EQ27_ALPHAS)[:, None],
            analytic_fixed_points.height_grid(params, beta, points=EQ27_HEIGHTS)[None, :],
        )
        counts.append(count.ravel())
        falls += int(np.sum((count == 0) & (last > 0)))
        if np.any(count == 0):
            betas.append(beta_deg)
    found = np.concatenate(counts)
    none = int(np.sum(found == 0))
    why = "all" if falls == none else f"{falls}"
    where = f" (beta {span(betas)} deg; {why} where the map fails before E' falls to E)"
    return (
        f"exactly 1 at {int(np.sum(found == 1))} of {found.size} (alpha, y), beta "
        f"{EQ27_BETAS_DEG[0]:g}-{EQ27_BETAS_DEG[-1]:g} deg; none at {none}{where if none else ''}; "
        f"2 or more at {int(np.sum(found >= 2))}",
        "-",
    )


def speed_scale(params: HopperParams) -> tuple[str, str]:
    return (
        f"xdotbar 1.5 = {units.speed_from_bar(params, 1.5):.2f} m/s (g = {params.g}, r0 = {params.r0} m)",
        "-",
    )
