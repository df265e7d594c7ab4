"""The recorder node, in a child process as ``tdslip run`` runs it, against the in-process plant.

Its bag is read back by two independent readers, ``mcap`` + ``mcap-ros2-support`` and ``rosbags``,
and held to what the nodes published: the counts per topic, the contents, and the 1 kHz state
stream without a gap.
"""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Any

import pytest
import yaml  # type: ignore[import-untyped]
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.parameter import Parameter
from rosbags.highlevel import AnyReader
from support.ros_harness import RosGraph, overrides, stop_process
from tdslip_msgs.msg import ApexEvent, HopperSamples

from tdslip_ros.interfaces import resolve
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.entry import wait_for_delivery, wait_for_matching, wait_until
from tdslip_ros.nodes.plant_node import TICK_PERIOD, PlantNode
from tdslip_ros.nodes.recorder_node import RecorderNode
from tdslip_ros.nodes.wire import SAMPLE_COLUMNS

NS = 1_000_000_000


def start_hopping(ros: RosGraph, **plant_values: object) -> tuple[PlantNode, ControllerNode]:
    """Plant (waiting for the recorder) and controller in-process; the plant starts by itself once
    the recorder has matched every publisher and the controller is connected."""
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(wait_for_recorder=True, **plant_values))
    )
    controller = ros.add(ControllerNode(context=ros.context))
    ros.spin_until(lambda: plant.start_wall_ns > 0, "the recorder and the controller to connect")
    return plant, controller


def published_counts(plant: PlantNode, controller: ControllerNode) -> dict[str, int]:
    """What the plant (on each of its topics, 0 included) and the controller published, by recorded (fully
    qualified) topic name."""
    # tdslip/samples is no topic of the bag: its rows are the state and force messages recorded.
    counts = {topic: plant.published[topic] for topic in plant.topic_names if topic != topics.SAMPLES}
    return {
        resolve(topic): count for topic, count in {**counts, topics.COMMAND: controller.published}.items()
    }


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
    recorder = ros.start_recorder(bag, bag.parent / "recorder.log", record_clock=True)
    apexes = ros.collect(ApexEvent, topics.APEX)
    plant, controller = start_hopping(ros, max_strides=3)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    ros.spin_until(
        lambda: len(apexes) == controller.published == plant.published[topics.APEX], "every apex answered"
    )
    assert plant.deliver(ros.executor) and wait_for_delivery(controller)
    # The recorder takes the 1 kHz samples in batches: nobody listens to the live state and force.
    assert plant.matched_subscribers(topics.STATE) == plant.matched_subscribers(topics.GRF) == 0
    assert stop_process(recorder) == 0
    published = published_counts(plant, controller)
    # Every topic but the hip torques a controller streams in stance feedback (the plant's applied ones: 0).
    assert set(published) == {resolve(t) for t in topics.MESSAGE_TYPES} - {
        resolve(topics.HIP_TORQUE),
        resolve(topics.SAMPLES),
    }

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
        assert [(m.stride, m.height, m.forward_speed) for m in decoded[resolve(topics.APEX)]] == [
            (m.stride, m.height, m.forward_speed) for m in apexes
        ]
        states = decoded[resolve(topics.STATE)]
        assert_gapless_from_start(states)
        assert [stamp_ns(m) for m in decoded[resolve(topics.GRF)]] == [stamp_ns(m) for m in states]
        assert [m.stride for m in decoded[resolve(topics.COMMAND)]] == list(range(len(apexes)))
        assert decoded[resolve(topics.STATUS)][-1].kind == "run_complete"


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_signal_mid_run_leaves_a_finalised_readable_bag(
    ros: RosGraph, tmp_path: Path, signum: signal.Signals
) -> None:
    bag = tmp_path / "bag"
    recorder = ros.start_recorder(bag, bag.parent / "recorder.log", record_clock=False)
    plant, _ = start_hopping(ros, max_strides=0)  # hops until stopped
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
    assert mcap_counts[resolve(topics.STATE)] >= 1500
    for decoded in (mcap_messages, rosbags_messages):
        assert_gapless_from_start(decoded[resolve(topics.STATE)])


def test_a_recorder_of_the_batches_counts_as_a_subscriber_of_the_state_for_min_subscribers(
    ros: RosGraph, tmp_path: Path
) -> None:
    """With min_subscribers 1 the plant starts once the recorder is there: it hears the state and the force
    through tdslip/samples, not on the live topics."""
    recorder = ros.start_recorder(tmp_path / "bag", tmp_path / "recorder.log", record_clock=False)
    plant, _ = start_hopping(ros, max_strides=2, min_subscribers=1, command_timeout=30.0)
    assert plant.matched_subscribers(topics.STATE) == 0 and plant.matched_subscribers(topics.SAMPLES) == 1
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome.kind == "run_complete" and plant.deliver(ros.executor)
    assert stop_process(recorder) == 0


def samples_batch(ticks: int) -> HopperSamples:
    """A batch of ``ticks`` rows; row k holds k in every column from x on."""
    rows = [(tick, 0, 0, 0, *([float(tick)] * (len(SAMPLE_COLUMNS) - 4))) for tick in range(ticks)]
    return HopperSamples(**{name: [row[i] for row in rows] for i, name in enumerate(SAMPLE_COLUMNS)})


def test_an_autostarting_recorder_records_what_its_taker_takes_before_the_activate_hook(
    ros: RosGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Autostarting, configure and activate are one step: a batch that arrives and is taken while configure
    still runs (in-process here, sent from inside its first discovery) is recorded, not dropped as if the
    recorder were paused. A loaded machine can stall configure that long after the subscriptions exist."""
    node = ros.node("someone")
    batches = node.create_publisher(HopperSamples, topics.SAMPLES, topics.STREAM_QOS)
    discover = RecorderNode._discover
    sent: list[bool] = []

    def discover_after_a_batch_was_taken(recorder: RecorderNode) -> None:
        if not sent:  # (no spinning here: inside the recorder's constructor; DDS matches on its own threads)
            sent.append(True)
            wait_until(lambda: batches.get_subscription_count() >= 1, 20.0)
            batches.publish(samples_batch(3))
            wait_until(lambda: bool(recorder.message_count or recorder.dropped_while_paused), 20.0)
        discover(recorder)

    monkeypatch.setattr(RecorderNode, "_discover", discover_after_a_batch_was_taken)
    bag = tmp_path / "bag"
    recorder = RecorderNode(context=ros.context, parameter_overrides=[Parameter("output", value=str(bag))])
    try:
        recorder.close()
        assert recorder.dropped_while_paused == {}
    finally:
        recorder.destroy_node()
    _, counts, messages = mcap_contents(bag / "bag_0.mcap")
    assert counts[resolve(topics.STATE)] == counts[resolve(topics.GRF)] == 3
    assert [m.x for m in messages[resolve(topics.STATE)]] == [0.0, 1.0, 2.0]


def test_a_malformed_batch_is_skipped_and_recording_goes_on(ros: RosGraph, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    recorder = ros.start_recorder(bag, bag.parent / "recorder.log", record_clock=False)
    node = ros.node("someone")
    batches = node.create_publisher(HopperSamples, topics.SAMPLES, topics.STREAM_QOS)
    ros.spin_until(lambda: batches.get_subscription_count() >= 1, "the recorder to subscribe")
    wait_for_matching(node, [batches], 5.0)
    batches.publish(HopperSamples(sec=[1, 2], nanosec=[0]))  # columns of unequal length
    batches.publish(samples_batch(3))
    assert wait_for_delivery(node)
    assert stop_process(recorder) == 0
    _, counts, messages = mcap_contents(bag / "bag_0.mcap")
    assert counts[resolve(topics.STATE)] == counts[resolve(topics.GRF)] == 3
    assert [m.x for m in messages[resolve(topics.STATE)]] == [0.0, 1.0, 2.0]
    assert "a malformed batch skipped" in (tmp_path / "recorder.log").read_text()
