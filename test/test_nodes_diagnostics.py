"""/diagnostics of the plant, the controller and the recorder, and the hopper as a robot (robot_description,
joint_states, /tf), each held to an independent truth: the plant's closing tick summary, the recorder's bag,
the 1 kHz state message. One ROS graph per test; the last two tests run the real ``ros2`` command line.
"""

from __future__ import annotations

import math
import subprocess
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import yaml  # type: ignore[import-untyped]
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import WrenchStamped
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from support.ros2_tools import ros2_command, ros2_environment, tf_message_type
from support.ros_harness import RosGraph, overrides, stop_process
from tdslip_msgs.msg import HopperState, Status

from tdslip_ros.bag.reader import mcap_file
from tdslip_ros.interfaces import resolve
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.diagnostics import (
    HARDWARE_ID,
    NodeStatus,
    Threshold,
    level_of,
)
from tdslip_ros.nodes.parameters import ParameterSpec
from tdslip_ros.nodes.plant_node import PlantNode

NS = 1_000_000_000
ECHO_TIMEOUT = 90.0  # s for four ros2 processes to start, discover and echo on the loaded 2-core VM


def statuses_of(arrays: list[Any], name: str) -> list[DiagnosticStatus]:
    return [status for array in arrays for status in array.status if status.name == name]


def values_of(status: DiagnosticStatus) -> dict[str, str]:
    return {pair.key: pair.value for pair in status.values}


def collect_diagnostics(ros: RosGraph) -> list[Any]:
    received: list[Any] = []
    ros.node("diagnostics_probe").create_subscription(
        DiagnosticArray, topics.DIAGNOSTICS, received.append, topics.DIAGNOSTICS_QOS
    )
    return received


def latest_where(
    ros: RosGraph, arrays: list[Any], name: str, condition: Callable[[DiagnosticStatus], bool], what: str
) -> DiagnosticStatus:
    """Spin until a status of node ``name`` published from now on meets ``condition``; that status."""
    seen = len(statuses_of(arrays, name))
    ros.spin_until(lambda: any(condition(s) for s in statuses_of(arrays, name)[seen:]), what)
    return next(s for s in statuses_of(arrays, name)[seen:] if condition(s))


def test_the_level_rule_error_on_a_failure_then_warn_past_a_threshold_else_ok() -> None:
    above = Threshold("late", ParameterSpec("warn_late", 0, "", 0, 10))
    below = Threshold("free", ParameterSpec("warn_free", 1.0, "", 0.0, 10.0), below=True)
    limits = {"warn_late": 2.0, "warn_free": 1.0}

    def level(late: int, free: float, failure: str | None = None) -> tuple[bytes, str]:
        return level_of(NodeStatus({"late": late, "free": free}, "fine", failure), (above, below), limits)

    assert level(2, 1.0) == (DiagnosticStatus.OK, "fine")  # at a threshold is not past it
    assert level(3, 1.0) == (DiagnosticStatus.WARN, "late 3 > 2")
    assert level(2, 0.5) == (DiagnosticStatus.WARN, "free 0.5 < 1")
    assert level(3, 0.5, "fell") == (DiagnosticStatus.ERROR, "fell")


def test_the_realtime_plants_missed_ticks_on_diagnostics_are_those_of_its_closing_summary(
    ros: RosGraph,
) -> None:
    arrays = collect_diagnostics(ros)
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=2, clock_mode="realtime"))
    )
    ros.add(ControllerNode(context=ros.context))
    # The closing summary (its log line, tdslip run's table) comes from the tick process after the outcome.
    ros.spin_until(lambda: plant.outcome is not None and plant.tick_timing is not None, "the summary", 60)
    final = latest_where(ros, arrays, "/plant", lambda s: True, "a status after the run")
    timing = plant.tick_timing
    assert timing is not None
    values = values_of(final)
    assert final.hardware_id == HARDWARE_ID
    warned = timing.missed > 0.01 * timing.ticks  # config/plant.yaml's diagnostics_warn_missed_ticks
    assert final.level == (DiagnosticStatus.WARN if warned else DiagnosticStatus.OK), final.message
    assert values["clock mode"] == "realtime" and values["lifecycle state"] == "active"
    assert (int(values["ticks"]), int(values["missed ticks"])) == (timing.ticks, timing.missed)
    assert [int(values[f"missed: {why}"]) for why in ("hypervisor steal", "waiting for a CPU")] == [
        timing.missed_stolen,
        timing.missed_waiting,
    ]
    assert [
        int(values[f"missed: {why}"]) for why in ("woken late", "interrupted or catching up", "unexplained")
    ] == [
        timing.missed_woken_late,
        timing.missed_interrupted,
        timing.missed_unexplained,
    ]
    assert float(values["hypervisor steal [s]"]) == pytest.approx(timing.stolen_ns * 1e-9, abs=1e-5)
    assert int(values["stride"]) == 2
    assert int(values[f"published {resolve(topics.APEX)}"]) == plant.published[topics.APEX] == 3


def test_levels_follow_the_thresholds_set_at_runtime_and_a_failed_run_is_an_error(ros: RosGraph) -> None:
    arrays = collect_diagnostics(ros)
    controller = ros.add(ControllerNode(context=ros.context))
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=0, clock_mode="lockstep"))
    )
    ros.spin_until(lambda: len(controller.planning_times) >= 2, "two apexes answered")
    # Any planning takes more than 0 ms: a threshold of 0 warns, naming the key.
    controller.set_parameters([Parameter("diagnostics_warn_planning_p99", value=0.0)])
    warned = latest_where(ros, arrays, "/controller", lambda s: s.level == DiagnosticStatus.WARN, "a WARN")
    assert warned.message.startswith("planning time p99 [ms] ") and warned.message.endswith("> 0")
    controller.set_parameters([Parameter("diagnostics_warn_planning_p99", value=1e6)])
    latest_where(ros, arrays, "/controller", lambda s: s.level == DiagnosticStatus.OK, "OK again")
    # The controller goes: the lockstep plant times out waiting for a command, a failed run.
    ros.executor.remove_node(controller)
    controller.destroy_node()
    ros.nodes.remove(controller)
    plant.set_parameters([Parameter("command_timeout", value=0.5)])
    ros.spin_until(lambda: plant.outcome is not None, "the command timeout", timeout=60)
    failed = latest_where(ros, arrays, "/plant", lambda s: s.level == DiagnosticStatus.ERROR, "an ERROR")
    assert plant.outcome is not None and failed.message == f"{plant.outcome.kind}: {plant.outcome.reason}"
    assert plant.outcome.kind == Status.KIND_COMMAND_TIMEOUT


def test_the_recorders_counts_on_diagnostics_are_what_its_bag_holds(ros: RosGraph, tmp_path: Path) -> None:
    arrays = collect_diagnostics(ros)
    bag = tmp_path / "bag"
    recorder = ros.start_recorder(bag, tmp_path / "recorder.log")
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(wait_for_recorder=True, max_strides=2))
    )
    ros.add(ControllerNode(context=ros.context))
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run", timeout=60)
    assert plant.deliver(ros.executor)
    state_topic = resolve(topics.STATE)

    def caught_up(status: DiagnosticStatus) -> bool:
        values = values_of(status)
        # The recorder has heard the plant's final count and written every state message of it.
        return values.get("messages lost") == "0" and values[f"written {state_topic}"] == str(
            plant.published[topics.STATE]
        )

    final = latest_where(ros, arrays, "/recorder", caught_up, "the recorder's final counts")
    assert stop_process(recorder) == 0
    information = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    in_bag = {
        t["topic_metadata"]["name"]: t["message_count"] for t in information["topics_with_message_count"]
    }
    values = values_of(final)
    written = {
        key.removeprefix("written "): int(v) for key, v in values.items() if key.startswith("written ")
    }
    assert {name: written[name] for name in in_bag} == in_bag
    assert not any(n for name, n in written.items() if name not in in_bag)
    assert final.level == DiagnosticStatus.OK and values["bag"] == str(bag / "bag_0.mcap")
    assert int(values["bag size [bytes]"]) > 0 and float(values["free disk [GB]"]) > 0


def rotated(quaternion: Any, vector: tuple[float, float, float]) -> tuple[float, float, float]:
    """``vector`` rotated by the unit quaternion (v' = q v q*, written out)."""
    w, (x, y, z) = quaternion.w, (quaternion.x, quaternion.y, quaternion.z)
    vx, vy, vz = vector
    tx, ty, tz = 2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)
    return (vx + w * tx + y * tz - z * ty, vy + w * ty + z * tx - x * tz, vz + w * tz + x * ty - y * tx)


def stamp_ns(message: Any) -> int:
    return int(message.header.stamp.sec) * NS + int(message.header.stamp.nanosec)


def toe_in_world(transforms: list[Any]) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The body's and the toe's positions in ``world`` from the chain world -> body -> leg -> toe."""
    frames = {(t.header.frame_id, t.child_frame_id): t.transform for t in transforms}
    assert list(frames) == [("world", "body"), ("body", "leg"), ("leg", "toe")]
    body, hip, toe = frames.values()
    body_at = (body.translation.x, body.translation.y, body.translation.z)
    toe_in_leg = (toe.translation.x, toe.translation.y, toe.translation.z)
    toe_in_body = rotated(hip.rotation, toe_in_leg)  # the hip has no offset from the body
    return body_at, tuple(a + b for a, b in zip(body_at, toe_in_body, strict=True))  # type: ignore[return-value]


def check_against_state(transforms: list[Any], state: Any) -> None:
    """REP 103 (x forward, z up, y = 0 in the hopper's plane): the body at (x, 0, y), the toe at
    (toe_x, 0, toe_y) of the state message."""
    body_at, toe_at = toe_in_world(transforms)
    assert body_at == (state.x, 0.0, state.y)
    assert toe_at == pytest.approx((state.toe_x, 0.0, state.toe_y), abs=1e-12)


def probed_run(ros: RosGraph, tf_message: type | None = None) -> dict[str, list[Any]]:
    """What a probe heard of a 2-stride run of the in-process plant and controller, by topic: the state,
    joint_states, the force, robot_description (subscribed after the plant published it: transient-local
    keeps it) and, given its message type, /tf."""
    probe = ros.node("robot_probe")
    heard: dict[str, list[Any]] = {}

    def listen(message_type: type, topic: str, qos: Any) -> None:
        heard[topic] = []
        probe.create_subscription(message_type, topic, heard[topic].append, qos)

    listen(HopperState, topics.STATE, topics.STREAM_QOS)
    listen(JointState, topics.JOINT_STATES, topics.STREAM_QOS)
    listen(WrenchStamped, topics.GRF, topics.STREAM_QOS)
    if tf_message is not None:
        listen(tf_message, topics.TF, topics.TF_QOS)
    plant = ros.add(PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=2)))
    ros.add(ControllerNode(context=ros.context))
    listen(String, topics.ROBOT_DESCRIPTION, topics.ROBOT_DESCRIPTION_QOS)
    descriptions, states = heard[topics.ROBOT_DESCRIPTION], heard[topics.STATE]
    ros.spin_until(lambda: plant.outcome is not None and descriptions, "the end of the run")
    ros.spin_until(lambda: len(states) == plant.published[topics.STATE], "every state")
    return heard


def test_joint_states_agree_with_the_state_message_and_the_urdf_names_the_joints(ros: RosGraph) -> None:
    heard = probed_run(ros)
    states, joints = heard[topics.STATE], heard[topics.JOINT_STATES]
    robot = ET.fromstring(heard[topics.ROBOT_DESCRIPTION][0].data)
    urdf_joints = {j.get("name"): (j.get("type"), j.find("axis").get("xyz")) for j in robot.iter("joint")}  # type: ignore[union-attr]
    assert urdf_joints == {"hip_angle": ("revolute", "0 -1 0"), "leg_length": ("prismatic", "0 0 -1")}
    assert {link.get("name") for link in robot.iter("link")} == {"body", "leg", "toe"}

    by_stamp = {stamp_ns(state): state for state in states}
    forces = {stamp_ns(wrench): wrench.wrench.force for wrench in heard[topics.GRF]}
    assert joints and len(joints) < len(states) / 10  # decimated to marker_rate, 60 Hz
    stances = 0
    for joint in joints:
        state = by_stamp[stamp_ns(joint)]
        assert list(joint.name) == list(urdf_joints)
        assert list(joint.position) == [state.leg_angle, state.leg_length]
        assert list(joint.velocity) == [state.leg_angle_rate, state.leg_length_rate]
        assert joint.effort[0] == state.hip_torque
        if state.phase == HopperState.PHASE_STANCE:
            stances += 1
            # The leg's axial force from another message: the ground reaction force on the body along the
            # leg, toe to body (-sin, cos); the hip torque's part of it is normal to the leg.
            force = forces[stamp_ns(joint)]
            along = -force.x * math.sin(state.leg_angle) + force.y * math.cos(state.leg_angle)
            assert joint.effort[1] == pytest.approx(along, rel=1e-9, abs=1e-6)
        else:
            assert joint.effort[1] == 0.0
    assert stances


def test_tf_agrees_with_the_state_message(ros: RosGraph) -> None:
    heard = probed_run(ros, tf_message_type())
    states, frames = heard[topics.STATE], heard[topics.TF]
    by_stamp = {stamp_ns(state): state for state in states}
    assert frames and len(frames) < len(states) / 10  # decimated to marker_rate, 60 Hz
    touchdown_seen = False
    for message in frames:
        (stamp,) = {stamp_ns(t) for t in message.transforms}
        state = by_stamp[stamp]
        check_against_state(list(message.transforms), state)
        if state.leg_angle > 0:  # the toe ahead of the body: +x, REP 103's forward
            touchdown_seen = True
            assert message.transforms[2].transform.translation.z < 0  # the toe below the hip, along -z
            assert toe_in_world(list(message.transforms))[1][0] > state.x
    assert touchdown_seen


def namespace_of(value: Any) -> Any:
    """A YAML mapping as attributes, as the message it was echoed from."""
    if isinstance(value, dict):
        return SimpleNamespace(**{key: namespace_of(item) for key, item in value.items()})
    if isinstance(value, list):
        return [namespace_of(item) for item in value]
    return value


def test_the_real_ros2_echoes_each_nodes_diagnostics_and_the_tf_of_a_run(
    ros: RosGraph, tmp_path: Path
) -> None:
    ros2 = ros2_command()
    recorder = ros.start_recorder(tmp_path / "bag", tmp_path / "recorder.log")
    plant = ros.add(
        PlantNode(
            context=ros.context,
            # max_stale_strides 0: the run goes on while four ros2 processes starting delay the controller.
            parameter_overrides=overrides(
                max_strides=0, max_stale_strides=0, clock_mode="realtime", wait_for_recorder=True
            ),
        )
    )
    ros.add(ControllerNode(context=ros.context))
    ros.spin_until(lambda: plant.running, "the run's start", timeout=60)
    environment = ros2_environment(ros.domain_id, tmp_path / "ros_log")
    echo = [str(ros2), "topic", "echo", "--once", "--no-daemon", "--spin-time", "2"]
    names = ("/plant", "/controller", "/recorder")
    # Typed: echo subscribes at once instead of waiting --spin-time for discovery to tell it the type.
    diagnostics = [topics.DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray"]
    commands = {name: [*echo, "--filter", f"m.status[0].name == '{name}'", *diagnostics] for name in names}
    commands["/tf"] = [*echo, topics.TF, "tf2_msgs/msg/TFMessage"]
    echoes = {
        what: subprocess.Popen(
            command, env=environment, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        for what, command in commands.items()
    }
    deadline = time.monotonic() + ECHO_TIMEOUT
    while any(p.poll() is None for p in echoes.values()) and time.monotonic() < deadline:
        ros.executor.spin_once(timeout_sec=0.05)
    for process in echoes.values():
        if process.poll() is None:
            process.kill()
    outputs = {what: process.communicate()[0] for what, process in echoes.items()}
    assert all(process.returncode == 0 for process in echoes.values()), outputs
    plant.end_run("the test's end")
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    for name in names:
        (status,) = yaml.safe_load(outputs[name].split("\n---", 1)[0])["status"]
        assert (status["name"], status["hardware_id"]) == (name, HARDWARE_ID), outputs[name]
        assert {pair["key"] for pair in status["values"]} >= {"lifecycle state"}
    echoed = namespace_of(yaml.safe_load(outputs["/tf"].split("\n---", 1)[0]))
    (stamp,) = {stamp_ns(t) for t in echoed.transforms}
    assert plant.deliver(ros.executor) and stop_process(recorder) == 0
    # The state of the echoed stamp, as the recorder wrote it (a 1 kHz subscription here would load the test).
    with mcap_file(tmp_path / "bag").open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        messages = reader.iter_decoded_messages(topics=[resolve(topics.STATE)])
        (state,) = [message for _, _, _, message in messages if stamp_ns(message) == stamp]
    check_against_state(echoed.transforms, state)
