"""The approximate return map: descent geometry, vectorisation, corrections, failures and validation."""

from __future__ import annotations

import numpy as np
import pytest

from tdslip_ros.model.analytic.apex_map import (
    approximate_map,
    approximate_map_energy,
    approximate_return_map,
    descent_map,
    gravity_momentum_correction,
    stance_map,
    torque_momentum_correction,
)
from tdslip_ros.model.analytic.map_kernels import CORRECTION_TOLERANCE, NO_LIFTOFF
from tdslip_ros.model.arrays import CommandArrays, ParamArrays
from tdslip_ros.model.events import NO_FAILURE_CODE, FailureKind, failure_code
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map

PARAMS = PAPER_PARAMS


def test_descent_map_keeps_speed_and_energy() -> None:
    p = ParamArrays.of(PARAMS)
    y, xdot, theta = np.array([1.0, 1.1, 1.3]), np.array([3.0, 4.5, 6.0]), np.array([0.3, 0.45, 0.55])
    touchdown = descent_map(p, y, xdot, theta)
    kinetic_td = 0.5 * PARAMS.m * (touchdown.rdot**2 + (PARAMS.r0 * touchdown.thetadot) ** 2)
    energy_td = kinetic_td + PARAMS.m * PARAMS.g * PARAMS.r0 * np.cos(theta)
    assert np.allclose(energy_td, PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2), rtol=1e-14)
    # The horizontal velocity of the body at touchdown is still xdot: xdot = -rdot sin - r0 thetadot cos.
    xdot_td = -touchdown.rdot * np.sin(theta) - PARAMS.r0 * touchdown.thetadot * np.cos(theta)
    assert np.allclose(xdot_td, xdot, rtol=1e-14)
    assert np.all(touchdown.rdot < 0.0) and np.all(touchdown.thetadot < 0.0)


def test_map_broadcasts_over_states_parameters_and_commands() -> None:
    params = [PAPER_PARAMS, HopperParams.from_dimensionless(20.0, 0.2, m=60.0)]
    stacked = ParamArrays.of(params)
    lanes = ParamArrays(*(np.asarray(v)[:, None, None] for v in vars(stacked).values()))
    y = np.array([1.0, 1.1, 1.25])[None, :, None]
    xdot = np.array([3.0, 4.5, 6.0, 7.0])[None, None, :]
    command = CommandArrays(np.asarray(0.45), np.array([-200.0, -400.0])[:, None, None], np.asarray(0.15))
    stride = approximate_map(lanes, y, xdot, command)
    assert stride.y.shape == (2, 3, 4) and stride.failure.shape == (2, 3, 4)
    for i, p in enumerate(params):
        for j, y_j in enumerate(y.ravel()):
            for k, x_k in enumerate(xdot.ravel()):
                single = approximate_map(p, y_j, x_k, StanceCommand(0.45, float(command.tau0[i, 0, 0]), 0.15))
                assert int(single.failure) == int(stride.failure[i, j, k])
                np.testing.assert_allclose(
                    [single.y, single.xdot, single.energy],
                    [stride.y[i, j, k], stride.xdot[i, j, k], stride.energy[i, j, k]],
                    rtol=1e-14,
                )


def test_energy_coordinates_give_the_same_map() -> None:
    y, xdot = np.array([1.05, 1.2]), np.array([3.5, 5.0])
    energy = PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)
    command = StanceCommand(0.42, -500.0, 0.14)
    by_speed = approximate_map(PARAMS, y, xdot, command)
    by_energy = approximate_map_energy(PARAMS, y, energy, command)
    np.testing.assert_allclose(by_energy.y, by_speed.y, rtol=1e-14)
    np.testing.assert_allclose(by_energy.energy, by_speed.energy, rtol=1e-14)
    np.testing.assert_allclose(
        by_speed.energy, PARAMS.m * (PARAMS.g * by_speed.y + 0.5 * by_speed.xdot**2), rtol=1e-13
    )


def test_next_energy_is_the_energy_balance_of_the_closed_forms() -> None:
    stride = approximate_map(PARAMS, 1.1, 4.5, StanceCommand(0.45, -600.0, 0.14))
    stance = stride.stance
    approx = stance.approximation
    energy = PARAMS.m * (PARAMS.g * 1.1 + 0.5 * 4.5**2)
    assert float(stride.energy) == pytest.approx(
        energy
        + float(approx.hip_energy(-600.0, 0.14, stance.t_lo))
        - float(approx.damping_loss(stance.t_lo))
        - 0.5 * PARAMS.k * (float(approx.r(stance.t_lo)) - PARAMS.r0) ** 2,
        rel=1e-14,
    )


def test_lossless_unforced_map_conserves_energy_and_lifts_off_at_rest_length() -> None:
    lossless = HopperParams.from_dimensionless(36.0, 0.0)
    y, xdot = np.linspace(1.0, 1.3, 4), np.linspace(3.0, 6.0, 4)
    for liftoff in ("paper", "force_root"):
        stride = approximate_map(lossless, y, xdot, StanceCommand(0.45, 0.0, 0.2), liftoff=liftoff)
        assert np.all(stride.ok)
        np.testing.assert_allclose(stride.energy, lossless.m * (lossless.g * y + 0.5 * xdot**2), rtol=1e-14)
        np.testing.assert_allclose(stride.stance.r_lo, lossless.r0, rtol=1e-13)


def test_corrections_iterate_eq_20_and_stop_on_convergence() -> None:
    p = ParamArrays.of(PARAMS)
    y, xdot, angle, tau0, t_f = np.array([1.05, 1.2]), np.array([4.0, 5.5]), 0.45, -500.0, 0.14
    touchdown = descent_map(p, y, xdot, angle)
    unforced = stance_map(p, angle, touchdown.rdot, touchdown.thetadot, tau0, t_f, corrections=0)
    np.testing.assert_allclose(unforced.momentum, PARAMS.m * PARAMS.r0**2 * touchdown.thetadot, rtol=1e-15)
    once = stance_map(p, angle, touchdown.rdot, touchdown.thetadot, tau0, t_f, corrections=1)
    expected = (
        unforced.momentum
        + torque_momentum_correction(tau0, t_f, unforced.t_lo)
        + gravity_momentum_correction(p, np.asarray(angle), unforced.t_lo, unforced.r_lo, unforced.theta_lo)
    )
    np.testing.assert_allclose(once.momentum, expected, rtol=1e-15)
    converged = stance_map(p, angle, touchdown.rdot, touchdown.thetadot, tau0, t_f, corrections=60)
    assert converged.corrections_done < 60
    # A fixed point of the correction: one more update leaves p_hat unchanged to the tolerance.
    again = (
        PARAMS.m * PARAMS.r0**2 * touchdown.thetadot
        + torque_momentum_correction(tau0, t_f, converged.t_lo)
        + gravity_momentum_correction(
            p, np.asarray(angle), converged.t_lo, converged.r_lo, converged.theta_lo
        )
    )
    np.testing.assert_allclose(again, converged.momentum, rtol=10 * CORRECTION_TOLERANCE)


def test_failures_are_named_like_the_exact_plant() -> None:
    soft = HopperParams.from_dimensionless(10.0, 0.5)
    cases = [
        (PARAMS, 0.6, 0.2, StanceCommand(0.2, -100.0, 0.15), FailureKind.TOE_STUBBING),
        (PARAMS, 1.5, 0.2, StanceCommand(1.2, -100.0, 0.15), FailureKind.REVERSAL),  # thetadot_td > 0
        (PARAMS, 0.6, 0.2, StanceCommand(1.0, -1500.0, 0.15), FailureKind.REVERSAL),  # bounces back
        (soft, 1.0, 3.0, StanceCommand(0.2, -1500.0, 0.15), FailureKind.FALL),
    ]
    for params, y, xdot, command, kind in cases:
        assert apex_return_map(params, ApexState(y, xdot), command).failure is kind
        stride = approximate_map(params, y, xdot, command)
        assert int(stride.failure) == failure_code(kind)
        assert np.isnan(stride.y) and np.isnan(stride.xdot) and np.isnan(stride.energy)
        assert approximate_return_map(params, ApexState(y, xdot), command) == (None, kind)


def test_no_liftoff_when_the_approximate_leg_force_stays_positive() -> None:
    soft = HopperParams.from_dimensionless(10.0, 0.5)
    assert int(approximate_map(soft, 0.6, 3.0, StanceCommand(1.0, -1500.0, 0.15)).failure) == NO_LIFTOFF
    # Already the unforced stance (the start of the corrections) has no force root after the bottom.
    stride = approximate_map(soft, 0.6, 3.0, StanceCommand(1.0, -1500.0, 0.15), corrections=0)
    assert int(stride.failure) == NO_LIFTOFF
    approx = stride.stance.approximation
    t = float(approx.bottom_time) + np.linspace(0.0, 2.0 * np.pi / float(approx.omega_d), 2001)
    assert np.all(approx.leg_force(t) > 0.0)


def test_scalar_wrapper_returns_the_next_apex() -> None:
    apex, failure = approximate_return_map(PARAMS, ApexState(1.1, 4.5), StanceCommand(0.45, -600.0, 0.14))
    stride = approximate_map(PARAMS, 1.1, 4.5, StanceCommand(0.45, -600.0, 0.14))
    assert failure is None and apex == ApexState(float(stride.y), float(stride.xdot))
    assert int(stride.failure) == NO_FAILURE_CODE


def test_invalid_parameters_and_commands_are_refused_by_name() -> None:
    with pytest.raises(ParameterError, match="zeta0"):
        approximate_map(HopperParams.from_dimensionless(36.0, 1.0), 1.1, 4.0, StanceCommand(0.4, 0.0, 0.1))
    with pytest.raises(ParameterError, match="zeta0"):
        ParamArrays.from_dimensionless(np.array([36.0, 36.0]), np.array([0.1, 1.2]))
    with pytest.raises(ParameterError, match="c \\(damping\\)"):
        ParamArrays(
            m=np.asarray(80.0), k=np.asarray(3e4), r0=np.asarray(1.0), c=np.asarray(-1.0), g=np.asarray(9.81)
        )
    with pytest.raises(ParameterError, match="touchdown_angle"):
        approximate_map(
            PARAMS, 1.1, 4.0, CommandArrays(np.array([0.4, 1.7]), np.asarray(0.0), np.asarray(0.1))
        )
    with pytest.raises(ParameterError, match="t_f"):
        approximate_map(PARAMS, 1.1, 4.0, CommandArrays(np.asarray(0.4), np.asarray(0.0), np.asarray(-0.1)))
    with pytest.raises(ValueError, match="liftoff method"):
        approximate_map(PARAMS, 1.1, 4.0, StanceCommand(0.4, 0.0, 0.1), liftoff="bogus")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="corrections"):
        approximate_map(PARAMS, 1.1, 4.0, StanceCommand(0.4, 0.0, 0.1), corrections=-1)
