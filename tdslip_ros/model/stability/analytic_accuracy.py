"""Accuracy of the approximate return map against the exact plant on a grid of strides.

One stride per grid point (apex height, apex speed, touchdown angle, dimensionless ramp torque); the ramp
lasts until the liftoff the analytic map predicts (:func:`controllers.ramp_to_liftoff`, as the paper's
policies do). The exact plant (:func:`exact_map.apex_return_map`) is the truth.

The corrections of eqs. 19-22 that the map applies once: :func:`correction_convergence` iterates them to
convergence on a grid's strides, the paper's claim (II.D) that they converge but for extreme cases and
that one iteration suffices.

Two views of the same comparison: :func:`accuracy` sums the errors up over a grid; :func:`domain_errors`,
:func:`domain_table` and :func:`boundaries` place them over the stance's maximum leg compression (measured on
the exact plant) and the touchdown angle, the two axes of the paper's claim (II.C) that the map "remains
accurate for leg compressions up to %75 of the spring rest length as well as deviations of up to 30 deg away
from the vertical", for both sources of the next apex speed (:data:`analytic.SpeedSource`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Literal

import numpy as np

from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import LiftoffMethod, SpeedSource, approximate_map
from tdslip_ros.model.analytic.map_kernels import CORRECTION_TOLERANCE
from tdslip_ros.model.arrays import Array, CommandArrays
from tdslip_ros.model.events import failure_code
from tdslip_ros.model.params import ApexState, HopperParams
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.policies.controllers import ramp_to_liftoff


@dataclass(frozen=True)
class StrideGrid:
    """Apex heights [m], apex speeds [m/s], touchdown angles [rad] and dimensionless torques taubar."""

    heights: tuple[float, ...]
    speeds: tuple[float, ...]
    angles: tuple[float, ...]
    torques: tuple[float, ...]

    def points(self) -> list[tuple[float, float, float, float]]:
        return list(itertools.product(self.heights, self.speeds, self.angles, self.torques))


# kbar = 36, zeta0 = 0.08 human-like strides: a broad grid, and the region of the paper's regulated gaits.
BROAD_GRID = StrideGrid(
    heights=(1.0, 1.05, 1.1, 1.2, 1.3),
    speeds=(3.0, 4.0, 5.0, 6.0),
    angles=tuple(float(a) for a in np.radians([20.0, 24.0, 28.0, 32.0])),
    torques=(0.0, -0.3, -0.6, -0.9),
)
OPERATING_GRID = StrideGrid(
    heights=(1.0, 1.05, 1.1, 1.15),
    speeds=(3.5, 4.5, 5.5),
    angles=tuple(float(a) for a in np.radians([20.0, 24.0, 28.0])),
    torques=(-0.5, -0.7, -0.9),
)
# The accuracy domain: touchdown angles 10-40 deg, and apex heights up to 5 r0 (8 r0 in the fine grid) so that
# the exact stance compresses the leg from about 5 % to beyond 50 %; running speeds, with and without the
# forward ramp torque. The fine grid is the one docs/paper.md reports (bench/bench_analytic.py --domain).
DOMAIN_GRID = StrideGrid(
    heights=(1.0, 1.25, 1.5, 2.0, 3.0, 5.0),
    speeds=(3.0, 4.5, 6.0, 7.5, 9.0),
    angles=tuple(float(a) for a in np.radians([10.0, 20.0, 30.0, 40.0])),
    torques=(0.0, -0.5),
)
FINE_DOMAIN_GRID = StrideGrid(
    heights=(1.0, 1.1, 1.2, 1.35, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0, 5.5, 8.0),
    speeds=(2.0, 3.0, 4.0, 5.0, 6.0, 7.5, 9.0),
    angles=tuple(float(a) for a in np.radians([10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0])),
    torques=(0.0, -0.5),
)


@dataclass(frozen=True)
class ExactStrides:
    """The exact plant's next apex on every grid point (NaN where it fails) under ``commands``."""

    grid: StrideGrid
    commands: CommandArrays
    y: Array
    xdot: Array
    failure: Array
    compression: Array  # 1 - r_min/r0 at the stance's first maximum compression (NaN where it has none)


@dataclass(frozen=True)
class Accuracy:
    """Relative errors |analytic/exact - 1| of the next apex over the lanes where both maps succeed."""

    corrections: int
    liftoff: LiftoffMethod
    lanes: int
    mean_height_error: float
    max_height_error: float
    mean_speed_error: float
    max_speed_error: float
    mean_liftoff_speed_error: float  # eq. 7's liftoff speed instead of the energy-balance speed
    max_liftoff_speed_error: float
    failure_mismatches: int  # lanes where exactly one of the two maps fails


def exact_strides(params: HopperParams, grid: StrideGrid, corrections: int = 1) -> ExactStrides:
    """Run the exact plant once per grid point, with t_f from the analytic map of ``corrections``."""
    points = np.array(grid.points())
    y, xdot, angle = points[:, 0], points[:, 1], points[:, 2]
    tau0 = units.torque_from_bar(params, points[:, 3])
    commands = ramp_to_liftoff(params, y, xdot, angle, tau0, corrections)
    next_y, next_xdot, failure, compression = (np.full(len(points), np.nan) for _ in range(4))
    for i in range(len(points)):
        if not np.isfinite(commands.t_f[i]):
            continue
        result = apex_return_map(params, ApexState(y[i], xdot[i]), commands.command(i))
        failure[i] = failure_code(result.failure)
        if result.bottom is not None:
            compression[i] = 1.0 - result.bottom.r / params.r0
        if result.apex is not None:
            next_y[i], next_xdot[i] = result.apex.y, result.apex.xdot
    return ExactStrides(grid, commands, next_y, next_xdot, failure, compression)


def accuracy(
    params: HopperParams, exact: ExactStrides, corrections: int, liftoff: LiftoffMethod = "paper"
) -> Accuracy:
    """The analytic map with ``corrections`` and ``liftoff`` against ``exact``, under the same commands."""
    points = np.array(exact.grid.points())
    valid = np.isfinite(exact.commands.t_f)
    commands = CommandArrays(*(field[valid] for field in exact.commands))
    y, xdot = points[valid, 0], points[valid, 1]
    stride = approximate_map(params, y, xdot, commands, corrections, liftoff)
    # Eq. 7's speed on the same lanes: where ours succeeds the paper's map does too (it lacks one failure).
    paper = approximate_map(params, y, xdot, commands, corrections, liftoff, speed="liftoff")
    exact_y, exact_xdot = exact.y[valid], exact.xdot[valid]
    both = stride.ok & np.isfinite(exact_y)
    height = np.abs(stride.y[both] / exact_y[both] - 1.0)
    speed = np.abs(stride.xdot[both] / exact_xdot[both] - 1.0)
    liftoff_speed = np.abs(paper.xdot[both] / exact_xdot[both] - 1.0)
    return Accuracy(
        corrections=corrections,
        liftoff=liftoff,
        lanes=int(both.sum()),
        mean_height_error=float(height.mean()),
        max_height_error=float(height.max()),
        mean_speed_error=float(speed.mean()),
        max_speed_error=float(speed.max()),
        mean_liftoff_speed_error=float(liftoff_speed.mean()),
        max_liftoff_speed_error=float(liftoff_speed.max()),
        failure_mismatches=int(np.sum(stride.ok != np.isfinite(exact_y))),
    )


CORRECTION_LIMIT = 50
"""The most corrections :func:`correction_convergence` applies (every stride of the grids here converges in
at most 13)."""


@dataclass(frozen=True)
class CorrectionConvergence:
    """The corrections of eqs. 19-22 iterated on a grid's strides, under the paper's ramp (t_f the liftoff of
    the map with one correction), over the strides where that ramp exists (``index``: their places in
    ``grid.points()``).

    ``iterations``: the corrections after which p_hat changes by at most CORRECTION_TOLERANCE (relative),
    the map's own stopping rule (-1: not within CORRECTION_LIMIT); ``height_change``, ``speed_change``:
    |one/converged - 1| of the next apex, the map with one correction against the converged one (NaN where
    either fails)."""

    grid: StrideGrid
    index: Array
    iterations: Array
    height_change: Array
    speed_change: Array


def correction_convergence(
    params: HopperParams, grid: StrideGrid, limit: int = CORRECTION_LIMIT
) -> CorrectionConvergence:
    """The corrections iterated up to ``limit`` times on every stride of ``grid`` (the analytic map only)."""
    points = np.array(grid.points())
    tau0 = units.torque_from_bar(params, points[:, 3])
    commands = ramp_to_liftoff(params, points[:, 0], points[:, 1], points[:, 2], tau0)
    index = np.flatnonzero(np.isfinite(commands.t_f))
    commands = CommandArrays(*(field[index] for field in commands))
    y, xdot = points[index, 0], points[index, 1]
    momentum = []
    with np.errstate(invalid="ignore"):
        for corrections in range(limit + 1):
            stride = approximate_map(params, y, xdot, commands, corrections)
            momentum.append(np.real(stride.stance.momentum))
            if corrections == 1:
                one = stride
    change = np.abs(np.diff(momentum, axis=0))
    with np.errstate(invalid="ignore"):
        settled = change <= CORRECTION_TOLERANCE * np.abs(np.array(momentum[1:]))
    iterations = np.where(settled.any(axis=0), np.argmax(settled, axis=0) + 1, -1)
    both = one.ok & stride.ok
    height_change, speed_change = np.full(index.size, np.nan), np.full(index.size, np.nan)
    height_change[both] = np.abs(one.y[both] / stride.y[both] - 1.0)
    speed_change[both] = np.abs(one.xdot[both] / stride.xdot[both] - 1.0)
    return CorrectionConvergence(grid, index, iterations, height_change, speed_change)


Quantity = Literal["height", "speed"]
"""A next-apex quantity whose relative error the domain measures."""
SPEED_SOURCES: tuple[SpeedSource, ...] = ("energy", "liftoff")
QUANTITIES: tuple[Quantity, ...] = ("height", "speed")
COMPRESSION_EDGES = tuple(round(0.05 * i, 2) for i in range(21))
"""Edges of the compression bins of :func:`domain_table`: 0, 0.05, ..., 1."""
ERROR_LEVELS = (0.01, 0.05)
"""The relative errors whose boundaries :func:`boundaries` reports (1 % and 5 %)."""


@dataclass(frozen=True)
class DomainErrors:
    """The next-apex errors of the analytic map over the strides of a grid whose exact stance has a bottom.

    Per stride (``index``: its place in ``grid.points()``): the touchdown angle [rad] and the exact plant's
    maximum leg compression 1 - r_min/r0; for every speed source and quantity, ``errors[speed, quantity]``,
    |map/exact - 1| of the next apex (NaN where the map or the exact plant fails), and for every speed source,
    ``mismatch[speed]``, where exactly one of the two fails (the map is wrong about the stride's outcome).
    """

    grid: StrideGrid
    corrections: int
    index: Array
    angle: Array
    compression: Array
    errors: dict[tuple[SpeedSource, Quantity], Array]
    mismatch: dict[SpeedSource, Array]


def domain_errors(params: HopperParams, exact: ExactStrides, corrections: int = 1) -> DomainErrors:
    """The analytic map with ``corrections`` (both speed sources, the paper's liftoff) against ``exact``."""
    points = np.array(exact.grid.points())
    index = np.flatnonzero(np.isfinite(exact.commands.t_f) & np.isfinite(exact.compression))
    commands = CommandArrays(*(field[index] for field in exact.commands))
    exact_y, exact_xdot = exact.y[index], exact.xdot[index]
    exact_ok = np.isfinite(exact_y)
    errors: dict[tuple[SpeedSource, Quantity], Array] = {}
    mismatch: dict[SpeedSource, Array] = {}
    for speed in SPEED_SOURCES:
        stride = approximate_map(
            params, points[index, 0], points[index, 1], commands, corrections, "paper", speed=speed
        )
        both = stride.ok & exact_ok
        for quantity in QUANTITIES:
            mapped, truth = (stride.y, exact_y) if quantity == "height" else (stride.xdot, exact_xdot)
            error = np.full(len(index), np.nan)
            error[both] = np.abs(mapped[both] / truth[both] - 1.0)
            errors[speed, quantity] = error
        mismatch[speed] = stride.ok != exact_ok
    compression = exact.compression[index]
    return DomainErrors(exact.grid, corrections, index, points[index, 2], compression, errors, mismatch)


@dataclass(frozen=True)
class DomainTable:
    """One error of a DomainErrors in bins of compression (rows: [edges[i], edges[i + 1])) by touchdown angle
    (columns: the grid's angles [rad]): the strides compared (both succeed), their median and largest error
    (NaN in empty cells), and the strides where exactly one of the map and the exact plant fails."""

    edges: tuple[float, ...]
    angles: tuple[float, ...]
    count: Array
    median: Array
    worst: Array
    mismatches: Array


def domain_table(
    domain: DomainErrors, speed: SpeedSource, quantity: Quantity, edges: tuple[float, ...] = COMPRESSION_EDGES
) -> DomainTable:
    """The DomainTable of one map's (``speed``) error in ``quantity``, in the bins of ``edges``."""
    error = domain.errors[speed, quantity]
    shape = (len(edges) - 1, len(domain.grid.angles))
    count, mismatches = np.zeros(shape, dtype=int), np.zeros(shape, dtype=int)
    median, worst = np.full(shape, np.nan), np.full(shape, np.nan)
    for row, (low, high) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        for column, angle in enumerate(domain.grid.angles):
            here = (domain.angle == angle) & (domain.compression >= low) & (domain.compression < high)
            cell = error[here & ~np.isnan(error)]
            count[row, column] = cell.size
            mismatches[row, column] = np.count_nonzero(here & domain.mismatch[speed])
            if cell.size:
                median[row, column], worst[row, column] = np.median(cell), cell.max()
    return DomainTable(edges, domain.grid.angles, count, median, worst, mismatches)


@dataclass(frozen=True)
class Boundary:
    """Where an error leaves ``level`` at one touchdown angle [rad], over the strides of the grid compared
    there (the map and the exact plant both succeed; :func:`first_mismatches` tells where not), ordered by
    compression: ``below``, the largest compression up to which every stride errs less than the level (None:
    not even the least compressed one does), and ``leaves``, the least compression at which a stride errs at
    or above it (None: no stride of the grid does; the boundary lies beyond ``below``, the grid's largest)."""

    angle: float
    level: float
    below: float | None
    leaves: float | None


def boundaries(domain: DomainErrors, speed: SpeedSource, quantity: Quantity, level: float) -> list[Boundary]:
    """The Boundary of one error at ``level`` for every touchdown angle of the grid."""
    error = domain.errors[speed, quantity]
    found = []
    for angle in domain.grid.angles:
        here = (domain.angle == angle) & ~np.isnan(error)
        compression, above = domain.compression[here], error[here] >= level
        leaves = float(compression[above].min()) if above.any() else None
        passing = compression if leaves is None else compression[compression < leaves]
        below = float(passing.max()) if passing.size else None
        found.append(Boundary(angle, level, below, leaves))
    return found


def first_mismatches(domain: DomainErrors, speed: SpeedSource) -> list[float | None]:
    """For every touchdown angle of the grid, the least compression at which exactly one of the map (with
    ``speed``) and the exact plant fails (None: nowhere in the grid)."""
    found = []
    for angle in domain.grid.angles:
        wrong = domain.compression[(domain.angle == angle) & domain.mismatch[speed]]
        found.append(float(wrong.min()) if wrong.size else None)
    return found
