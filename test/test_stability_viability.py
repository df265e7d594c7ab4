"""Viability kernels on the batched engine (model/stability/viability.py, viability_spaces.py).

Truth used: the scipy exact map stride by stride (exact_map.apex_return_map), cell for cell; the definition
of a viable set (every viable pair's successor judged viable, every other non-failing pair's not), judged
here again with numpy.digitize and argmin, independently of successor_cells; the basin of fig. 10's
energy regulator at beta = 26 deg (basins.regulated_basin, the closed loop run for its strides); and the
kernel's boundary on a grid refined twofold per axis. About 15 s in all (numba's cache warm).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from tdslip_ros.model.events import NO_FAILURE_CODE, failure_code
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.perturbations import StrideConditions
from tdslip_ros.model.plant.terrain import Step
from tdslip_ros.model.stability import basins
from tdslip_ros.model.stability.viability import (
    ANGLE_REFUSED_CODE,
    QMap,
    successor_cells,
    viable_set,
)
from tdslip_ros.model.stability.viability_spaces import ApexSpace, EnergySpace, q_map

SLIP = HopperParams(m=80.0, k=8200.0, r0=1.0, c=0.0, g=9.81)  # vibly's SLIP demo
SLIP_ENERGY = SLIP.m * (SLIP.g * 0.85 + 0.5 * 5.5**2)
DAMPED = ApexSpace(
    PAPER_PARAMS,
    np.linspace(0.85, 1.6, 8),
    np.linspace(0.5, 6.0, 8),
    np.radians(np.linspace(12.0, 36.0, 7)),
    np.linspace(-900.0, -100.0, 5),
    0.2,
)


@pytest.fixture(scope="module")
def damped() -> QMap:
    return q_map(DAMPED)


def test_the_batched_q_map_equals_the_exact_map_stride_by_stride_cell_for_cell() -> None:
    # Angles 0 and 90 deg are refused by the map: failing actions of their own kind here. 0.8 m is below the
    # touchdown height at 40 deg (toe stubbing); 0.5 m/s at 40 deg reverses.
    space = ApexSpace(
        PAPER_PARAMS,
        np.array([0.8, 1.1, 1.5]),
        np.array([0.5, 3.0, 6.0]),
        np.radians([0.0, 10.0, 25.0, 40.0, 90.0]),
        np.array([-400.0, 0.0]),
        0.2,
    )
    qmap = q_map(space)
    kinds = set()
    for index in np.ndindex(qmap.failure.shape):
        y, xdot = space.heights[index[0]], space.speeds[index[1]]
        angle, tau0 = space.angles[index[2]], space.torques[index[3]]
        if not 0.0 < angle < math.pi / 2:
            assert qmap.failure[index] == ANGLE_REFUSED_CODE
            assert np.all(np.isnan(qmap.successor[index]))
            continue
        stride = apex_return_map(PAPER_PARAMS, ApexState(y, xdot), StanceCommand(angle, tau0, 0.2))
        assert qmap.failure[index] == failure_code(stride.failure), index
        kinds.add(stride.failure)
        if stride.apex is None:
            assert np.all(np.isnan(qmap.successor[index]))
        else:
            np.testing.assert_allclose(qmap.successor[index], (stride.apex.y, stride.apex.xdot), rtol=1e-10)
    assert len(kinds) >= 3  # apexes and at least two failure kinds were compared


def judged_viable(
    states: tuple[np.ndarray, ...], kernel: np.ndarray, point: np.ndarray, judge: str, outside: str
) -> bool:
    """The verdict on one successor, from the definitions (module docstring of viability.py)."""
    choices = []
    for axis, value in zip(states, point, strict=True):
        if judge == "conservative":
            upper = int(np.digitize(value, axis))  # axis[upper - 1] <= value < axis[upper]
            beyond, picks = upper in (0, axis.size), {upper - 1, upper}
        else:
            beyond, picks = not axis[0] <= value <= axis[-1], {int(np.argmin(np.abs(axis - value)))}
        if beyond:
            if outside == "failure":
                return False
            picks = {0} if value < axis[0] else {axis.size - 1}
        choices.append(sorted(picks))
    return all(kernel[cell] for cell in itertools.product(*choices))


@pytest.mark.parametrize("judge", ["conservative", "nearest"])
@pytest.mark.parametrize("outside", ["failure", "edge"])
def test_the_viable_set_is_invariant_and_the_largest(damped: QMap, judge: str, outside: str) -> None:
    result = viable_set(damped, judge, outside)
    assert result.iterations > 1  # pairs left the set on the way: the fixed point did work
    assert 0 < result.kernel.sum() < result.kernel.size
    alive = damped.failure == NO_FAILURE_CODE
    for index in zip(*np.nonzero(alive), strict=True):
        verdict = judged_viable(damped.states, result.kernel, damped.successor[index], judge, outside)
        assert result.viable[index] == verdict, index
    assert not np.any(result.viable & ~alive)
    np.testing.assert_array_equal(result.kernel, result.viable.any(axis=(2, 3)))
    np.testing.assert_array_equal(result.measure, result.viable.mean(axis=(2, 3)))


def test_successors_between_on_and_beyond_grid_points_are_judged_as_documented() -> None:
    states = (np.array([0.0, 1.0, 2.0]),)
    successors = np.array([[0.5], [1.0], [1.9], [2.0], [-0.1], [2.5]])
    conservative = successor_cells(states, successors, "conservative", "failure")
    assert [sorted(set(row)) for row in conservative.tolist()] == [[0, 1], [1, 2], [1, 2], [-1], [-1], [-1]]
    edge = successor_cells(states, successors, "conservative", "edge")
    assert [sorted(set(row)) for row in edge.tolist()] == [[0, 1], [1, 2], [1, 2], [2], [0], [2]]
    nearest = successor_cells(states, successors, "nearest", "failure")
    assert nearest[:, 0].tolist() == [0, 1, 2, 2, -1, -1]


def test_every_state_of_fig10_s_basin_is_in_the_regulated_kernel() -> None:
    # Fig. 10's policy: energy regulation at beta = 26 deg, each trajectory's goal its initial energy. On one
    # energy level, the states it keeps running must be viable for the space whose actions include 26 deg.
    energy = 3.0 * PAPER_PARAMS.m * PAPER_PARAMS.g * PAPER_PARAMS.r0
    space = EnergySpace(
        PAPER_PARAMS,
        energy,
        np.linspace(0.3, 0.95, 27),
        np.radians(np.linspace(18.0, 34.0, 9)),
        regulated=True,
    )
    assert np.any(np.isclose(space.angles, math.radians(26.0)))
    result = viable_set(q_map(space))  # the strict default: conservative, nothing beyond the grid
    basin = basins.regulated_basin(PAPER_PARAMS, math.radians(26.0), space.height(space.fractions), energy)
    running = np.isin(basin.outcome, (basins.CONVERGED, basins.SUSTAINED))
    assert 3 <= running.sum() < running.size
    assert np.all(result.kernel[running]), space.fractions[running & ~result.kernel]


def slip_viability(fractions: int, angles: int) -> tuple[EnergySpace, np.ndarray]:
    space = EnergySpace(
        SLIP, SLIP_ENERGY, np.linspace(0.1, 0.995, fractions), np.radians(np.linspace(-10.0, 70.0, angles))
    )
    return space, viable_set(q_map(space)).viable


def test_refining_the_grid_moves_the_kernel_s_boundary_by_less_than_one_coarse_cell() -> None:
    # Each axis doubled: 2 n - 1 points, the coarse grid's points among them. The boundary of the kernel (its
    # lowest and highest state) and of the viable set (per coarse state, its lowest and highest viable angle).
    coarse, coarse_viable = slip_viability(46, 41)
    fine, fine_viable = slip_viability(91, 81)
    state_cell, angle_cell = np.diff(coarse.fractions[:2])[0], np.diff(coarse.angles[:2])[0]
    for bound in (0, -1):
        assert (
            abs(fine.fractions[fine_viable.any(1)][bound] - coarse.fractions[coarse_viable.any(1)][bound])
            < state_cell
        )
    shared = fine_viable[::2]
    both = shared.any(1) & coarse_viable.any(1)
    assert both.sum() > 30
    for coarse_row, fine_row in zip(coarse_viable[both], shared[both], strict=True):
        for bound in (0, -1):
            assert abs(fine.angles[fine_row][bound] - coarse.angles[coarse_row][bound]) < angle_cell


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (
            lambda: EnergySpace(SLIP, SLIP_ENERGY, np.array([]), np.array([0.3])),
            "the grid of height fractions is empty",
        ),
        (
            lambda: EnergySpace(SLIP, SLIP_ENERGY, np.array([0.5, 0.4]), np.array([0.3])),
            "must be strictly increasing",
        ),
        (
            lambda: EnergySpace(PAPER_PARAMS, 2000.0, np.array([0.5]), np.array([0.3])),
            "a damped leg with an idle hip",
        ),
        (
            lambda: EnergySpace(
                SLIP, SLIP_ENERGY, np.array([0.5]), np.array([0.3]), conditions=StrideConditions(push=0.1)
            ),
            "a push changes the energy",
        ),
        (
            lambda: ApexSpace(
                SLIP,
                np.array([1.0]),
                np.array([3.0]),
                np.array([0.3]),
                np.array([0.0]),
                0.2,
                StrideConditions(terrain=Step(-0.05, 1.0)),
            ),
            "terrain cannot be taken",
        ),
    ],
)
def test_spaces_refuse_what_they_cannot_hold_in_one_line(make, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        make()
