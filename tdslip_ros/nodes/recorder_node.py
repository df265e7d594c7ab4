"""The recorder node: the suite's topics (and /clock if asked) into a rosbag2-compatible MCAP bag.

It records the topics of :data:`~tdslip_ros.nodes.topics.RECORDED_TOPICS` in its namespace (so
``__ns:=/h1`` records hopper /h1). It subscribes to them at once (reliable and volatile, which any
reliable publisher matches), so a node started after it finds its subscription there from the
start; the plant's state and force through its batches (below). Like rosbag2 it adapts to what the
publishers offer (the graph is looked at every :data:`DISCOVERY_PERIOD` s;
:func:`~tdslip_ros.nodes.topics.adapted_qos`): a topic is registered in the bag with its publishers'
offered profiles when the first one appears, and a subscription that has recorded nothing yet is made
best-effort or transient-local if every publisher is.
The messages are taken raw (the CDR bytes go to :class:`~tdslip_ros.bag.RosbagMcapWriter`
untouched) by a thread, in batches, without a Python callback per message (see
:class:`RecorderNode`); the thread sleeps in a wait set until messages arrive, so a quiet stream
costs no wake-ups; the log time is the system time [ns] at which the message was taken, the
publish time the publisher's source timestamp.

The plant's 1 kHz state and force (:data:`~tdslip_ros.nodes.topics.BATCHED_TOPICS`) are recorded from
its batches on ``tdslip/samples`` while a publisher offers them there: each row is written as the
tdslip/state and tdslip/grf message the plant publishes live at that tick, byte for byte
(:mod:`tdslip_ros.nodes.wire`), with the batch's log and publish time. The bag holds the two topics, not
the batches. Where nobody publishes tdslip/samples (``tdslip replay``, another plant) the recorder
subscribes to the two topics themselves.

Progress goes out on ``tdslip/recorder_status`` (``tdslip_msgs/RecorderStatus``) every
:data:`STATUS_MESSAGES` recorded messages and every DISCOVERY_PERIOD: per topic the messages
written and the publishers matched. A plant with ``wait_for_recorder`` paces itself on it.

Stopping (SIGINT or SIGTERM): the recorder first records what has already reached it (it spins
until no message came for ``DRAIN_QUIET`` s, at most ``DRAIN_LIMIT`` s), then finalises the bag
(summary, ``metadata.yaml``), so the file is complete and readable. A hard kill (SIGKILL) loses at
most the open chunk (``tdslip recover`` makes the rest readable); see :mod:`tdslip_ros.bag.writer`.
A write error (disk full, I/O error) stops the recording with one logged line; the bag is closed,
finalised with everything written when the writer's reserve made that possible, and reported
closed on tdslip/recorder_status, so that a plant stops waiting for it.

A managed node (:mod:`tdslip_ros.nodes.lifecycle`): configure opens the bag, activate starts writing,
deactivate stops writing (what arrives meanwhile is taken and dropped) and finalises the bag, so that it is
complete and valid while the recorder waits; activating again opens the next bag beside it (``<output>_2``,
``<output>_3``, ...: :attr:`RecorderNode.bags`); cleanup and shutdown finalise the open one. A bag closed
after a pause says in its metadata's ``custom_data`` how many messages per topic the recorder had dropped
while paused until then (:data:`DROPPED_WHILE_PAUSED_KEY`, JSON): the last bag's is the run's total. With
``end_with_run`` the executable stops as on SIGINT when the plant's run ends.

Run it in a process of its own next to a 1 kHz plant: every message written costs Python work.
"""

from __future__ import annotations

import contextlib
import json
import sys
import threading
import time
from collections import Counter
from datetime import datetime
from pathlib import Path
from typing import Any

from rclpy.executors import Executor
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from tdslip_msgs.msg import RecorderStatus

from tdslip_ros.bag import BagClosedError, BagWriteError, OfferedQos, RosbagMcapWriter
from tdslip_ros.model.params import ParameterError
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.diagnostics import RECORDER_THRESHOLDS, specs_of
from tdslip_ros.nodes.entry import run_node
from tdslip_ros.nodes.lifecycle import AUTOSTART, END_WITH_RUN, ManagedNode
from tdslip_ros.nodes.node_status import recorder_diagnostics
from tdslip_ros.nodes.parameters import ParameterSpec, ParameterValue
from tdslip_ros.nodes.realtime import name_this_thread
from tdslip_ros.nodes.wire import grf_encoder, sample_rows, serialized, state_encoder

DISCOVERY_PERIOD = 0.05  # s between two looks for new publishers (and status reports)
TAKE_PERIOD = 0.001
"""s the taker thread pauses after a take that found messages, before it waits for the next ones: under a
fast stream (lockstep) each take then finds a batch of them, and a slow one (realtime, ~200 messages a
second) wakes it about twice per burst instead of every TAKE_PERIOD."""
DROPPED_WHILE_PAUSED_KEY = "tdslip_dropped_while_paused"
"""The ``custom_data`` key of a bag's metadata that holds the messages per topic dropped while paused."""
TAKER_THREAD = "tdslip-take"  # the taker thread's name, as ps -L and top -H show it
WAIT_LIMIT_NS = 50_000_000  # the longest the taker sleeps in its wait set before it looks at its stop flag
STATUS_MESSAGES = 100
"""Recorded messages between two status reports: a lockstep plant's flow control sees progress
every ~50 ticks."""
DRAIN_QUIET = 0.2  # s without a message: everything sent before the stop has been recorded
DRAIN_LIMIT = 1.0  # s, the longest a stop waits for the stream to go quiet
SPECS: tuple[ParameterSpec, ...] = (
    AUTOSTART,
    END_WITH_RUN,
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
        "flush_interval",
        1.0,
        "close the open chunk after this much log time [s]: a hard kill loses at most that (0: by size)",
        0.0,
        3600.0,
        read_only=True,
    ),
    ParameterSpec(
        "record_clock", False, "also record /clock (lockstep runs publish it at 1 kHz)", read_only=True
    ),
    ParameterSpec(
        "custom_data",
        "",
        "space-separated KEY=VALUE pairs for the bag metadata's custom_data (ros2 bag record --custom-data)",
        read_only=True,
    ),
    *specs_of(RECORDER_THRESHOLDS),
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


class RecorderNode(ManagedNode):
    """Records into ``bag`` while active, from configure until :meth:`close` (see the module docstring).

    The subscriptions live on a second node (``<name>_reader``) that no executor spins: a thread of
    this node sleeps in a wait set of them until one has messages, then takes every subscription's in
    a batch, with the MessageInfo of each, at about two thirds of the cost of a callback per message.
    The log time is when the message was taken (in DDS's order, so each topic's log times rise with its
    messages even when one was repaired after a loss in transport), the publish time the publisher's
    source timestamp.
    """

    def __init__(self, **node_options: object) -> None:
        self._taker: threading.Thread | None = None  # first: destroy_node must work if the rest raises
        self._reader: Node | None = None
        self.bag: RosbagMcapWriter | None = None
        """The bag being written, or the last one written (finalised), once configured."""
        self.bags: list[Path] = []
        """The bag directories written, one per activation (see the module docstring)."""
        self._recording = threading.Event()  # active: what the taker takes is written
        self._pause_lock = threading.Lock()  # held by the taker while it writes a take, and to pause
        self._active_since_ns = 0
        """System time of the latest activation: a message DDS received before it arrived while paused."""
        self.write_error: str | None = None
        """Why the bag stopped taking messages (a full disk, an I/O error), if it did."""
        self.dropped_while_paused: Counter[str] = Counter()
        """Messages per topic that arrived while the recorder was inactive, taken and not written."""
        self._written_before: Counter[str] = Counter()  # in the bags finalised at earlier pauses
        super().__init__("recorder", SPECS, **node_options)

    def configure(self, values: dict[str, ParameterValue]) -> None:
        output = str(values["output"]) or f"rosbag2_{datetime.now():%Y_%m_%d-%H_%M_%S}"
        self._output = Path(output)
        self._bag_settings = {
            "compression": values["compression"],
            "chunk_size": int(values["chunk_size"]),
            "flush_interval_ns": round(float(values["flush_interval"]) * 1e9),
            "custom_data": parse_custom_data(str(values["custom_data"])),
        }
        self._wake_taker = GuardCondition(None, None, context=self.context)
        """Triggered when the subscriptions change or taking stops: the taker leaves its wait set."""
        self._registered: set[str] = set()
        relative = [*topics.RECORDED_TOPICS, *((topics.CLOCK,) if values["record_clock"] else ())]
        self.topic_names = [self.resolve_topic_name(topic) for topic in relative]
        """The recorded topics, fully qualified, in the order of the status reports."""
        self._message_classes = {
            name: topics.MESSAGE_TYPES[topic] for name, topic in zip(self.topic_names, relative, strict=True)
        }
        self._samples_topic = self.resolve_topic_name(topics.SAMPLES)
        self._message_classes[self._samples_topic] = topics.MESSAGE_TYPES[topics.SAMPLES]
        self._state_topic, self._grf_topic = (self.resolve_topic_name(t) for t in topics.BATCHED_TOPICS)
        self._batched = {self._state_topic, self._grf_topic}
        """The topics recorded from the batches on tdslip/samples while it has a publisher."""
        self._state_encoder, self._grf_encoder = state_encoder(), grf_encoder()
        self.write_error = None
        self._open_bag()
        assert self.bag is not None
        self._reader = Node(
            f"{self.get_name()}_reader",
            namespace=self.get_namespace(),
            context=self.context,
            use_global_arguments=False,  # the names are resolved already; no second remap of the node
        )
        self._topic_subscriptions: dict[str, Subscription[Any]] = {}
        self._subscriptions_lock = threading.Lock()  # the taker thread and the discovery timer
        self._status_lock = threading.Lock()
        self._warned: set[str] = set()
        self._unreported = 0
        self._status = RecorderStatus(bag=str(self.bag.mcap_path), topics=self.topic_names)
        self._status_publisher = self.create_publisher(
            RecorderStatus, topics.RECORDER_STATUS, topics.RECORDER_STATUS_QOS
        )
        # Subscribed from the start (reliable, volatile: any reliable publisher matches), so that
        # a publisher that appears later has the recorder's subscription to match from its start; the
        # batched topics through tdslip/samples, until _discover finds them published without it.
        for name in [self._samples_topic, *self.topic_names]:
            if name not in self._batched:
                self._subscribe(name, topics.adapted_qos([]))
        self._stop_taking = threading.Event()
        if self._autostarting:  # activate runs after the rest of configure: the taker's first take records
            self._recording.set()
        self._taker = threading.Thread(target=self._take_loop, name=TAKER_THREAD, daemon=True)
        self._taker.start()
        self.create_timer(DISCOVERY_PERIOD, self._discover)
        self._discover()
        self.diagnostics = recorder_diagnostics(self, self)

    def _open_bag(self) -> None:
        """Create the bag of this activation: ``output`` the first time, ``output_2``, ... after a pause."""
        if self.bag is not None:
            self._written_before.update(self.bag.message_counts)
        path = (
            self._output
            if not self.bags
            else self._output.with_name(f"{self._output.name}_{len(self.bags) + 1}")
        )
        self.bag = RosbagMcapWriter(path, **self._bag_settings)  # type: ignore[arg-type]
        self.bags.append(path)
        self._registered.clear()
        self.get_logger().info(f"recording {', '.join(self.topic_names)} into {self.bag.mcap_path}")

    def activate(self) -> None:
        assert self.bag is not None
        if self.bag.closed:  # paused before: a new bag, the last one stays as it was finalised
            self._open_bag()
            self._status.bag = str(self.bag.mcap_path)
            self._discover()
        # Autostarting, configure and activate are one step: all that the new subscriptions received counts.
        self._active_since_ns = 0 if self._autostarting else time.time_ns()
        self._recording.set()

    def deactivate(self) -> None:
        """Stop writing (what is taken meanwhile is dropped) and finalise the bag, which is then complete."""
        with self._pause_lock:
            self._recording.clear()
        self._finalise()

    def cleanup(self) -> None:
        self.close()
        if self._reader is not None:
            self._reader.destroy_node()
            self._reader = None
        if hasattr(self, "_wake_taker"):
            self._wake_taker.destroy()
            del self._wake_taker

    def _discover(self) -> None:
        """Register newly published topics in the bag with their offered QoS and adapt a subscription
        that has recorded nothing yet to what its publishers offer (the batched topics: take them from
        tdslip/samples while it has a publisher, else subscribe to them); then report progress."""
        batches = self.count_publishers(self._samples_topic) > 0
        for name in self.topic_names:
            offered = [
                topics.offered_qos(info.qos_profile) for info in self.get_publishers_info_by_topic(name)
            ]
            if not offered:
                continue
            self._register(name, offered)
            subscription = self._topic_subscriptions.get(name)
            if name in self._batched and batches:
                if subscription is not None:  # a plant with batches came after a replay
                    with self._subscriptions_lock:
                        self._unsubscribe(name)
                continue
            wanted = topics.adapted_qos(offered)
            if subscription is None:  # a batched topic published without batches
                if self.count_publishers(self._samples_topic) == 0:  # (still: discovery goes on meanwhile)
                    with self._subscriptions_lock:
                        self._subscribe(name, wanted)
                continue
            if _same_policies(subscription.qos_profile, wanted):
                continue
            if self.bag.message_counts.get(name, 0) == 0:
                with self._subscriptions_lock:
                    self._unsubscribe(name)
                    self._subscribe(name, wanted)
            elif name not in self._warned and not _compatible(subscription.qos_profile, offered):
                self._warned.add(name)
                self.get_logger().warning(
                    f"{name}: a publisher offers a QoS ({offered[-1]}) the recorder's subscription "
                    "cannot hear; its messages are not recorded"
                )
        self.publish_status()

    def _register(self, name: str, offered: list[OfferedQos]) -> None:
        """Add the topic to the bag (once) with the QoS profiles its publishers offer."""
        if name not in self._registered and not self.bag.closed:
            self.bag.add_topic(name, topics.type_name(self._message_classes[name]), offered_qos=offered)
            self._registered.add(name)

    def _subscribe(self, name: str, qos: QoSProfile) -> None:
        assert self._reader is not None
        self._topic_subscriptions[name] = self._reader.create_subscription(
            self._message_classes[name], name, lambda message: None, qos, raw=True
        )
        self._wake_taker.trigger()

    def _unsubscribe(self, name: str) -> None:
        assert self._reader is not None
        self._reader.destroy_subscription(self._topic_subscriptions.pop(name))
        self._wake_taker.trigger()

    def _take_loop(self) -> None:
        name_this_thread(TAKER_THREAD)
        try:
            while not self._stop_taking.is_set():
                if self.take_and_write():
                    time.sleep(TAKE_PERIOD)
                self._wait_for_messages()
        except Exception as error:  # the recording cannot go on: say so, and let the node stop (exit 1)
            if not self._stop_taking.is_set() and self.context.ok():  # (a shut-down context: a stop)
                self.write_error = f"the recorder's taker failed: {error!r}"
                self.get_logger().error(self.write_error)

    def _wait_for_messages(self) -> None:
        """Sleep until a subscription has messages, the subscriptions change, taking stops, or
        WAIT_LIMIT_NS has passed."""
        with contextlib.ExitStack() as held:
            # Held in use, a subscription the discovery timer destroys meanwhile stays valid until the wait
            # ends (rclpy defers its destruction); the timer then wakes the taker.
            with self._subscriptions_lock:
                handles = [s.handle for s in self._topic_subscriptions.values()]
                for handle in handles:
                    held.enter_context(handle)
            wake = self._wake_taker.handle
            held.enter_context(wake)
            held.enter_context(self.context.handle)
            wait_set = _rclpy.WaitSet(len(handles), 1, 0, 0, 0, 0, self.context.handle)
            for handle in handles:
                wait_set.add_subscription(handle)
            wait_set.add_guard_condition(wake)
            wait_set.wait(WAIT_LIMIT_NS)

    def take_and_write(self) -> int:
        """Take every message waiting on the subscriptions and write them, each topic in the order
        DDS delivers it; the number written."""
        taken: list[tuple[int, int, str, bytes]] = []
        with self._subscriptions_lock:
            for name, subscription in self._topic_subscriptions.items():
                handle, message_type = subscription.handle, subscription.msg_type
                with handle:
                    while (message := handle.take_message(message_type, True)) is not None:
                        data, info = message
                        if info["received_timestamp"] >= self._active_since_ns:
                            taken.append((time.time_ns(), info["source_timestamp"], name, data))
                        else:  # it arrived while paused, before the latest activation
                            self._count_dropped(name, data)
        with self._pause_lock:  # a pause comes before or after these, whole
            if not self._recording.is_set():
                for _, _, name, data in taken:
                    self._count_dropped(name, data)
                return 0
            if not taken or self.write_error is not None:
                return 0
            written = 0
            for received, sent, name, data in taken:
                try:
                    if name == self._samples_topic:
                        written += self._write_samples(data, received, sent)
                    else:
                        self._write(name, data, received, sent)
                        written += 1
                except BagWriteError as error:  # the bag is closed now (finalised if it could be)
                    self.write_error = str(error)
                    self.get_logger().error(self.write_error)
                    self.publish_status()
                    return 0
                except BagClosedError:  # closed meanwhile: nothing more is recorded
                    return 0
        self._unreported += written
        if self._unreported >= STATUS_MESSAGES:
            self.publish_status()
        return written

    def _count_dropped(self, name: str, data: bytes) -> None:
        """Count a message taken while paused under the topic(s) it would have been written as."""
        if name != self._samples_topic:
            self.dropped_while_paused[name] += 1
            return
        with contextlib.suppress(ValueError):  # a malformed batch would not have been written either
            rows = sum(1 for _ in sample_rows(data))
            self.dropped_while_paused.update({self._state_topic: rows, self._grf_topic: rows})

    @property
    def written(self) -> Counter[str]:
        """Messages per topic written into every bag of this node (each activation's)."""
        counts = Counter(self._written_before)
        if self.bag is not None:
            counts.update(self.bag.message_counts)
        return counts

    def _write(self, name: str, data: bytes, received: int, sent: int) -> None:
        if name not in self._registered:  # a message before its publisher was discovered
            self._register(
                name, [topics.offered_qos(i.qos_profile) for i in self.get_publishers_info_by_topic(name)]
            )
        self.bag.write(name, data, received, sent)

    def _write_samples(self, data: bytes, received: int, sent: int) -> int:
        """Write a batch of samples as the state and force messages of its ticks; the number written. A
        batch that is no HopperSamples of equal columns is skipped, with one warning."""
        encode_state, encode_grf = self._state_encoder.encode, self._grf_encoder.encode
        state, grf = self._state_topic, self._grf_topic
        try:
            batch = list(sample_rows(data))
        except ValueError as error:  # e.g. `ros2 topic pub` of unequal arrays
            if self._samples_topic not in self._warned:
                self._warned.add(self._samples_topic)
                self.get_logger().warning(f"{self._samples_topic}: a malformed batch skipped ({error})")
            return 0
        rows = 0
        for row in batch:
            self._write(state, encode_state(row[:-2]), received, sent)
            self._write(grf, encode_grf((row[0], row[1], row[-2], row[-1])), received, sent)
            rows += 1
        return 2 * rows

    def publish_status(self) -> None:
        """Report what has been written so far (tdslip/recorder_status)."""
        with self._status_lock:
            self._unreported = 0
            counts = self.bag.message_counts
            status = self._status
            status.header.stamp = self.get_clock().now().to_msg()
            status.recorded = [counts.get(name, 0) for name in self.topic_names]
            status.publishers = [
                subscription.get_publisher_count()
                if (subscription := self._topic_subscriptions.get(name) or self._batch_subscription(name))
                else 0
                for name in self.topic_names
            ]
            status.closed = self.bag.closed
            self._status_publisher.publish(serialized(status))

    def _batch_subscription(self, name: str) -> Subscription[Any] | None:
        """The tdslip/samples subscription, if ``name`` is recorded from it."""
        return self._topic_subscriptions[self._samples_topic] if name in self._batched else None

    @property
    def message_count(self) -> int:
        return 0 if self.bag is None else sum(self.bag.message_counts.values())

    def close(self) -> None:
        """Take what has arrived, stop taking and finalise the bag (idempotent)."""
        if self._taker is not None:
            self._stop_taking.set()
            self._wake_taker.trigger()
            self._taker.join()
            self._taker = None
            self.take_and_write()
        self._recording.clear()
        self._finalise()

    def _finalise(self) -> None:
        if self.bag is not None and not self.bag.closed:
            if self.dropped_while_paused:
                dropped = json.dumps(dict(self.dropped_while_paused))
                self.bag.update_custom_data({DROPPED_WHILE_PAUSED_KEY: dropped})
            self.bag.close()
            counts = ", ".join(f"{topic} {count}" for topic, count in self.bag.message_counts.items())
            self.get_logger().info(f"bag {self.bag.mcap_path} closed: {counts}")
            self.publish_status()

    def destroy_node(self) -> None:
        self.cleanup()
        super().destroy_node()


def _same_policies(actual: QoSProfile, wanted: QoSProfile) -> bool:
    return actual.reliability == wanted.reliability and actual.durability == wanted.durability


def _compatible(requested: QoSProfile, offered: list[OfferedQos]) -> bool:
    """Whether a subscription with the ``requested`` QoS hears every one of the ``offered`` ones."""
    reliable = requested.reliability == ReliabilityPolicy.RELIABLE
    transient = requested.durability == DurabilityPolicy.TRANSIENT_LOCAL
    return all(
        (not reliable or qos.reliability == "reliable")
        and (not transient or qos.durability == "transient_local")
        for qos in offered
    )


def drain(executor: Executor, recorder: RecorderNode) -> None:
    """Spin (status reports) while the taker records, until no message came for DRAIN_QUIET s (at
    most DRAIN_LIMIT s)."""
    deadline = time.monotonic() + DRAIN_LIMIT
    count, quiet_since = recorder.message_count, time.monotonic()
    while (now := time.monotonic()) < deadline and now - quiet_since < DRAIN_QUIET:
        executor.spin_once(timeout_sec=DRAIN_QUIET / 4)
        if recorder.message_count != count:
            count, quiet_since = recorder.message_count, time.monotonic()


def main(argv: list[str] | None = None) -> int:
    """``recorder_node [--ros-args -p output:=DIR ...]``: record until SIGINT/SIGTERM (or the run's end,
    ``end_with_run``)."""

    def finish(recorder: RecorderNode, executor: Executor) -> None:
        drain(executor, recorder)
        recorder.close()

    return run_node(
        RecorderNode,
        "recorder.yaml",
        sys.argv if argv is None else argv,
        # Nothing more can be recorded, or (end_with_run) nothing more is coming.
        lambda node: node.write_error is not None or node.run_ended,
        exit_status=lambda node: 1 if node.write_error is not None else 0,
        on_stop=finish,
        specs=SPECS,
    )


if __name__ == "__main__":
    sys.exit(main())
