"""Re-publish a recording on its original topics, like ``ros2 bag play`` (what ``tdslip replay RUN
[--rate R]`` does).

Every message of the recording (a bag directory or a bare ``.mcap``) is published as the raw CDR
bytes it was recorded as, in the order of its log (receive) time, and spaced as it was recorded:
message i goes out ``(log_time_i - log_time_0) / R`` after the first (``--rate inf``: as fast as
possible). Each topic gets a publisher of its recorded message type with the QoS recorded as
offered (``offered_qos_profiles``: history, depth, reliability, durability), so reliable KEEP_ALL topics
stay lossless. Publishers are reliable within one process and topic, so every subscriber receives
each topic's messages in the recorded order. Before the first message the replay can wait for
subscribers (``--wait-for-subscribers N``: N on every topic), since volatile topics are not kept for
late joiners, and for a recorder_node (``--wait-for-recorder``) that reports on
``tdslip/recorder_status`` a matched publisher on every replayed topic. Both are needed for a
complete recording: discovery completes on the two sides at different moments, and a reader that
has not yet matched a volatile writer drops what that writer sends it (the first tens of
milliseconds of a replay, about one run in twenty). At the end it waits until reliable subscribers
have acknowledged everything.

The recording is read with the checks of ``tdslip analyze`` (:mod:`tdslip_ros.bag.reader`: magic,
footer, summary CRC, every chunk's CRC, message counts) in a full pass before ROS starts, so a
damaged file is refused with one line before anything is published. A rate at which the replay
would take longer than MAX_REPLAY_DURATION is refused too.

It publishes on the ROS domain of the environment (``ROS_DOMAIN_ID``), as any ROS tool does.
SIGINT or SIGTERM stops it between two messages, also while it waits for the next one.
"""

from __future__ import annotations

import importlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tdslip_msgs.msg import RecorderStatus

from tdslip_ros.bag.reader import Bag, BagReadError, TopicInfo, iter_messages, open_bag, verify
from tdslip_ros.bag.schema import (
    MessageDefinitionError,
    canonical_type_name,
    message_definition,
    message_fields,
    split_type_name,
)
from tdslip_ros.interfaces import RECORDER_STATUS
from tdslip_ros.nodes.entry import SPIN_SLICE, spin_until
from tdslip_ros.nodes.flow_control import FLOW_WINDOW, RecorderProgress
from tdslip_ros.nodes.topics import RECORDER_STATUS_QOS, STREAM_DEPTH

ACK_TIMEOUT = 10.0  # s for reliable subscribers to acknowledge the last messages
UNKNOWN_HISTORY_DEPTH = STREAM_DEPTH
"""Depth of a replayed topic whose recorded history is unknown: the plant's own."""
MAX_REPLAY_DURATION = 365 * 24 * 3600.0
"""s, the longest replay accepted (recording span / rate)."""
_NS_PER_S = 1_000_000_000
_HISTORY = {"keep_all": HistoryPolicy.KEEP_ALL, "keep_last": HistoryPolicy.KEEP_LAST}
_RELIABILITY = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {"volatile": DurabilityPolicy.VOLATILE, "transient_local": DurabilityPolicy.TRANSIENT_LOCAL}


class ReplayError(RuntimeError):
    """The recording cannot be replayed (unreadable, unknown message type, no subscribers in time)."""


@dataclass(frozen=True)
class ReplayResult:
    published: dict[str, int]
    duration: float
    """s of wall time from the first message to the last."""
    acknowledged: bool
    stopped: bool


def message_class(type_name: str) -> type:
    """The generated Python class of ``pkg/msg/Type`` (the package must be installed)."""
    package, name = split_type_name(type_name)
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)  # type: ignore[no-any-return]
    except (ImportError, AttributeError):
        raise ReplayError(f"message type {type_name} is not installed (no {package}.msg.{name})") from None


def check_layout(topic: TopicInfo) -> None:
    """ReplayError unless the topic's recorded messages have the fields of the installed type: its bytes are
    published as they are, and subscribers decode them by the installed definition (a bag of tdslip_msgs
    0.1.0 lacks 0.2.0's pitch, which ``tdslip analyze`` reads as 0, but which replay cannot add)."""
    if topic.schema is None:
        return
    name = canonical_type_name(topic.type_name)
    try:
        installed = message_fields(name, message_definition(name))
    except MessageDefinitionError:
        return  # not installed: refused by name when its publisher is made (message_class)
    recorded = message_fields(name, topic.schema.data.decode())
    if recorded != installed:
        own = {field.name for field in installed[1][installed[0]]}
        stored = {field.name for field in recorded[1][recorded[0]]}
        differ = ", ".join(sorted(own ^ stored)) or "a nested type's"
        raise ReplayError(
            f"{topic.topic}: recorded as a {name} of other fields than the installed one (differing: "
            f"{differ}); replay publishes the recorded bytes, which today's subscribers could not decode. "
            "tdslip analyze reads the recording as it is"
        )


def offered_qos(topic: TopicInfo) -> QoSProfile:
    """The first offered QoS profile recorded for ``topic`` (rclpy's defaults where it has none).

    The ROS graph does not report a publisher's history (rosbag2 and the recorder store it as
    ``unknown``, depth 0): such a topic is replayed KEEP_LAST with UNKNOWN_HISTORY_DEPTH samples.
    """
    try:
        profiles = yaml.safe_load(topic.metadata.get("offered_qos_profiles", "")) or []
    except yaml.YAMLError as error:
        raise ReplayError(f"{topic.topic}: unreadable offered_qos_profiles ({error})") from None
    profile: dict[str, object] = profiles[0] if profiles else {}
    history = _HISTORY.get(str(profile.get("history")), HistoryPolicy.KEEP_LAST)
    depth = int(str(profile.get("depth", 10))) if history is HistoryPolicy.KEEP_LAST else 0
    if history is HistoryPolicy.KEEP_LAST and depth == 0:
        depth = UNKNOWN_HISTORY_DEPTH
    return QoSProfile(
        history=history,
        depth=depth,
        reliability=_RELIABILITY.get(str(profile.get("reliability")), ReliabilityPolicy.RELIABLE),
        durability=_DURABILITY.get(str(profile.get("durability")), DurabilityPolicy.VOLATILE),
    )


def check_rate(rate: float, bag: Bag | None = None) -> float:
    """``rate`` if it is positive and, for ``bag``, replays it within MAX_REPLAY_DURATION; else ValueError."""
    if not rate > 0.0:
        raise ValueError(f"rate must be positive (inf: as fast as possible), got {rate}")
    if bag is not None:
        span = (bag.end_ns - bag.start_ns) / _NS_PER_S
        if span / rate > MAX_REPLAY_DURATION:
            raise ValueError(
                f"at rate {rate:g} the {span:.3f} s of {bag.mcap_path} would take {span / rate:.3g} s to "
                f"replay (more than {MAX_REPLAY_DURATION:.3g} s); choose a larger --rate"
            )
    return rate


def checked_bag(path: Path) -> Bag:
    """The recording at ``path``, opened and read through once with every check, each topic's fields those of
    its installed type (ReplayError if not)."""
    try:
        bag = open_bag(path)
        verify(bag)
    except BagReadError as error:
        raise ReplayError(str(error)) from None
    for topic in bag.topics.values():
        check_layout(topic)
    return bag


def send_offset(log_time_ns: int, first_log_time_ns: int, rate: float) -> float:
    """Seconds after the first message at which a message logged at ``log_time_ns`` is published."""
    return 0.0 if math.isinf(rate) else (log_time_ns - first_log_time_ns) / _NS_PER_S / rate


class ReplayNode(Node):
    """Publishers for the topics of a recording; :meth:`play` sends its messages."""

    def __init__(self, bag: Bag, topics: list[str] | None = None, **node_options: object) -> None:
        super().__init__("replay", **node_options)  # type: ignore[arg-type]
        chosen = list(bag.topics) if topics is None else topics
        unknown = [topic for topic in chosen if topic not in bag.topics]
        if unknown:
            raise ReplayError(f"{bag.mcap_path}: no topic {', '.join(unknown)} in the recording")
        self.bag = bag
        self.topic_publishers: dict[str, Publisher[Any]] = {
            topic: self.create_publisher(
                message_class(bag.topics[topic].type_name), topic, offered_qos(bag.topics[topic])
            )
            for topic in chosen
        }
        self._progress = RecorderProgress()
        self._executor: SingleThreadedExecutor | None = None

    def wait_for_subscribers(self, count: int, timeout: float, stop: Callable[[], bool]) -> None:
        """Until every publisher has ``count`` matched subscriptions; ReplayError after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while not all(p.get_subscription_count() >= count for p in self.topic_publishers.values()):
            if stop():
                return
            if time.monotonic() > deadline:
                missing = [t for t, p in self.topic_publishers.items() if p.get_subscription_count() < count]
                raise ReplayError(
                    f"fewer than {count} subscriber(s) on {', '.join(missing)} after {timeout} s"
                )
            time.sleep(SPIN_SLICE / 10)

    def wait_for_recorder(self, timeout: float, stop: Callable[[], bool]) -> None:
        """Until a recorder reports (``tdslip/recorder_status``) a matched publisher on every replayed topic;
        ReplayError after ``timeout`` s. From then on :meth:`play` never runs more than
        :data:`~tdslip_ros.nodes.flow_control.FLOW_WINDOW` messages per topic ahead of what the slowest
        recorder has written, so that a recorder starved of CPU slows the replay instead of losing messages
        (the publishers keep twice that many)."""
        if self._executor is None:
            self.create_subscription(
                RecorderStatus, RECORDER_STATUS, self._progress.update, RECORDER_STATUS_QOS
            )
            self._executor = SingleThreadedExecutor(context=self.context)
            self._executor.add_node(self)
        if not spin_until(
            self._executor, lambda: stop() or self._progress.hears(self.topic_publishers), timeout
        ):
            raise ReplayError(f"no recorder reported every replayed topic matched within {timeout} s")

    def _wait_for_room(self, topic: str, published: int, stop: Callable[[], bool]) -> None:
        """While the recorder followed is a window behind on ``topic``, let it catch up."""
        if self._executor is not None:
            spin_until(self._executor, lambda: stop() or self._progress.lag(topic, published) < FLOW_WINDOW)

    def destroy_node(self) -> None:
        if self._executor is not None:
            self._executor.shutdown()
            self._executor = None
        super().destroy_node()

    def play(self, rate: float = 1.0, stop: Callable[[], bool] = lambda: False) -> ReplayResult:
        """Publish the recording's messages (module docstring); returns the counts per topic."""
        check_rate(rate, self.bag)
        published = dict.fromkeys(self.topic_publishers, 0)
        start, first, stopped = time.monotonic(), None, False
        try:
            for channel, message in iter_messages(self.bag, self.topic_publishers, log_time_order=True):
                if first is None:
                    start, first = time.monotonic(), message.log_time
                due = start + send_offset(message.log_time, first, rate)
                while not (stopped := stop()) and (delay := due - time.monotonic()) > 0.0:
                    time.sleep(min(delay, SPIN_SLICE))
                self._wait_for_room(channel.topic, published[channel.topic], stop)
                if stopped or (stopped := stop()):
                    break
                self.topic_publishers[channel.topic].publish(message.data)
                published[channel.topic] += 1
        except BagReadError as error:
            raise ReplayError(str(error)) from None
        duration = time.monotonic() - start
        acknowledged = all(
            p.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT)) for p in self.topic_publishers.values()
        )
        return ReplayResult(published, duration, acknowledged, stopped)


def replay(
    path: Path,
    rate: float = 1.0,
    *,
    topics: list[str] | None = None,
    wait_for_subscribers: int = 0,
    wait_for_recorder: bool = False,
    wait_timeout: float = 30.0,
    context: Context | None = None,
    stop: Callable[[], bool] = lambda: False,
) -> ReplayResult:
    """Replay the recording at ``path`` in ``context`` (an initialised rclpy context, default rclpy's)."""
    node = ReplayNode(checked_bag(path), topics, context=context)
    try:
        if wait_for_subscribers:
            node.wait_for_subscribers(wait_for_subscribers, wait_timeout, stop)
        if wait_for_recorder:
            node.wait_for_recorder(wait_timeout, stop)
        return node.play(rate, stop)
    finally:
        node.destroy_node()
