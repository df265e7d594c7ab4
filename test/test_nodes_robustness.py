"""The plant against inputs that used to crash, hang or misdrive it (issue 9): quick resets racing
the controller's answers, a controller that falls silent in realtime, absurd reset apexes, and a
fuzz of random commands and resets. Each ends in a clean outcome: a refusal with a reason, a named
failure Status, and never a dead plant or a non-finite published number."""

from __future__ import annotations

import math
import random
import time
from typing import Any

import pytest
from support.ros_harness import RosGraph, overrides
from tdslip_msgs.msg import ApexEvent, ContactEvent, HopperState, StanceCommand, Status
from tdslip_msgs.srv import Reset
from test_nodes_lockstep import energy_policy

from tdslip_ros.model.events import FailureKind
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.plant_node import PlantNode


def reset_client(ros: RosGraph) -> Any:
    return ros.node("reset_client").create_client(Reset, topics.RESET_SERVICE)


def call_reset(ros: RosGraph, client: Any, height: float, speed: float) -> Reset.Response:
    future = client.call_async(Reset.Request(height=height, forward_speed=speed))
    ros.spin_until(future.done, "the reset response")
    return future.result()


FIRST_RESET, SECOND_RESET = (1.0, 5.0), (1.1, 4.0)  # different apexes, so different answers


def test_two_quick_resets_never_apply_the_first_ones_answer_to_the_second_run(ros: RosGraph) -> None:
    """Each reset starts a new epoch; an answer to the previous epoch's apex is never applied, even
    when it arrives after the next reset (it used to be, in 24 of 30 trials)."""
    plant = ros.add(PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=1)))
    ros.add(ControllerNode(context=ros.context))
    touchdowns = ros.collect(ContactEvent, topics.CONTACT)
    ros.spin_until(lambda: plant.outcome is not None, "the first run")
    client = reset_client(ros)
    for trial in range(10):
        epoch = reset_twice(ros, client, FIRST_RESET, SECOND_RESET)
        assert epoch == 2 * trial + 2
        ros.spin_until(lambda: plant.outcome is not None and plant.epoch == epoch, "the second run's end")  # noqa: B023
        assert plant.outcome.kind == Status.KIND_RUN_COMPLETE, plant.outcome
        ros.spin_until(lambda: any(t.epoch == epoch for t in touchdowns), "its touchdown")  # noqa: B023
        (touchdown,) = [t for t in touchdowns if t.epoch == epoch and t.kind == ContactEvent.TOUCHDOWN]
        own = energy_policy(*SECOND_RESET)
        assert (touchdown.state.leg_angle, touchdown.state.hip_torque) == (own.touchdown_angle, own.tau0)


def reset_twice(ros: RosGraph, client: Any, first: tuple[float, float], second: tuple[float, float]) -> int:
    """Two resets sent back to back; the epoch of the second."""
    calls = [client.call_async(Reset.Request(height=y, forward_speed=xdot)) for y, xdot in (first, second)]
    ros.spin_until(lambda: all(call.done() for call in calls), "both resets")
    responses = [call.result() for call in calls]
    assert all(r.success for r in responses) and responses[1].epoch == responses[0].epoch + 1
    return int(responses[1].epoch)


def test_a_controller_that_falls_silent_in_realtime_ends_the_run(ros: RosGraph) -> None:
    limit = 3
    plant = ros.add(
        PlantNode(
            context=ros.context,
            parameter_overrides=overrides(max_strides=0, clock_mode="realtime", max_stale_strides=limit),
        )
    )
    controller = ros.add(ControllerNode(context=ros.context))
    apexes = ros.collect(ApexEvent, topics.APEX)
    ros.spin_until(lambda: len(apexes) >= 3, "three answered apexes")
    ros.executor.remove_node(controller)
    controller.destroy_node()  # the controller dies mid-run
    silent_from = len(apexes)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome.kind == Status.KIND_COMMAND_TIMEOUT
    assert f"the last {limit} strides" in plant.outcome.reason
    # It noticed within max_stale_strides strides (one more if the controller died mid-answer).
    assert plant.outcome.stride - silent_from in (limit - 1, limit)


def test_answers_that_arrive_after_their_touchdown_are_counted_late_and_never_applied(ros: RosGraph) -> None:
    """A controller too slow for its window: each answer arrives at the touchdown it was for. The plant
    holds the command in force, refuses the answer with its reason, and counts it late."""
    plant = ros.add(
        PlantNode(
            context=ros.context,
            parameter_overrides=overrides(max_strides=0, clock_mode="realtime", max_stale_strides=0),
        )
    )
    slow = ros.node("slow_controller")
    publisher = slow.create_publisher(StanceCommand, topics.COMMAND, topics.COMMAND_QOS)
    latest: list[ApexEvent] = []
    sent: list[int] = []

    def answer_at_touchdown(contact: ContactEvent) -> None:
        apex = latest[-1] if latest else None
        if contact.kind != ContactEvent.TOUCHDOWN or apex is None or apex.stride != contact.stride:
            return
        command = energy_policy(apex.height, apex.forward_speed)
        publisher.publish(
            StanceCommand(
                epoch=apex.epoch,
                stride=apex.stride,
                touchdown_angle=command.touchdown_angle,
                tau0=command.tau0,
                t_f=command.t_f,
                policy="slow",
            )
        )
        sent.append(apex.stride)

    slow.create_subscription(ApexEvent, topics.APEX, latest.append, topics.STREAM_QOS)
    slow.create_subscription(ContactEvent, topics.CONTACT, answer_at_touchdown, topics.STREAM_QOS)
    statuses = ros.collect(Status, topics.STATUS)

    def refusals() -> list[str]:
        return [s.reason for s in statuses if s.kind == Status.KIND_COMMAND_REJECTED]

    ros.spin_until(lambda: len(refusals()) >= 3, "three refused answers")
    assert all("arrived after the touchdown" in reason for reason in refusals())
    assert plant.counts.late_commands >= len(refusals())
    assert plant.counts.late_commands in (len(sent), len(sent) - 1)  # the latest may still be on its way
    assert len(plant.command_latencies_ns) == 0  # none was applied
    assert plant.outcome is None  # the command in force held: the hopper runs on


@pytest.mark.parametrize(
    ("height", "speed", "named"),
    [
        (1.0, 1e150, "apex speed"),
        (1e9, 5.0, "apex height"),
        (math.nan, 5.0, "apex height"),
        (1.0, math.inf, "apex speed"),
        (-1.0, 5.0, "apex height"),
    ],
)
def test_an_absurd_reset_apex_is_refused_and_the_run_goes_on(
    ros: RosGraph, height: float, speed: float, named: str
) -> None:
    plant = ros.add(PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=2)))
    ros.add(ControllerNode(context=ros.context))
    ros.spin_until(lambda: plant.start_wall_ns > 0, "the start")
    response = call_reset(ros, reset_client(ros), height, speed)
    assert not response.success and named in response.message and response.epoch == 0
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome.kind == Status.KIND_RUN_COMPLETE and plant.epoch == 0


def finite(message: Any) -> bool:
    """Every float field of a message, nested ones included, is finite."""
    for name in message.get_fields_and_field_types():
        value = getattr(message, name)
        if hasattr(value, "get_fields_and_field_types"):
            if not finite(value):
                return False
        elif isinstance(value, float) and not math.isfinite(value):
            return False
    return True


def test_fuzzed_commands_and_resets_leave_the_plant_alive_and_every_number_finite(ros: RosGraph) -> None:
    rng = random.Random(20261201)
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=0, command_timeout=0.2))
    )
    probe = ros.node("fuzz")
    commands = probe.create_publisher(StanceCommand, topics.COMMAND, topics.COMMAND_QOS)
    received = [
        ros.collect(message, topic, probe)
        for topic, message in (
            (topics.STATE, HopperState),
            (topics.APEX, ApexEvent),
            (topics.CONTACT, ContactEvent),
        )
    ]
    statuses = ros.collect(Status, topics.STATUS, probe)
    client = reset_client(ros)
    ros.spin_until(lambda: plant.count_publishers(topics.COMMAND) >= 1, "the fuzzer")
    plant.start()
    magnitudes = [0.0, 1e-300, 1e-9, 1.0, 0.3, 100.0, 1e6, 1e12, 1e100, 1e300, math.inf, math.nan]

    def number() -> float:
        return rng.choice([1, -1]) * rng.choice(magnitudes) * rng.random() ** rng.choice([0, 1])

    deadline = time.monotonic() + 8.0
    sent = 0
    resets = []
    while time.monotonic() < deadline:
        if rng.random() < 0.05:
            resets.append(
                client.call_async(Reset.Request(height=abs(number()) or 1.0, forward_speed=number()))
            )
        if rng.random() < 0.3:  # a sensible answer now and then keeps the hopper moving
            command = energy_policy(1.0, 5.0)
            values = (command.touchdown_angle, command.tau0, command.t_f)
        else:
            values = (number(), number(), number())
        epoch, stride = plant.epoch, plant.stride  # the apex being waited for
        commands.publish(
            StanceCommand(
                epoch=epoch,
                stride=stride,
                touchdown_angle=values[0],
                tau0=values[1],
                t_f=values[2],
                policy="fuzz",
            )
        )
        sent += 1
        ros.executor.spin_once(timeout_sec=0.002)
    assert sent > 500 and len(resets) > 10
    # Let the plant take what is queued (a service keeps the last 10 requests; older ones are dropped).
    settle = time.monotonic() + 1.0
    ros.spin_until(lambda: time.monotonic() > settle, "the queued commands and resets")
    assert sum(reset.done() for reset in resets) >= 10
    # Alive: a reset to a sensible apex and the policy's answers give a run again.
    ros.add(ControllerNode(context=ros.context))
    ros.spin_until(lambda: plant.matched_subscribers(topics.APEX) >= 2, "the controller")
    response = call_reset(ros, client, 1.0, 5.0)
    assert response.success
    ros.spin_until(
        lambda: plant.epoch == response.epoch and plant.stride >= 3,
        "three strides after the fuzz",
    )
    for messages in received:
        assert messages and all(finite(m) for m in messages)
    named = {
        *(kind.value for kind in FailureKind),
        "command_rejected",
        "command_timeout",
        "reset",
        "run_complete",
    }
    assert {status.kind for status in statuses} <= named
