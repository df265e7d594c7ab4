"""Viability on a grid: the viable set of a Q-map, its kernel and its measure (Heim and Sproewitz, "Beyond
basins of attraction: quantifying robustness of natural dynamics", IEEE T-RO 2019; their code: sheim/vibly).

A Q-map (:class:`QMap`, computed by :mod:`.viability_spaces`) holds, for every pair of a state grid and an
action grid, the next state the plant reaches from the state under the action, or the failure it meets.
:func:`viable_set` finds the largest set of pairs whose successors land in states that have a viable pair
themselves: the standard fixed-point iteration, which starts from the pairs that do not fail and removes,
until nothing changes, every pair whose successor is judged not viable. The kernel is the set of states
with a viable pair; the measure of a state is the fraction of its actions that are viable.

How a successor between grid points is judged (``judge``):

* ``"conservative"`` (default): viable only if every grid state of the cell it lies in is viable, the cell
  being, per axis, the two grid points around it. A successor exactly on grid point j is taken to lie in
  the cell [j, j + 1], as ``numpy.digitize`` bins it. This is vibly's ``bin`` mode.
* ``"nearest"``: viable if its nearest grid state is viable.

How a successor beyond the grid is judged (``outside``):

* ``"failure"`` (default): never viable; the kernel claims nothing the grid does not show.
* ``"edge"``: as if it were on the grid's edge (clamped per axis): the grid is taken to extend the edge's
  verdict. vibly does this above its grids' last point (its successors below the first point never
  count as viable; on the SLIP demo grid that lowest cell fails for every action, so the two agree there).

The successors are judged once (:func:`successor_cells`), so that each iteration is a gather over arrays.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.events import FAILURE_KINDS, NO_FAILURE_CODE
from tdslip_ros.model.params import ParameterError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
Judge = Literal["conservative", "nearest"]
Outside = Literal["failure", "edge"]
JUDGES: tuple[Judge, ...] = ("conservative", "nearest")
OUTSIDE: tuple[Outside, ...] = ("failure", "edge")

ANGLE_REFUSED = "touchdown_angle_refused"
"""The failure of an action whose touchdown angle the plant does not take (at or below 0, at 90 degrees or
beyond): the leg would touch down behind or beside the body (vibly's demo grid holds such angles)."""
NO_COMMAND = "no_command"
"""The failure of a pair whose policy found no command (its planner had no solution)."""
QMAP_FAILURES: tuple[str, ...] = (*(kind.value for kind in FAILURE_KINDS), ANGLE_REFUSED, NO_COMMAND)
"""The failure kinds of a Q-map, indexed by its failure codes (NO_FAILURE_CODE for none): the plant's
(:data:`tdslip_ros.model.events.FAILURE_KINDS`, same codes), then the two above."""
ANGLE_REFUSED_CODE = QMAP_FAILURES.index(ANGLE_REFUSED)
NO_COMMAND_CODE = QMAP_FAILURES.index(NO_COMMAND)
_OUTSIDE_CELL = -1
"""Cell index of a successor judged beyond the grid under outside="failure"."""


def check_grid(name: str, values: npt.ArrayLike) -> FloatArray:
    """A grid axis as a 1-D float array; ParameterError (one line) if empty, not finite or not strictly
    increasing."""
    axis = np.asarray(values, dtype=np.float64)
    if axis.ndim != 1 or axis.size == 0:
        raise ParameterError(f"the grid of {name} is empty")
    if not np.all(np.isfinite(axis)):
        raise ParameterError(f"the grid of {name} holds a value that is not finite")
    if axis.size > 1 and not np.all(np.diff(axis) > 0.0):
        raise ParameterError(
            f"the grid of {name} must be strictly increasing, got {axis[0]!r} ... {axis[-1]!r}"
        )
    return axis


@dataclass(frozen=True)
class QMap:
    """The transitions of a state grid x action grid.

    states, actions: the grids' axes (1-D, strictly increasing), in SI (their names: state_names,
    action_names); successor: (*state shape, *action shape, len(states)) the next state, NaN where the pair
    failed; failure: (*state shape, *action shape) the code of its failure in :data:`QMAP_FAILURES`, or
    NO_FAILURE_CODE.
    """

    states: tuple[FloatArray, ...]
    actions: tuple[FloatArray, ...]
    state_names: tuple[str, ...]
    action_names: tuple[str, ...]
    successor: FloatArray
    failure: IntArray

    @property
    def state_shape(self) -> tuple[int, ...]:
        return tuple(axis.size for axis in self.states)

    @property
    def failure_counts(self) -> dict[str, int]:
        """Pairs per failure kind (kinds that occur)."""
        codes, counts = np.unique(self.failure[self.failure != NO_FAILURE_CODE], return_counts=True)
        return {QMAP_FAILURES[code]: int(count) for code, count in zip(codes, counts, strict=True)}


@dataclass(frozen=True)
class ViabilityResult:
    """The viable set of a Q-map (like scipy's result objects: fields, no behaviour).

    viable: (*state shape, *action shape) the viable pairs; kernel: (*state shape) the states with a
    viable pair (the viability kernel on the grid); measure: (*state shape) the fraction of a state's
    actions that are viable (0 outside the kernel); iterations: the fixed-point iterations until nothing
    changed; judge, outside: how successors were judged (module docstring).
    """

    viable: BoolArray
    kernel: BoolArray
    measure: FloatArray
    iterations: int
    judge: Judge
    outside: Outside


def successor_cells(
    states: Sequence[FloatArray],
    successor: FloatArray,
    judge: Judge = "conservative",
    outside: Outside = "failure",
) -> IntArray:
    """(pairs, cells) the flat indices of the grid states each successor's verdict depends on (all must be
    viable), -1 for "beyond the grid" under outside="failure", for successors (pairs, len(states)) that
    are finite (a pair that failed needs no cells: the caller leaves it out)."""
    if judge not in JUDGES:
        raise ParameterError(f"judge must be one of {', '.join(JUDGES)}, got {judge!r}")
    if outside not in OUTSIDE:
        raise ParameterError(f"outside must be one of {', '.join(OUTSIDE)}, got {outside!r}")
    shape = tuple(axis.size for axis in states)
    per_axis: list[IntArray] = []  # (pairs, 2 or 1) the indices along each axis, -1 beyond the grid
    for dim, axis in enumerate(states):
        value = successor[:, dim]
        if judge == "conservative":
            upper = np.searchsorted(axis, value, side="right")  # numpy.digitize's bin: axis[upper-1] <= v
            candidates = np.stack((upper - 1, upper), axis=1)
            beyond = (upper == 0) | (upper == axis.size)
            # Inside the grid both neighbours count; beyond it the one edge point (or nothing, failure).
            clamped = np.clip(candidates, 0, axis.size - 1)
            if outside == "failure":
                clamped[beyond] = _OUTSIDE_CELL
        else:
            nearest = np.clip(np.searchsorted(axis, value), 1, max(axis.size - 1, 1))
            if axis.size > 1:
                nearest = np.where(value - axis[nearest - 1] <= axis[nearest] - value, nearest - 1, nearest)
            else:
                nearest = np.zeros_like(nearest)
            clamped = nearest[:, None]
            if outside == "failure":
                beyond = (value < axis[0]) | (value > axis[-1])
                clamped = np.where(beyond[:, None], _OUTSIDE_CELL, clamped)
        per_axis.append(clamped.astype(np.int64))
    combos = list(itertools.product(*(range(part.shape[1]) for part in per_axis)))
    cells = np.empty((successor.shape[0], len(combos)), dtype=np.int64)
    for column, combo in enumerate(combos):
        index = [part[:, choice] for part, choice in zip(per_axis, combo, strict=True)]
        outside_any = np.any(np.stack(index) == _OUTSIDE_CELL, axis=0)
        flat = np.ravel_multi_index(tuple(np.maximum(i, 0) for i in index), shape)
        cells[:, column] = np.where(outside_any, _OUTSIDE_CELL, flat)
    return cells


def viable_set(qmap: QMap, judge: Judge = "conservative", outside: Outside = "failure") -> ViabilityResult:
    """The largest set of the Q-map's pairs whose successors are judged viable (module docstring), its
    kernel and measure; iterations until no pair leaves the set (at most the number of pairs)."""
    state_size = int(np.prod(qmap.state_shape))
    action_size = qmap.failure.size // state_size
    alive = (qmap.failure == NO_FAILURE_CODE).reshape(state_size, action_size)
    successor = qmap.successor.reshape(state_size * action_size, len(qmap.states))
    pairs = np.flatnonzero(alive.ravel())
    cells = successor_cells(qmap.states, successor[pairs], judge, outside)
    viable = alive.ravel().copy()
    # A last slot, never viable, for the cells beyond the grid (index -1).
    kernel = np.zeros(state_size + 1, dtype=bool)
    iterations = 0
    while True:
        iterations += 1
        kernel[:state_size] = viable.reshape(state_size, action_size).any(axis=1)
        keep = kernel[cells].all(axis=1)
        dropped = viable[pairs] & ~keep
        if not dropped.any():
            break
        viable[pairs[dropped]] = False
    shape = qmap.failure.shape
    viable_pairs = viable.reshape(shape)
    measure = viable.reshape(state_size, action_size).mean(axis=1).reshape(qmap.state_shape)
    return ViabilityResult(
        viable=viable_pairs,
        kernel=kernel[:state_size].reshape(qmap.state_shape),
        measure=measure,
        iterations=iterations,
        judge=judge,
        outside=outside,
    )
