"""Accuracy of the approximate return map against the exact plant on a grid of strides.

One stride per grid point (apex height, apex speed, touchdown angle, dimensionless ramp torque); the ramp
lasts until the liftoff the analytic map predicts (:func:`controllers.ramp_to_liftoff`, as the paper's
policies do). The exact plant (:func:`exact_map.apex_return_map`) is the truth.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from tdslip_ros.model import units
from tdslip_ros.model.analytic import LiftoffMethod, approximate_map
from tdslip_ros.model.arrays import Array, CommandArrays
from tdslip_ros.model.controllers import ramp_to_liftoff
from tdslip_ros.model.events import failure_code
from tdslip_ros.model.exact_map import apex_return_map
from tdslip_ros.model.params import ApexState, HopperParams


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


@dataclass(frozen=True)
class ExactStrides:
    """The exact plant's next apex on every grid point (NaN where it fails) under ``commands``."""

    grid: StrideGrid
    commands: CommandArrays
    y: Array
    xdot: Array
    failure: Array


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
    next_y, next_xdot, failure = (np.full(len(points), np.nan) for _ in range(3))
    for i in range(len(points)):
        if not np.isfinite(commands.t_f[i]):
            continue
        result = apex_return_map(params, ApexState(y[i], xdot[i]), commands.command(i))
        failure[i] = failure_code(result.failure)
        if result.apex is not None:
            next_y[i], next_xdot[i] = result.apex.y, result.apex.xdot
    return ExactStrides(grid, commands, next_y, next_xdot, failure)


def accuracy(
    params: HopperParams, exact: ExactStrides, corrections: int, liftoff: LiftoffMethod = "paper"
) -> Accuracy:
    """The analytic map with ``corrections`` and ``liftoff`` against ``exact``, under the same commands."""
    points = np.array(exact.grid.points())
    valid = np.isfinite(exact.commands.t_f)
    commands = CommandArrays(*(field[valid] for field in exact.commands))
    stride = approximate_map(params, points[valid, 0], points[valid, 1], commands, corrections, liftoff)
    exact_y, exact_xdot = exact.y[valid], exact.xdot[valid]
    both = stride.ok & np.isfinite(exact_y)
    height = np.abs(stride.y[both] / exact_y[both] - 1.0)
    speed = np.abs(stride.xdot[both] / exact_xdot[both] - 1.0)
    liftoff_speed = np.abs(stride.liftoff_xdot[both] / exact_xdot[both] - 1.0)
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
