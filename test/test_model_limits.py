"""Plausibility limits (issue 9): inputs beyond them are refused by name, states beyond them end as the
failure state_limit, and no number makes an integrator raise, hang or report a non-finite value."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from support.helpers import deadline

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.analytic.apex_map import approximate_return_map
from tdslip_ros.model.events import EventKind, FailureKind, HopperState, failure_from_code
from tdslip_ros.model.limits import PlausibilityLimits, check_hopper, check_tolerances
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant import exact_map
from tdslip_ros.model.plant.batch import batch_apex_return_map, batch_feedback_return_map, simulate_strides
from tdslip_ros.model.plant.batch_stance import feedback_stance
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stance_kernel import STANCE_LIFTOFF, STANCE_STEP_COLLAPSE
from tdslip_ros.model.plant.stance_laws import StanceSample
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.model.policies.controllers import deadbeat

PARAMS = PAPER_PARAMS
LIMITS = PlausibilityLimits.for_hopper(PARAMS)
GAIT = StanceCommand(math.radians(20.0), -273.0, 0.13)  # the paper's energy-regulated gait
GAIT_LANES = (GAIT.touchdown_angle, GAIT.tau0, GAIT.t_f)  # the batch's arguments
START = ApexState(1.0, 5.0)


def gait_policy(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[float, float, float]:
    return GAIT_LANES


def test_default_limits_scale_with_the_hopper() -> None:
    spring_period = 2.0 * math.pi * math.sqrt(PARAMS.m / PARAMS.k)
    assert LIMITS.max_torque == pytest.approx(20.0 * 80.0 * 9.81)
    assert (LIMITS.max_apex_height, LIMITS.max_apex_speed) == pytest.approx((10.0, 10.0 * math.sqrt(9.81)))
    assert (LIMITS.min_ramp_duration, LIMITS.max_ramp_duration) == pytest.approx(
        (1e-3 * spring_period, 10.0 * spring_period)
    )
    assert LIMITS.max_stance_time == dynamics.max_stance_duration(PARAMS)
    toy = HopperParams(m=2.0, k=500.0, r0=0.25, c=3.0, g=9.0)
    toy_limits = PlausibilityLimits.for_hopper(toy)
    assert units.torque_to_bar(toy, toy_limits.max_torque) == pytest.approx(20.0)
    assert units.height_to_bar(toy, toy_limits.max_apex_height) == pytest.approx(10.0)
    assert units.speed_to_bar(toy, toy_limits.max_apex_speed) == pytest.approx(10.0)


def test_the_packages_own_commands_are_within_the_limits() -> None:
    """The gait of the paper, and the deadbeat controller's largest asks: the first stride of the fig. 13
    sweep (from 5 m/s at 1 m to every desired speed xdotbar* in [0.5, 3])."""
    LIMITS.check_command(GAIT)
    LIMITS.check_apex(START)
    speeds = units.speed_from_bar(PARAMS, np.arange(0.5, 3.001, 0.25))
    commands = deadbeat(PARAMS, START.y, START.xdot, 1.0, speeds)
    assert np.all(np.isfinite(commands.tau0))
    for lane in range(speeds.size):
        LIMITS.check_command(commands.command(lane))
    # The sweep's largest torque is ~9.7 m g r0: the limit keeps a margin of 2.
    assert np.max(np.abs(commands.tau0)) > 0.4 * LIMITS.max_torque


@pytest.mark.parametrize(
    ("tau0", "t_f", "phrase"),
    [
        (-1e12, 0.13, "tau0 = -1000000000000.0 N m exceeds the actuator limit"),
        (1e300, 0.13, "tau0 = 1e+300 N m exceeds the actuator limit"),
        (-1.6e4, 0.13, "actuator limit |tau0| <= 15696 N m"),
        (-273.0, 1.3e-4, "t_f = 0.00013 s is outside"),
        (-273.0, 100.0, "t_f = 100.0 s is outside"),
    ],
)
def test_commands_beyond_the_limits_are_refused_by_name(tau0: float, t_f: float, phrase: str) -> None:
    with pytest.raises(ParameterError, match=phrase.replace("|", "\\|").replace("+", "\\+")):
        LIMITS.check_command(StanceCommand(GAIT.touchdown_angle, tau0, t_f))


@pytest.mark.parametrize(
    ("apex", "phrase"),
    [
        (ApexState(1.0, 1e150), "apex speed xdot = 1e\\+150 m/s exceeds max_apex_speed"),
        (ApexState(1.0, -40.0), "apex speed xdot = -40.0 m/s"),
        (ApexState(1e9, 5.0), "apex height y = 1000000000.0 m exceeds max_apex_height = 10 m"),
    ],
)
def test_apexes_beyond_the_limits_are_refused_by_every_integrator(apex: ApexState, phrase: str) -> None:
    """Issue 9 item 7: an apex of 1e150 m/s crashed the plant at the next command, 1e9 m meant a 14,000 s
    fall."""
    with pytest.raises(ParameterError, match=phrase):
        LIMITS.check_apex(apex)
    with pytest.raises(ParameterError, match=phrase):
        FixedStepStepper(PARAMS, apex, GAIT)
    with pytest.raises(ParameterError, match=phrase):
        apex_return_map(PARAMS, apex, GAIT)
    with pytest.raises(ParameterError, match=phrase + ".* in lane 1"):
        batch_apex_return_map(
            PARAMS, [START.y, apex.y], [START.xdot, apex.xdot], GAIT.touchdown_angle, -273, 0.13
        )
    with pytest.raises(ParameterError, match=phrase):
        simulate_strides(PARAMS, apex.y, apex.xdot, gait_policy, 1)
    with pytest.raises(ParameterError, match=phrase):
        approximate_return_map(PARAMS, apex, GAIT)


def test_an_apex_no_hopper_can_hold_is_refused_where_it_is_built() -> None:
    """Its energy would overflow (0.5 m xdot^2 raised OverflowError for xdot = 1e200)."""
    with pytest.raises(
        ParameterError, match=r"apex speed xdot = 1e\+200 m/s is out of the floating-point range"
    ):
        ApexState(1.0, 1e200)
    with pytest.raises(ParameterError, match=r"apex height y = 1e\+160 m is out of the floating-point"):
        ApexState(1e160, 1.0)


def test_hopper_parameters_out_of_their_domain_are_refused_by_name() -> None:
    """Issue 9 items 12 and 13: HopperParams(m=None) raised TypeError, r0 = 1e-300 a ZeroDivisionError in the
    exact map, and a damping of 1e7 N s/m (zeta0 3326) was accepted."""
    with pytest.raises(ParameterError, match="m must be a number, got None"):
        HopperParams(m=None, k=PARAMS.k, r0=1.0, c=PARAMS.c)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="c must be a number, got 'soft'"):
        HopperParams(m=80.0, k=PARAMS.k, r0=1.0, c="soft")  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="r0 = 1e-300.*m r0\\^2"):
        HopperParams(m=80.0, k=PARAMS.k, r0=1e-300, c=PARAMS.c)
    with pytest.raises(ParameterError, match="m = 1e-300, k = 1e-300.*m k = 0.0"):
        HopperParams(m=1e-300, k=1e-300, r0=1.0, c=0.0)
    # Issue 17: m g = 0 reached the division of kbar (ZeroDivisionError).
    with pytest.raises(ParameterError, match="m = 1e-300, k = 1e-300, r0 = 1e-300, g = 1e-300 .* m g r0"):
        HopperParams(1e-300, 1e-300, 1e-300, 0, 1e-300)
    with pytest.raises(ParameterError, match="floating-point range: zeta0"):
        HopperParams(m=1e-300, k=1e-3, r0=1.0, c=1e300)
    overdamped = HopperParams(m=PARAMS.m, k=PARAMS.k, r0=PARAMS.r0, c=1e7)
    with pytest.raises(ParameterError, match="zeta0 = c/\\(2 sqrt\\(m k\\)\\) = 3325.79.*zeta0 < 1"):
        check_hopper(overdamped)
    check_hopper(PARAMS)


def test_an_overdamped_leg_is_integrated_alike_or_refused() -> None:
    """zeta0 = 3326 (damping 1e7 N s/m): the batched engine accepted an overflowed DOP853 step (NaN error
    taken for 0) and reported a reversal where the exact map hops on; the 1 kHz stepper cannot resolve
    the leg (its fastest mode is 1.25e5 1/s) and says so."""
    overdamped = HopperParams(m=PARAMS.m, k=PARAMS.k, r0=PARAMS.r0, c=1e7)
    exact = apex_return_map(overdamped, START, GAIT)
    assert exact.apex is not None
    batch = batch_apex_return_map(overdamped, START.y, START.xdot, *GAIT_LANES)
    assert failure_from_code(int(batch.failure)) is None
    assert float(batch.y) == pytest.approx(exact.apex.y, abs=1e-9)
    assert float(batch.xdot) == pytest.approx(exact.apex.xdot, abs=1e-9)
    with pytest.raises(ParameterError, match="cannot resolve this hopper, whose fastest rate is 125000 1/s"):
        FixedStepStepper(overdamped, START, GAIT)


def test_limits_are_validated_and_belong_to_their_hopper() -> None:
    """Issue 9 item 13: max_stance_time = NaN hung the exact map; -1 reported a fall at 1149 m/s."""
    for value in (math.nan, -1.0, 0.0, math.inf):
        with pytest.raises(ParameterError, match="max_stance_time must be a positive finite number"):
            dataclasses.replace(LIMITS, max_stance_time=value)
    with pytest.raises(ParameterError, match="min_ramp_duration .* exceeds max_ramp_duration"):
        dataclasses.replace(LIMITS, min_ramp_duration=1.0, max_ramp_duration=0.5)
    other = PlausibilityLimits.for_hopper(HopperParams.from_dimensionless(20.0, 0.08))
    with pytest.raises(ParameterError, match="the limits were made for"):
        apex_return_map(PARAMS, START, GAIT, limits=other)
    # A shorter stance bound is honoured by every integrator alike.
    short = dataclasses.replace(LIMITS, max_stance_time=0.05)
    exact = apex_return_map(PARAMS, START, GAIT, limits=short)
    assert exact.failure is FailureKind.NO_LIFTOFF and exact.touchdown is not None
    assert exact.failure_state is not None
    assert exact.failure_state.t - exact.touchdown.t == pytest.approx(0.05, rel=1e-12)
    batch = batch_apex_return_map(PARAMS, START.y, START.xdot, *GAIT_LANES, limits=short)
    assert failure_from_code(int(batch.failure)) is FailureKind.NO_LIFTOFF
    stepper = FixedStepStepper(PARAMS, START, GAIT, limits=short)
    while stepper.failed is None:
        stepper.step()
    assert stepper.failed is FailureKind.NO_LIFTOFF
    assert stepper.t == pytest.approx(exact.failure_state.t, abs=1e-12)


@pytest.mark.parametrize(
    ("rtol", "atol", "phrase"),
    [
        (0.0, 0.0, "rtol"),
        (math.nan, 1e-12, "rtol"),
        (1e-300, 1e-12, "rtol"),
        (1.0, 1e-12, "rtol"),
        (1e-12, math.nan, "atol"),
        (1e-12, -1.0, "atol"),
        (1e-12, math.inf, "atol"),
    ],
)
def test_tolerances_that_cannot_finish_are_refused(rtol: float, atol: float, phrase: str) -> None:
    """Issue 9 item 13: rtol = atol = 0 and rtol = NaN hung the exact map and the batch (> 150 s)."""
    with deadline(20.0):
        with pytest.raises(ParameterError, match=phrase):
            check_tolerances(rtol, atol)
        with pytest.raises(ParameterError, match=phrase):
            apex_return_map(PARAMS, START, GAIT, rtol=rtol, atol=atol)
        with pytest.raises(ParameterError, match=phrase):
            batch_apex_return_map(PARAMS, START.y, START.xdot, *GAIT_LANES, rtol=rtol, atol=atol)
        with pytest.raises(ParameterError, match=phrase):
            simulate_strides(PARAMS, START.y, START.xdot, gait_policy, 1, rtol=rtol, atol=atol)


def test_the_exact_map_never_returns_a_failed_integration(monkeypatch: pytest.MonkeyPatch) -> None:
    """When DOP853 gives up, the exact map used to go on from the last state as if the stance had ended
    (|tau0| >= 1e200 gave the unforced apex with hip_work 0). A failed solve is now state_limit."""
    real_solve = exact_map.solve_ivp

    def failing_solve(*args: Any, **kwargs: Any) -> Any:
        solution = real_solve(*args, **kwargs)
        solution.status, solution.message = -1, "Required step size is less than spacing between numbers."
        return solution

    monkeypatch.setattr(exact_map, "solve_ivp", failing_solve)
    result = apex_return_map(PARAMS, START, GAIT)
    assert result.failure is FailureKind.STATE_LIMIT and result.apex is None and result.energy is None
    assert "the stance integration failed" in result.reason and "step size" in result.reason
    assert result.touchdown is not None and result.failure_state is not None
    assert result.failure_state.t > result.touchdown.t


class _TurnsNaN:
    """A stance law that holds -200 N m, except in lane 1 from its first sample after 20 ms of stance on:
    NaN, which every trial step then carries out of the floats. Keeps that sample (s, r, theta, rdot,
    thetadot): the last state the lane can reach."""

    def __init__(self) -> None:
        self.poisoned_at: tuple[float, ...] | None = None

    def torque(self, sample: StanceSample, lanes: np.ndarray | None = None) -> Any:
        poisoned = (lanes == 1) & (sample.s > 0.02)
        if self.poisoned_at is None and poisoned.any():
            at = int(np.flatnonzero(poisoned)[0])
            self.poisoned_at = tuple(float(v[at]) for v in sample[1:6])
        return np.where(poisoned, math.nan, -200.0)


def test_a_batch_lane_whose_steps_collapse_fails_alone() -> None:
    """A lane whose torque turns NaN can take no step: its step size collapses (STANCE_STEP_COLLAPSE) at
    its last accepted state (the batch used to take NaN errors for 0 and accept the step, or stall), it
    ends as state_limit and its neighbours hop on."""
    angle = GAIT.touchdown_angle
    healthy = batch_feedback_return_map(PARAMS, START.y, START.xdot, angle, _TurnsNaN())
    with deadline(20.0):
        batch = batch_feedback_return_map(PARAMS, [START.y, START.y], START.xdot, angle, _TurnsNaN())
    assert failure_from_code(int(batch.failure[1])) is FailureKind.STATE_LIMIT
    assert math.isnan(batch.y[1]) and math.isnan(batch.hip_work[1])
    assert failure_from_code(int(batch.failure[0])) is None
    assert (batch.y[0], batch.xdot[0]) == pytest.approx((float(healthy.y), float(healthy.xdot)), abs=1e-12)

    # The compiled stance itself, from touchdown on a sample grid that starts there.
    sin_td, cos_td = math.sin(angle), math.cos(angle)
    ydot_td = -math.sqrt(2.0 * PARAMS.g * (START.y - dynamics.touchdown_height(PARAMS, cos_td)))
    rdot_td, thetadot_td = dynamics.polar_velocity(PARAMS.r0, sin_td, cos_td, START.xdot, ydot_td)
    y = np.tile([PARAMS.r0, angle, rdot_td, thetadot_td, 0.0, 0.0], (2, 1))
    law = _TurnsNaN()
    with deadline(20.0):
        outcome, s = feedback_stance(
            PARAMS,
            y,
            law,
            1e-3,
            np.zeros(2),
            np.full(2, LIMITS.max_torque),
            None,
            np.arange(2),
            np.zeros(2, dtype=bool),
            LIMITS.max_stance_time,
            1e-12,
            1e-12,
        )
    assert outcome.tolist() == [STANCE_LIFTOFF, STANCE_STEP_COLLAPSE]
    assert law.poisoned_at is not None and law.poisoned_at[0] == 21 * 1e-3
    assert (s[1], *y[1, :4]) == law.poisoned_at
    assert np.all(np.isfinite(y))


# --- fuzz ---------------------------------------------------------------------------------------

EXTREMES = (0.0, 1e-300, -1e-300, 1e-12, -1e12, 1e12, -1e100, 1e300, -1e300, math.nan, math.inf, -math.inf)
FUZZ_SAMPLES = 300


def _fuzz_value(rng: np.random.Generator, low: float, high: float) -> float:
    """A plausible value mostly (so that strides run), else an extreme, or a plausible one negated or scaled
    by a power of ten."""
    draw = rng.random()
    if draw < 0.75:
        return float(rng.uniform(low, high))
    if draw < 0.9:
        return float(EXTREMES[rng.integers(len(EXTREMES))])
    return float(rng.uniform(low, high) * 10.0 ** rng.integers(-6, 7) * rng.choice([-1.0, 1.0]))


def _fuzz_inputs(rng: np.random.Generator) -> tuple[float, float, float, float, float]:
    """(y, xdot, touchdown_angle, tau0, t_f)"""
    return (
        _fuzz_value(rng, 0.9, 2.0),
        _fuzz_value(rng, 0.5, 8.0),
        _fuzz_value(rng, 0.2, 0.6),
        _fuzz_value(rng, -1500.0, 200.0),
        _fuzz_value(rng, 0.05, 0.3),
    )


def _assert_plausible(state: HopperState) -> None:
    assert LIMITS.state_violation(state) is None, state


def _first_stride_on_the_stepper(apex: ApexState, command: StanceCommand) -> FailureKind | None:
    """Step to the first apex or failure, checking every state; bounded by the limits' longest stride."""
    stepper = FixedStepStepper(PARAMS, apex, command)
    longest_stride = LIMITS.max_flight_time + LIMITS.max_stance_time
    for _ in range(math.ceil(longest_stride / 1e-3) + 1):
        for event in stepper.step():
            _assert_plausible(event.state)
            if event.kind is EventKind.APEX:
                return None
        _assert_plausible(stepper.state)
        if stepper.failed is not None:
            return stepper.failed
    raise AssertionError(f"no apex and no failure within {longest_stride:.3g} s from {apex}, {command}")


def test_fuzz_every_engine_refuses_or_reports_the_same_failure() -> None:
    """Random apexes and commands, finite, huge, tiny, negative, NaN and infinite. Each is refused with
    ParameterError (by the records themselves or by the limits) by every engine alike, or each engine runs
    its stride to the same outcome with every reported value finite, the stepper within a bounded time."""
    rng = np.random.default_rng(20240609)
    accepted: list[tuple[float, ...]] = []
    kinds: list[FailureKind | None] = []
    outcomes = set()
    for _ in range(FUZZ_SAMPLES):
        y, xdot, angle, tau0, t_f = _fuzz_inputs(rng)
        try:
            apex, command = ApexState(y, xdot), StanceCommand(angle, tau0, t_f)
            LIMITS.check_apex(apex)
        except ParameterError:
            with pytest.raises(ParameterError):
                batch_apex_return_map(PARAMS, [START.y, y], [START.xdot, xdot], angle, tau0, t_f)
            with pytest.raises(ParameterError):  # in ApexState, StanceCommand or the limits
                FixedStepStepper(PARAMS, ApexState(y, xdot), StanceCommand(angle, tau0, t_f))
            with pytest.raises(ParameterError):
                apex_return_map(PARAMS, ApexState(y, xdot), StanceCommand(angle, tau0, t_f))
            outcomes.add("refused")
            continue
        with deadline(30.0):
            kind = _first_stride_on_the_stepper(apex, command)
            exact = apex_return_map(PARAMS, apex, command)
        assert exact.failure is kind, (apex, command, exact.reason)
        for state in (exact.touchdown, exact.bottom, exact.liftoff, exact.failure_state):
            if state is not None:
                _assert_plausible(state)
        accepted.append((y, xdot, angle, tau0, t_f))
        kinds.append(kind)
        outcomes.add(kind)
    with deadline(30.0):
        batch = batch_apex_return_map(PARAMS, *np.array(accepted).T)
    assert [failure_from_code(int(code)) for code in batch.failure] == kinds
    assert np.all(np.isfinite(batch.y[batch.failure == -1]))
    # The sample covers refusals, successful strides and the failures extreme numbers cause.
    assert {"refused", None, FailureKind.STATE_LIMIT, FailureKind.TOE_STUBBING} <= outcomes


def test_fuzz_commands_changed_in_flight_never_break_the_stepper() -> None:
    """A controller sending random commands at random ticks: set_command refuses with ParameterError
    (out of domain, in stance, unreachable angle) or takes the command; the stepper never raises and
    never reports a non-finite or implausible state."""
    rng = np.random.default_rng(7)
    failures: list[FailureKind] = []
    taken = refused = 0
    with deadline(60.0):
        for _ in range(8):
            stepper = FixedStepStepper(PARAMS, START, GAIT)
            for _ in range(4000):
                if rng.random() < 0.02:
                    _, _, angle, tau0, t_f = _fuzz_inputs(rng)
                    try:
                        stepper.set_command(StanceCommand(angle, tau0, t_f))
                        taken += 1
                    except ParameterError:
                        refused += 1
                for event in stepper.step():
                    _assert_plausible(event.state)
                _assert_plausible(stepper.state)
                if stepper.failed is not None:
                    failures.append(stepper.failed)
                    break
    # Both paths were exercised, and the random commands ended the hopping as named failures.
    assert taken > 0 and refused > 0, (taken, refused)
    assert len(failures) >= 4 and all(isinstance(kind, FailureKind) for kind in failures), failures
