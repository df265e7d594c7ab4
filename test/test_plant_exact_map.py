"""The exact return map: conservation, energy bookkeeping, stance symmetry, and every named failure."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from support.failure_cases import FAILURE_CASES

from tdslip_ros.model import dynamics
from tdslip_ros.model.events import FailureKind, Phase
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map

PARAMS = PAPER_PARAMS
LOSSLESS = HopperParams.from_dimensionless(36.0, 0.0)
# A stable lossless gait: beta = 20 deg at Ebar = 2.5 has a stable fixed point near ybar = 0.97
# (_lossless_fixed_point).
LOSSLESS_COMMAND = StanceCommand(math.radians(20.0), tau0=0.0, t_f=0.1)
LOSSLESS_START = ApexState.from_height_energy(LOSSLESS, 1.0, 2.5 * LOSSLESS.m * LOSSLESS.g * LOSSLESS.r0)


def _lossless_height_change(y: float) -> float:
    """y' - y [m] of the lossless stride from the apex at height ``y`` with LOSSLESS_START's energy."""
    start = ApexState.from_height_energy(LOSSLESS, y, LOSSLESS_START.energy(LOSSLESS))
    result = apex_return_map(LOSSLESS, start, LOSSLESS_COMMAND)
    assert result.apex is not None, result.reason
    return result.apex.y - y


def _lossless_fixed_point() -> float:
    """The apex height [m] the lossless stride maps to itself at LOSSLESS_START's energy: the root of
    y' - y, bracketed between 0.95 and 1.05 m."""
    return float(brentq(_lossless_height_change, 0.95, 1.05, xtol=1e-14))


def test_lossless_apex_energy_is_conserved_over_50_strides() -> None:
    energy0 = LOSSLESS_START.energy(LOSSLESS)
    apex = LOSSLESS_START
    worst = 0.0
    for _ in range(50):
        result = apex_return_map(LOSSLESS, apex, LOSSLESS_COMMAND)
        assert result.apex is not None, result.reason
        assert result.energy is not None
        assert result.energy.hip_work == 0.0
        assert result.energy.damping_loss == 0.0
        assert result.energy.spring_loss < 1e-18 * energy0  # liftoff at rest length
        apex = result.apex
        worst = max(worst, abs(apex.energy(LOSSLESS) - energy0) / energy0)
    assert worst <= 1e-9
    # It did settle on the stable lossless gait: its fixed point, where the stride's slope is below 1.
    y_fixed, step = _lossless_fixed_point(), 1e-6
    slope = 1.0 + (_lossless_height_change(y_fixed + step) - _lossless_height_change(y_fixed - step)) / (
        2 * step
    )
    assert abs(slope) < 1.0
    assert apex.y == pytest.approx(y_fixed, abs=1e-8)


@pytest.mark.parametrize(
    ("y", "xdot", "angle_deg"), [(1.0, 5.5, 20.0), (1.1, 4.0, 24.0), (1.2, 5.0, 22.0), (1.3, 5.0, 26.0)]
)
def test_lossless_stride_is_time_reversible(y: float, xdot: float, angle_deg: float) -> None:
    """Lossless stance is reversible under (theta, rdot, t) -> (-theta, -rdot, -t): if P takes apex a
    at touchdown angle beta to a' with liftoff angle theta_lo, then P takes a' at touchdown angle
    -theta_lo back to a, lifting off at -beta, with the mirrored event states and durations."""
    angle = math.radians(angle_deg)
    forward = apex_return_map(LOSSLESS, ApexState(y, xdot), StanceCommand(angle, 0.0, 0.1))
    assert forward.apex is not None and forward.liftoff is not None and forward.touchdown is not None
    assert forward.liftoff.r == pytest.approx(LOSSLESS.r0, abs=1e-12)  # lossless liftoff at rest length
    backward = apex_return_map(LOSSLESS, forward.apex, StanceCommand(-forward.liftoff.theta, 0.0, 0.1))
    assert backward.apex is not None and backward.liftoff is not None and backward.touchdown is not None
    assert backward.apex.y == pytest.approx(y, abs=1e-10)
    assert backward.apex.xdot == pytest.approx(xdot, abs=1e-10)
    assert backward.liftoff.theta == pytest.approx(-angle, abs=1e-10)
    assert backward.touchdown.rdot == pytest.approx(-forward.liftoff.rdot, abs=1e-10)
    assert backward.liftoff.rdot == pytest.approx(-forward.touchdown.rdot, abs=1e-10)
    assert backward.liftoff.thetadot == pytest.approx(forward.touchdown.thetadot, abs=1e-10)
    forward_stance = forward.liftoff.t - forward.touchdown.t
    assert backward.liftoff.t - backward.touchdown.t == pytest.approx(forward_stance, abs=1e-11)


def test_symmetric_lossless_stance_bottoms_out_at_the_vertical() -> None:
    """At the lossless fixed point the stance is symmetric: bottom at theta = 0, half-way through."""
    start = ApexState.from_height_energy(LOSSLESS, _lossless_fixed_point(), LOSSLESS_START.energy(LOSSLESS))
    result = apex_return_map(LOSSLESS, start, LOSSLESS_COMMAND)
    td, bottom, lo = result.touchdown, result.bottom, result.liftoff
    assert td is not None and bottom is not None and lo is not None
    assert bottom.theta == pytest.approx(0.0, abs=1e-9)
    assert lo.theta == pytest.approx(-LOSSLESS_COMMAND.touchdown_angle, abs=1e-9)
    assert bottom.t - td.t == pytest.approx(lo.t - bottom.t, abs=1e-10)


@pytest.mark.parametrize(
    ("y", "xdot", "angle_deg", "tau0", "t_f"),
    [
        (1.2, 4.0, 20.0, -610.0, 0.15),
        (1.1, 4.0, 26.0, -620.0, 0.155),
        (1.05, 5.0, 22.0, -900.0, 0.08),  # the ramp ends early in stance
        (1.3, 3.0, 24.0, -200.0, 0.4),  # the ramp outlasts the stance
        (1.0, 3.0, 20.0, 150.0, 0.1),  # braking torque: negative hip work
    ],
)
def test_energy_balance_per_stride(y: float, xdot: float, angle_deg: float, tau0: float, t_f: float) -> None:
    apex = ApexState(y, xdot)
    result = apex_return_map(PARAMS, apex, StanceCommand(math.radians(angle_deg), tau0, t_f))
    assert result.apex is not None and result.energy is not None, result.reason
    assert result.touchdown is not None and result.liftoff is not None
    energy0 = apex.energy(PARAMS)
    gain = result.apex.energy(PARAMS) - energy0
    assert abs(gain - result.energy.net_gain) <= 1e-8 * energy0
    # Inside stance: the mechanical energy (spring included) changes by the hip work minus the damper loss.
    stance_change = result.liftoff.energy - result.touchdown.energy
    assert stance_change == pytest.approx(
        result.energy.hip_work - result.energy.damping_loss, abs=1e-8 * energy0
    )
    assert result.energy.damping_loss > 0.0 and result.energy.spring_loss > 0.0
    assert math.copysign(1.0, result.energy.hip_work) == -math.copysign(1.0, tau0)


def test_event_states_are_the_events() -> None:
    result = apex_return_map(PARAMS, ApexState(1.2, 4.0), StanceCommand(math.radians(20.0), -610.0, 0.15))
    td, bottom, lo = result.touchdown, result.bottom, result.liftoff
    assert td is not None and bottom is not None and lo is not None and result.apex_time is not None
    assert td.y == pytest.approx(PARAMS.r0 * math.cos(math.radians(20.0)), abs=1e-15)
    assert td.t == pytest.approx(math.sqrt(2 * (1.2 - td.y) / PARAMS.g), abs=1e-15)
    assert td.toe_x - td.x == pytest.approx(PARAMS.r0 * math.sin(math.radians(20.0)), abs=1e-15)
    assert bottom.rdot == pytest.approx(0.0, abs=1e-9)
    assert dynamics.leg_force(PARAMS, lo.r, lo.rdot) == pytest.approx(0.0, abs=1e-7)
    assert lo.r < PARAMS.r0  # the damped leg lifts off before it is back at rest length
    assert td.t < bottom.t < lo.t < result.apex_time
    assert all(state.phase is Phase.STANCE for state in (td, bottom, lo))


@pytest.mark.parametrize(
    ("params", "apex", "command", "kind", "phrase"),
    [case[1:] for case in FAILURE_CASES],
    ids=[case.name for case in FAILURE_CASES],
)
def test_each_failure_is_reported_by_name(
    params: HopperParams, apex: ApexState, command: StanceCommand, kind: FailureKind, phrase: str
) -> None:
    result = apex_return_map(params, apex, command)
    assert result.apex is None
    assert result.failure is kind
    assert phrase in result.reason
    assert result.failure_state is not None
    if kind is FailureKind.TOE_STUBBING:
        assert result.touchdown is None and result.failure_state.phase is Phase.FLIGHT
    if kind is FailureKind.NO_LIFTOFF:
        stance_time = result.failure_state.t - result.touchdown.t  # type: ignore[union-attr]
        assert stance_time == pytest.approx(dynamics.max_stance_duration(params), rel=1e-12)


def test_tolerance_controls_the_accuracy() -> None:
    apex, command = ApexState(1.2, 4.0), StanceCommand(math.radians(20.0), -610.0, 0.15)
    reference = apex_return_map(PARAMS, apex, command, rtol=1e-13, atol=1e-13).apex
    loose = apex_return_map(PARAMS, apex, command, rtol=1e-6, atol=1e-6).apex
    default = apex_return_map(PARAMS, apex, command).apex
    assert reference is not None and loose is not None and default is not None
    default_error = abs(default.y - reference.y) + abs(default.xdot - reference.xdot)
    loose_error = abs(loose.y - reference.y) + abs(loose.xdot - reference.xdot)
    assert default_error < 1e-11 < loose_error
    assert np.isfinite(loose_error)
