"""The controller node answers apex events with exactly the model policy's command, and its
policy and targets change at runtime through validated parameters."""

from __future__ import annotations

import math
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from support.learned_policy import learned_file, malformed_file
from support.ros_harness import RosGraph, overrides
from tdslip_msgs.msg import ApexEvent, StanceCommand

from tdslip_ros.model import units
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.model.policies import controllers
from tdslip_ros.model.policies.registry import PolicySpec
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.parameters import PAPER_PARAMS as PARAMS

BETA = math.radians(22.0)
TARGET = (1.05, 4.6)  # m, m/s


def apex_event(stride: int, y: float, xdot: float, epoch: int = 0) -> ApexEvent:
    """An apex as the plant publishes it on flat ground without sensing noise (measured = true)."""
    return ApexEvent(
        epoch=epoch,
        stride=stride,
        height=y,
        forward_speed=xdot,
        measured_height=y,
        measured_forward_speed=xdot,
    )


class Bench:
    """A controller with a probe that publishes apex events and collects the answers."""

    def __init__(self, ros: RosGraph) -> None:
        self.ros = ros
        self.controller = ros.add(ControllerNode(context=ros.context))
        probe = ros.node("probe")
        self.apex = probe.create_publisher(ApexEvent, topics.APEX, topics.STREAM_QOS)
        self.commands: list[StanceCommand] = ros.collect(StanceCommand, topics.COMMAND, probe)
        ros.spin_until(
            lambda: self.apex.get_subscription_count() >= 1 and probe.count_publishers(topics.COMMAND) >= 1,
            "the controller to connect",
        )

    def set(self, **values: object) -> bool:
        results = self.controller.set_parameters(
            [Parameter(name, value=value) for name, value in values.items()]
        )
        return all(result.successful for result in results)

    def answer(self, stride: int, y: float, xdot: float) -> StanceCommand:
        count = len(self.commands)
        self.apex.publish(apex_event(stride, y, xdot))
        self.ros.spin_until(lambda: len(self.commands) > count, f"the answer to apex {stride}")
        assert len(self.commands) == count + 1
        return self.commands[-1]


def fields(msg: StanceCommand | ModelCommand) -> tuple[float, float, float]:
    return (msg.touchdown_angle, msg.tau0, msg.t_f)


def test_each_policy_answers_with_the_model_policy_command(ros: RosGraph) -> None:
    bench = Bench(ros)
    assert bench.set(touchdown_angle=BETA, target_height=TARGET[0], target_speed=TARGET[1], corrections=1)
    apexes = [(1.0, 5.0), (0.98, 4.9)]
    energy = 1700.0
    power = 900.0  # W
    expected = {
        "open_loop": [
            controllers.fixed_power(PARAMS, y, xdot, BETA, units.power_to_alpha(PARAMS, power))
            for y, xdot in apexes
        ],
        "energy": [controllers.energy_regulation(PARAMS, y, xdot, BETA, energy) for y, xdot in apexes],
        "deadbeat": [controllers.deadbeat(PARAMS, y, xdot, *TARGET) for y, xdot in apexes[:1]],
        # Foot placement's derivative term uses the previous apex of the run (none at stride 0).
        "apex_foot_placement": [
            controllers.apex_foot_placement(PARAMS, *apexes[0], apexes[0][1], *TARGET),
            controllers.apex_foot_placement(PARAMS, *apexes[1], apexes[0][1], *TARGET),
        ],
    }
    assert bench.set(touchdown_power=power, target_energy=energy)
    for policy, commands in expected.items():
        assert bench.set(policy=policy)
        for stride, (command, (y, xdot)) in enumerate(zip(commands, apexes, strict=False)):
            answer = bench.answer(stride, y, xdot)
            assert (answer.stride, answer.policy) == (stride, policy)
            assert fields(answer) == fields(command.command())


def test_targets_change_at_runtime_and_bad_values_are_refused(ros: RosGraph) -> None:
    bench = Bench(ros)
    apex = (1.0, 5.0)
    assert bench.set(policy="energy", target_energy=1750.0)
    before = bench.answer(0, *apex)
    assert bench.set(target_energy=1800.0)
    after = bench.answer(1, *apex)
    angle = bench.controller.get_parameter("touchdown_angle").value
    assert fields(after) == fields(controllers.energy_regulation(PARAMS, *apex, angle, 1800.0).command())
    assert after.tau0 < before.tau0  # more energy to put in: more forward thrust (tau0 < 0)

    assert not bench.set(policy="bogus")  # not one of the choices
    assert not bench.set(target_height=-1.0)  # out of range
    assert not bench.set(mass=70.0)  # read-only: the hopper is the plant's
    assert not bench.set(corrections=1.5)  # wrong type
    assert bench.controller.get_parameter("policy").value == "energy"
    assert bench.controller.get_parameter("mass").value == PARAMS.m
    assert fields(bench.answer(2, *apex)) == fields(after)


def test_the_analytic_map_is_a_parameter_and_a_misspelt_one_is_refused(ros: RosGraph) -> None:
    bench = Bench(ros)
    apex = (1.0, 5.0)
    assert bench.controller.get_parameter("analytic_map").value == "ours"
    assert bench.set(policy="deadbeat", target_height=TARGET[0], target_speed=TARGET[1], analytic_map="paper")
    paper = bench.answer(0, *apex)
    assert fields(paper) == fields(controllers.deadbeat(PARAMS, *apex, *TARGET, speed="liftoff").command())
    assert not bench.set(analytic_map="papr")  # not one of the choices: refused, the map kept
    assert bench.controller.get_parameter("analytic_map").value == "paper"
    assert bench.set(analytic_map="ours")
    ours = bench.answer(1, *apex)
    assert fields(ours) == fields(controllers.deadbeat(PARAMS, *apex, *TARGET).command())
    assert abs(ours.touchdown_angle - paper.touchdown_angle) > 1e-3  # rad


def test_an_apex_without_a_command_gets_no_answer(ros: RosGraph) -> None:
    bench = Bench(ros)
    assert bench.set(policy="energy")
    # At 0.5 m the leg cannot be placed at 20 degrees (r0 cos = 0.94 m): no command exists.
    bench.apex.publish(apex_event(0, 0.5, 5.0))
    answer = bench.answer(1, 1.0, 5.0)  # answers come in order: the first apex produced nothing
    assert answer.stride == 1 and len(bench.commands) == 1


def test_an_apex_published_again_gets_the_same_answer_without_planning_again(ros: RosGraph) -> None:
    """A lockstep plant publishes an apex no command reached again: the controller sends its answer again,
    byte for byte, and neither plans again (the PD's previous speed would move on) nor refuses twice."""
    bench = Bench(ros)
    assert bench.set(policy="energy")
    bench.answer(0, 1.0, 5.0)
    first = bench.answer(1, 1.02, 4.9)
    planned = len(bench.controller.planning_times)
    again = bench.answer(1, 1.02, 4.9)
    assert again == first and len(bench.controller.planning_times) == planned
    bench.apex.publish(apex_event(2, 0.5, 5.0))  # no command exists (see below), twice
    bench.apex.publish(apex_event(2, 0.5, 5.0))
    assert bench.answer(3, 1.0, 5.0).stride == 3
    assert bench.controller.unanswered == 1
    assert bench.set(target_energy=1800.0)  # new settings: an equal apex is planned anew
    assert fields(bench.answer(3, 1.0, 5.0)) == fields(
        controllers.energy_regulation(
            PARAMS, 1.0, 5.0, bench.controller.get_parameter("touchdown_angle").value, 1800.0
        ).command()
    )


def test_the_learned_policy_answers_from_its_file_and_not_without_one(ros: RosGraph, tmp_path: Path) -> None:
    bench = Bench(ros)
    assert bench.set(policy="learned", policy_file=str(tmp_path / "missing.json"))
    bench.apex.publish(apex_event(0, 1.0, 5.0))  # unreadable file: logged, no answer
    # Heard (it keeps the apex's speed for the next), before the file is set: no public sign of a refusal.
    bench.ros.spin_until(lambda: bench.controller._previous_speed == 5.0, "the controller to hear apex 0")
    policy_file = learned_file(tmp_path / "policy.json")
    assert bench.set(policy_file=policy_file)
    answer = bench.answer(1, 0.98, 4.9)
    assert answer.stride == 1 and len(bench.commands) == 1 and answer.policy == "learned"
    spec = replace(PolicySpec.default("learned"), policy_file=policy_file)
    assert fields(answer) == fields(spec.commands(PARAMS, 0.98, 4.9, 4.9).command())


@pytest.mark.parametrize("policy", ["energy", "open_loop"])
def test_answer_keeps_the_apex_stamp_and_epoch(ros: RosGraph, policy: str) -> None:
    bench = Bench(ros)
    assert bench.set(policy=policy)
    msg = apex_event(4, 1.0, 5.0, epoch=7)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 345_000_000
    count = len(bench.commands)
    bench.apex.publish(msg)
    ros.spin_until(lambda: len(bench.commands) > count, "the answer")
    assert (bench.commands[-1].header.stamp.sec, bench.commands[-1].header.stamp.nanosec) == (12, 345_000_000)
    assert (bench.commands[-1].epoch, bench.commands[-1].stride) == (7, 4)


def test_a_late_subscriber_gets_the_next_command_not_an_old_one(ros: RosGraph) -> None:
    """What ``ros2 topic echo --once tdslip/command`` shows: it asks for the publishers' durability
    (volatile), so no old answer is replayed to it; the next one is what it prints."""
    bench = Bench(ros)
    for stride in range(3):
        bench.answer(stride, 1.0 - 0.01 * stride, 5.0)
    late = ros.node("late")
    received: list[StanceCommand] = []
    late.create_subscription(
        StanceCommand,
        topics.COMMAND,
        received.append,
        QoSProfile(
            depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
        ),
    )
    late.create_subscription(StanceCommand, topics.COMMAND, received.append, 10)
    ros.spin_until(lambda: bench.controller.count_subscribers(topics.COMMAND) >= 3, "the late subscribers")
    ros.executor.spin_once(timeout_sec=0.5)
    assert received == []  # the transient-local one is incompatible: nothing old is replayed
    bench.answer(3, 0.97, 5.0)
    ros.spin_until(lambda: len(received) >= 1, "the next answer")
    assert [msg.stride for msg in received] == [3]


def test_the_exact_plant_is_loaded_when_the_policy_changes_to_one_that_plans_on_it(
    ros: RosGraph, tmp_path: Path
) -> None:
    """Loaded at the change, not at the next apex (whose answer 0.2 s of loading would make late): for
    energy_exact, and for a learned policy whose base is energy_exact; not for the analytic policies."""
    bench = Bench(ros)
    assert bench.set(policy="energy") and not bench.controller.exact_plant_ready
    base_exact = malformed_file(tmp_path, base={"policy": "energy_exact", "settings": {}})
    assert bench.set(policy_file=str(base_exact), policy="learned")
    assert bench.controller.exact_plant_ready
    other = Bench(ros)
    assert other.set(policy="deadbeat") and not other.controller.exact_plant_ready
    assert other.set(policy="energy_exact") and other.controller.exact_plant_ready


def test_the_first_answer_waits_for_a_plant_whose_subscription_it_has_not_seen(
    ros: RosGraph,
) -> None:
    """Discovery is not symmetric: a plant may have matched the controller's publisher and asked before the
    controller has discovered the plant's command subscription. The answer to the first apex of a run waits
    for it (a volatile answer published before would never reach the plant)."""
    controller = ros.add(ControllerNode(context=ros.context))
    plant = ros.node("late_plant")
    apex = plant.create_publisher(ApexEvent, topics.APEX, topics.STREAM_QOS)
    ros.spin_until(lambda: apex.get_subscription_count() >= 1, "the controller to subscribe")
    commands: list[StanceCommand] = []
    subscribe = threading.Timer(
        0.3, lambda: plant.create_subscription(StanceCommand, topics.COMMAND, commands.append, 10)
    )
    subscribe.start()  # while the controller's callback runs: the executor is busy with it
    try:
        apex.publish(apex_event(0, 1.0, 5.0))
        ros.spin_until(lambda: len(commands) == 1, "the answer to the first apex")
    finally:
        subscribe.cancel()
    assert (commands[0].epoch, commands[0].stride) == (0, 0) and controller.published == 1


def test_with_min_subscribers_it_subscribes_to_the_apex_once_its_answers_reach_that_many(
    ros: RosGraph,
) -> None:
    """What tdslip run and hop.launch.py set (2: the plant and the recorder). A recorder that has matched
    the controller's publisher may not yet be matched by it (discovery is not symmetric), and a volatile
    answer published then never reaches the recorder; a plant does not start on a controller that does not
    subscribe to its apex. Here the first subscription matches, the controller waits; the second matches,
    it subscribes, and its answer reaches both."""
    answers_two = overrides(min_subscribers=2)
    controller = ros.add(ControllerNode(context=ros.context, parameter_overrides=answers_two))
    probe = ros.node("probe")
    apex = probe.create_publisher(ApexEvent, topics.APEX, topics.STREAM_QOS)
    plant_commands: list[StanceCommand] = ros.collect(StanceCommand, topics.COMMAND, probe)
    ros.spin_until(lambda: controller.count_subscribers(topics.COMMAND) >= 1, "the plant's subscription")
    waited = time.monotonic() + 0.5
    ros.spin_until(lambda: time.monotonic() > waited, "half a second")
    assert controller.count_subscribers(topics.COMMAND) == 1
    assert (apex.get_subscription_count(), probe.count_subscribers(topics.APEX)) == (0, 0)
    recorder_commands: list[StanceCommand] = ros.collect(StanceCommand, topics.COMMAND)
    ros.spin_until(lambda: apex.get_subscription_count() >= 1, "the controller to subscribe to the apex")
    apex.publish(apex_event(0, 1.0, 5.0))
    ros.spin_until(lambda: len(plant_commands) == len(recorder_commands) == 1, "the answer at both")
    assert controller.published == 1


def test_the_apex_subscription_made_after_configure_is_destroyed_by_cleanup(ros: RosGraph) -> None:
    """The lifecycle destroys at cleanup what the node made from configure on, also the apex subscription
    made later, once its answers were heard: configured again, the controller has one apex subscription
    and answers an apex once."""
    managed = overrides(autostart=False, min_subscribers=1)
    controller = ros.add(ControllerNode(context=ros.context, parameter_overrides=managed))
    probe = ros.node("probe")
    apex = probe.create_publisher(ApexEvent, topics.APEX, topics.STREAM_QOS)

    def configured_answers(height: float) -> list[StanceCommand]:
        assert controller.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert controller.trigger_activate() == TransitionCallbackReturn.SUCCESS
        waited = time.monotonic() + 0.3
        ros.spin_until(lambda: time.monotonic() > waited, "0.3 s")
        assert apex.get_subscription_count() == 0  # nobody hears the answers yet
        commands: list[StanceCommand] = ros.collect(StanceCommand, topics.COMMAND, probe)
        ros.spin_until(lambda: apex.get_subscription_count() >= 1, "the controller to subscribe to the apex")
        assert apex.get_subscription_count() == 1
        apex.publish(apex_event(0, height, 5.0))
        ros.spin_until(lambda: len(commands) >= 1, "the answer")
        assert controller.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
        assert controller.trigger_cleanup() == TransitionCallbackReturn.SUCCESS
        ros.spin_until(lambda: apex.get_subscription_count() == 0, "the apex subscription to go")
        probe.destroy_subscription(list(probe.subscriptions)[-1])
        ros.spin_until(lambda: probe.count_subscribers(topics.COMMAND) == 0, "the answers' listener to go")
        return commands

    assert [len(configured_answers(height)) for height in (1.0, 0.99)] == [1, 1]
