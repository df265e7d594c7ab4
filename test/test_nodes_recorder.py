"""The recorder node, in a child process as ``tdslip run`` runs it, against the in-process plant.

Its bag is read back by two independent readers, ``mcap`` + ``mcap-ros2-support`` and ``rosbags``,
and held to what the nodes published: the counts per topic, the contents, and the 1 kHz state
stream without a gap.
"""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml  # type: ignore[import-untyped]
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from ros_harness import RosGraph, overrides, stop_process
from rosbags.highlevel import AnyReader
from tdslip_msgs.msg import ApexEvent

from tdslip_ros.nodes import topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.entry import wait_for_delivery
from tdslip_ros.nodes.plant_node import TICK_PERIOD, PlantNode

RECORDER = "tdslip_ros.nodes.recorder_node"
NS = 1_000_000_000


def start_recorder(ros: RosGraph, bag: Path, record_clock: bool) -> subprocess.Popen[bytes]:
    arguments = ["-p", f"output:={bag}", "-p", f"record_clock:={str(record_clock).lower()}"]
    return ros.start_module(RECORDER, arguments, bag.parent / "recorder.log")


def start_hopping(
    ros: RosGraph, record_clock: bool, **plant_values: object
) -> tuple[PlantNode, ControllerNode]:
    """Plant and controller in-process; the plant starts once the recorder listens everywhere."""
    plant = ros.add(
        PlantNode(context=ros.context, autostart=False, parameter_overrides=overrides(**plant_values))
    )
    controller = ros.add(ControllerNode(context=ros.context))
    published = [t for t in topics.TDSLIP_TOPICS if t != topics.COMMAND] + (
        [topics.CLOCK] if record_clock else []
    )
    ros.spin_until(
        lambda: (
            all(plant.matched_subscribers(t) >= 1 for t in published)
            and plant.matched_subscribers(topics.APEX) >= 2
            and plant.count_subscribers(topics.COMMAND) >= 2
        ),
        "the recorder and the controller to connect",
    )
    plant.start()
    return plant, controller


def mcap_contents(path: Path) -> tuple[Any, dict[str, int], dict[str, list[Any]]]:
    """(summary, messages per topic from the summary statistics, decoded messages per topic)."""
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        statistics = summary.statistics.channel_message_counts
        counts = {channel.topic: statistics.get(key, 0) for key, channel in summary.channels.items()}
        decoded: dict[str, list[Any]] = {}
        for _, channel, _, message in reader.iter_decoded_messages():
            decoded.setdefault(channel.topic, []).append(message)
    return summary, counts, decoded


def rosbags_contents(bag: Path) -> tuple[dict[str, int], dict[str, list[Any]]]:
    with AnyReader([bag]) as reader:
        counts = {connection.topic: connection.msgcount for connection in reader.connections}
        decoded: dict[str, list[Any]] = {}
        for connection, _, raw in reader.messages():
            decoded.setdefault(connection.topic, []).append(reader.deserialize(raw, connection.msgtype))
    return counts, decoded


def metadata_counts(bag: Path) -> dict[str, int]:
    information = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {
        entry["topic_metadata"]["name"]: entry["message_count"]
        for entry in information["topics_with_message_count"]
    }


def stamp_ns(message: Any) -> int:
    return int(message.header.stamp.sec) * NS + int(message.header.stamp.nanosec)


def assert_gapless_from_start(states: list[Any]) -> None:
    """Every tick from t = 0 on, each exactly once, in order."""
    tick_ns = round(TICK_PERIOD * NS)
    assert [stamp_ns(state) for state in states] == [k * tick_ns for k in range(len(states))]


def test_recording_decodes_in_two_readers_with_the_published_counts(ros: RosGraph, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    recorder = start_recorder(ros, bag, record_clock=True)
    apexes = ros.collect(ApexEvent, topics.APEX)
    plant, controller = start_hopping(ros, record_clock=True, max_strides=3)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    ros.spin_until(
        lambda: len(apexes) == controller.published == plant.published[topics.APEX], "every apex answered"
    )
    assert wait_for_delivery(plant) and wait_for_delivery(controller)
    assert stop_process(recorder) == 0
    published = {**plant.published, topics.COMMAND: controller.published}
    assert set(published) == set(topics.MESSAGE_TYPES)

    summary, mcap_counts, mcap_messages = mcap_contents(bag / "bag_0.mcap")
    assert mcap_counts == published
    for channel in summary.channels.values():
        assert channel.message_encoding == "cdr"
        assert {"offered_qos_profiles", "topic_type_hash"} <= set(channel.metadata)
        assert summary.schemas[channel.schema_id].encoding == "ros2msg"
    rosbags_counts, rosbags_messages = rosbags_contents(bag)
    assert rosbags_counts == published
    assert metadata_counts(bag) == published

    for decoded in (mcap_messages, rosbags_messages):
        assert [(m.stride, m.height, m.forward_speed) for m in decoded[topics.APEX]] == [
            (m.stride, m.height, m.forward_speed) for m in apexes
        ]
        assert_gapless_from_start(decoded[topics.STATE])
        assert [stamp_ns(m) for m in decoded[topics.GRF]] == [stamp_ns(m) for m in decoded[topics.STATE]]
        assert [m.stride for m in decoded[topics.COMMAND]] == list(range(len(apexes)))
        assert decoded[topics.STATUS][-1].kind == "run_complete"


def test_commands_published_before_the_recorder_matched_are_recorded(ros: RosGraph, tmp_path: Path) -> None:
    """The controller may answer before the recorder has matched it (tdslip run cannot see that)."""
    controller = ros.add(ControllerNode(context=ros.context))
    apex = ros.node("probe").create_publisher(ApexEvent, topics.APEX, topics.QOS)
    ros.spin_until(lambda: apex.get_subscription_count() >= 1, "the controller")
    apex.publish(ApexEvent(stride=0, height=1.0, forward_speed=5.0))
    ros.spin_until(lambda: controller.published == 1, "the answer")

    bag = tmp_path / "bag"
    recorder = start_recorder(ros, bag, record_clock=False)
    (answers,) = (publisher for publisher in controller.publishers if publisher.topic_name == topics.COMMAND)
    ros.spin_until(lambda: answers.get_subscription_count() >= 1, "the recorder to match the controller")
    assert wait_for_delivery(controller)  # acknowledged by the recorder: it has the old answer
    assert stop_process(recorder) == 0
    _, counts, messages = mcap_contents(bag / "bag_0.mcap")
    assert counts[topics.COMMAND] == 1 and messages[topics.COMMAND][0].stride == 0


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_signal_mid_run_leaves_a_finalised_readable_bag(
    ros: RosGraph, tmp_path: Path, signum: signal.Signals
) -> None:
    bag = tmp_path / "bag"
    recorder = start_recorder(ros, bag, record_clock=False)
    plant, _ = start_hopping(ros, record_clock=False, max_strides=0)  # hops until stopped
    ros.spin_until(lambda: plant.published[topics.STATE] >= 1500, "1.5 s of simulated hopping")
    recorder.send_signal(signum)
    ros.spin_until(
        lambda: recorder.poll() is not None, "the recorder to exit", timeout=30.0
    )  # plant keeps going
    assert recorder.returncode == 0
    assert plant.outcome is None  # the signal came mid-run

    _, mcap_counts, mcap_messages = mcap_contents(bag / "bag_0.mcap")  # needs the summary: finalised
    rosbags_counts, rosbags_messages = rosbags_contents(bag)
    assert mcap_counts == rosbags_counts == metadata_counts(bag)
    assert mcap_counts[topics.STATE] >= 1500
    for decoded in (mcap_messages, rosbags_messages):
        assert_gapless_from_start(decoded[topics.STATE])
