"""``tdslip replay``: record -> replay -> record again gives the same messages in the same order."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import rclpy
from mcap.reader import make_reader
from rclpy.context import Context
from rclpy.qos import HistoryPolicy
from rclpy.signals import SignalHandlerOptions
from support.analysis_runs import as_recorded_before_pitch, by_topic, raw_messages

from tdslip_ros.bag.reader import mcap_file, open_bag
from tdslip_ros.commands.replay import main
from tdslip_ros.interfaces import config_file, resolve
from tdslip_ros.nodes import isolation, topics
from tdslip_ros.nodes.replay import ReplayError, check_rate, checked_bag, offered_qos, replay, send_offset
from tdslip_ros.nodes.runner import ChildNode, RunReport


@contextmanager
def ros_domain() -> Iterator[tuple[Context, dict[str, str]]]:
    """An rclpy context on a private domain, and the environment for child processes on it."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = isolation.DISCOVERY_RANGE  # read at init
    with isolation.reserved_domain() as domain_id:
        context = Context()
        rclpy.init(context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        try:
            yield context, isolation.isolated_environment(domain_id)
        finally:
            rclpy.try_shutdown(context=context)


def test_record_replay_record_gives_the_same_messages_in_the_same_order(
    energy: RunReport, tmp_path: Path
) -> None:
    original = mcap_file(energy.bag)
    again = tmp_path / "again"
    with ros_domain() as (context, environment):
        recorder = ChildNode.start(
            "tdslip_ros.nodes.recorder_node",
            ["--params-file", str(config_file("recorder.yaml")), "-p", f"output:={again}"],
            environment,
        )
        try:
            # Original timing (rate 1): the replay can be no faster than the recording's log times.
            result = replay(energy.bag, 1.0, wait_for_subscribers=1, wait_for_recorder=True, context=context)
            recorder.stop()
        finally:
            recorder.close()
    recorded = by_topic(original)
    assert result.published == {topic: len(recorded.get(topic, [])) for topic in result.published}
    assert result.acknowledged and not result.stopped
    log_times = [log_time for _, _, log_time, _, _ in raw_messages(original)]
    assert result.duration >= (max(log_times) - min(log_times)) * 1e-9
    replayed = by_topic(mcap_file(again))
    streamed = {resolve(topics.HIP_TORQUE), resolve(topics.APPLIED_TORQUE)}  # stance feedback: none here
    assert set(replayed) == set(recorded) == {resolve(topic) for topic in topics.RECORDED_TOPICS} - streamed
    for topic, messages in recorded.items():
        assert replayed[topic] == messages, topic  # same CDR bytes, same order, nothing lost


def test_replay_publishes_with_the_recorded_qos(energy: RunReport) -> None:
    recording = open_bag(energy.bag)
    for topic in set(topics.RECORDED_TOPICS) - {topics.HIP_TORQUE}:  # a ramp run: no hip torque publisher
        replayed, published = offered_qos(recording.topics[resolve(topic)]), topics.qos(topic)
        assert (replayed.reliability, replayed.durability) == (published.reliability, published.durability)
        # The graph reports no history (recorded as unknown): kept last, as deep as the plant's.
        assert replayed.history is HistoryPolicy.KEEP_LAST and replayed.depth == topics.STREAM_DEPTH, topic


def test_schedule_scales_the_recorded_spacing() -> None:
    first = 1_700_000_000_000_000_000
    assert send_offset(first, first, 1.0) == 0.0
    assert send_offset(first + 500_000_000, first, 1.0) == pytest.approx(0.5)
    assert send_offset(first + 500_000_000, first, 2.0) == pytest.approx(0.25)
    assert send_offset(first + 500_000_000, first, 0.5) == pytest.approx(1.0)
    assert send_offset(first + 500_000_000, first, math.inf) == 0.0
    for rate in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="rate must be positive"):
            check_rate(rate)


def test_replay_refuses_a_flipped_byte_before_publishing_anything(
    energy: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A flipped byte inside a chunk (the summary still intact) is found by the full checked pass."""
    source = mcap_file(energy.bag)
    with source.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    start = min(index.chunk_start_offset for index in summary.chunk_indexes)
    data = bytearray(source.read_bytes())
    data[start + 500] ^= 0x01
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(data))
    assert main([str(path), "--rate", "inf"]) == 2
    error = capsys.readouterr().err
    assert error.startswith("tdslip replay: ") and "corrupt data" in error and error.count("\n") == 1
    with pytest.raises(ReplayError, match="corrupt data"):
        replay(path, math.inf)


@pytest.mark.parametrize("rate", ["1e-300", "0", "-1", "nan"])
def test_a_rate_that_cannot_replay_the_recording_is_one_line(
    energy: RunReport, capsys: pytest.CaptureFixture[str], rate: str
) -> None:
    assert main([str(energy.bag), "--rate", rate]) == 2
    error = capsys.readouterr().err
    assert error.startswith("tdslip replay: ") and error.count("\n") == 1 and "rate" in error


def test_a_recording_of_older_messages_is_refused_by_name_before_ros_starts(
    energy: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bag of tdslip_msgs 0.1.0 holds HopperState, ApexEvent and ContactEvent without the pitch: replayed
    as recorded, today's subscribers could not decode them. The command says so in one line."""
    old = as_recorded_before_pitch(mcap_file(energy.bag), tmp_path / "old.mcap")
    assert main([str(old), "--rate", "inf"]) == 2
    error = capsys.readouterr().err
    assert error.startswith("tdslip replay: ") and error.count("\n") == 1
    assert "differing: pitch, pitch_rate" in error and "tdslip analyze reads" in error
    assert checked_bag(energy.bag).message_count == open_bag(old).message_count  # today's bag passes


def test_replay_of_a_damaged_recording_fails_cleanly(
    energy: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "cut.mcap"
    path.write_bytes(mcap_file(energy.bag).read_bytes()[:5000])
    with pytest.raises(ReplayError, match="truncated"):
        replay(path)
    assert main([str(path)]) == 2  # checked before ROS starts: a usage error
    captured = capsys.readouterr()
    assert captured.err.startswith("tdslip replay: ") and "Traceback" not in captured.err
