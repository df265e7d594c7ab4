"""Fixed points of the analytic map and their stability: open loop (section III), energy regulation (IV).

Truth used: a fixed point maps to itself under the map; eigenvalues of central finite differences of the
map (independent of the complex-step Jacobian the module uses); at a saddle-node an eigenvalue is 1; the
paper's stable energy ranges (kbar = 36, zeta0 = 0.08) and its qualitative claims.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.stability import analytic_fixed_points

PARAMS = PAPER_PARAMS
BETA = math.radians(26.0)
MG = PARAMS.m * PARAMS.g


def _open_loop_jacobian_by_differences(alpha: float, y: float, energy: float) -> np.ndarray:
    """Central differences of the (y, E) map, steps 1e-6 r0 and 1e-6 m g r0."""
    steps = np.array([1e-6 * PARAMS.r0, 1e-6 * MG * PARAMS.r0])
    columns = []
    for axis, step in enumerate(steps):
        shift = np.zeros(2)
        shift[axis] = step
        plus = analytic_fixed_points.open_loop_energy_map(
            PARAMS, BETA, alpha, y + shift[0], energy + shift[1]
        )
        minus = analytic_fixed_points.open_loop_energy_map(
            PARAMS, BETA, alpha, y - shift[0], energy - shift[1]
        )
        columns.append((np.array(plus) - np.array(minus)) / (2.0 * step))
    return np.stack(columns, axis=-1)


@pytest.fixture(scope="module")
def open_loop_trace() -> analytic_fixed_points.FixedPoints:
    return analytic_fixed_points.open_loop_fixed_points(PARAMS, BETA, [1.0, 1.25, 1.6])


def test_open_loop_fixed_points_map_to_themselves_with_the_eigenvalues_of_the_map(
    open_loop_trace: analytic_fixed_points.FixedPoints,
) -> None:
    found = np.isfinite(open_loop_trace.y)
    assert found.sum() == 5  # one, three, one
    for row, column in zip(*np.nonzero(found), strict=True):
        alpha = float(open_loop_trace.parameter[row])
        y, energy = float(open_loop_trace.y[row, column]), float(open_loop_trace.energy[row, column])
        y_next, energy_next = analytic_fixed_points.open_loop_energy_map(PARAMS, BETA, alpha, y, energy)
        assert float(y_next) == pytest.approx(y, rel=1e-10)
        assert float(energy_next) == pytest.approx(energy, rel=1e-10)
        expected = np.linalg.eigvals(_open_loop_jacobian_by_differences(alpha, y, energy))
        expected = expected[np.argsort(-np.abs(expected))]
        np.testing.assert_allclose(open_loop_trace.eigenvalues[row, column], expected, rtol=1e-5, atol=1e-6)


def test_energy_fixed_point_is_the_single_crossing_of_a_unimodal_energy_map() -> None:
    heights = np.array([1.0, 1.4, 1.8])
    fixed = analytic_fixed_points.energy_fixed_point(PARAMS, BETA, 1.5, heights)
    _, energy_next = analytic_fixed_points.open_loop_energy_map(PARAMS, BETA, 1.5, heights, fixed)
    np.testing.assert_allclose(energy_next, fixed, rtol=1e-11)
    # On a fine grid E' - E changes sign exactly once, from + to -, at E* (eq. 27's unique solution).
    energies = (heights[:, None] + np.linspace(0.005, 10.0, 2000)) * MG * PARAMS.r0
    _, mapped = analytic_fixed_points.open_loop_energy_map(PARAMS, BETA, 1.5, heights[:, None], energies)
    gain = mapped - energies
    for row, energy in enumerate(fixed):
        valid = np.isfinite(gain[row])
        signs = np.sign(gain[row, valid])
        changes = np.flatnonzero(np.diff(signs) != 0)
        assert changes.size == 1 and signs[0] > 0
        assert energies[row, valid][changes[0]] <= energy <= energies[row, valid][changes[0] + 1]


def test_open_loop_has_a_high_robust_family_and_a_realistic_marginal_one(
    open_loop_trace: analytic_fixed_points.FixedPoints,
) -> None:
    """Paper, section III.B at beta = 26 deg: (i) ~2 r0 high, |lambda| well below 1; (ii) realistic, |lambda|
    close to 1; three fixed points in between, the middle one unstable."""
    high_y, high_radius = open_loop_trace.y[0, 0], open_loop_trace.spectral_radius[0, 0]
    assert 1.7 * PARAMS.r0 < high_y < 2.0 * PARAMS.r0 and high_radius < 0.8
    low_y, low_radius = open_loop_trace.y[2, 0], open_loop_trace.spectral_radius[2, 0]
    assert low_y < 1.0 * PARAMS.r0 and 0.95 < low_radius < 1.0
    assert list(open_loop_trace.count) == [1, 3, 1]
    assert list(open_loop_trace.stable[1]) == [True, False, True]


def test_saddle_nodes_bound_the_three_fixed_point_region_where_an_eigenvalue_reaches_one() -> None:
    heights = analytic_fixed_points.height_grid(PARAMS, BETA, top=1.9, points=40)
    trace = analytic_fixed_points.open_loop_fixed_points(PARAMS, BETA, [1.1, 1.25, 1.45], heights)
    assert list(trace.count) == [1, 3, 1]
    low, high = analytic_fixed_points.saddle_nodes(PARAMS, BETA, trace, heights)
    assert 1.1 < low < 1.25 < high < 1.45
    # Approaching a fold, the eigenvalue of each of the two merging fixed points tends to 1 like the square
    # root of the distance in alpha: at a quarter of the distance, half the deviation.
    deviation = []
    for distance in (0.008, 0.002):
        inside = analytic_fixed_points.open_loop_fixed_points(
            PARAMS, BETA, [low + distance, high - distance], heights
        )
        assert list(inside.count) == [3, 3]
        merging = np.stack([inside.eigenvalues[0, [0, 1], 0], inside.eigenvalues[1, [1, 2], 0]])
        deviation.append(np.abs(np.real(merging) - 1.0))
    assert np.all(deviation[1] < 0.07)
    np.testing.assert_allclose(deviation[0] / deviation[1], 2.0, rtol=0.3)


def test_regulated_map_conserves_energy_and_its_fixed_points_have_the_map_s_slope() -> None:
    energies = np.array([2.0, 3.0, 4.0]) * MG * PARAMS.r0
    points = analytic_fixed_points.regulated_fixed_points(PARAMS, BETA, energies)
    assert np.all(points.count >= 1)
    y = points.y[:, 0]
    np.testing.assert_allclose(
        analytic_fixed_points.regulated_height_map(PARAMS, BETA, energies, y), y, rtol=1e-10
    )
    np.testing.assert_allclose(points.energy[:, 0], energies, rtol=0)
    step = 1e-6 * PARAMS.r0
    slope = (
        analytic_fixed_points.regulated_height_map(PARAMS, BETA, energies, y + step)
        - analytic_fixed_points.regulated_height_map(PARAMS, BETA, energies, y - step)
    ) / (2.0 * step)
    np.testing.assert_allclose(np.real(points.eigenvalues[:, 0, 0]), slope, rtol=1e-5, atol=1e-7)


def test_heights_below_leg_placement_are_infeasible() -> None:
    bottom = analytic_fixed_points.infeasible_height(PARAMS, BETA)
    assert bottom == pytest.approx(PARAMS.r0 * math.cos(BETA))
    mapped = analytic_fixed_points.regulated_height_map(
        PARAMS, BETA, 3.0 * MG, [bottom * 0.999, bottom * 1.001]
    )
    assert np.isnan(mapped[0]) and np.isfinite(mapped[1])


@pytest.mark.parametrize(
    ("beta_deg", "low", "high"),
    [
        # Paper: [1.1, 3.4]. Ours: about [0.97, 3.32]; both ends are where the fixed point's eigenvalue
        # crosses -1 (a flip), sensitive to the approximation's details.
        (20.0, (0.9, 1.05), (3.2, 3.45)),
        # Paper: [3.45, 11.9]. Ours: about [1.91, 12.69]: the upper end is the flip at -1; the lower end is
        # where the stable fixed point reaches y_max(E), the highest apex from which the leg placed at beta
        # still swings forward. With the backward torque root (before issue 10) the map failed there and the
        # range began at 2.88; docs/paper.md compares the exact plant's ranges.
        (30.0, (1.85, 2.0), (12.4, 13.0)),
    ],
)
def test_energy_regulation_has_stable_fixed_points_over_the_paper_s_energy_ranges(
    beta_deg: float, low: tuple[float, float], high: tuple[float, float]
) -> None:
    energies = units.energy_from_bar(PARAMS, np.linspace(0.8, 14.0, 34))
    start, end = analytic_fixed_points.stable_energy_range(
        PARAMS, math.radians(beta_deg), energies, bisections=6
    )
    start_bar, end_bar = units.energy_to_bar(PARAMS, start), units.energy_to_bar(PARAMS, end)
    assert low[0] < start_bar < low[1]
    assert high[0] < end_bar < high[1]
