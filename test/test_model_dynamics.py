"""The shared equations of motion against kinematics and Newton's law, computed independently.

A stance trajectory is solved tightly with solve_ivp; along it, the body's Cartesian position is
differentiated numerically (no use of the model's velocity map), and m * acceleration is compared
with the ground reaction force plus gravity. Energy rates are checked the same way.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from tdslip_ros.model import dynamics
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import StanceCommand

PARAMS = PAPER_PARAMS
COMMAND = StanceCommand(touchdown_angle=math.radians(22.0), tau0=-600.0, t_f=0.12)


def _stance_solution() -> tuple[object, float]:
    """Dense solution of (r, theta, rdot, thetadot) from a running touchdown, and its end time."""

    def rhs(s: float, y: np.ndarray) -> list[float]:
        tau = dynamics.ramp_torque(COMMAND.tau0, COMMAND.t_f, s)
        rddot, thetaddot = dynamics.stance_accelerations(
            PARAMS, y[0], math.sin(y[1]), math.cos(y[1]), y[2], y[3], tau
        )
        return [y[2], y[3], rddot, thetaddot]

    y0 = [PARAMS.r0, COMMAND.touchdown_angle, -1.8, -4.0]
    sol = solve_ivp(rhs, (0.0, 0.11), y0, method="DOP853", rtol=1e-13, atol=1e-13, dense_output=True)
    return sol.sol, 0.11


def _body_position(state: np.ndarray, toe_x: float = 0.3) -> np.ndarray:
    r, theta = state[0], state[1]
    return np.array([toe_x - r * math.sin(theta), r * math.cos(theta)])


@pytest.mark.parametrize("s", [0.01, 0.04, 0.07, 0.1])
def test_ground_reaction_force_is_mass_times_acceleration_minus_gravity(s: float) -> None:
    solution, _ = _stance_solution()
    step = 1e-4
    # Fourth-order central difference of the body position: an acceleration from geometry alone.
    positions = [_body_position(solution(s + j * step)) for j in (-2, -1, 0, 1, 2)]
    acceleration = (
        -positions[0] + 16 * positions[1] - 30 * positions[2] + 16 * positions[3] - positions[4]
    ) / (12 * step**2)
    r, theta, rdot, _ = solution(s)
    force = dynamics.ground_reaction_force(
        PARAMS, r, math.sin(theta), math.cos(theta), rdot, dynamics.ramp_torque(COMMAND.tau0, COMMAND.t_f, s)
    )
    expected = np.array(force) + PARAMS.m * np.array([0.0, -PARAMS.g])
    np.testing.assert_allclose(PARAMS.m * acceleration, expected, rtol=0, atol=1e-5 * np.abs(expected).max())
    # The force's moment about the toe is the hip torque (the leg itself carries none).
    body = _body_position(solution(s), toe_x=0.0)
    assert body[0] * force[1] - body[1] * force[0] == pytest.approx(
        dynamics.ramp_torque(COMMAND.tau0, COMMAND.t_f, s), abs=1e-9
    )


@pytest.mark.parametrize("s", [0.02, 0.05, 0.09])
def test_cartesian_velocity_is_the_derivative_of_the_body_position(s: float) -> None:
    solution, _ = _stance_solution()
    step = 1e-5
    numeric = (_body_position(solution(s + step)) - _body_position(solution(s - step))) / (2 * step)
    r, theta, rdot, thetadot = solution(s)
    velocity = dynamics.cartesian_velocity(r, math.sin(theta), math.cos(theta), rdot, thetadot)
    np.testing.assert_allclose(velocity, numeric, atol=1e-8)
    back = dynamics.polar_velocity(r, math.sin(theta), math.cos(theta), *velocity)
    np.testing.assert_allclose(back, (rdot, thetadot), rtol=1e-14, atol=1e-14)


def test_touchdown_polar_velocity_follows_the_leg_geometry() -> None:
    """Eq. 6: a body falling ballistically past a fixed toe; r and theta from atan2 of the geometry."""
    xdot, ydot, angle = 4.0, -2.2, math.radians(25.0)
    toe = np.array([PARAMS.r0 * math.sin(angle), 0.0])

    def leg(t: float) -> tuple[float, float]:
        body = np.array([xdot * t, PARAMS.r0 * math.cos(angle) + ydot * t - 0.5 * PARAMS.g * t * t])
        rel = body - toe
        return float(np.hypot(*rel)), math.atan2(-rel[0], rel[1])

    step = 1e-6
    (r_plus, th_plus), (r_minus, th_minus) = leg(step), leg(-step)
    rdot, thetadot = dynamics.polar_velocity(PARAMS.r0, math.sin(angle), math.cos(angle), xdot, ydot)
    assert rdot == pytest.approx((r_plus - r_minus) / (2 * step), abs=1e-8)
    assert thetadot == pytest.approx((th_plus - th_minus) / (2 * step), abs=1e-8)
    assert thetadot < 0.0  # forward running: theta decreases in stance


def test_energy_rate_is_hip_power_minus_damper_power() -> None:
    solution, _ = _stance_solution()
    step = 1e-5
    for s in (0.03, 0.06, 0.1):

        def energy(t: float) -> float:
            r, theta, rdot, thetadot = solution(t)
            return float(dynamics.stance_energy(PARAMS, r, math.cos(theta), rdot, thetadot))

        rate = (energy(s + step) - energy(s - step)) / (2 * step)
        _, _, rdot, thetadot = solution(s)
        hip, damper = dynamics.stance_powers(
            PARAMS, rdot, thetadot, dynamics.ramp_torque(COMMAND.tau0, COMMAND.t_f, s)
        )
        assert rate == pytest.approx(hip - damper, rel=1e-7)


def test_generic_functions_agree_on_floats_and_arrays() -> None:
    rng = np.random.default_rng(3)
    r, theta = rng.uniform(0.7, 1.0, 20), rng.uniform(-0.6, 0.6, 20)
    rdot, thetadot, tau = rng.uniform(-3, 3, 20), rng.uniform(-6, -0.1, 20), rng.uniform(-900, 0, 20)
    vectorised = dynamics.stance_accelerations(PARAMS, r, np.sin(theta), np.cos(theta), rdot, thetadot, tau)
    for i in range(20):
        scalar = dynamics.stance_accelerations(
            PARAMS, r[i], math.sin(theta[i]), math.cos(theta[i]), rdot[i], thetadot[i], tau[i]
        )
        assert scalar == pytest.approx((vectorised[0][i], vectorised[1][i]), rel=1e-15, abs=1e-12)


def test_ramp_torque_is_eq_18() -> None:
    s = np.linspace(0.0, 0.3, 301)
    tau = dynamics.ramp_torque(COMMAND.tau0, COMMAND.t_f, s)
    on = s <= COMMAND.t_f
    assert tau[0] == COMMAND.tau0
    np.testing.assert_allclose(np.diff(tau[on]), COMMAND.tau0 * -(s[1] - s[0]) / COMMAND.t_f, rtol=1e-9)
    assert np.all(tau[~on] == 0.0)


def test_fall_time_reaches_the_target_height_while_descending() -> None:
    for y, ydot, target in [(1.2, 0.0, 0.9), (1.0, 2.0, 0.95), (0.97, -1.5, 0.9)]:
        t = dynamics.fall_time(y, ydot, target, PARAMS.g)
        _, y_t, _, ydot_t = dynamics.ballistic(0.0, y, 0.0, ydot, t, PARAMS.g)
        assert y_t == pytest.approx(target, abs=1e-14)
        assert ydot_t < 0.0


def test_event_rates_are_the_derivatives_of_the_event_values() -> None:
    solution, _ = _stance_solution()
    step = 1e-6
    for s in (0.02, 0.05, 0.09):

        def values(t: float) -> np.ndarray:
            r, theta, rdot, thetadot = solution(t)
            return np.array(dynamics.stance_event_values(PARAMS, r, math.cos(theta), rdot, thetadot))

        r, theta, rdot, thetadot = solution(s)
        rddot, thetaddot = dynamics.stance_accelerations(
            PARAMS,
            r,
            math.sin(theta),
            math.cos(theta),
            rdot,
            thetadot,
            dynamics.ramp_torque(COMMAND.tau0, COMMAND.t_f, s),
        )
        rates = dynamics.stance_event_rates(
            PARAMS, r, math.sin(theta), math.cos(theta), rdot, thetadot, rddot, thetaddot
        )
        numeric = (values(s + step) - values(s - step)) / (2 * step)
        np.testing.assert_allclose(rates, numeric, rtol=1e-6, atol=1e-6)
