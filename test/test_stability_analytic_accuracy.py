"""Accuracy of the approximate map against the exact plant on the operating region of the paper's gaits.

Grid (analytic_accuracy.OPERATING_GRID, kbar = 36, zeta0 = 0.08, m = 80 kg, r0 = 1 m): apex heights
1.0-1.15 m, speeds 3.5-5.5 m/s, touchdown angles 20-28 deg, ramp torques taubar = -0.5 to -0.9 (the
torques energy regulation asks for), ramp to the predicted liftoff. Measured when written (relative errors
of the next apex, mean / max): corrections = 1: height 0.0057 / 0.0235, speed 0.0090 / 0.0772;
corrections = 0: height 0.0224 / 0.0528, speed 0.0297 / 0.0878; eq. 7's liftoff speed with one
correction: 0.0525 / 0.0954. The bounds below are those values with a margin of about 1.5, so that a
regression in any closed form or in the corrections fails, while the model error itself is accepted.
"""

from __future__ import annotations

import pytest

from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.stability.analytic_accuracy import OPERATING_GRID, ExactStrides, accuracy, exact_strides

PARAMS = PAPER_PARAMS

# corrections: (mean height, max height, mean speed, max speed) bounds on |analytic/exact - 1|.
BOUNDS = {1: (0.010, 0.035, 0.015, 0.11), 0: (0.035, 0.08, 0.045, 0.13)}


@pytest.fixture(scope="module")
def exact() -> ExactStrides:
    return exact_strides(PARAMS, OPERATING_GRID)


@pytest.mark.parametrize("corrections", [0, 1])
def test_next_apex_errors_stay_within_the_measured_bounds(exact: ExactStrides, corrections: int) -> None:
    row = accuracy(PARAMS, exact, corrections)
    assert row.lanes == len(OPERATING_GRID.points())  # every stride of the grid succeeds in both maps
    assert row.failure_mismatches == 0
    mean_height, max_height, mean_speed, max_speed = BOUNDS[corrections]
    assert row.mean_height_error < mean_height and row.max_height_error < max_height
    assert row.mean_speed_error < mean_speed and row.max_speed_error < max_speed


def test_corrections_and_the_energy_balance_improve_the_map(exact: ExactStrides) -> None:
    unforced, corrected = accuracy(PARAMS, exact, 0), accuracy(PARAMS, exact, 1)
    # The torque and gravity corrections of p_hat (eqs. 19-22) matter for torque-driven strides ...
    assert corrected.mean_height_error < 0.5 * unforced.mean_height_error
    assert corrected.mean_speed_error < 0.5 * unforced.mean_speed_error
    # ... and the next speed from the energy balance beats the liftoff speed of eq. 7.
    assert corrected.mean_speed_error < 0.5 * corrected.mean_liftoff_speed_error


def test_both_liftoff_approximations_give_the_same_accuracy(exact: ExactStrides) -> None:
    paper, root = accuracy(PARAMS, exact, 1, "paper"), accuracy(PARAMS, exact, 1, "force_root")
    assert paper.mean_height_error == pytest.approx(root.mean_height_error, rel=0.01)
    assert paper.mean_speed_error == pytest.approx(root.mean_speed_error, rel=0.01)
