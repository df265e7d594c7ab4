"""/diagnostics: each node's status as a ``diagnostic_msgs/DiagnosticArray``, about once a second.

There is no diagnostic_updater for rclpy among the wheels, so this is the small part of it the suite needs:
:class:`DiagnosticsPublisher` publishes one ``DiagnosticStatus`` per node (name: the node's fully qualified
name, hardware_id :data:`HARDWARE_ID`) from a 1 Hz timer of the steady clock, from what the node's report
function reads of counters the node keeps anyway (:mod:`tdslip_ros.nodes.node_status`), so nothing is added to
the plant's 1 kHz path. :func:`level_of` is the one rule of the levels: ERROR when the node reports a failure,
else WARN when a value passes its :class:`Threshold` (a parameter, settable at runtime), else OK.

The thresholds of each node are declared here, once; their parameters join each node's SPECS with the switch
:data:`DIAGNOSTICS` (off: no publisher, no timer; ``bench/bench_diagnostics.py`` compares the two).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription
from rclpy.timer import Timer

from tdslip_ros.nodes import topics
from tdslip_ros.nodes.parameters import ParameterSpec

HARDWARE_ID = "tdslip"
PERIOD = 1.0  # s of the steady clock between two statuses (diagnostic_updater's default period)
_COUNT_RANGE = (0, 2**31 - 1)

DIAGNOSTICS = ParameterSpec(
    "diagnostics",
    True,
    "publish this node's status on /diagnostics about once a second (false: no publisher, no timer)",
    read_only=True,
)


@dataclass(frozen=True)
class Threshold:
    """WARN when the value of ``key`` is above the parameter ``spec`` (below it, with ``below``)."""

    key: str
    spec: ParameterSpec
    below: bool = False

    def passed(self, value: float, limit: float) -> bool:
        return value < limit if self.below else value > limit


def _count_threshold(key: str, name: str, what: str) -> Threshold:
    return Threshold(key, ParameterSpec(name, 0, f"/diagnostics WARN above this many {what}", *_COUNT_RANGE))


MISSED_TICKS_FRACTION = "missed ticks fraction"
REJECTED = "rejected commands and torques"
STALE_TORQUES = "stale torques"
PLANNING_P99 = "planning time p99 [ms]"
UNANSWERED = "unanswered apexes"
LOST = "messages lost"
FREE_DISK = "free disk [GB]"

PLANT_THRESHOLDS = (
    Threshold(
        MISSED_TICKS_FRACTION,
        ParameterSpec(
            "diagnostics_warn_missed_ticks",
            0.01,
            "/diagnostics WARN when more than this fraction of the realtime ticks was missed",
            0.0,
            1.0,
        ),
    ),
    _count_threshold(
        REJECTED, "diagnostics_warn_rejected", "rejected commands and torques (late ones included)"
    ),
    _count_threshold(
        STALE_TORQUES, "diagnostics_warn_stale_torques", "stance ticks that held a stale torque"
    ),
)
CONTROLLER_THRESHOLDS = (
    Threshold(
        PLANNING_P99,
        ParameterSpec(
            "diagnostics_warn_planning_p99",
            5.0,
            "/diagnostics WARN when the 99th percentile of recent apexes' planning times exceeds this [ms]",
            0.0,
            1e6,
        ),
    ),
    _count_threshold(UNANSWERED, "diagnostics_warn_unanswered", "apexes the policy could not answer"),
)
RECORDER_THRESHOLDS = (
    _count_threshold(LOST, "diagnostics_warn_lost", "messages lost (published by the plant, not recorded)"),
    Threshold(
        FREE_DISK,
        ParameterSpec(
            "diagnostics_warn_free_disk",
            1.0,
            "/diagnostics WARN when the bag's file system has less free space than this [GB]",
            0.0,
            1e9,
        ),
        below=True,
    ),
)


def specs_of(thresholds: tuple[Threshold, ...]) -> tuple[ParameterSpec, ...]:
    """The parameters of a node's diagnostics: the switch and its thresholds."""
    return (DIAGNOSTICS, *(threshold.spec for threshold in thresholds))


@dataclass(frozen=True)
class NodeStatus:
    """What a node reports: its values by key (numbers or text), a one-line ``summary`` and its ``failure``
    (None: none)."""

    values: Mapping[str, object]
    summary: str
    failure: str | None = None


def level_of(
    status: NodeStatus, thresholds: tuple[Threshold, ...], limits: Mapping[str, float]
) -> tuple[bytes, str]:
    """The level and message of ``status``, its thresholds at ``limits`` (by parameter name): ERROR on a
    failure, WARN where a value passes its threshold, else OK."""
    if status.failure is not None:
        return DiagnosticStatus.ERROR, status.failure
    passed = [
        f"{t.key} {status.values[t.key]} {'<' if t.below else '>'} {limits[t.spec.name]:g}"
        for t in thresholds
        if t.key in status.values and t.passed(float(status.values[t.key]), limits[t.spec.name])  # type: ignore[arg-type]
    ]
    if passed:
        return DiagnosticStatus.WARN, "; ".join(passed)
    return DiagnosticStatus.OK, status.summary


def _text(value: object) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


@dataclass
class Heard:
    """The latest status of each other tdslip node on /diagnostics, by name, as key -> value."""

    statuses: dict[str, dict[str, str]] = field(default_factory=dict)

    def update(self, array: DiagnosticArray) -> None:
        for status in array.status:
            if status.hardware_id == HARDWARE_ID:
                self.statuses[status.name] = {pair.key: pair.value for pair in status.values}


class DiagnosticsPublisher:
    """Publishes ``report(heard)`` for ``node`` on /diagnostics every :data:`PERIOD` s, unless the node's
    :data:`DIAGNOSTICS` parameter is false; ``listen``: also hear the other tdslip nodes' statuses
    (``heard``). :meth:`destroy` removes what it made."""

    def __init__(
        self,
        node: Node,
        report: Callable[[Heard], NodeStatus],
        thresholds: tuple[Threshold, ...] = (),
        *,
        listen: bool = False,
    ) -> None:
        self._node = node
        self._report = report
        self._thresholds = thresholds
        self.name = node.get_fully_qualified_name()
        self.heard = Heard()
        self._publisher: Publisher[DiagnosticArray] | None = None
        self._timer: Timer | None = None
        self._subscription: Subscription[DiagnosticArray] | None = None
        if not node.get_parameter(DIAGNOSTICS.name).value:
            return
        self._publisher = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, topics.DIAGNOSTICS_QOS)
        steady = Clock(clock_type=ClockType.STEADY_TIME)  # about 1 Hz of wall time, whatever the node's clock
        self._timer = node.create_timer(PERIOD, self.publish, clock=steady)
        if listen:
            self._subscription = node.create_subscription(
                DiagnosticArray, topics.DIAGNOSTICS, self.heard.update, topics.DIAGNOSTICS_QOS
            )

    def status(self) -> DiagnosticStatus:
        """The node's status now."""
        reported = self._report(self.heard)
        limits = {t.spec.name: float(self._node.get_parameter(t.spec.name).value) for t in self._thresholds}
        level, message = level_of(reported, self._thresholds, limits)
        values = [KeyValue(key=key, value=_text(value)) for key, value in reported.values.items()]
        return DiagnosticStatus(
            level=level, name=self.name, message=message, hardware_id=HARDWARE_ID, values=values
        )

    def publish(self) -> None:
        assert self._publisher is not None
        array = DiagnosticArray(status=[self.status()])
        array.header.stamp = self._node.get_clock().now().to_msg()
        self._publisher.publish(array)

    def destroy(self) -> None:
        if self._timer is not None:
            self._node.destroy_timer(self._timer)
        if self._subscription is not None:
            self._node.destroy_subscription(self._subscription)
        if self._publisher is not None:
            self._node.destroy_publisher(self._publisher)
        self._publisher = self._timer = self._subscription = None
