"""Stance feedback (model/plant/stance_laws.py) in the three engines: the exact map, the 1 kHz stepper and the
batched engine agree on strides under a sampled law; the energy balance closes; a stepper stride's
recorded torques replayed on the exact map give its apex; the torque limits clip; a torque stream fed
one torque per tick is the law; and a hand-written RK4 of the sampled law, without scipy, agrees.

The ramp path is checked elsewhere, unchanged: test_plant_exact_map, test_plant_stepper, test_plant_batch
and test_plant_perturbed_engines hold it to their reference values."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tdslip_ros.model import units
from tdslip_ros.model.events import EventKind, Phase
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.paper import PAPER_PARAMS as PARAMS
from tdslip_ros.model.params import ApexState, ParameterError
from tdslip_ros.model.plant.batch import batch_feedback_return_map, simulate_strides
from tdslip_ros.model.plant.exact_map import StrideResult, apex_return_map
from tdslip_ros.model.plant.perturbations import Perturbations, StrideConditions
from tdslip_ros.model.plant.stance_laws import RecordedTorques, StanceFeedback, StanceSample, TorqueStream
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.model.policies.stance_pd import StancePDSpeedEnergy

BETA = math.radians(22.0)
LAW = StancePDSpeedEnergy(PARAMS, target_y=1.2, target_xdot=4.0)
FEEDBACK = StanceFeedback(BETA, LAW)
START = ApexState(1.3, 3.5)
ENERGY_SCALE = units.energy_scale(PARAMS)


def assert_same_apex(y: float, xdot: float, apex: ApexState | None, tolerance: float = 1e-9) -> None:
    """Dimensionless height and speed within ``tolerance``."""
    assert apex is not None
    assert units.height_to_bar(PARAMS, y - apex.y) == pytest.approx(0.0, abs=tolerance)
    assert units.speed_to_bar(PARAMS, xdot - apex.xdot) == pytest.approx(0.0, abs=tolerance)


@dataclasses.dataclass(frozen=True)
class SteppedStride:
    """One stride of the stepper: its apex (and time), the next apex (and time), touchdown and liftoff
    times, the recorded torques and the stance's (time, theta) at each tick end and at its events."""

    apex: ApexState
    apex_time: float
    next_apex: ApexState
    next_apex_time: float
    touchdown: float
    liftoff: float
    torques: tuple[tuple[float, float], ...]
    thetas: tuple[tuple[float, float], ...]
    hip_work: float


def step_stride(stepper: FixedStepStepper) -> SteppedStride:
    """Step from an apex to the next one."""
    apex = stepper.apex_state
    thetas: list[tuple[float, float]] = []
    times: dict[EventKind, float] = {}
    while True:
        events = stepper.step()
        assert stepper.failed is None
        for event in events:
            times[event.kind] = event.t
            if event.kind in (EventKind.TOUCHDOWN, EventKind.LIFTOFF):
                thetas.append((event.t, event.state.theta))
            if event.kind is EventKind.APEX:
                energy = stepper.last_stride_energy
                assert energy is not None
                return SteppedStride(
                    ApexState(apex.y, apex.xdot),
                    apex.t,
                    ApexState(event.state.y, event.state.xdot),
                    event.t,
                    times[EventKind.TOUCHDOWN],
                    times[EventKind.LIFTOFF],
                    stepper.stance_torques,
                    tuple(sorted(thetas)),
                    energy.hip_work,
                )
        state = stepper.state
        if state.phase is Phase.STANCE:
            thetas.append((state.t, state.theta))


def test_exact_map_stepper_and_batch_agree_on_strides_under_the_law() -> None:
    stepper = FixedStepStepper(PARAMS, START, FEEDBACK)
    for _ in range(4):
        stride = step_stride(stepper)
        exact = apex_return_map(
            PARAMS, stride.apex, FEEDBACK, apex_time=stride.apex_time, rtol=1e-13, atol=1e-13
        )
        assert exact.apex is not None and exact.apex_time is not None and exact.liftoff is not None
        assert_same_apex(stride.next_apex.y, stride.next_apex.xdot, exact.apex)
        assert stride.next_apex_time == pytest.approx(stride.apex_time + exact.apex_time, abs=1e-9)
        assert stride.liftoff == pytest.approx(stride.apex_time + exact.liftoff.t, abs=1e-9)
        # The same sample grid: the first sample is the first tick boundary after touchdown.
        assert [t for t, _ in stride.torques] == [t for t, _ in exact.stance_torques]
        assert stride.touchdown < stride.torques[0][0] <= stride.touchdown + 1e-3
        held = np.array([[a[1], b[1]] for a, b in zip(stride.torques, exact.stance_torques, strict=True)])
        assert held[:, 0] == pytest.approx(held[:, 1], abs=1e-6)

        batch = batch_feedback_return_map(
            PARAMS, stride.apex.y, stride.apex.xdot, BETA, LAW, apex_time=stride.apex_time
        )
        assert_same_apex(float(batch.y), float(batch.xdot), exact.apex)
        assert float(batch.stride_time) == pytest.approx(exact.apex_time, abs=1e-9)
        assert exact.energy is not None
        assert float(batch.hip_work) == pytest.approx(exact.energy.hip_work, abs=1e-9 * ENERGY_SCALE)


def test_the_apex_time_puts_the_stride_on_the_grid() -> None:
    """The same apex at another phase of the tick is another stride: the grid is absolute time."""
    strides = [apex_return_map(PARAMS, START, FEEDBACK, apex_time=t) for t in (0.0, 0.0004)]
    first_samples = [stride.stance_torques[0][0] for stride in strides]
    touchdowns = [t + stride.touchdown.t for t, stride in zip((0.0, 0.0004), strides, strict=True)]
    for sample, touchdown in zip(first_samples, touchdowns, strict=True):
        assert sample == pytest.approx(round(sample / 1e-3) * 1e-3, abs=1e-15)
        assert touchdown < sample <= touchdown + 1e-3
    apexes = [stride.apex for stride in strides]
    assert apexes[0] is not None and apexes[1] is not None
    assert abs(apexes[0].y - apexes[1].y) > 1e-6  # the phase changes the stride


def energy_change(stride: StrideResult, apex: ApexState) -> float:
    assert stride.apex is not None
    return stride.apex.energy(PARAMS) - apex.energy(PARAMS)


def test_the_energy_balance_closes() -> None:
    """Hip work (the integral of tau thetadot) less the damper's and the spring's losses is the apex
    energy change, in the exact map and the batch; the hip work is also sum_n tau_n (theta_{n+1} - theta_n)
    over the stepper's held torques, from its thetas at the sample instants."""
    apex, t = START, 0.0
    stepper = FixedStepStepper(PARAMS, START, FEEDBACK)
    for _ in range(3):
        exact = apex_return_map(PARAMS, apex, FEEDBACK, apex_time=t, rtol=1e-13, atol=1e-13)
        assert exact.energy is not None and exact.apex is not None and exact.apex_time is not None
        scale = apex.energy(PARAMS)
        assert exact.energy.net_gain == pytest.approx(energy_change(exact, apex), abs=1e-9 * scale)
        assert exact.energy.hip_work != 0.0
        batch = batch_feedback_return_map(PARAMS, apex.y, apex.xdot, BETA, LAW, apex_time=t)
        gain = float(batch.hip_work - batch.damping_loss - batch.spring_loss)
        batch_change = PARAMS.m * (PARAMS.g * (batch.y - apex.y) + 0.5 * (batch.xdot**2 - apex.xdot**2))
        assert gain == pytest.approx(float(batch_change), abs=1e-9 * scale)

        stride = step_stride(stepper)
        thetas = dict(stride.thetas)
        held = [(stride.touchdown, 0.0), *stride.torques]
        ends = [t for t, _ in stride.torques] + [stride.liftoff]
        work = sum(tau * (thetas[end] - thetas[start]) for (start, tau), end in zip(held, ends, strict=True))
        assert work == pytest.approx(stride.hip_work, abs=1e-9 * scale)
        assert work == pytest.approx(exact.energy.hip_work, abs=1e-9 * scale)
        apex, t = exact.apex, t + exact.apex_time


def test_replaying_a_stepper_strides_recorded_torques_on_the_exact_map_gives_its_apex() -> None:
    stepper = FixedStepStepper(PARAMS, START, FEEDBACK)
    step_stride(stepper)
    stride = step_stride(stepper)  # a stride whose apex is off the grid
    times, torques = (np.array(column) for column in zip(*stride.torques, strict=True))
    for clock in (times, np.round(times * 1e9) * 1e-9):  # as recorded, and on a nanosecond clock
        replay = StanceFeedback(BETA, RecordedTorques(clock, torques))
        exact = apex_return_map(
            PARAMS, stride.apex, replay, apex_time=stride.apex_time, rtol=1e-13, atol=1e-13
        )
        assert_same_apex(stride.next_apex.y, stride.next_apex.xdot, exact.apex)
        assert [tau for _, tau in exact.stance_torques] == list(torques)
    # The recording is what was applied: another recording gives another stride.
    other = StanceFeedback(BETA, RecordedTorques(times, torques * 1.01))
    moved = apex_return_map(PARAMS, stride.apex, other, apex_time=stride.apex_time).apex
    assert moved is not None and abs(moved.y - stride.next_apex.y) > 1e-4


def test_the_torque_limits_clip_the_law_in_every_engine() -> None:
    tau_max = 150.0
    exact = apex_return_map(
        PARAMS, START, FEEDBACK, rtol=1e-13, atol=1e-13, conditions=StrideConditions(tau_max=tau_max)
    )
    held = np.array([tau for _, tau in exact.stance_torques])
    assert np.all(np.abs(held) <= tau_max) and np.any(held == -tau_max)
    stepper = FixedStepStepper(PARAMS, START, FEEDBACK, perturbations=Perturbations(tau_max=tau_max))
    stride = step_stride(stepper)
    assert stepper.saturated_strides == 1
    assert [tau for _, tau in stride.torques] == pytest.approx(list(held), abs=1e-6)
    assert_same_apex(stride.next_apex.y, stride.next_apex.xdot, exact.apex)
    batch = batch_feedback_return_map(
        PARAMS, START.y, START.xdot, BETA, LAW, conditions=StrideConditions(tau_max=[tau_max, math.inf])
    )
    assert batch.saturated.tolist() == [True, False]
    assert_same_apex(float(batch.y[0]), float(batch.xdot[0]), exact.apex)
    # The plausibility limit max_torque is an actuator limit too for a law (a ramp's tau0 beyond it fails).
    limits = dataclasses.replace(PlausibilityLimits.for_hopper(PARAMS), max_torque=tau_max)
    limited = apex_return_map(PARAMS, START, FEEDBACK, limits=limits, rtol=1e-13, atol=1e-13)
    assert limited.apex == exact.apex and limited.stance_torques == exact.stance_torques
    run = simulate_strides(PARAMS, START.y, START.xdot, lambda k, y, xdot: (BETA, LAW), 1, limits=limits)
    assert not run.saturated[0]  # saturation counts tau_max, the perturbation
    assert_same_apex(float(run.y[1]), float(run.xdot[1]), exact.apex)


def test_a_torque_stream_fed_each_tick_is_the_law() -> None:
    """A controller outside the stepper, as the plant node's would be: after each tick it reads the state
    and holds its law's torque for the next tick (hold_torque) at each tick whose torque is due
    (torque_due: every tick in stance). The stepper runs exactly the law."""
    inside = FixedStepStepper(PARAMS, START, FEEDBACK)
    outside = FixedStepStepper(PARAMS, START, StanceFeedback(BETA, TorqueStream()))
    touchdown = 0.0
    for _ in range(3000):
        expected, events = inside.step(), outside.step()
        assert [(e.kind, e.t, e.state) for e in events] == [(e.kind, e.t, e.state) for e in expected]
        touchdown = next((e.t for e in events if e.kind is EventKind.TOUCHDOWN), touchdown)
        state = outside.state
        assert outside.torque_due == (state.phase is Phase.STANCE) and not inside.torque_due
        if state.phase is Phase.STANCE:
            seen = StanceSample(
                outside.t,
                outside.t - touchdown,
                state.r,
                state.theta,
                state.rdot,
                state.thetadot,
                state.hip_torque,
            )
            outside.hold_torque(LAW.torque(seen))
        if outside.stride == 3:
            break
    assert outside.stride == 3 and outside.stance_torques == inside.stance_torques
    with pytest.raises(ParameterError, match="finite"):
        outside.hold_torque(math.nan)


def test_the_law_holds_the_paper_hopper_near_its_target() -> None:
    """50 strides from four apexes: within 2 % of the target height and 1 % of the target speed, as the
    module's docstring says of the defaults at 22 deg."""
    y0, xdot0 = np.array([1.3, 1.1, 1.2, 1.4]), np.array([3.5, 4.5, 4.0, 3.0])
    run = simulate_strides(PARAMS, y0, xdot0, lambda k, y, xdot: (BETA, LAW), 50)
    assert np.all(run.failure == -1)
    assert np.abs(run.y[-1] / 1.2 - 1.0).max() < 0.02
    assert np.abs(run.xdot[-1] / 4.0 - 1.0).max() < 0.01
    assert np.abs(run.y[-1] - run.y[-2]).max() < 1e-4  # settled, within the sampling's jitter
    assert np.all(np.diff(run.t, axis=0) > 0.0)


def test_per_lane_targets_and_bad_inputs() -> None:
    speeds = np.array([3.5, 4.0, 4.5])
    law = StancePDSpeedEnergy(PARAMS, 1.2, speeds)
    batch = batch_feedback_return_map(PARAMS, 1.2, speeds, BETA, law)
    for lane, speed in enumerate(speeds):
        exact = apex_return_map(
            PARAMS, ApexState(1.2, speed), StanceFeedback(BETA, StancePDSpeedEnergy(PARAMS, 1.2, speed))
        )
        assert_same_apex(float(batch.y[lane]), float(batch.xdot[lane]), exact.apex)
    with pytest.raises(ParameterError, match="batched engine"):
        apex_return_map(PARAMS, START, StanceFeedback(BETA, law))
    with pytest.raises(ParameterError, match="torque stream"):
        apex_return_map(PARAMS, START, StanceFeedback(BETA, TorqueStream()))
    with pytest.raises(ParameterError, match="torque stream"):
        batch_feedback_return_map(PARAMS, 1.2, 4.0, BETA, TorqueStream())
    with pytest.raises(ParameterError, match="tick"):
        FixedStepStepper(PARAMS, START, StanceFeedback(BETA, LAW, sample_period=2e-3))
    with pytest.raises(ParameterError, match="apex_time"):
        batch_feedback_return_map(PARAMS, 1.2, 4.0, BETA, LAW, apex_time=[0.0, math.nan])
    for apex_time in (math.nan, math.inf):  # before: the exact map integrated to a NaN time for ever
        with pytest.raises(ParameterError, match="apex_time must be finite"):
            apex_return_map(PARAMS, START, StanceFeedback(BETA, LAW), apex_time=apex_time)
    with pytest.raises(ParameterError, match="touchdown_angle"):
        StanceFeedback(2.0, LAW)
    with pytest.raises(ParameterError, match="increase"):
        RecordedTorques([0.0, 0.0], [1.0, 2.0])
    with pytest.raises(ParameterError, match="speed_gain"):
        StancePDSpeedEnergy(PARAMS, 1.2, 4.0, speed_gain=math.inf)


# --- a scipy-free check: RK4 written here, with the law written again from its docstring -------------------


def derivative(tau: float, r: float, theta: float, rdot: float, thetadot: float) -> tuple[float, ...]:
    """Eq. 2 (params.py's convention): m rddot = m r thetadot^2 - m g cos - k (r - r0) - c rdot,
    m r^2 thetaddot + 2 m r rdot thetadot = m g r sin + tau."""
    m, k, c, g, r0 = PARAMS.m, PARAMS.k, PARAMS.c, PARAMS.g, PARAMS.r0
    rddot = r * thetadot**2 - g * math.cos(theta) - (k * (r - r0) + c * rdot) / m
    thetaddot = (g * r * math.sin(theta) + tau / m - 2.0 * r * rdot * thetadot) / (r * r)
    return rdot, thetadot, rddot, thetaddot


def rk4(tau: float, y: tuple[float, ...], h: float) -> tuple[float, ...]:
    k1 = derivative(tau, *y)
    k2 = derivative(tau, *(a + 0.5 * h * b for a, b in zip(y, k1, strict=True)))
    k3 = derivative(tau, *(a + 0.5 * h * b for a, b in zip(y, k2, strict=True)))
    k4 = derivative(tau, *(a + h * b for a, b in zip(y, k3, strict=True)))
    return tuple(
        a + h / 6.0 * (p + 2.0 * q + 2.0 * u + v) for a, p, q, u, v in zip(y, k1, k2, k3, k4, strict=True)
    )


def law_by_hand(y: tuple[float, ...], held: float) -> float:
    """k_E (E - E*) + k_p (xdot - xdot*) + k_d F_x / m, with F_x the leg's and the hip's horizontal force."""
    m, k, c, g, r0 = PARAMS.m, PARAMS.k, PARAMS.c, PARAMS.g, PARAMS.r0
    r, theta, rdot, thetadot = y
    energy = 0.5 * m * (rdot**2 + (r * thetadot) ** 2) + m * g * r * math.cos(theta) + 0.5 * k * (r - r0) ** 2
    xdot = -rdot * math.sin(theta) - r * thetadot * math.cos(theta)
    leg = k * (r0 - r) - c * rdot
    force_x = -leg * math.sin(theta) - held / r * math.cos(theta)
    target = m * (g * LAW.target_y + 0.5 * LAW.target_xdot**2)
    return (
        LAW.energy_gain * (energy - target)
        + LAW.speed_gain * (xdot - LAW.target_xdot)
        + LAW.speed_rate_gain * force_x / m
    )


def test_a_hand_written_rk4_of_the_sampled_law_agrees_with_the_exact_map() -> None:
    period, substeps = 1e-3, 50
    apex_time = 0.0123
    fall = math.sqrt(2.0 * (START.y - PARAMS.r0 * math.cos(BETA)) / PARAMS.g)
    t_touchdown = apex_time + fall
    ydot = -PARAMS.g * fall
    y = (
        PARAMS.r0,
        BETA,
        -START.xdot * math.sin(BETA) + ydot * math.cos(BETA),
        (-START.xdot * math.cos(BETA) - ydot * math.sin(BETA)) / PARAMS.r0,
    )

    def leg_force(state: tuple[float, ...]) -> float:
        return PARAMS.k * (PARAMS.r0 - state[0]) - PARAMS.c * state[2]

    held, t = 0.0, t_touchdown
    sample = math.ceil(t_touchdown / period) * period
    while True:  # one sample interval per pass, in equal RK4 steps, until the leg force crosses zero
        h = (sample - t) / substeps
        for _ in range(substeps):
            after = rk4(held, y, h)
            if leg_force(after) <= 0.0:  # liftoff inside this step: bisect its length
                low, high = 0.0, h
                for _ in range(60):
                    mid = 0.5 * (low + high)
                    low, high = (mid, high) if leg_force(rk4(held, y, mid)) > 0.0 else (low, mid)
                r, theta, rdot, thetadot = rk4(held, y, high)
                xdot = -rdot * math.sin(theta) - r * thetadot * math.cos(theta)
                ydot_lo = rdot * math.cos(theta) - r * thetadot * math.sin(theta)
                by_hand = ApexState(r * math.cos(theta) + ydot_lo**2 / (2.0 * PARAMS.g), xdot)
                exact = apex_return_map(PARAMS, START, FEEDBACK, apex_time=apex_time, rtol=1e-13, atol=1e-13)
                assert_same_apex(by_hand.y, by_hand.xdot, exact.apex)
                return
            y = after
        t = sample
        sample += period
        held = law_by_hand(y, held)
