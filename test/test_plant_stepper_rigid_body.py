"""The 1 kHz stepper with a rigid body (issue 36): strides against the exact map, the fixed-body limit, the
energy balance with the rotation, tipping, toe stubbing, the perturbations it runs and its refusals.

Independent truth: the exact map (DOP853 at rtol = atol = 1e-13, its own flight and event location) from
each apex the stepper reached, at the stepper's apex time (the sample grid of stance feedback); the
point-mass stepper, whose strides a hip at the centre of mass leaves unchanged whatever the inertia; the
energy balance of the stance, J phidot^2 / 2 included. RK4 at 4 sub-steps per tick meets the exact map to
4e-11 over these strides (apex pitch rate, the largest; 1 sub-step 1e-8, 2: 7e-10, 8: 3e-12) and the energy
balance to 4e-12 of the apex energy, so the tolerances below are the point mass's, 1e-9 and 1e-10.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest
from support.rigid_bodies import (
    BETA,
    PIVOT_BODIES,
    RAMP_BODIES,
    TIPPING,
    hip_regulator,
    ramp_start,
    with_body,
)

from tdslip_ros.model.events import Event, EventKind, FailureKind, HopperState, Phase, StrideEnergy
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody, StanceCommand
from tdslip_ros.model.plant.exact_map import StrideResult, apex_return_map
from tdslip_ros.model.plant.perturbations import (
    Perturbations,
    PlacementNoise,
    Pushes,
    SensingNoise,
    StrideConditions,
)
from tdslip_ros.model.plant.stance_laws import StanceFeedback, StanceSample, TorqueStream
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.model.plant.terrain import Step
from tdslip_ros.model.policies.virtual_pivot import VirtualPivot

LEVEL_TOLERANCE = 1e-9
"""m, m/s, rad, rad/s and s: the stepper's strides against the exact map's (module docstring)."""

Policy = Callable[[ApexState], StanceCommand | StanceFeedback]


def apex_of(state: HopperState) -> ApexState:
    return ApexState(state.y, state.xdot, state.pitch, state.pitch_rate)


def motion(state: HopperState) -> tuple[float, ...]:
    """Time, the centre of mass's position and velocity, the pitch and its rate."""
    return state.t, state.x, state.y, state.xdot, state.ydot, state.pitch, state.pitch_rate


@dataclasses.dataclass
class Stride:
    """One stride of the stepper: its apex and time, its command, its first event of each kind, the flows
    and the stance's held torques."""

    apex: ApexState
    t0: float
    command: StanceCommand | StanceFeedback
    events: dict[EventKind, Event] = dataclasses.field(default_factory=dict)
    energy: StrideEnergy | None = None
    torques: tuple[tuple[float, float], ...] = ()


def run_strides(stepper: FixedStepStepper, strides: int, policy: Policy | None = None) -> list[Stride]:
    """Step to the ``strides``-th apex, answering every apex before it with ``policy``; the strides begun
    (the last one holds the failure, if any)."""
    done: list[Stride] = []
    current = Stride(apex_of(stepper.apex_state), 0.0, stepper.command)
    for _ in range(20_000):
        if stepper.stride >= strides or stepper.failed is not None:
            break
        tick_start = stepper.t
        for event in stepper.step():
            assert tick_start <= event.t <= tick_start + 1e-3 + 1e-15
            current.events.setdefault(event.kind, event)
            if event.kind is EventKind.APEX:
                current.energy, current.torques = stepper.last_stride_energy, stepper.stance_torques
                done.append(current)
                if policy is not None and stepper.stride < strides:
                    stepper.set_command(policy(apex_of(event.state)))
                current = Stride(apex_of(event.state), event.t, stepper.command)
    return [*done, current] if current.events else done


def assert_stride_is_the_exact_maps(stride: Stride, exact: StrideResult) -> None:
    assert exact.failure is None, exact.reason
    assert exact.apex is not None and exact.apex_time is not None
    assert exact.touchdown is not None and exact.bottom is not None and exact.liftoff is not None
    reached = stride.events[EventKind.APEX].state
    stepped = (reached.y, reached.xdot, reached.pitch, reached.pitch_rate)
    expected = (exact.apex.y, exact.apex.xdot, exact.apex.pitch, exact.apex.pitch_rate)
    assert stepped == pytest.approx(expected, abs=LEVEL_TOLERANCE)
    times = [stride.events[kind].t - stride.t0 for kind in (EventKind.TOUCHDOWN, EventKind.BOTTOM)]
    times += [stride.events[kind].t - stride.t0 for kind in (EventKind.LIFTOFF, EventKind.APEX)]
    exact_times = [exact.touchdown.t, exact.bottom.t, exact.liftoff.t, exact.apex_time]
    assert times == pytest.approx(exact_times, abs=LEVEL_TOLERANCE)


def ramp_run(name: str) -> tuple[HopperParams, list[Stride]]:
    body, count = RAMP_BODIES[name]
    params = with_body(body)
    policy = hip_regulator(params)
    start = ramp_start(body)
    strides = run_strides(FixedStepStepper(params, start, policy(start)), count, policy)
    assert len(strides) == count and all(EventKind.FAILURE not in stride.events for stride in strides)
    return params, strides


@pytest.mark.parametrize("name", RAMP_BODIES)
def test_ramp_strides_are_the_exact_maps(name: str) -> None:
    params, strides = ramp_run(name)
    for stride in strides:
        exact = apex_return_map(params, stride.apex, stride.command, rtol=1e-13, atol=1e-13)
        assert_stride_is_the_exact_maps(stride, exact)
        kinds = [event.kind for event in stride.events.values()]
        assert kinds == [EventKind.TOUCHDOWN, EventKind.BOTTOM, EventKind.LIFTOFF, EventKind.APEX]
    # The bodies turn: the strides test the pitch, not a body held still.
    assert max(abs(stride.apex.pitch_rate - strides[0].apex.pitch_rate) for stride in strides) > 0.1


@pytest.mark.parametrize("name", PIVOT_BODIES)
def test_strides_under_the_virtual_pivot_are_the_exact_maps(name: str) -> None:
    """Stance feedback: the law samples the 8-value state (its pitch and rate) at the tick boundaries; the
    exact map, put on the same grid by the stepper's apex time, samples at the same instants."""
    body = PIVOT_BODIES[name]
    params = with_body(body)
    command = StanceFeedback(BETA, VirtualPivot(params, above=0.3, forward=0.03))
    strides = run_strides(FixedStepStepper(params, ApexState(1.0 - body.hip_y, 5.0, 0.05, -0.2), command), 4)
    assert len(strides) == 4 and all(EventKind.FAILURE not in stride.events for stride in strides)
    for stride in strides:
        exact = apex_return_map(params, stride.apex, command, rtol=1e-13, atol=1e-13, apex_time=stride.t0)
        assert_stride_is_the_exact_maps(stride, exact)
        assert [t for t, _ in stride.torques] == [t for t, _ in exact.stance_torques]
        held = np.array([[a[1], b[1]] for a, b in zip(stride.torques, exact.stance_torques, strict=True)])
        assert held[:, 0] == pytest.approx(held[:, 1], abs=1e-6)
        assert np.ptp(held[:, 0]) > 10.0  # the law acts
        touchdown = stride.events[EventKind.TOUCHDOWN].t
        assert touchdown < stride.torques[0][0] <= touchdown + 1e-3


def test_a_torque_stream_of_the_laws_torques_is_the_law() -> None:
    """The plant node's path: a TorqueStream fed, before each tick that needs one, the law's torque of the
    state the stepper shows (its pitch and rate) runs the law's strides exactly."""
    body = PIVOT_BODIES["below"]
    params = with_body(body)
    law = VirtualPivot(params, above=0.3, forward=0.03)
    start = ApexState(1.2, 5.0, 0.05, -0.2)
    by_law = FixedStepStepper(params, start, StanceFeedback(BETA, law))
    streamed = FixedStepStepper(params, start, StanceFeedback(BETA, TorqueStream()))
    held, touchdown, fed = 0.0, 0.0, 0
    while by_law.stride < 2:
        if streamed.torque_due:
            state = streamed.state
            seen = StanceSample(
                state.t, state.t - touchdown, state.r, state.theta, state.rdot, state.thetadot, held,
                state.pitch, state.pitch_rate,
            )  # fmt: skip
            held = float(law.torque(seen))
            streamed.hold_torque(held)
            fed += 1
        events = streamed.step()
        assert by_law.step() == events
        assert by_law.state == streamed.state
        touchdown = next((event.t for event in events if event.kind is EventKind.TOUCHDOWN), touchdown)
    assert fed > 100 and by_law.stance_torques == streamed.stance_torques


@pytest.mark.parametrize(("inertia", "count"), [(2.0, 2), (7.2, 4), (1e6, 4)])
def test_a_hip_at_the_centre_of_mass_hops_the_point_masss_strides(inertia: float, count: int) -> None:
    """d = 0: the centre of mass moves as the point mass does for any inertia; the body only spins, by
    J dphidot = -int(tau) per stance. It starts spinning backwards so that it turns back and forth over
    ``count`` strides (a light body turns fast)."""
    command = StanceCommand(BETA, -150.0, 0.15)
    spin = -command.tau0 * command.t_f / 2.0 / inertia
    point = run_strides(FixedStepStepper(PAPER_PARAMS, ApexState(1.25, 4.0), command), count)
    body = with_body(RigidBody(inertia, tip_limit=math.pi))
    start = ApexState(1.25, 4.0, 0.1, -spin * count / 2.0)
    rigid = run_strides(FixedStepStepper(body, start, command), count)
    assert len(point) == len(rigid) == count
    for fixed, turning in zip(point, rigid, strict=True):
        for kind in (EventKind.TOUCHDOWN, EventKind.BOTTOM, EventKind.LIFTOFF, EventKind.APEX):
            assert motion(turning.events[kind].state)[:5] == pytest.approx(
                motion(fixed.events[kind].state)[:5], abs=LEVEL_TOLERANCE
            )
    reached = rigid[-1].events[EventKind.APEX].state.pitch_rate
    assert reached == pytest.approx(start.pitch_rate + count * spin, abs=LEVEL_TOLERANCE)


@pytest.mark.parametrize("name", ["behind_and_below_J7", "ahead_and_above_J100", "far_below_J1000"])
def test_the_energy_balance_closes_with_the_rotation(name: str) -> None:
    """Hip work (int tau (thetadot - phidot)) minus damper loss is the stance's change of the total energy,
    J phidot^2 / 2 included; less the spring's loss at liftoff, the apexes' change."""
    params, strides = ramp_run(name)
    for stride in strides:
        flows = stride.energy
        assert flows is not None and flows.hip_work != 0.0 and flows.damping_loss > 0.0
        scale = stride.apex.energy(params)
        touchdown, liftoff = stride.events[EventKind.TOUCHDOWN].state, stride.events[EventKind.LIFTOFF].state
        assert liftoff.energy - touchdown.energy == pytest.approx(
            flows.hip_work - flows.damping_loss, abs=1e-10 * scale
        )
        reached = stride.events[EventKind.APEX].state.energy
        assert reached - scale == pytest.approx(flows.net_gain, abs=1e-10 * scale)
        rotation = 0.5 * params.body.inertia * (liftoff.pitch_rate**2 - touchdown.pitch_rate**2)
        assert abs(rotation) > 1e-3 * abs(flows.hip_work)  # the rotation's share is not negligible


@pytest.mark.parametrize("name", TIPPING)
def test_tipping_is_the_exact_maps_failure_at_the_limit(name: str) -> None:
    body, apex, tau0, phrase, max_apex_height = TIPPING[name]
    params = with_body(body)
    limits = PlausibilityLimits.for_hopper(params)
    if max_apex_height is not None:
        limits = dataclasses.replace(limits, max_apex_height=max_apex_height)
    command = StanceCommand(math.radians(22.0), tau0, 0.15)
    stepper = FixedStepStepper(params, apex, command, limits=limits)
    events = [event for stride in run_strides(stepper, 1) for event in stride.events.values()]
    exact = apex_return_map(params, apex, command, rtol=1e-13, atol=1e-13, limits=limits)
    assert exact.failure is FailureKind.TIPPED and phrase in exact.reason
    failure = events[-1]
    assert stepper.failed is FailureKind.TIPPED and failure.failure is FailureKind.TIPPED
    assert failure.reason == exact.reason
    state, expected = failure.state, exact.failure_state
    assert expected is not None
    assert abs(state.pitch) == pytest.approx(body.tip_limit, abs=1e-12)
    assert state.phase is expected.phase
    assert motion(state) == pytest.approx(motion(expected), abs=LEVEL_TOLERANCE)
    assert stepper.state == state
    with pytest.raises(RuntimeError, match="tipped"):
        stepper.step()


def test_the_hip_decides_toe_stubbing_as_in_the_exact_map() -> None:
    """The leg hangs from the hip: a hip below the touchdown height stubs the toe though the centre of mass
    is above it, and a hip above lets the leg land though the centre of mass is below."""
    command = StanceCommand(BETA, -150.0, 0.15)
    y_td = PAPER_PARAMS.r0 * math.cos(BETA)
    low_hip = with_body(RigidBody(20.0, hip_y=-0.2))
    apex = ApexState(y_td + 0.1, 4.0, 0.1)
    stepper = FixedStepStepper(low_hip, apex, command)
    exact = apex_return_map(low_hip, apex, command)
    assert exact.failure is FailureKind.TOE_STUBBING
    [failure] = stepper.step()
    assert (failure.failure, failure.reason, failure.t) == (exact.failure, exact.reason, 0.0)
    assert failure.state.pitch == 0.1

    high_hip = with_body(RigidBody(20.0, hip_y=0.2))
    apex = ApexState(y_td - 0.05, 4.0)
    [stride] = run_strides(FixedStepStepper(high_hip, apex, command), 1)
    assert_stride_is_the_exact_maps(stride, apex_return_map(high_hip, apex, command, rtol=1e-13, atol=1e-13))


def test_toe_stubbing_after_an_apex_is_declared_at_the_next_tick() -> None:
    """The command in force at an apex whose hip is too low for it stubs the toe at the first tick after
    the apex, as for the point mass; the exact map from that apex says so too."""
    params = with_body(RigidBody(20.0, hip_y=-0.2))
    command = StanceCommand(math.radians(12.0), 0.0, 0.15)  # a leg steep for the apex that comes
    stepper = FixedStepStepper(params, ApexState(1.25, 4.0), command)
    strides = run_strides(stepper, 2)
    apex, failure = strides[0].events[EventKind.APEX], strides[1].events[EventKind.FAILURE]
    exact = apex_return_map(params, apex_of(apex.state), command)
    assert failure.failure is exact.failure is FailureKind.TOE_STUBBING
    assert failure.reason == exact.reason
    assert failure.t == pytest.approx(math.ceil(apex.t / 1e-3) * 1e-3, abs=1e-15)
    assert failure.state.phase is Phase.FLIGHT and failure.state.ydot < 0.0


def test_perturbations_it_runs_are_the_exact_maps() -> None:
    """Saturation, pushes and placement errors: each stride is the exact map's under the same conditions
    (the placement error is the draw the stepper took at that apex)."""
    body, _ = RAMP_BODIES["below_J100"]
    params = with_body(body)
    policy = hip_regulator(params)
    perturbations = Perturbations(
        tau_max=450.0, pushes=Pushes(((1, 0.4), (2, -0.3))), placement=PlacementNoise(0.02, seed=3)
    )
    start = ApexState(1.3, 4.0, 0.05, -0.3)
    stepper = FixedStepStepper(params, start, policy(start), perturbations=perturbations)
    strides = run_strides(stepper, 4, policy)
    assert len(strides) == 4 and stepper.saturated_strides >= 2
    for k, stride in enumerate(strides):
        draws = perturbations.draws([0], k, 1)
        conditions = StrideConditions(
            tau_max=450.0, push=float(draws.push[0, 0]), angle_error=float(draws.angle_error[0, 0])
        )
        exact = apex_return_map(
            params, stride.apex, stride.command, rtol=1e-13, atol=1e-13, conditions=conditions
        )
        assert_stride_is_the_exact_maps(stride, exact)
        assert stride.events[EventKind.TOUCHDOWN].state.theta == exact.touchdown.theta != BETA


def test_set_command_judges_the_leg_from_the_hip() -> None:
    params = with_body(RigidBody(20.0, hip_y=-0.2))
    command, steeper = (
        StanceCommand(math.radians(30.0), -150.0, 0.15),
        StanceCommand(math.radians(28.0), 0.0, 0.1),
    )
    stepper = FixedStepStepper(params, ApexState(1.1, 4.0), command)
    # The centre of mass at 1.1 m would reach a leg at 5 deg (0.996 m) and at 25 deg (0.906 m), its hip at
    # 0.9 m does not.
    for angle in (5.0, 25.0):
        with pytest.raises(ParameterError, match="needs the hip at"):
            stepper.set_command(StanceCommand(math.radians(angle), -150.0, 0.15))
    stepper.set_command(steeper)  # 0.883 m: placeable
    [stride] = run_strides(stepper, 1)
    assert stride.events[EventKind.TOUCHDOWN].state.theta == steeper.touchdown_angle
    # Once the hip has fallen below 0.883 m, the 28 deg leg would already have landed.
    late = FixedStepStepper(params, ApexState(1.1, 4.0), command)
    while late.state.y - 0.2 > PAPER_PARAMS.r0 * math.cos(steeper.touchdown_angle):
        late.step()
    assert late.state.phase is Phase.FLIGHT
    with pytest.raises(ParameterError, match="before the command arrived"):
        late.set_command(steeper)
    assert late.command == command


def test_what_the_stepper_does_not_run_for_a_body_is_refused_by_name() -> None:
    params = with_body(RigidBody(20.0, hip_y=-0.2, tip_limit=1.0))
    apex, command = ApexState(1.3, 4.0), StanceCommand(BETA, -150.0, 0.15)
    with pytest.raises(ParameterError, match="flat ground.*step terrain"):
        FixedStepStepper(params, apex, command, perturbations=Perturbations(terrain=Step(0.5, 0.05)))
    with pytest.raises(ParameterError, match="apex noise"):
        FixedStepStepper(params, apex, command, perturbations=Perturbations(sensing=SensingNoise(0.01)))
    with pytest.raises(ParameterError, match="tip_limit"):
        FixedStepStepper(params, ApexState(1.3, 4.0, -1.0), command)
    with pytest.raises(ParameterError, match="body is fixed"):
        FixedStepStepper(PAPER_PARAMS, ApexState(1.3, 4.0, 0.0, 0.1), command)
    # An inertia whose spin and hip motion a 0.25 ms sub-step cannot follow.
    with pytest.raises(ParameterError, match="cannot resolve"):
        FixedStepStepper(with_body(RigidBody(1e-4, hip_y=-0.2)), apex, command)
    with pytest.raises(ParameterError, match="cannot resolve"):
        FixedStepStepper(with_body(RigidBody(20.0)), ApexState(1.3, 4.0, 0.0, 5e3), command)
