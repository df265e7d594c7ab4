"""Complex-step Jacobian of the approximate map (and of the closed loops) against central differences."""

from __future__ import annotations

import numpy as np
import pytest

from tdslip_ros.model.analytic.apex_map import LiftoffMethod
from tdslip_ros.model.analytic.closed_loop import (
    Coordinates,
    Policy,
    closed_loop_map,
    eigenvalues,
    fixed_command,
    map_jacobian,
)
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import StanceCommand
from tdslip_ros.model.policies.controllers import energy_regulation, fixed_power

PARAMS = PAPER_PARAMS
Y = np.array([1.02, 1.1, 1.25])
XDOT = np.array([3.5, 4.5, 5.5])
ENERGY = PARAMS.m * (PARAMS.g * Y + 0.5 * XDOT**2)
BETA = np.radians(26.0)

POLICIES: dict[str, Policy] = {
    "fixed command": fixed_command(StanceCommand(BETA, -600.0, 0.14)),
    "energy regulation": lambda p, y, xdot: energy_regulation(p, y, xdot, BETA),
    "fixed power": lambda p, y, xdot: fixed_power(PARAMS, y, xdot, BETA, 1.5),
}


def _central_differences(
    policy: Policy, second: np.ndarray, coordinates: Coordinates, corrections: int, liftoff: LiftoffMethod
) -> np.ndarray:
    def image(y: np.ndarray, s: np.ndarray) -> np.ndarray:
        stride = closed_loop_map(PARAMS, y, s, policy, coordinates, corrections, liftoff)
        return np.stack([stride.y, stride.xdot if coordinates == "speed" else stride.energy], axis=-1)

    columns = []
    for dy, ds in ((1e-5 * Y, 0.0 * second), (0.0 * Y, 1e-5 * second)):
        step = dy + ds
        columns.append((image(Y + dy, second + ds) - image(Y - dy, second - ds)) / (2.0 * step)[:, None])
    return np.stack(columns, axis=-1)


@pytest.mark.parametrize("policy_name", list(POLICIES))
@pytest.mark.parametrize("coordinates", ["speed", "energy"])
@pytest.mark.parametrize(("corrections", "liftoff"), [(1, "paper"), (0, "paper"), (2, "force_root")])
def test_complex_step_jacobian_matches_central_differences(
    policy_name: str, coordinates: Coordinates, corrections: int, liftoff: LiftoffMethod
) -> None:
    policy = POLICIES[policy_name]
    second = XDOT if coordinates == "speed" else ENERGY
    jacobian = map_jacobian(PARAMS, Y, second, policy, coordinates, corrections, liftoff)
    reference = _central_differences(policy, second, coordinates, corrections, liftoff)
    assert jacobian.shape == (3, 2, 2)
    scale = np.max(np.abs(reference), axis=(-2, -1), keepdims=True)
    error = np.abs(jacobian - reference)
    assert np.all(error <= 1e-6 * (np.abs(reference) + scale)), (jacobian, reference)


def test_energy_regulation_closes_the_energy_row() -> None:
    # E_next = E exactly under eq. 32, so the energy row of the (y, E) Jacobian is (0, 1).
    policy = POLICIES["energy regulation"]
    jacobian = map_jacobian(PARAMS, Y, ENERGY, policy, "energy")
    np.testing.assert_allclose(jacobian[:, 1, 0], 0.0, atol=1e-8)
    np.testing.assert_allclose(jacobian[:, 1, 1], 1.0, rtol=1e-10)


def test_jacobian_is_nan_on_failed_lanes() -> None:
    jacobian = map_jacobian(PARAMS, np.array([0.5, 1.1]), np.array([4.0, 4.0]), POLICIES["fixed command"])
    assert np.all(np.isnan(jacobian[0])) and np.all(np.isfinite(jacobian[1]))


def test_eigenvalues_are_sorted_by_modulus() -> None:
    rng = np.random.default_rng(3)
    matrices = rng.normal(size=(20, 2, 2))
    values = eigenvalues(matrices)
    assert np.all(np.abs(values[:, 0]) >= np.abs(values[:, 1]))
    for matrix, pair in zip(matrices, values, strict=True):
        # Each is a root of the characteristic polynomial, and together they give trace and determinant.
        assert np.sum(pair) == pytest.approx(np.trace(matrix), abs=1e-12)
        assert np.prod(pair) == pytest.approx(np.linalg.det(matrix), abs=1e-12)
