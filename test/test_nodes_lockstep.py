"""The plant and controller nodes in a private in-process graph (lockstep unless said otherwise).

Truths the runs are held to: the model itself (the same stepper and policy looped without ROS,
which a lockstep run must reproduce bit for bit), the exact closed-loop fixed point and its
Jacobian from the high-accuracy return map, and the analytic map's fixed point.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
import pytest
from scipy.optimize import root
from support.ros_harness import RosGraph, overrides
from tdslip_msgs.msg import ApexEvent, ContactEvent, StanceCommand, Status
from tdslip_msgs.srv import Reset

from tdslip_ros.model import arrays
from tdslip_ros.model.analytic import closed_loop
from tdslip_ros.model.events import EventKind
from tdslip_ros.model.params import ApexState
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.model.policies import controllers
from tdslip_ros.model.policies.registry import (
    DEFAULT_APEX_HEIGHT,
    DEFAULT_APEX_SPEED,
    DEFAULT_TARGET_ENERGY,
    DEFAULT_TOUCHDOWN_ANGLE,
)
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.parameters import PAPER_PARAMS as PARAMS
from tdslip_ros.nodes.plant_node import TICK_PERIOD, PlantNode
from tdslip_ros.nodes.plant_run import APEX_REPEAT

START = ApexState(DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED)
Policy = Callable[[float, float], ModelCommand]


def energy_policy(y: float, xdot: float) -> ModelCommand:
    """What the controller node computes with its default parameters."""
    return controllers.energy_regulation(
        PARAMS, y, xdot, DEFAULT_TOUCHDOWN_ANGLE, DEFAULT_TARGET_ENERGY
    ).command()


def model_loop(policy: Policy, strides: int, start: ApexState = START) -> list[tuple[float, float, float]]:
    """(t, y, xdot) of apexes 0..strides: the stepper driven by ``policy`` directly, no ROS."""
    stepper = FixedStepStepper(PARAMS, start, policy(start.y, start.xdot), dt=TICK_PERIOD)
    apexes = [(0.0, start.y, start.xdot)]
    while len(apexes) <= strides:
        for event in stepper.step():
            assert event.kind is not EventKind.FAILURE, event.reason
            if event.kind is EventKind.APEX:
                apexes.append((event.t, event.state.y, event.state.xdot))
                stepper.set_command(policy(event.state.y, event.state.xdot))
    return apexes


def run_closed_loop(ros: RosGraph, strides: int, **plant_values: object) -> tuple[PlantNode, list[ApexEvent]]:
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=strides, **plant_values))
    )
    ros.add(ControllerNode(context=ros.context))
    apexes = ros.collect(ApexEvent, topics.APEX)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    ros.spin_until(lambda: len(apexes) == strides + 1, "every apex event")
    return plant, apexes


def exact_closed_loop_next(state: np.ndarray) -> np.ndarray:
    apex = ApexState(float(state[0]), float(state[1]))
    result = apex_return_map(PARAMS, apex, energy_policy(apex.y, apex.xdot))
    assert result.apex is not None, result.reason
    return np.array([result.apex.y, result.apex.xdot])


def test_energy_regulation_converges_to_the_fixed_point_the_model_predicts(ros: RosGraph) -> None:
    strides = 12
    plant, apex_msgs = run_closed_loop(ros, strides)
    assert plant.outcome is not None and plant.outcome.kind == Status.KIND_RUN_COMPLETE
    recorded = [(msg.sim_time, msg.height, msg.forward_speed) for msg in apex_msgs]
    assert [msg.stride for msg in apex_msgs] == list(range(strides + 1))

    # Lockstep is deterministic and the nodes add no physics: the ROS run is the model, bit for bit.
    assert recorded == model_loop(energy_policy, strides)

    # The exact closed-loop fixed point (DOP853 return map, rtol 1e-12) and its Jacobian.
    solution = root(lambda v: exact_closed_loop_next(v) - v, [recorded[-1][1], recorded[-1][2]], tol=1e-13)
    assert solution.success, solution.message
    fixed_point = solution.x
    final = np.array(recorded[-1][1:])
    np.testing.assert_allclose(final, fixed_point, rtol=1e-8)

    step = 1e-6
    jacobian = np.column_stack(
        [
            (exact_closed_loop_next(fixed_point + step * e) - exact_closed_loop_next(fixed_point - step * e))
            / (2 * step)
            for e in np.eye(2)
        ]
    )
    dominant = max(abs(np.linalg.eigvals(jacobian)))
    deviation = np.linalg.norm(np.array([r[1:] for r in recorded]) - fixed_point, axis=1)
    # Once the transient has died out (stride 4 on), each stride shrinks the deviation by |lambda|.
    np.testing.assert_allclose(deviation[4:7] / deviation[3:6], dominant, rtol=5e-3)

    # The analytic map (0 + 1 correction) predicts the same fixed point up to its approximation error.
    def analytic_policy(params: arrays.ParamArrays, y: np.ndarray, xdot: np.ndarray) -> arrays.CommandArrays:
        return controllers.energy_regulation(params, y, xdot, DEFAULT_TOUCHDOWN_ANGLE, DEFAULT_TARGET_ENERGY)

    y, xdot = START.y, START.xdot
    for _ in range(40):
        stride = closed_loop.closed_loop_map(PARAMS, y, xdot, analytic_policy)
        y, xdot = float(stride.y), float(stride.xdot)
    np.testing.assert_allclose(final, [y, xdot], rtol=1e-3)
    predicted = closed_loop.eigenvalues(closed_loop.map_jacobian(PARAMS, y, xdot, analytic_policy))
    assert abs(predicted[0]) < 1.0  # stable, as the run shows


def test_bad_commands_are_rejected_and_the_plant_runs_on(ros: RosGraph) -> None:
    low_start = 0.95  # m: a leg at 0.1 rad needs the body at r0 cos(0.1) = 0.995 m
    plant = ros.add(
        PlantNode(
            context=ros.context,
            start_when_ready=False,
            parameter_overrides=overrides(max_strides=1, initial_height=low_start),
        )
    )
    probe = ros.node("probe")
    commands = probe.create_publisher(StanceCommand, topics.COMMAND, topics.COMMAND_QOS)
    statuses = ros.collect(Status, topics.STATUS, probe)
    touchdowns = ros.collect(ContactEvent, topics.CONTACT, probe)
    ros.spin_until(lambda: plant.count_publishers(topics.COMMAND) >= 1, "the probe's command publisher")
    plant.start()
    good = energy_policy(low_start, START.xdot)

    def command(stride: int = 0, **fields: float) -> StanceCommand:
        values = {"touchdown_angle": good.touchdown_angle, "tau0": good.tau0, "t_f": good.t_f, **fields}
        return StanceCommand(stride=stride, policy="probe", **values)

    bad = [
        (command(stride=3), "stride"),
        (command(tau0=math.nan), "tau0"),
        (command(touchdown_angle=2.0), "touchdown_angle"),
        (command(t_f=-0.1), "t_f"),
        (command(touchdown_angle=0.1), "touchdown_angle"),  # the body cannot reach 0.995 m
    ]
    for msg, _ in bad:
        commands.publish(msg)
    ros.spin_until(lambda: len(statuses) == len(bad), "a status per bad command")
    for status, (_, field) in zip(statuses, bad, strict=True):
        assert (status.kind, status.fatal, status.stride) == (Status.KIND_COMMAND_REJECTED, False, 0)
        assert field in status.reason
    # Nothing was applied: the plant is still at the initial apex, waiting.
    assert plant.published[topics.STATE] == 1 and plant.outcome is None

    commands.publish(command())
    commands.publish(command(touchdown_angle=0.5))  # a second answer to stride 0 in lockstep
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    ros.spin_until(lambda: len(statuses) == len(bad) + 2, "the duplicate's rejection and run_complete")
    assert (
        statuses[-2].kind == Status.KIND_COMMAND_REJECTED and "already has its command" in statuses[-2].reason
    )
    assert plant.outcome.kind == Status.KIND_RUN_COMPLETE
    assert statuses[-1].kind == Status.KIND_RUN_COMPLETE and statuses[-1].fatal
    # The stance used exactly the valid command.
    ros.spin_until(lambda: len(touchdowns) >= 1, "the touchdown event")
    assert touchdowns[0].kind == ContactEvent.TOUCHDOWN
    assert touchdowns[0].state.leg_angle == good.touchdown_angle


def test_an_apex_no_command_answers_is_published_again_for_a_controller_that_missed_it(ros: RosGraph) -> None:
    """A controller whose answer to the first apex was lost (it had not discovered the plant's subscription)
    or that started after it: the lockstep plant publishes the apex it waits on again, the same message, every
    APEX_REPEAT s while no command at all has come, and the run goes on once one answers it. A command that
    came, even a rejected one, stops the repeats: the controller is there."""
    strides = 2
    plant = ros.add(
        PlantNode(
            context=ros.context,
            start_when_ready=False,
            parameter_overrides=overrides(max_strides=strides, command_timeout=30.0),
        )
    )
    probe = ros.node("probe")
    commands = probe.create_publisher(StanceCommand, topics.COMMAND, topics.COMMAND_QOS)
    apexes = ros.collect(ApexEvent, topics.APEX, probe)
    statuses = ros.collect(Status, topics.STATUS, probe)
    ros.spin_until(
        lambda: plant.count_publishers(topics.COMMAND) >= 1 and plant.count_subscribers(topics.APEX) >= 1,
        "the probe",
    )
    plant.start()
    ros.spin_until(lambda: len(apexes) >= 2, "the first apex and a repeat")
    fields = [(a.epoch, a.stride, a.sim_time, a.height, a.forward_speed, a.energy) for a in apexes]
    assert fields == [fields[0]] * len(apexes) and fields[0][:2] == (0, 0)

    def answer(stride: int, **values: float) -> StanceCommand:
        good = energy_policy(apexes[-1].height, apexes[-1].forward_speed)
        fields = {"touchdown_angle": good.touchdown_angle, "tau0": good.tau0, "t_f": good.t_f} | values
        return StanceCommand(stride=stride, policy="probe", **fields)

    commands.publish(answer(0, tau0=math.nan))
    ros.spin_until(lambda: len(statuses) == 1, "the rejection")
    assert statuses[0].kind == Status.KIND_COMMAND_REJECTED
    heard = len(apexes)
    deadline = time.monotonic() + 1.5 * APEX_REPEAT
    ros.spin_until(lambda: time.monotonic() > deadline, "1.5 repeat periods")
    assert len(apexes) == heard  # a command came: no more repeats

    for stride in range(strides):
        commands.publish(answer(stride))
        ros.spin_until(lambda s=stride: apexes[-1].stride > s or plant.outcome is not None, "the next apex")
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome.kind == Status.KIND_RUN_COMPLETE, plant.outcome
    ros.spin_until(lambda: len(apexes) == plant.published[topics.APEX], "every apex published")
    assert sorted({a.stride for a in apexes}) == list(range(strides + 1))


def test_missing_controller_ends_the_run_with_command_timeout(ros: RosGraph) -> None:
    timeout = 0.3
    plant = ros.add(
        PlantNode(
            context=ros.context,
            start_when_ready=False,
            parameter_overrides=overrides(command_timeout=timeout),
        )
    )
    statuses = ros.collect(Status, topics.STATUS)
    ros.spin_until(lambda: plant.count_subscribers(topics.STATUS) >= 1, "the status probe")
    started = time.monotonic()
    plant.start()
    ros.spin_until(lambda: plant.outcome is not None, "the command timeout")
    waited = time.monotonic() - started
    assert plant.outcome.kind == Status.KIND_COMMAND_TIMEOUT
    assert timeout <= waited < timeout + 5.0
    ros.spin_until(lambda: len(statuses) == 1, "the timeout status")
    assert (statuses[0].kind, statuses[0].fatal, statuses[0].stride) == (Status.KIND_COMMAND_TIMEOUT, True, 0)
    assert "stride 0" in statuses[0].reason
    assert plant.published[topics.STATE] == 1  # it never integrated past the initial apex


def test_reset_restarts_the_run_from_the_requested_apex(ros: RosGraph) -> None:
    strides = 2
    plant, apexes = run_closed_loop(ros, strides)
    first_run = [(msg.height, msg.forward_speed) for msg in apexes]
    end_of_first = plant.sim_time
    assert plant.outcome is not None and plant.outcome.sim_time == end_of_first
    client = ros.node("reset_client").create_client(Reset, topics.RESET_SERVICE)

    def reset(height: float, speed: float) -> Reset.Response:
        future = client.call_async(Reset.Request(height=height, forward_speed=speed))
        ros.spin_until(future.done, "the reset response")
        return future.result()

    refused = reset(-1.0, 5.0)
    assert not refused.success and "apex height" in refused.message

    assert reset(START.y, START.xdot).success
    ros.spin_until(lambda: plant.outcome is not None, "the end of the second run")
    ros.spin_until(lambda: len(apexes) == 2 * (strides + 1), "the second run's apexes")
    second_run = apexes[strides + 1 :]
    assert [msg.stride for msg in second_run] == list(range(strides + 1))
    # The same run again (bit for bit), later in simulated time, which never runs backwards.
    assert [(msg.height, msg.forward_speed) for msg in second_run] == first_run
    assert second_run[0].sim_time == pytest.approx(end_of_first, abs=TICK_PERIOD / 2)
    assert plant.outcome.kind == Status.KIND_RUN_COMPLETE
    assert plant.outcome.sim_time == pytest.approx(2 * end_of_first, abs=TICK_PERIOD / 2)


def test_realtime_mode_keeps_simulated_time_with_wall_time(ros: RosGraph) -> None:
    strides = 3
    plant, apex_msgs = run_closed_loop(ros, strides, clock_mode="realtime")
    assert plant.outcome is not None and plant.outcome.kind == Status.KIND_RUN_COMPLETE
    # The run ends at the tick of the last apex, due sim_time after the start in wall time.
    assert plant.outcome.wall_time == pytest.approx(plant.outcome.sim_time, abs=0.02)

    def timed_ticks() -> int | None:
        timing = plant.tick_timing
        return None if timing is None else timing.ticks

    # Every tick came from the tick process (its last firing is recorded last).
    ros.spin_until(lambda: timed_ticks() == round(plant.sim_time / TICK_PERIOD), "the last firing's record")
    # Each command arrived in the flight it was for, so the stances match the lockstep model.
    assert len(plant.command_latencies_ns) == strides
    assert [(m.height, m.forward_speed) for m in apex_msgs] == [
        a[1:] for a in model_loop(energy_policy, strides)
    ]
