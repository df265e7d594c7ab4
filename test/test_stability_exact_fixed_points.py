"""Fixed points of the exact plant's closed loop and their eigenvalues; the horizon as a cross-check.

Truth used: the scalar exact map (exact_map.apex_return_map, solve_ivp with event location, independent
of the batched engine the module uses) for the fixed points and their slopes; the stride horizon of
basins for the verdicts; the issue's independent exact-plant computation at beta = 32 deg (one fixed
point at every alpha in 2.443-2.491).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.policies.controllers import exact_energy_regulation
from tdslip_ros.model.stability import analytic_fixed_points, basins
from tdslip_ros.model.stability import exact_fixed_points as xs

PARAMS = PAPER_PARAMS
BETA = math.radians(26.0)


def _scalar_next_height(y: float, goal: float) -> float:
    """y' from the apex (y, goal) under energy_exact, on the scalar exact map."""
    apex = ApexState.from_height_energy(PARAMS, y, goal)
    result = apex_return_map(
        PARAMS, apex, exact_energy_regulation(PARAMS, apex.y, apex.xdot, BETA, goal).command()
    )
    assert result.apex is not None
    return result.apex.y


def test_energy_exact_fixed_points_map_to_themselves_with_the_slope_of_the_scalar_exact_map() -> None:
    goals = units.energy_from_bar(PARAMS, np.array([3.0, 5.0]))
    points = xs.fixed_points(xs.ExactLoop.of(PARAMS, BETA, "energy_exact", goals))
    assert list(points.count) == [1, 1]
    for row, goal in enumerate(goals):
        y = float(points.y[row, 0])
        assert float(points.energy[row, 0]) == pytest.approx(goal, rel=1e-10)
        assert _scalar_next_height(y, goal) == pytest.approx(y, rel=1e-9)
        step = 1e-5 * PARAMS.r0
        slope = (_scalar_next_height(y + step, goal) - _scalar_next_height(y - step, goal)) / (2 * step)
        # The energy is held, so the map is 1-D: eigenvalues dy'/dy and 0.
        dominant, other = points.eigenvalues[row, 0]
        assert np.real(dominant) == pytest.approx(slope, abs=1e-5)
        assert abs(other) < 1e-5


def test_fixed_point_verdicts_agree_with_the_horizon_wherever_it_converged() -> None:
    """Energy regulation (analytic planning) at 26 deg. Ebar 2.2: a fixed point just below y_max(E*),
    where the energy map's bracket reaches out of its domain (found by the edge search). Ebar 3: fast,
    converged in 50 strides, to the fixed point. Ebar 8: stable but slow (|lambda| ~ 0.89): only sustained
    after 50 strides (the old verdict's cut), converged within 300. Ebar 10: |lambda| > 1, the horizon
    never converges."""
    goals = units.energy_from_bar(PARAMS, np.array([2.2, 3.0, 8.0, 10.0]))
    points = xs.fixed_points(xs.ExactLoop.of(PARAMS, BETA, "energy", goals))
    stable = points.stable.any(axis=1)
    assert list(stable) == [True, True, True, False]
    assert 0.85 < points.spectral_radius[2, 0] < 1.0 < np.nanmin(points.spectral_radius[3])
    # Next to the fixed points (0.923 and 0.917 r0 at Ebar 8 and 10; 1.90 r0 at 2.2).
    start = PARAMS.r0 * np.array([1.8, 0.95, 0.95, 0.95])
    short = basins.regulated_basin(PARAMS, BETA, start, goals, strides=50)
    assert list(short.outcome == basins.CONVERGED) == [True, True, False, False]
    long = basins.regulated_basin(PARAMS, BETA, start[2:], goals[2:], strides=300)
    assert list(long.outcome == basins.CONVERGED) == [True, False]
    # Where the horizon converged it reached the fixed point (to its 1e-4 tolerance, over 1 - |lambda|).
    reached = np.concatenate([short.y[:2], long.y[:1]])
    for row in (0, 1, 2):
        assert abs(units.height_to_bar(PARAMS, reached[row] - points.y[row, 0])) < 1e-4 / (
            1.0 - points.spectral_radius[row, 0]
        )


@pytest.mark.parametrize(
    ("beta_deg", "inside", "outside"),
    [
        # energy_exact: stable over about [1.09, 3.34] at 20 deg and [3.24, 16.9] at 30 deg (docs/paper.md).
        (20.0, [1.15, 3.25], [1.0, 3.45]),
        (30.0, [3.35, 16.5], [3.1, 17.5]),
    ],
)
def test_the_ideal_regulator_s_stable_range_ends_where_the_docs_say(
    beta_deg: float, inside: list[float], outside: list[float]
) -> None:
    goals = units.energy_from_bar(PARAMS, np.array([*inside, *outside]))
    points = xs.fixed_points(xs.ExactLoop.of(PARAMS, math.radians(beta_deg), "energy_exact", goals))
    assert list(points.stable.any(axis=1)) == [True, True, False, False]


def test_beta_32_analytic_fixed_points_are_classified_on_the_exact_plant() -> None:
    """At beta = 32 deg, alpha = 2.47 the analytic map has three fixed points (1.13, 1.48, 1.94 r0); the
    exact plant (open loop, the paper's t_f) has one, near 1.05 r0, stable: the two upper ones are the
    approximation's artifact."""
    beta = math.radians(32.0)
    analytic = analytic_fixed_points.open_loop_fixed_points(PARAMS, beta, [2.47])
    exact = xs.fixed_points(xs.ExactLoop.of(PARAMS, beta, "open_loop", [2.47]))
    assert analytic.count[0] == 3 and exact.count[0] == 1
    assert units.height_to_bar(PARAMS, float(exact.y[0, 0])) == pytest.approx(1.05, abs=0.02)
    assert exact.stable[0, 0]
    assert list(xs.exists_on_exact_plant(analytic, exact)[0]) == [True, False, False]
