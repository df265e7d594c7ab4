"""What a plant knows of the recorders that report on ``tdslip/recorder_status``.

A recorder_node publishes, per recorded topic, how many messages it has written and how many
publishers it has matched (``tdslip_msgs/RecorderStatus``). A plant told to wait for a recorder
(``wait_for_recorder``) uses that to start only once the recorder hears every publisher, to pace
a lockstep run so that it never gets more than a window of messages ahead of what the recorder has
written (its publishers keep :data:`~tdslip_ros.nodes.topics.STREAM_DEPTH` samples, so nothing
is dropped), and to wait at the end until everything it published is in the bag.

The acknowledgements of DDS cannot do this: they cover every subscriber alike, so a stalled
``ros2 topic echo`` would hold the plant as firmly as a slow recorder.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from tdslip_msgs.msg import RecorderStatus

from tdslip_ros.nodes.topics import STREAM_DEPTH

FLOW_WINDOW = 500
"""Messages per topic a lockstep plant (or a replay) may run ahead of the recorder it waits for: well
inside the publishers' history (STREAM_DEPTH), so the recorder never misses one."""
assert FLOW_WINDOW < STREAM_DEPTH


@dataclass
class _Report:
    recorded: dict[str, int]
    publishers: dict[str, int]
    closed: bool
    received_ns: int
    missed: dict[str, int]
    """Per topic, what had been published and not written when this bag was first reported during the run:
    a recorder that opened it mid-run (activated again after a pause) is held only to what came after."""


class RecorderProgress:
    """The latest report of each recorder (by its bag), topics by fully qualified name."""

    def __init__(self) -> None:
        self._reports: dict[str, _Report] = {}

    def update(self, msg: RecorderStatus, published: Mapping[str, int] | None = None) -> None:
        """Take a report; ``published``: the messages published so far by topic, while a run is on."""
        recorded = dict(zip(msg.topics, (int(n) for n in msg.recorded), strict=True))
        known = self._reports.get(msg.bag)
        if known is not None:
            missed = known.missed
        else:
            published = published or {}
            missed = {topic: max(0, published.get(topic, 0) - count) for topic, count in recorded.items()}
        self._reports[msg.bag] = _Report(
            recorded=recorded,
            publishers=dict(zip(msg.topics, (int(n) for n in msg.publishers), strict=True)),
            closed=bool(msg.closed),
            received_ns=time.monotonic_ns(),
            missed=missed,
        )

    def _recording(self, topic: str) -> list[_Report]:
        return [report for report in self._reports.values() if topic in report.recorded and not report.closed]

    def ready(self, published_topics: Iterable[str], answer_publishers: Mapping[str, int]) -> bool:
        """A recorder has matched this plant on every topic it records and every publisher of the
        controllers' topics (``answer_publishers``: the commands', the hip torques', by topic)."""
        for report in self._reports.values():
            if report.closed:
                continue
            matched = all(report.publishers.get(topic, 1) >= 1 for topic in published_topics)
            if matched and all(report.publishers.get(t, 0) >= n for t, n in answer_publishers.items()):
                return True
        return False

    def hears(self, published_topics: Iterable[str]) -> bool:
        """An open recorder has matched a publisher on every one of ``published_topics`` it records."""
        topics = list(published_topics)
        return any(
            not report.closed and all(report.publishers.get(topic, 0) >= 1 for topic in topics)
            for report in self._reports.values()
        )

    def lag(self, topic: str, published: int) -> int:
        """Messages on ``topic`` published but not yet written by the slowest recorder (0 if none
        records it)."""
        return max(
            (published - report.recorded[topic] - report.missed[topic] for report in self._recording(topic)),
            default=0,
        )

    def caught_up(self, published: Mapping[str, int]) -> bool:
        """Every recorder has written everything published on the topics it records."""
        return all(self.lag(topic, count) <= 0 for topic, count in published.items())

    def silent_for(self, now_ns: int) -> float:
        """Seconds since the latest report of any open recorder (inf without one)."""
        times = [report.received_ns for report in self._reports.values() if not report.closed]
        return (now_ns - max(times)) * 1e-9 if times else float("inf")

    @property
    def heard(self) -> bool:
        return bool(self._reports)
