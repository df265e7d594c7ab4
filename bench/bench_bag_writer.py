"""Throughput of RosbagMcapWriter.write against the recorder's need and against bare mcap.

    python bench/bench_bag_writer.py [--messages N]

For each chunk compression it writes N pre-serialized 1 kHz-style messages (WrenchStamped with a
changing stamp and force, round-robin over three topics) and prints, side by side: the cost per
write, the sustainable rate as a multiple of the 5 kHz the recorder must absorb from a Python
callback, the cost relative to calling ``mcap.writer.Writer.add_message`` directly (the price of
the rosbag2 bookkeeping, locking and validation), the close time and the compression ratio.
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

from geometry_msgs.msg import Vector3, Wrench, WrenchStamped
from mcap.writer import Writer
from rclpy.serialization import serialize_message
from std_msgs.msg import Header

from tdslip_ros.bag import RosbagMcapWriter
from tdslip_ros.bag.writer import MCAP_COMPRESSION

REQUIRED_RATE_HZ = 5_000
TOPICS = ("/tdslip/state", "/tdslip/grf", "/tdslip/energy")


def payloads(count: int) -> list[bytes]:
    messages = []
    for index in range(count):
        message = WrenchStamped(
            header=Header(frame_id="world"), wrench=Wrench(force=Vector3(x=0.001 * index))
        )
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(index * 1_000_000, 1_000_000_000)
        messages.append(serialize_message(message))
    return messages


def time_rosbag_writer(directory: Path, compression: str, data: list[bytes]) -> tuple[float, float, int]:
    bag = RosbagMcapWriter(directory / compression, compression=compression)  # type: ignore[arg-type]
    for topic in TOPICS:
        bag.add_topic(topic, "geometry_msgs/msg/WrenchStamped")
    start = time.perf_counter()
    for index, payload in enumerate(data):
        bag.write(TOPICS[index % 3], payload, 1_000_000 * index)
    written = time.perf_counter()
    bag.close()
    closed = time.perf_counter()
    return written - start, closed - written, bag.mcap_path.stat().st_size


def time_bare_mcap(compression: str, data: list[bytes]) -> float:
    writer = Writer(io.BytesIO(), compression=MCAP_COMPRESSION[compression])
    writer.start(profile="ros2")
    schema = writer.register_schema("geometry_msgs/msg/WrenchStamped", "ros2msg", b"")
    channels = [writer.register_channel(topic, "cdr", schema) for topic in TOPICS]
    start = time.perf_counter()
    for index, payload in enumerate(data):
        writer.add_message(channels[index % 3], 1_000_000 * index, payload, 1_000_000 * index, index)
    elapsed = time.perf_counter() - start
    writer.finish()  # type: ignore[no-untyped-call]
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=100_000)
    count = parser.parse_args().messages
    data = payloads(count)
    raw_bytes = sum(len(payload) for payload in data)
    print(f"{count} messages of {len(data[0])} B, round-robin on {len(TOPICS)} topics")
    print(
        f"{'compression':<12}{'us/write':>10}{'rate/5kHz':>11}{'vs bare mcap':>14}"
        f"{'close ms':>10}{'raw/file':>10}"
    )
    with tempfile.TemporaryDirectory() as scratch:
        for compression in ("none", "lz4", "zstd"):
            write_s, close_s, size = time_rosbag_writer(Path(scratch), compression, data)
            bare_s = time_bare_mcap(compression, data)
            per_write = write_s / count
            print(
                f"{compression:<12}{per_write * 1e6:>10.2f}{1 / per_write / REQUIRED_RATE_HZ:>10.0f}x"
                f"{write_s / bare_s:>13.2f}x{close_s * 1e3:>10.1f}{raw_bytes / size:>10.2f}"
            )


if __name__ == "__main__":
    main()
