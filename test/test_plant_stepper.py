"""The 1 kHz stepper against the high-accuracy return map, energy invariants, event timing, commands
and failures."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
from support.failure_cases import FAILURE_CASES

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.events import Event, EventKind, FailureKind, Phase
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stance_models import unrolled_rk4
from tdslip_ros.model.plant.stepper import FixedStepStepper

PARAMS = PAPER_PARAMS
BETA = math.radians(20.0)
TARGET_ENERGY = ApexState(1.2, 4.0).energy(PARAMS)


def energy_policy(apex: ApexState) -> StanceCommand:
    """A proportional energy regulator at beta = 20 deg; it converges, so errors do not grow."""
    return StanceCommand(BETA, -610.8 + 3.0 * (apex.energy(PARAMS) - TARGET_ENERGY), 0.15)


def run(
    stepper: FixedStepStepper,
    strides: int,
    policy: Callable[[ApexState], StanceCommand] | None = None,
    max_ticks: int = 100_000,
) -> list[Event]:
    """Step until ``strides`` apexes or a failure, answering each apex with ``policy``."""
    events: list[Event] = []
    for _ in range(max_ticks):
        if stepper.stride >= strides or stepper.failed is not None:
            break
        tick_start = stepper.t
        new = stepper.step()
        for event in new:
            assert tick_start <= event.t <= tick_start + 1e-3 + 1e-15
            if event.kind is EventKind.APEX and policy is not None:
                stepper.set_command(policy(ApexState(event.state.y, event.state.xdot)))
        events += new
    return events


def of_kind(events: list[Event], kind: EventKind) -> list[Event]:
    return [event for event in events if event.kind is kind]


def test_stepper_matches_high_accuracy_solve_over_20_strides() -> None:
    start = ApexState(1.25, 3.8)
    stepper = FixedStepStepper(PARAMS, start, energy_policy(start))
    events = run(stepper, 20, energy_policy)
    assert stepper.failed is None

    apex, t0 = start, 0.0
    for k in range(20):
        exact = apex_return_map(PARAMS, apex, energy_policy(apex), rtol=1e-13, atol=1e-13)
        assert exact.apex is not None and exact.apex_time is not None
        assert exact.touchdown is not None and exact.bottom is not None and exact.liftoff is not None
        expected_times = {
            EventKind.TOUCHDOWN: t0 + exact.touchdown.t,
            EventKind.BOTTOM: t0 + exact.bottom.t,
            EventKind.LIFTOFF: t0 + exact.liftoff.t,
            EventKind.APEX: t0 + exact.apex_time,
        }
        for kind, expected in expected_times.items():
            assert of_kind(events, kind)[k].t == pytest.approx(expected, abs=1e-9), (k, kind)
        stepped = of_kind(events, EventKind.APEX)[k].state
        assert units.height_to_bar(PARAMS, stepped.y) == pytest.approx(
            units.height_to_bar(PARAMS, exact.apex.y), abs=1e-7
        )
        assert units.speed_to_bar(PARAMS, stepped.xdot) == pytest.approx(
            units.speed_to_bar(PARAMS, exact.apex.xdot), abs=1e-7
        )
        apex, t0 = exact.apex, t0 + exact.apex_time
    # The events of a stride come in order, once each (one bottom per stance here).
    kinds = [event.kind for event in events]
    assert kinds == [EventKind.TOUCHDOWN, EventKind.BOTTOM, EventKind.LIFTOFF, EventKind.APEX] * 20
    assert [event.stride for event in of_kind(events, EventKind.APEX)] == list(range(1, 21))


def test_lossless_apex_energy_is_conserved_over_50_strides() -> None:
    lossless = HopperParams.from_dimensionless(36.0, 0.0)
    start = ApexState.from_height_energy(lossless, 1.0, 2.5 * lossless.m * lossless.g * lossless.r0)
    stepper = FixedStepStepper(lossless, start, StanceCommand(BETA, 0.0, 0.1))
    apexes = of_kind(run(stepper, 50), EventKind.APEX)
    assert len(apexes) == 50
    energy0 = start.energy(lossless)
    assert max(abs(event.state.energy - energy0) for event in apexes) <= 1e-9 * energy0


def test_energy_balance_per_stride() -> None:
    start = ApexState(1.25, 3.8)
    stepper = FixedStepStepper(PARAMS, start, energy_policy(start))
    assert stepper.last_stride_energy is None
    previous = start.energy(PARAMS)
    for _ in range(8):
        apex = of_kind(run(stepper, stepper.stride + 1, energy_policy), EventKind.APEX)[-1]
        flows = stepper.last_stride_energy
        assert flows is not None and flows.hip_work > 0.0 and flows.damping_loss > 0.0
        assert abs(apex.state.energy - previous - flows.net_gain) <= 1e-8 * previous
        previous = apex.state.energy


def test_states_follow_the_physics_between_ticks() -> None:
    start = ApexState(1.2, 4.0)
    stepper = FixedStepStepper(PARAMS, start, StanceCommand(BETA, -610.8, 0.15), x0=2.0)
    first = stepper.state
    assert (first.t, first.x, first.y, first.xdot, first.ydot, first.stride) == (0.0, 2.0, 1.2, 4.0, 0.0, 0)
    dt = 1e-3
    flight_ticks, stance_ticks = 0, 0
    for _ in range(700):
        before = stepper.state
        events = stepper.step()
        after = stepper.state
        assert after.t == pytest.approx(before.t + dt, abs=1e-15)
        if after.phase is Phase.STANCE:
            stance_ticks += 1
            assert after.toe_y == 0.0
            assert after.x == pytest.approx(after.toe_x - after.r * math.sin(after.theta), abs=1e-15)
            assert after.grf_y > 0.0 and after.hip_torque <= 0.0
        elif not events:
            flight_ticks += 1
            # Flight: ballistic, no ground force, the leg held at the commanded angle.
            assert (after.grf_x, after.grf_y, after.hip_torque) == (0.0, 0.0, 0.0)
            assert after.xdot == before.xdot
            assert after.ydot - before.ydot == pytest.approx(-PARAMS.g * dt, abs=1e-12)
            assert after.theta == BETA
            assert after.toe_y == pytest.approx(after.y - PARAMS.r0 * math.cos(BETA), abs=1e-15)
    assert flight_ticks > 300 and stance_ticks > 100


def test_events_fall_inside_ticks_not_on_them() -> None:
    start = ApexState(1.2, 4.0)
    stepper = FixedStepStepper(PARAMS, start, StanceCommand(BETA, -610.8, 0.15))
    events = run(stepper, 3)
    ticks = [event.t / 1e-3 for event in events]
    assert all(abs(tick - round(tick)) > 1e-6 for tick in ticks)
    touchdown = of_kind(events, EventKind.TOUCHDOWN)[0]
    assert touchdown.state.y == pytest.approx(PARAMS.r0 * math.cos(BETA), abs=1e-14)
    liftoff = of_kind(events, EventKind.LIFTOFF)[0]
    assert dynamics.leg_force(PARAMS, liftoff.state.r, liftoff.state.rdot) == pytest.approx(0.0, abs=1e-7)
    bottom = of_kind(events, EventKind.BOTTOM)[0]
    assert bottom.state.rdot == pytest.approx(0.0, abs=1e-9)
    apex = of_kind(events, EventKind.APEX)[0]
    assert apex.state.ydot == 0.0


def test_set_command_applies_to_the_next_touchdown_and_rejects_what_cannot_happen() -> None:
    start = ApexState(1.2, 4.0)
    stepper = FixedStepStepper(PARAMS, start, StanceCommand(BETA, -610.8, 0.15))
    new_angle = math.radians(24.0)
    stepper.set_command(StanceCommand(new_angle, -500.0, 0.12))
    touchdown = of_kind(run(stepper, 1), EventKind.TOUCHDOWN)[0]
    assert touchdown.state.theta == new_angle
    assert touchdown.state.hip_torque == -500.0
    # In stance: rejected.
    while stepper.state.phase is Phase.FLIGHT:
        stepper.step()
    with pytest.raises(ParameterError, match="during stance"):
        stepper.set_command(StanceCommand(BETA, -100.0, 0.1))
    # Descending below the new touchdown height: rejected, and the old command stays.
    low = FixedStepStepper(PARAMS, ApexState(0.99, 4.0), StanceCommand(BETA, -610.8, 0.15))
    low.step()
    with pytest.raises(ParameterError, match="reaches at most"):
        low.set_command(StanceCommand(math.radians(5.0), -610.8, 0.15))
    assert low.command.touchdown_angle == BETA


def test_ascending_command_is_judged_by_the_coming_apex() -> None:
    stepper = FixedStepStepper(PARAMS, ApexState(1.0, 5.0), StanceCommand(BETA, -300.0, 0.15))
    while stepper.state.phase is Phase.FLIGHT:
        stepper.step()
    while stepper.state.phase is Phase.STANCE:
        stepper.step()
    state = stepper.state
    coming_apex = state.y + state.ydot**2 / (2 * PARAMS.g)
    reachable, unreachable = math.radians(15.0), math.radians(10.0)
    # Below the reachable command's touchdown height now, but not at the coming apex: accepted.
    assert state.ydot > 0.0 and state.y < PARAMS.r0 * math.cos(reachable) < coming_apex
    stepper.set_command(StanceCommand(reachable, -300.0, 0.15))
    assert coming_apex < PARAMS.r0 * math.cos(unreachable)
    with pytest.raises(ParameterError, match="reaches at most"):
        stepper.set_command(StanceCommand(unreachable, -300.0, 0.15))
    touchdown = of_kind(run(stepper, 2), EventKind.TOUCHDOWN)[0]
    assert touchdown.state.theta == reachable


def test_toe_stubbing_is_declared_at_the_tick_after_the_apex_unless_the_command_changes() -> None:
    # From (1.0 m, 5 m/s) at 15 deg the first stride ends at an apex near 0.93 m, below the
    # touchdown height r0 cos(15 deg) = 0.966 m of the command still in force.
    start, command = ApexState(1.0, 5.0), StanceCommand(math.radians(15.0), -300.0, 0.15)
    stepper = FixedStepStepper(PARAMS, start, command)
    apex = of_kind(run(stepper, 1), EventKind.APEX)[0]
    assert apex.state.y < PARAMS.r0 * math.cos(command.touchdown_angle)
    # Answering the apex with a reachable command: no failure, the next touchdown happens.
    stepper.set_command(StanceCommand(math.radians(25.0), -300.0, 0.15))
    events = run(stepper, 2)
    assert stepper.failed is None and of_kind(events, EventKind.TOUCHDOWN)

    # Leaving the command in force stubs the toe at the start of the tick after the apex.
    stepper = FixedStepStepper(PARAMS, start, command)
    events = run(stepper, 2)
    apex_event, failure = of_kind(events, EventKind.APEX)[0], of_kind(events, EventKind.FAILURE)[0]
    assert failure.failure is FailureKind.TOE_STUBBING and stepper.failed is FailureKind.TOE_STUBBING
    assert failure.t == pytest.approx(math.ceil(apex_event.t / 1e-3) * 1e-3, abs=1e-15)
    assert failure.state.phase is Phase.FLIGHT and failure.state.ydot < 0.0
    assert "below the touchdown height" in failure.reason

    # At the initial apex: at t = 0.
    stubbed = FixedStepStepper(PARAMS, ApexState(0.9, 4.0), StanceCommand(BETA, -300.0, 0.15))
    assert [(event.kind, event.failure, event.t) for event in stubbed.step()] == [
        (EventKind.FAILURE, FailureKind.TOE_STUBBING, 0.0)
    ]


@pytest.mark.parametrize(
    ("params", "apex", "command", "kind"),
    [case[1:5] for case in FAILURE_CASES],
    ids=[case.name for case in FAILURE_CASES],
)
def test_failures_match_the_exact_map_by_name_and_time(
    params: HopperParams, apex: ApexState, command: StanceCommand, kind: FailureKind
) -> None:
    stepper = FixedStepStepper(params, apex, command)
    events = run(stepper, 1, max_ticks=5000)
    failure = of_kind(events, EventKind.FAILURE)
    assert stepper.failed is kind
    assert len(failure) == 1 and events[-1] is failure[0]
    assert failure[0].failure is kind and failure[0].reason
    exact = apex_return_map(params, apex, command)
    assert exact.failure is kind and exact.failure_state is not None
    assert failure[0].reason.split(" ")[0] == exact.reason.split(" ")[0]
    assert failure[0].t == pytest.approx(exact.failure_state.t, abs=1e-8)
    assert stepper.state == failure[0].state
    with pytest.raises(RuntimeError, match=kind.value):
        stepper.step()


def test_bad_stepper_settings_are_refused_by_name() -> None:
    with pytest.raises(ParameterError, match="dt"):
        FixedStepStepper(PARAMS, ApexState(1.2, 4.0), StanceCommand(BETA, 0.0, 0.1), dt=0.0)
    with pytest.raises(ParameterError, match="substeps"):
        FixedStepStepper(PARAMS, ApexState(1.2, 4.0), StanceCommand(BETA, 0.0, 0.1), substeps=0)


@pytest.mark.parametrize(("size", "fed"), [(6, (0, 1, 2, 3)), (8, (0, 1, 2, 3, 6, 7))])
def test_the_written_out_rk4_is_classical_rk4(size: int, fed: tuple[int, ...]) -> None:
    """stance_models writes RK4 out term by term from one template (the point mass's six values and the
    rigid body's eight): it is the loop of classical RK4, bit for bit, the values not fed integrated only."""

    def field(s: float, *values: float) -> tuple[float, ...]:
        mixed = math.sin(s) + sum(math.cos(v * (i + 1)) for i, v in enumerate(values))
        return tuple(mixed * (i + 1) - 0.3 * values[i % len(values)] for i in range(size))

    def loop_rk4(s: float, y: tuple[float, ...], h: float) -> tuple[float, ...]:
        def at(t: float, k: tuple[float, ...], step: float) -> tuple[float, ...]:
            return field(t, *[y[i] + step * k[i] for i in fed])

        half = 0.5 * h
        k1 = field(s, *[y[i] for i in fed])
        k2 = at(s + half, k1, half)
        k3 = at(s + half, k2, half)
        k4 = at(s + h, k3, h)
        return tuple(y[i] + h / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]) for i in range(size))

    step = unrolled_rk4(size, fed)(field)
    for s, h in ((0.0, 2.5e-4), (0.37, 1e-3), (1.2, 3e-7)):
        y = tuple(0.1 * i - 0.25 + s for i in range(size))
        assert step(s, y, h) == loop_rk4(s, y, h)
