"""Each closed form of the stance approximation against numerical integration of its own definition.

r(t), rdot(t): the linear ODE (8) solved by solve_ivp; thetadot: omega (3 - 2 r/r0) along that solution
(the linearised omega r0^2/r^2 of eq. 14); theta: quadrature of thetadot; the leg force and its root;
E_c, E_tau: quadrature; the momentum corrections: double integrals. Touchdown states are drawn over a wide
range so that every quadrant of phi1 (signs of A and B) and both orders of t_f and t_lo occur.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

from tdslip_ros.model.analytic.apex_map import (
    StanceApproximation,
    gravity_momentum_correction,
    torque_momentum_correction,
)
from tdslip_ros.model.arrays import ParamArrays
from tdslip_ros.model.paper import PAPER_KBAR, PAPER_ZETA0


def _touchdown_cases() -> list[tuple[float, float, float, float, float]]:
    """(kbar, zeta0, rdot_td, omega, theta_td) covering A > 0 and A < 0 (r0 omega^2 > g), B of both signs."""
    rng = np.random.default_rng(7)
    cases = [
        (36.0, 0.08, -3.5, -4.2, 0.45),  # typical running stance
        (36.0, 0.0, -2.0, -3.0, 0.3),  # undamped
        (20.0, 0.3, -1.0, -5.0, 0.5),  # A < 0: centrifugal term beats gravity
        (50.0, 0.5, -0.05, -1.0, 0.2),  # nearly no compression speed: B > 0
        (15.0, 0.9, -4.0, -2.0, 0.6),  # heavy damping
    ]
    for _ in range(10):
        cases.append(
            (
                float(rng.uniform(10.0, 60.0)),
                float(rng.uniform(0.0, 0.6)),
                float(rng.uniform(-5.0, -0.05)),
                float(rng.uniform(-6.0, -0.5)),
                float(rng.uniform(0.1, 0.7)),
            )
        )
    return cases


CASES = _touchdown_cases()


def _stance(case: tuple[float, float, float, float, float]) -> StanceApproximation:
    kbar, zeta0, rdot_td, omega, theta_td = case
    params = ParamArrays.from_dimensionless(kbar, zeta0)
    return StanceApproximation.build(params, np.asarray(theta_td), np.asarray(rdot_td), np.asarray(omega))


def _radial_ode(stance: StanceApproximation, t_end: float) -> object:
    p = stance.params
    m, k, r0, c, g = (float(v) for v in (p.m, p.k, p.r0, p.c, p.g))
    omega = float(stance.omega)

    def rhs(t: float, s: np.ndarray) -> list[float]:
        r, rdot = s
        # Eq. (8): rddot + (c/m) rdot + (w0^2 + 3 omega^2) r = -g + r0 w0^2 + 4 r0 omega^2.
        return [rdot, -(c / m) * rdot - (k / m + 3 * omega**2) * r - g + r0 * k / m + 4 * r0 * omega**2]

    return solve_ivp(
        rhs,
        (0.0, t_end),
        [r0, float(stance.rdot_td)],
        method="DOP853",
        rtol=1e-12,
        atol=1e-13,
        dense_output=True,
    )


def test_quadrants_are_covered() -> None:
    signs = {(float(_stance(c).amplitude_a) > 0, float(np.sin(_stance(c).phi1)) > 0) for c in CASES}
    assert {(True, True), (False, True), (True, False)} <= signs


@pytest.mark.parametrize("case", CASES)
def test_radial_and_angular_solution_match_their_odes(case: tuple[float, float, float, float, float]) -> None:
    stance = _stance(case)
    t_end = 2.5 * float(stance.bottom_time)
    solution = _radial_ode(stance, t_end)
    t = np.linspace(0.0, t_end, 201)
    r_num, rdot_num = solution.sol(t)
    assert np.allclose(stance.r(t), r_num, rtol=0, atol=1e-11)
    assert np.allclose(stance.rdot(t), rdot_num, rtol=0, atol=1e-10)
    r0, omega = float(stance.params.r0), float(stance.omega)
    assert np.allclose(stance.thetadot(t), omega * (3.0 - 2.0 * r_num / r0), rtol=0, atol=1e-10)
    for t_i in t[::20]:
        integral, _ = quad(lambda s: float(stance.thetadot(s)), 0.0, t_i, epsabs=1e-14, epsrel=1e-13)
        assert float(stance.theta(t_i)) == pytest.approx(float(stance.theta_td) + integral, abs=1e-12)
    force_num = float(stance.params.k) * (r0 - r_num) - float(stance.params.c) * rdot_num
    assert np.allclose(stance.leg_force(t), force_num, rtol=0, atol=1e-7 * float(stance.params.k))
    # Bottom time: the first zero of rdot, from below.
    bottom = brentq(lambda s: float(solution.sol(s)[1]), 1e-9, float(stance.bottom_time) * 1.5, xtol=1e-15)
    assert float(stance.bottom_time) == pytest.approx(bottom, rel=1e-10)
    assert np.all(rdot_num[t < bottom] < 0.0)


@pytest.mark.parametrize("case", CASES)
def test_force_root_liftoff_is_the_first_zero_of_the_leg_force_after_the_bottom(
    case: tuple[float, float, float, float, float],
) -> None:
    stance = _stance(case)
    t_lo, exists = stance.liftoff_time("force_root")
    t_b = float(stance.bottom_time)
    grid = np.linspace(t_b, t_b + 2.0 * np.pi / float(stance.omega_d), 4001)
    force = stance.leg_force(grid)
    crossings = np.nonzero((force[:-1] > 0.0) & (force[1:] <= 0.0))[0]
    assert bool(exists) == (crossings.size > 0)
    if crossings.size:
        i = crossings[0]
        reference = brentq(lambda s: float(stance.leg_force(s)), grid[i], grid[i + 1], xtol=1e-15, rtol=1e-15)
        assert float(t_lo) == pytest.approx(reference, rel=1e-12)


@pytest.mark.parametrize("case", CASES)
def test_paper_liftoff_solves_the_frozen_envelope_equation(
    case: tuple[float, float, float, float, float],
) -> None:
    # The paper's t_lo: the zero of k A - Mbar M e^{-2 a t_b} cos(wd t + phi1 + phi3) on the decreasing branch
    # after the bottom (the force with its envelope frozen at twice the bottom time).
    stance = _stance(case)
    t_lo, exists = stance.liftoff_time("paper")
    t_b = float(stance.bottom_time)
    frozen = float(stance.force_amplitude * stance.amplitude * np.exp(-2 * stance.decay * t_b))
    k_a = float(stance.params.k * stance.amplitude_a)

    def frozen_force(t: float) -> float:
        return k_a - frozen * float(np.cos(stance.omega_d * t + stance.phi1 + stance.phi3))

    # The window: from the bottom to the end of the cosine's rising branch [pi, 2 pi] in the bottom's cycle.
    wd, offset = float(stance.omega_d), float(stance.phi1 + stance.phi3)
    bottom_phase = wd * t_b + offset
    cycle = 2.0 * np.pi * np.floor(bottom_phase / (2.0 * np.pi))
    start = (max(bottom_phase, cycle + np.pi) - offset) / wd
    end = (cycle + 2.0 * np.pi - offset) / wd
    has_root = frozen_force(start) >= 0.0 >= frozen_force(end)
    assert bool(exists) == has_root
    if has_root:
        reference = brentq(frozen_force, start, end, xtol=1e-15, rtol=1e-15)
        assert float(t_lo) == pytest.approx(reference, rel=1e-12)


@pytest.mark.parametrize("case", CASES)
def test_the_printed_phases_and_eq_16_against_ours(case: tuple[float, float, float, float, float]) -> None:
    """The text as printed (docs/paper.md, the printed equations and ours): phi1 = arctan(-B/A) puts r(0)
    at r0 only where A > 0; phi3 = arctan(c wh sin phi2/(c wh cos phi2 - k)) is ours while k > c^2/(2m);
    eq. 16 with it, its Mbar and atan2's phi1 is our liftoff time."""
    stance = _stance(case)
    k, c, m, r0 = (
        float(value) for value in (stance.params.k, stance.params.c, stance.params.m, stance.params.r0)
    )
    wh, zeta, wd = float(stance.omega_hat), float(stance.zeta), float(stance.omega_d)
    a, amplitude, t_b = float(stance.amplitude_a), float(stance.amplitude), float(stance.bottom_time)
    b = (float(stance.rdot_td) + zeta * wh * a) / wd  # eq. 11
    r_start = amplitude * np.cos(np.arctan(-b / a)) + r0 - a  # eq. 12 at t = 0, F/wh^2 = r0 - A (eq. 10)
    assert (abs(r_start - r0) < 1e-12) == (a > 0.0)
    with np.errstate(divide="ignore"):
        phi2 = float(np.arctan(np.divide(-np.sqrt(1.0 - zeta**2), zeta)))  # principal value: -pi/2 at zeta 0
    phi3 = np.arctan(c * wh * np.sin(phi2) / (c * wh * np.cos(phi2) - k))
    spring_wins = k > c**2 / (2.0 * m)
    assert (abs(phi3 - float(stance.phi3)) < 1e-12) == spring_wins
    if spring_wins:
        force_amplitude = np.sqrt(k**2 - 2.0 * k * c * wh * np.cos(phi2) + c**2 * wh**2)
        assert force_amplitude == pytest.approx(float(stance.force_amplitude), rel=1e-13)
        q = k * a / (force_amplitude * amplitude * np.exp(-zeta * wh * 2.0 * t_b))
        t_lo, exists = stance.liftoff_time("paper")
        assert bool(exists) == (abs(q) <= 1.0)
        if exists:
            printed = (2.0 * np.pi - np.arccos(q) - float(stance.phi1) - phi3) / wd
            assert float(t_lo) == pytest.approx(printed, rel=1e-12)


def test_both_liftoff_methods_are_exact_without_damping() -> None:
    stance = _stance((36.0, 0.0, -2.0, -3.0, 0.3))
    paper, _ = stance.liftoff_time("paper")
    root, _ = stance.liftoff_time("force_root")
    assert float(paper) == pytest.approx(float(root), rel=1e-13)
    assert float(stance.r(paper)) == pytest.approx(float(stance.params.r0), abs=1e-13)


@pytest.mark.parametrize("case", CASES)
def test_damping_loss_and_spring_energy_match_quadrature(
    case: tuple[float, float, float, float, float],
) -> None:
    stance = _stance(case)
    c = float(stance.params.c)
    for t_end in (0.3, 1.0, 1.7):
        t = t_end * 2.0 * float(stance.bottom_time)
        integral, _ = quad(
            lambda s: c * float(stance.rdot(s)) ** 2, 0.0, t, epsabs=1e-13, epsrel=1e-13, limit=200
        )
        assert float(stance.damping_loss(t)) == pytest.approx(integral, rel=1e-11, abs=1e-11)


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("ramp_fraction", [0.6, 1.0, 1.4])
def test_hip_energy_matches_quadrature(
    case: tuple[float, float, float, float, float], ramp_fraction: float
) -> None:
    stance = _stance(case)
    t_end = 2.0 * float(stance.bottom_time)
    t_f = ramp_fraction * t_end
    tau0 = -250.0
    integral, _ = quad(
        lambda s: tau0 * (1.0 - s / t_f) * float(stance.thetadot(s)),
        0.0,
        min(t_f, t_end),
        epsabs=1e-12,
        epsrel=1e-13,
    )
    assert float(stance.hip_energy(tau0, t_f, t_end)) == pytest.approx(integral, rel=1e-11)


@pytest.mark.parametrize("t_f", [0.05, 0.14, 0.3])
def test_torque_correction_is_the_time_average_of_the_integrated_ramp(t_f: float) -> None:
    t_lo, tau0 = 0.14, -300.0

    def integrated_ramp(eta: float) -> float:
        value, _ = quad(
            lambda s: tau0 * (1.0 - s / t_f) if s <= t_f else 0.0, 0.0, eta, points=[t_f], epsabs=1e-13
        )
        return value

    average, _ = quad(integrated_ramp, 0.0, t_lo, points=[t_f], epsabs=1e-13)
    assert float(torque_momentum_correction(tau0, t_f, t_lo)) == pytest.approx(average / t_lo, rel=1e-10)
    if t_f == t_lo:
        assert float(torque_momentum_correction(tau0, t_f, t_lo)) == pytest.approx(
            tau0 * t_lo / 3.0, rel=1e-14
        )


def test_gravity_correction_is_the_time_average_of_the_interpolated_gravity_impulse() -> None:
    params = ParamArrays.from_dimensionless(PAPER_KBAR, PAPER_ZETA0)
    m, g, r0 = float(params.m), float(params.g), float(params.r0)
    theta_td, t_lo, r_lo, theta_lo = 0.45, 0.14, 0.97, -0.27
    h0, h1 = r0 * np.sin(theta_td), r_lo * np.sin(theta_lo)

    def impulse(eta: float) -> float:
        value, _ = quad(lambda s: m * g * (h0 + (h1 - h0) * s / t_lo), 0.0, eta, epsabs=1e-13)
        return value

    average, _ = quad(impulse, 0.0, t_lo, epsabs=1e-13)
    value = gravity_momentum_correction(
        params, np.asarray(theta_td), np.asarray(t_lo), np.asarray(r_lo), np.asarray(theta_lo)
    )
    assert float(value) == pytest.approx(average / t_lo, rel=1e-12)
