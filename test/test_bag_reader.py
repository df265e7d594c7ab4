"""The generic rosbag2 reader (tdslip_ros.bag.reader): the checks it makes before anything is read,
the rosbag2 record it takes, message order; and that the bag package imports nothing above it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from tdslip_ros.bag import RosbagMcapWriter
from tdslip_ros.bag.qos import dump_yaml
from tdslip_ros.bag.reader import BagReadError, iter_messages, open_bag, verify

STRING = bytes([0, 1, 0, 0, 4, 0, 0, 0]) + b"abc\0"


def test_the_bag_package_and_the_replay_import_nothing_above_them(repo_root: Path) -> None:
    """Imports point down: bag/ needs neither the analysis nor the nodes (nor rclpy), and the replay
    node reads recordings through bag/, not through the analysis."""
    code = (
        "import sys, importlib\n"
        "above = ('tdslip_ros.analysis', 'tdslip_ros.nodes', 'rclpy')\n"
        "for name in ('reader', 'writer', 'cdr', 'recover', 'qos', 'schema'):\n"
        "    importlib.import_module('tdslip_ros.bag.' + name)\n"
        "print(sorted(m for m in sys.modules if m.startswith(above)))\n"
        "import tdslip_ros.nodes.replay\n"
        "print(sorted(m for m in sys.modules if m.startswith('tdslip_ros.analysis')))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=repo_root, capture_output=True, text=True, check=True, timeout=120
    )
    assert result.stdout.split("\n")[:2] == ["[]", "[]"]


def small_bag(path: Path) -> Path:
    with RosbagMcapWriter(path, bag_directory=False, chunk_size=1024) as bag:
        bag.add_topic("/chatter", "std_msgs/msg/String")
        for number in range(200):
            bag.write("/chatter", STRING, 1_000 * number)
    return path


def test_a_corrupt_summary_section_is_refused(tmp_path: Path) -> None:
    path = small_bag(tmp_path / "run.mcap")
    with path.open("rb") as stream:
        reader = make_reader(stream)
        reader.get_summary()
        stream.seek(-(8 + 29), 2)  # the footer: opcode, length, summary start, ...
        footer = stream.read(29)
    summary_start = int.from_bytes(footer[9:17], "little")
    data = bytearray(path.read_bytes())
    data[summary_start + 40] ^= 0x20  # inside the first summary record (a schema's text)
    path.write_bytes(bytes(data))
    with pytest.raises(BagReadError, match="the summary section is corrupt"):
        open_bag(path)


def test_the_closing_rosbag2_record_is_the_one_read(tmp_path: Path) -> None:
    """rosbag2 writes its record at open and at close; like its reader, the last one counts."""
    path = tmp_path / "two_records.mcap"
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2")
        for policy in ("at open", "at close"):
            information = {"custom_data": {"policy": policy}, "ros_distro": "kilted"}
            writer.add_metadata("rosbag2", {"serialized_metadata": dump_yaml(information)})
        writer.finish()  # type: ignore[no-untyped-call]
    bag = open_bag(path)
    assert (bag.custom_data, bag.ros_distro, bag.message_count) == ({"policy": "at close"}, "kilted", 0)


def test_messages_come_in_file_or_log_time_order(tmp_path: Path) -> None:
    path = tmp_path / "unordered.mcap"
    times = [5, 1, 4, 2, 3, 0]
    with RosbagMcapWriter(path, bag_directory=False, chunk_size=64) as bag:
        bag.add_topic("/chatter", "std_msgs/msg/String")
        for time in times:
            bag.write("/chatter", STRING, time)
    opened = open_bag(path)
    assert [message.log_time for _, message in iter_messages(opened)] == times
    assert [message.log_time for _, message in iter_messages(opened, log_time_order=True)] == sorted(times)
    assert (opened.start_ns, opened.end_ns) == (0, 5)
    verify(opened)
    assert list(iter_messages(opened, topics=["/other"])) == []
