"""What each node says on /diagnostics (:mod:`tdslip_ros.nodes.diagnostics`), from counters it keeps anyway.

Each ``*_diagnostics(...)`` makes the node's :class:`~tdslip_ros.nodes.diagnostics.DiagnosticsPublisher`
(one call to create, ``destroy()`` to remove); docs/nodes.md lists the keys. The nodes are reached through
the small protocols below (what a report reads), so that this module imports no node module.
"""

from __future__ import annotations

import math
import shutil
import time
from collections import Counter, deque
from collections.abc import Mapping
from typing import Protocol

from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node

from tdslip_ros.bag import RosbagMcapWriter
from tdslip_ros.nodes.diagnostics import (
    CONTROLLER_THRESHOLDS,
    FREE_DISK,
    LOST,
    MISSED_TICKS_FRACTION,
    PLANNING_P99,
    PLANT_THRESHOLDS,
    RECORDER_THRESHOLDS,
    REJECTED,
    STALE_TORQUES,
    UNANSWERED,
    DiagnosticsPublisher,
    Heard,
    NodeStatus,
)
from tdslip_ros.nodes.plant_run import RunCounts, RunOutcome

PUBLISHED = "published "
"""The prefix of the plant's key of the messages it published on a topic (its fully qualified name)."""
WRITTEN = "written "
"""The prefix of the recorder's key of the messages it wrote of a topic (its fully qualified name)."""
DROPPED_WHILE_PAUSED = "dropped while paused"
"""The recorder's key of the messages that arrived while it was inactive (taken, not written)."""
PLANNING_WINDOW = 256
"""Apexes whose planning times the controller's percentiles cover (a bounded window: recent behaviour)."""
_GB = 1e9


def lifecycle_state(node: Node) -> str:
    """The managed node's lifecycle state (``unconfigured``, ``inactive``, ``active``, ...)."""
    assert isinstance(node, LifecycleNode), node  # every node of the suite is managed (nodes/lifecycle.py)
    # rclpy exposes the state only through its services; the state machine is the one they read.
    return str(node._state_machine.current_state[1])


class PlantCounters(Protocol):
    """What the plant's report reads of a PlantNode."""

    lockstep: bool
    counts: RunCounts
    outcome: RunOutcome | None
    published: Counter[str]
    topic_names: dict[str, str]
    received_commands: int
    received_torques: int

    @property
    def sim_time(self) -> float: ...

    @property
    def stride(self) -> int: ...

    @property
    def epoch(self) -> int: ...

    @property
    def running(self) -> bool: ...


class PlantReport:
    """The plant's status: tick rate, missed ticks and why, late, rejected and stale commands and torques,
    hypervisor steal, lifecycle state, what it published per topic; ERROR when its run failed."""

    def __init__(self, plant: PlantCounters, node: Node) -> None:
        self._plant = plant
        self._node = node
        self._last = (plant.sim_time, time.monotonic_ns())

    def __call__(self, heard: Heard) -> NodeStatus:
        plant = self._plant
        counts, outcome = plant.counts, plant.outcome
        now = (plant.sim_time, time.monotonic_ns())
        elapsed_ns = now[1] - self._last[1]
        tick_rate = (now[0] - self._last[0]) / (elapsed_ns * 1e-9) if elapsed_ns else 0.0
        self._last = now
        values: dict[str, object] = {
            "lifecycle state": lifecycle_state(self._node),
            "clock mode": "lockstep" if plant.lockstep else "realtime",
            "epoch": plant.epoch,
            "stride": plant.stride,
            "simulated time [s]": plant.sim_time,
            "tick rate [Hz]": tick_rate * 1000.0,  # simulated ms per wall second: ticks per second
            "commands received": plant.received_commands,
            "late commands": counts.late_commands,
            REJECTED: counts.rejected,
            "answers to earlier apexes": counts.earlier_answers,
            "torques received": plant.received_torques,
            "late torques": counts.late_torques,
            STALE_TORQUES: counts.stale_torques,
        }
        missed = counts.missed_ticks
        if missed is not None:
            values |= {
                "ticks": missed.ticks,
                "missed ticks": missed.missed,
                MISSED_TICKS_FRACTION: missed.missed / missed.ticks if missed.ticks else 0.0,
                "missed: hypervisor steal": missed.stolen,
                "missed: waiting for a CPU": missed.waiting,
                "missed: woken late": missed.woken_late,
                "missed: interrupted or catching up": missed.interrupted,
                "missed: unexplained": missed.unexplained,
                "hypervisor steal [s]": missed.stolen_ns * 1e-9,
            }
        values |= {PUBLISHED + plant.topic_names[topic]: n for topic, n in sorted(plant.published.items())}
        if outcome is None:
            summary = f"running, stride {plant.stride}" if plant.running else "waiting to start"
            return NodeStatus(values, summary)
        failure = None if outcome.ok else f"{outcome.kind}: {outcome.reason}"
        return NodeStatus(values, f"{outcome.kind} at stride {outcome.stride}", failure)


def plant_diagnostics(plant: PlantCounters, node: Node) -> DiagnosticsPublisher:
    return DiagnosticsPublisher(node, PlantReport(plant, node), PLANT_THRESHOLDS)


class PlanningTimes:
    """The planning times of the latest :data:`PLANNING_WINDOW` apexes and their percentiles."""

    def __init__(self) -> None:
        self._recent: deque[int] = deque(maxlen=PLANNING_WINDOW)

    def add(self, nanoseconds: int) -> None:
        self._recent.append(nanoseconds)

    def __len__(self) -> int:
        return len(self._recent)

    def percentile(self, percent: float) -> float:
        """The nearest-rank percentile [ms] of the window (0 when it is empty)."""
        if not self._recent:
            return 0.0
        ordered = sorted(self._recent)
        rank = min(len(ordered), max(1, math.ceil(percent / 100 * len(ordered))))
        return ordered[rank - 1] * 1e-6


class ControllerCounters(Protocol):
    published: int
    unanswered: int
    planning_times: PlanningTimes


def controller_diagnostics(controller: ControllerCounters, node: Node) -> DiagnosticsPublisher:
    """The controller's status: policy, apexes answered and unanswered, planning time p50/p99."""

    def report(heard: Heard) -> NodeStatus:
        times = controller.planning_times
        values: dict[str, object] = {
            "lifecycle state": lifecycle_state(node),
            "policy": node.get_parameter("policy").value,
            "apexes answered": controller.published,
            UNANSWERED: controller.unanswered,
            "planning time p50 [ms]": times.percentile(50),
            PLANNING_P99: times.percentile(99),
            "planning times in window": len(times),
        }
        return NodeStatus(values, f"{controller.published} apexes answered")

    return DiagnosticsPublisher(node, report, CONTROLLER_THRESHOLDS)


class StanceControllerCounters(Protocol):
    commands: int
    torques: int
    unanswered: int

    @property
    def policy(self) -> str: ...


def stance_controller_diagnostics(controller: StanceControllerCounters, node: Node) -> DiagnosticsPublisher:
    """The stance controller's status: its policy, the commands and hip torques it sent."""

    def report(heard: Heard) -> NodeStatus:
        values = {
            "lifecycle state": lifecycle_state(node),
            "policy": controller.policy,
            "apexes answered": controller.commands,
            "hip torques sent": controller.torques,
            "apexes unanswered": controller.unanswered,
        }
        return NodeStatus(values, f"{controller.commands} apexes answered")

    return DiagnosticsPublisher(node, report)


class RecorderCounters(Protocol):
    bag: RosbagMcapWriter
    topic_names: list[str]
    write_error: str | None
    dropped_while_paused: Mapping[str, int]

    @property
    def written(self) -> Mapping[str, int]: ...


def recorder_diagnostics(recorder: RecorderCounters, node: Node) -> DiagnosticsPublisher:
    """The recorder's status: messages written per topic (into every bag of its activations), dropped while
    it was paused, messages lost (what a plant on /diagnostics says it published minus what was written or
    dropped while paused, per topic it reports), bag size, free disk; ERROR on a write error."""

    def report(heard: Heard) -> NodeStatus:
        written, dropped, path = recorder.written, recorder.dropped_while_paused, recorder.bag.mcap_path
        values: dict[str, object] = {"lifecycle state": lifecycle_state(node), "bag": str(path)}
        values |= {WRITTEN + name: written.get(name, 0) for name in recorder.topic_names}
        values[DROPPED_WHILE_PAUSED] = sum(dropped.values())
        published = {
            key.removeprefix(PUBLISHED): int(value)
            for status in heard.statuses.values()
            for key, value in status.items()
            if key.startswith(PUBLISHED) and key.removeprefix(PUBLISHED) in recorder.topic_names
        }
        if published:
            values[LOST] = sum(
                max(0, n - written.get(name, 0) - dropped.get(name, 0)) for name, n in published.items()
            )
        values["bag size [bytes]"] = path.stat().st_size if path.exists() else 0
        values[FREE_DISK] = shutil.disk_usage(path.parent).free / _GB
        return NodeStatus(values, f"{sum(written.values())} messages written", recorder.write_error)

    return DiagnosticsPublisher(node, report, RECORDER_THRESHOLDS, listen=True)
