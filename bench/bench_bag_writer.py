"""Throughput of RosbagMcapWriter.write against the recorder's need and against bare mcap.

    python bench/bench_bag_writer.py [--messages N]

For each chunk compression it writes N pre-serialized 1 kHz-style messages (WrenchStamped with a
changing stamp and force, round-robin over three topics) and prints, side by side: the cost per
write, the sustainable rate as a multiple of the 5 kHz the recorder must absorb from a Python
callback, the cost relative to calling ``mcap.writer.Writer.add_message`` directly (the price of
the rosbag2 bookkeeping, locking and validation), the close time and the compression ratio.

A second table prices the periodic flush (``flush_interval_ns``), which bounds what a hard kill of
the recorder loses to that much log time instead of one full chunk: zstd, messages logged at
FLUSH_RATE_HZ (a realtime run's state and force streams), side by side with no flush.
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

from geometry_msgs.msg import Vector3, Wrench, WrenchStamped
from mcap.reader import make_reader
from mcap.writer import Writer
from rclpy.serialization import serialize_message
from std_msgs.msg import Header

from tdslip_ros.bag import RosbagMcapWriter
from tdslip_ros.bag.writer import MCAP_COMPRESSION

REQUIRED_RATE_HZ = 5_000
FLUSH_RATE_HZ = 2_000
FLUSH_INTERVALS_S = (0.0, 2.0, 1.0, 0.5, 0.25, 0.1)
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


def time_rosbag_writer(
    path: Path, compression: str, data: list[bytes], spacing_ns: int = 1_000_000, flush_interval_ns: int = 0
) -> tuple[float, float, int]:
    bag = RosbagMcapWriter(path, compression=compression, flush_interval_ns=flush_interval_ns)  # type: ignore[arg-type]
    for topic in TOPICS:
        bag.add_topic(topic, "geometry_msgs/msg/WrenchStamped")
    start = time.perf_counter()
    for index, payload in enumerate(data):
        bag.write(TOPICS[index % 3], payload, spacing_ns * index)
    written = time.perf_counter()
    bag.close()
    closed = time.perf_counter()
    return written - start, closed - written, bag.mcap_path.stat().st_size


def chunk_count(path: Path) -> int:
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    return 0 if summary is None or summary.statistics is None else summary.statistics.chunk_count


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
            write_s, close_s, size = time_rosbag_writer(Path(scratch) / compression, compression, data)
            bare_s = time_bare_mcap(compression, data)
            per_write = write_s / count
            print(
                f"{compression:<12}{per_write * 1e6:>10.2f}{1 / per_write / REQUIRED_RATE_HZ:>10.0f}x"
                f"{write_s / bare_s:>13.2f}x{close_s * 1e3:>10.1f}{raw_bytes / size:>10.2f}"
            )

        print_flush_costs(Path(scratch), data, raw_bytes)


def print_flush_costs(scratch: Path, data: list[bytes], raw_bytes: int, repeats: int = 3) -> None:
    """The flush table (module docstring); write times are the best of ``repeats``."""
    spacing_ns = 1_000_000_000 // FLUSH_RATE_HZ
    print(f"\nperiodic flush, zstd, messages logged at {FLUSH_RATE_HZ} Hz (best of {repeats})")
    print(
        f"{'flush every':<12}{'chunks':>8}{'us/write':>10}{'vs never':>10}{'raw/file':>10}{'vs never':>10}"
        f"{'kill loses at most':>22}"
    )
    baseline: tuple[float, int] | None = None
    for interval_s in FLUSH_INTERVALS_S:
        interval_ns = round(interval_s * 1e9)
        runs = []
        for repeat in range(repeats):
            path = scratch / f"flush-{interval_s}-{repeat}"
            runs.append((*time_rosbag_writer(path, "zstd", data, spacing_ns, interval_ns), path))
        write_s = min(run[0] for run in runs)
        size, path = runs[0][2], runs[0][3]
        chunks = chunk_count(path / f"{path.name}_0.mcap")
        baseline = baseline or (write_s, size)
        label = f"{interval_s:g} s" if interval_s else "never"
        bound = label if interval_s else f"{len(data) / chunks / FLUSH_RATE_HZ:.2f} s (a chunk)"
        print(
            f"{label:<12}{chunks:>8}{write_s / len(data) * 1e6:>10.2f}{write_s / baseline[0]:>9.2f}x"
            f"{raw_bytes / size:>10.2f}{baseline[1] / size:>9.2f}x{bound:>22}"
        )


if __name__ == "__main__":
    main()
