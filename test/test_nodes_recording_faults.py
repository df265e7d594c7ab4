"""Faults of the recorder node in the middle of a lockstep hop, the recorder in a child process as
``tdslip run`` runs it: a hard kill (then ``tdslip recover``) and a full disk each leave a bag that
the analysis and the replay read, and the messages lost are counted against those published."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from rclpy.parameter import Parameter
from support.ros_harness import RosGraph
from tdslip_msgs.msg import RecorderStatus
from test_nodes_recorder import published_counts, start_hopping

from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.bag import open_bag
from tdslip_ros.bag.recover import recover
from tdslip_ros.interfaces import resolve
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.flow_control import FLOW_WINDOW
from tdslip_ros.nodes.recorder_node import TAKER_THREAD, RecorderNode
from tdslip_ros.nodes.replay import checked_bag
from tdslip_ros.nodes.run_options import RunOptions, run_custom_data

CHUNK_SIZE = 64 * 1024


def lost_against_published(bag: Path, published: dict[str, int]) -> dict[str, int]:
    recorded = {topic: info.message_count for topic, info in open_bag(bag).topics.items()}
    return {topic: count - recorded.get(topic, 0) for topic, count in published.items()}


def check_readable(bag: Path, published: dict[str, int]) -> None:
    """The analysis reads the bag with the parameters stored in it; its 1 kHz samples run gapless
    from t = 0; the replay accepts it."""
    run = read_run(bag)
    assert run.params_source == "stored in the recording" and run.params == PAPER_PARAMS
    assert np.array_equal(np.round(run.samples.t * 1000.0), np.arange(len(run.samples)))
    assert 0 < len(run.samples) <= published[resolve(topics.STATE)]
    checked_bag(bag)


def test_a_hard_killed_recorder_loses_only_its_open_chunk(ros: RosGraph, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    recorder = ros.start_recorder(
        bag,
        tmp_path / "recorder.log",
        chunk_size=CHUNK_SIZE,
        custom_data=run_custom_data(RunOptions(out=bag), PAPER_PARAMS),
    )
    plant, controller = start_hopping(ros, max_strides=0)
    ros.spin_until(lambda: plant.published[topics.STATE] >= 2000, "2 s of simulated hopping")
    recorder.kill()
    recorder.wait(30)
    published = published_counts(plant, controller)

    recovery = recover(bag)
    lost = lost_against_published(bag, published)
    print(
        f"\nrecorder killed: published {published}, lost {lost}, {recovery.scan.discarded_bytes} B discarded"
    )
    assert all(count >= 0 for count in lost.values()) and sum(lost.values()) > 0
    # Lost: what was in the open chunk (state and force messages are over 100 B each) and what the
    # lockstep plant may run ahead of the recorder.
    assert lost[resolve(topics.STATE)] + lost[resolve(topics.GRF)] <= CHUNK_SIZE // 100 + 2 * FLOW_WINDOW
    check_readable(bag, published)


def test_a_full_disk_stops_the_recording_with_a_finalised_readable_bag(
    ros: RosGraph, tmp_path: Path, tiny_disk: Path
) -> None:
    # Leave about 0.9 MB: the recorder's reserve (two 16 KiB chunks and 512 KiB) and ~350 kB of data.
    free = os.statvfs(tiny_disk).f_bavail * os.statvfs(tiny_disk).f_frsize
    (tiny_disk / "filler").write_bytes(bytes(free - 900_000))
    bag = tiny_disk / "bag"
    recorder = ros.start_recorder(
        bag,
        tmp_path / "recorder.log",
        chunk_size=16 * 1024,
        custom_data=run_custom_data(RunOptions(out=bag), PAPER_PARAMS),
    )
    statuses: list[RecorderStatus] = []
    ros.node("status_probe").create_subscription(
        RecorderStatus, topics.RECORDER_STATUS, statuses.append, topics.RECORDER_STATUS_QOS
    )
    plant, controller = start_hopping(ros, max_strides=0)
    ros.spin_until(lambda: any(status.closed for status in statuses), "the recorder to report its bag closed")
    published = published_counts(plant, controller)
    assert plant.published[topics.STATE] > 0 and plant.outcome is None  # the plant goes on hopping
    # The recorder ends by itself with status 1: it can record nothing more.
    assert recorder.wait(30) == 1

    log = (tmp_path / "recorder.log").read_text()
    errors = [line for line in log.splitlines() if "No space left on device" in line]
    assert len(errors) == 1 and "recording stopped, the bag is finalised with all" in errors[0], log
    assert "Traceback" not in log
    lost = lost_against_published(bag, published)
    print(f"\ndisk full: published {published}, not recorded {lost}")
    assert (bag / "metadata.yaml").is_file()
    check_readable(bag, published)


def test_a_taker_that_fails_stops_the_recording_with_one_line_and_a_finalised_bag(
    ros: RosGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The thread that takes the messages fails (in-process here, its wait made to raise): the recorder says
    why once and asks to stop (its exit status 1), instead of recording nothing more while it looks alive."""

    names: list[str] = []

    def broken_wait(recorder: RecorderNode) -> None:
        names.append(Path("/proc/thread-self/comm").read_text())
        raise RuntimeError("wait set lost")

    monkeypatch.setattr(RecorderNode, "_wait_for_messages", broken_wait)
    bag = tmp_path / "bag"
    recorder = RecorderNode(context=ros.context, parameter_overrides=[Parameter("output", value=str(bag))])
    try:
        ros.spin_until(lambda: recorder.write_error is not None, "the taker to fail")
        assert recorder.write_error == "the recorder's taker failed: RuntimeError('wait set lost')"
        assert names == [f"{TAKER_THREAD}\n"]  # as ps -L and top -H show the thread
    finally:
        recorder.destroy_node()
    assert (bag / "metadata.yaml").is_file()
    assert open_bag(bag).topics == {}
