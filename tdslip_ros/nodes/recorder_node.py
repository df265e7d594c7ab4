"""The recorder node: every /tdslip/* topic (and /clock if asked) into a rosbag2-compatible MCAP bag.

Subscriptions are raw (the CDR bytes go to :class:`~tdslip_ros.bag.RosbagMcapWriter` untouched)
with the publishers' QoS (:mod:`tdslip_ros.nodes.topics`), so every message published while the
recorder is matched is recorded, and the controller's answers also from before it matched. Every
topic is in the bag from the start, with the suite's QoS as offered QoS, even if nothing is
published on it. Log and publish time are both the system time [ns] at
which the callback takes the message (rosbag2 before Jazzy did the same): rclpy's EventsExecutor
cannot yet pass the MessageInfo with the publisher's source timestamp (Kilted: "SystemError: null
argument to internal routine"), and the Python executors are too slow for 1 kHz topics.

Stopping (SIGINT or SIGTERM): the recorder first records what has already reached it (it spins
until no message came for ``DRAIN_QUIET`` s, at most ``DRAIN_LIMIT`` s), then finalises the bag
(summary, ``metadata.yaml``), so the file is complete and readable. A publisher that has seen all
its messages acknowledged (``wait_for_all_acked``) before the signal therefore finds all of them
in the bag. A hard kill (SIGKILL) loses at most the open chunk; see :mod:`tdslip_ros.bag.writer`.

Run it in a process of its own next to a 1 kHz plant: each message costs a Python callback.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

from rclpy.executors import Executor
from rclpy.node import Node

from tdslip_ros.bag import RosbagMcapWriter
from tdslip_ros.model.params import ParameterError
from tdslip_ros.nodes import parameters, topics
from tdslip_ros.nodes.entry import run_node
from tdslip_ros.nodes.parameters import ParameterSpec

DRAIN_QUIET = 0.2  # s without a message: everything sent before the stop has been recorded
DRAIN_LIMIT = 1.0  # s, the longest a stop waits for the stream to go quiet
SPECS: tuple[ParameterSpec, ...] = (
    ParameterSpec(
        "output",
        "",
        "bag directory to create (must not exist); empty: rosbag2_<date>-<time> in the working directory",
        read_only=True,
    ),
    ParameterSpec(
        "compression", "zstd", "MCAP chunk compression", choices=("zstd", "lz4", "none"), read_only=True
    ),
    ParameterSpec("chunk_size", 768 * 1024, "MCAP chunk size [bytes]", 1024, 1 << 30, read_only=True),
    ParameterSpec(
        "record_clock", False, "also record /clock (lockstep runs publish it at 1 kHz)", read_only=True
    ),
    ParameterSpec(
        "custom_data",
        "",
        "space-separated KEY=VALUE pairs for the bag metadata's custom_data (ros2 bag record --custom-data)",
        read_only=True,
    ),
)


def parse_custom_data(text: str) -> dict[str, str]:
    """``"k1=v1 k2=v2"`` as a mapping; ParameterError names an item without a key and a ``=``."""
    pairs = {}
    for item in text.split():
        key, equals, value = item.partition("=")
        if not key or not equals:
            raise ParameterError(f"custom_data: {item!r} is not KEY=VALUE")
        pairs[key] = value
    return pairs


class RecorderNode(Node):
    """Records into ``bag`` from construction until :meth:`close`."""

    def __init__(self, **node_options: object) -> None:
        super().__init__("recorder", **node_options)  # type: ignore[arg-type]
        self.add_on_set_parameters_callback(lambda changed: parameters.validate(SPECS, changed))
        values = parameters.declare(self, SPECS)
        output = str(values["output"]) or f"rosbag2_{datetime.now():%Y_%m_%d-%H_%M_%S}"
        self.bag = RosbagMcapWriter(
            Path(output),
            compression=values["compression"],  # type: ignore[arg-type]
            chunk_size=int(values["chunk_size"]),
            custom_data=parse_custom_data(str(values["custom_data"])),
        )
        recorded = [*topics.TDSLIP_TOPICS, *((topics.CLOCK,) if values["record_clock"] else ())]
        for topic in recorded:
            message_class = topics.MESSAGE_TYPES[topic]
            self.bag.add_topic(
                topic, topics.type_name(message_class), offered_qos=(topics.offered_qos(topic),)
            )
            self.create_subscription(message_class, topic, self._writer(topic), topics.qos(topic), raw=True)
        self.get_logger().info(f"recording {', '.join(recorded)} into {self.bag.mcap_path}")

    def _writer(self, topic: str) -> Callable[[bytes], None]:
        write = self.bag.write

        def record(data: bytes) -> None:
            write(topic, data, time.time_ns())

        return record

    @property
    def message_count(self) -> int:
        return sum(self.bag.message_counts.values())

    def close(self) -> None:
        """Finalise the bag (idempotent); the subscriptions stay but write nothing more."""
        if not self.bag.closed:
            self.bag.close()
            counts = ", ".join(f"{topic} {count}" for topic, count in self.bag.message_counts.items())
            self.get_logger().info(f"bag {self.bag.mcap_path} closed: {counts}")

    def destroy_node(self) -> None:
        self.close()
        super().destroy_node()


def drain(executor: Executor, recorder: RecorderNode) -> None:
    """Spin until no message arrived for DRAIN_QUIET s (at most DRAIN_LIMIT s)."""
    deadline = time.monotonic() + DRAIN_LIMIT
    count, quiet_since = recorder.message_count, time.monotonic()
    while (now := time.monotonic()) < deadline and now - quiet_since < DRAIN_QUIET:
        executor.spin_once(timeout_sec=DRAIN_QUIET / 4)
        if recorder.message_count != count:
            count, quiet_since = recorder.message_count, time.monotonic()


def main(argv: list[str] | None = None) -> int:
    """``recorder_node [--ros-args -p output:=DIR ...]``: record until SIGINT/SIGTERM."""

    def finish(recorder: RecorderNode, executor: Executor) -> None:
        drain(executor, recorder)
        recorder.close()

    return run_node(
        RecorderNode, "recorder.yaml", sys.argv if argv is None else argv, lambda node: False, on_stop=finish
    )


if __name__ == "__main__":
    sys.exit(main())
