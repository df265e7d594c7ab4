"""The closed loop of the approximate map: a stance policy chooses each stride's command from its apex, and
the loop's Jacobian by complex step, with its eigenvalues (the stability analyses of
:mod:`tdslip_ros.model.stability.analytic_fixed_points`).

The Jacobian runs the map and the policy in complex arithmetic (the complex step: no subtraction, so exact
to rounding); the policies of :mod:`tdslip_ros.model.policies.controllers` that plan on the map's torque are
complex-step safe.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np

from tdslip_ros.model.analytic.apex_map import LiftoffMethod, SpeedSource, Stride, approximate_map
from tdslip_ros.model.arrays import Array, ArrayLike, CommandArrays, ParamArrays, command_arrays
from tdslip_ros.model.dynamics import speed_from_energy
from tdslip_ros.model.params import HopperParams, StanceCommand

Coordinates = Literal["speed", "energy"]
COMPLEX_STEP = 1e-30
"""Imaginary step of the complex-step Jacobian (any tiny value works: there is no subtraction)."""


Policy = Callable[[ParamArrays, Array, Array], CommandArrays]
"""A stance policy: (params, y, xdot) -> command arrays. Must be complex-step safe to be differentiated."""


def fixed_command(command: CommandArrays | StanceCommand) -> Policy:
    """The policy that always returns ``command``."""
    fields = command_arrays(command)
    return lambda params, y, xdot: fields


def closed_loop_map(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    second: ArrayLike,
    policy: Policy,
    coordinates: Coordinates = "speed",
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> Stride:
    """One stride with the command chosen by ``policy`` from the apex; ``second`` is xdot or E."""
    params = ParamArrays.of(params)
    y = np.asarray(y)
    xdot = np.asarray(second) if coordinates == "speed" else speed_from_energy(params, y, second)
    return approximate_map(params, y, xdot, policy(params, y, xdot), corrections, liftoff, speed=speed)


def map_jacobian(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    second: ArrayLike,
    policy: Policy,
    coordinates: Coordinates = "speed",
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> Array:
    """Jacobian d(y', s')/d(y, s) of the closed-loop map by complex step, shape (..., 2, 2).

    ``s`` is xdot (``coordinates="speed"``) or E (``"energy"``). NaN on failed lanes.
    """
    y = np.asarray(y, dtype=float)
    second = np.asarray(second, dtype=float)
    y, second = np.broadcast_arrays(y, second)
    columns = []
    for direction in ((1.0, 0.0), (0.0, 1.0)):
        stride = closed_loop_map(
            params,
            y + 1j * COMPLEX_STEP * direction[0],
            second + 1j * COMPLEX_STEP * direction[1],
            policy,
            coordinates,
            corrections,
            liftoff,
            speed=speed,
        )
        out_second = stride.xdot if coordinates == "speed" else stride.energy
        column = np.stack([np.imag(stride.y), np.imag(out_second)], axis=-1) / COMPLEX_STEP
        columns.append(np.where(stride.ok[..., None], column, np.nan))
    return np.stack(columns, axis=-1)


def eigenvalues(jacobian: ArrayLike) -> Array:
    """Eigenvalues of (..., 2, 2) Jacobians, shape (..., 2), sorted by decreasing modulus."""
    values = np.linalg.eigvals(np.asarray(jacobian))
    order = np.argsort(-np.abs(values), axis=-1)
    return np.take_along_axis(values, order, axis=-1)
