"""The realtime tick's process: its pipe protocol (no ROS), and a plant whose tick process is refused a
scheduling wish or dies."""

from __future__ import annotations

import fcntl
import os
import signal
import time
from pathlib import Path

import pytest
from support.ros_harness import RosGraph, overrides
from tdslip_msgs.msg import ApexEvent, Status

from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.plant_node import PlantNode
from tdslip_ros.nodes.plant_run import SAMPLES_PER_BATCH, TICK_NS, PlantRun, PlantSink, RunSettings
from tdslip_ros.nodes.tick_process import (
    REPLAY_THREAD,
    TICK_THREAD,
    FrameReader,
    PipeSink,
    _TickServer,
    framed,
)


def state(t: float) -> tuple[float, ...]:
    """A stand-in for the model's HopperState: the sink passes it on as it is."""
    return (t, t, 1.0, 5.0, 0.0)


def written(fd: int) -> bytes:
    try:
        return os.read(fd, 1 << 20)
    except BlockingIOError:
        return b""


class TickTimes(PlantSink):
    """A sink that keeps the simulated time of every sample."""

    def __init__(self) -> None:
        self.times: list[float] = []

    @property
    def live(self) -> bool:
        return False

    def tick(self, state: object, t: float, tick: int) -> None:
        self.times.append(t)


def test_a_late_firing_catches_up_without_stepping_a_tick_before_its_time() -> None:
    """Firings 0.3, 0.7 (more than half a period), 1.2 and 2.6 ms late step every tick due by then and none
    after: simulated time never leads wall time, and a tick is missed only once its successor was due. The
    next firing is due at the next tick's deadline, none skipped."""
    sink = TickTimes()
    hopper = PAPER_PARAMS
    settings = RunSettings(
        hopper,
        PlausibilityLimits.for_hopper(hopper),
        Perturbations(),
        ModelCommand(0.35, 0.0, 0.2),
        lockstep=False,
        max_strides=0,
        max_stale_strides=0,
        torque_max_age_ticks=10,
    )
    run = PlantRun(settings, ApexState(1.0, 5.0), sink)
    start = 10**12
    run.start(start)
    for deadline_ticks, late_ns, stepped in (
        (1, 300_000, 1),
        (2, 700_000, 1),
        (3, 1_200_000, 2),
        (5, 2_600_000, 3),
    ):
        before = len(sink.times)
        now = start + deadline_ticks * TICK_NS + late_ns
        assert run.next_deadline_ns == start + deadline_ticks * TICK_NS
        run.advance_to(now, busy_ns=0)
        assert len(sink.times) - before == stepped
        assert sink.times[-1] <= sink.times[0] + (now - start) * 1e-9  # no sample ahead of the wall clock
        assert run.next_deadline_ns == start + len(sink.times) * TICK_NS  # the initial sample: tick 0
    assert run.tick_timing is not None
    assert (run.tick_timing.missed, run.tick_timing.missed_by_half_period) == (3, 1 + 1 + 3)


def calls(data: bytes) -> list[tuple[str, tuple[object, ...], dict[str, object]]]:
    """The sink calls in what a PipeSink wrote, in order (it writes them in lists)."""
    return [call for batch in FrameReader().feed(data) for call in batch]


class CatchingUpRun:
    """A run behind its deadline: its first firing works 4 ms of CPU for 8 ticks (catching up), the second
    one tick; then it asks the server to stop. It keeps what the server told it of its own work."""

    def __init__(self, stop_fd: int) -> None:
        self.ticks, self.running, self.next_deadline_ns = 0, True, time.monotonic_ns()
        self.told: list[tuple[int, int]] = []
        self._stop_fd = stop_fd

    def advance_to(self, now_ns: int, busy_ns: int, busy_cpu_ns: int) -> None:
        self.told.append((busy_ns, busy_cpu_ns))
        if len(self.told) == 1:
            start = time.thread_time_ns()
            while time.thread_time_ns() - start < 4_000_000:
                pass
            self.ticks += 8
        else:
            self.ticks += 1
            os.write(self._stop_fd, framed(("stop",)))


class QuietSink:
    def flush(self, *, unless_routine: bool = False) -> None:
        pass


def test_the_work_of_catching_up_is_not_counted_as_the_tick_processs_own() -> None:
    """A firing that catches up 8 ticks in 4 ms of CPU makes the next one late by more than 4 ms; its own
    share of that work, told to the timing, is one tick's: 0.5 ms (test_nodes_timing.py: less than half a
    period is not ours)."""
    inbox, stop = os.pipe()
    run = CatchingUpRun(stop)
    try:
        _TickServer(run, QuietSink()).serve(inbox, FrameReader())  # type: ignore[arg-type]
    finally:
        os.close(inbox)
        os.close(stop)
    (_, _), (busy, busy_cpu) = run.told
    assert busy >= 4_000_000
    assert 400_000 <= busy_cpu <= 700_000


def test_messages_fed_in_pieces_come_out_whole_and_in_order() -> None:
    messages = [("tick", (state(0.001 * k), 0.001 * k, k), {}) for k in range(20)] + [("stop",)]
    data = b"".join(framed(message) for message in messages)
    for piece in (1, 7, 4096):
        reader = FrameReader()
        received = []
        for start in range(0, len(data), piece):
            received += reader.feed(data[start : start + piece])
        assert received == messages


def test_the_pipe_sink_writes_events_at_once_and_routine_ticks_every_few() -> None:
    read, write = os.pipe()
    os.set_blocking(read, False)
    try:
        sink = PipeSink(write)
        for k in range(SAMPLES_PER_BATCH - 1):
            sink.tick(state(k * 1e-3), k * 1e-3, k)
            sink.counted(None)
            sink.flush(unless_routine=True)
        sink.drain()
        assert written(read) == b""  # routine calls wait for the batch
        sink.tick(state(0.009), 0.009, SAMPLES_PER_BATCH - 1)
        sink.flush(unless_routine=True)
        sink.drain()
        received = calls(written(read))
        assert [name for name, _, _ in received].count("tick") == SAMPLES_PER_BATCH
        sink.tick(state(0.010), 0.010, SAMPLES_PER_BATCH)
        sink.log("warning", "an event")
        sink.flush(unless_routine=True)
        sink.drain()
        assert [name for name, _, _ in calls(written(read))] == ["tick", "log"]
        sink.live = True  # someone takes the samples live: every tick goes out at once
        sink.tick(state(0.011), 0.011, SAMPLES_PER_BATCH + 1)
        sink.flush(unless_routine=True)
        sink.drain()
        assert [name for name, _, _ in calls(written(read))] == ["tick"]
        with pytest.raises(AttributeError):
            sink.not_a_sink_call  # noqa: B018
        sink.close()
    finally:
        os.close(read)
        os.close(write)


def test_the_tick_hands_its_calls_to_the_writer_and_does_not_wait_for_the_pipe() -> None:
    """A flush returns while the pipe is full (the node's process not reading): its thread writes, in order
    and whole, once the reader reads again; close writes the rest."""
    read, write = os.pipe()
    os.set_blocking(read, False)
    try:
        filler = b"x" * fcntl.fcntl(write, fcntl.F_GETPIPE_SZ)
        os.write(write, filler)  # full: a write on this thread would block here
        sink = PipeSink(write)

        def blocked(signum: int, frame: object) -> None:
            raise AssertionError("the flush waited for the pipe")

        previous = signal.signal(signal.SIGALRM, blocked)
        signal.alarm(10)  # a write on the tick's thread would block until the reader reads: end it instead
        try:
            sink.log("warning", "first")
            sink.flush()  # returns: the writer thread waits for room instead
            sink.log("warning", "second")
            sink.flush()
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)
        drained = b""
        while len(drained) < len(filler):
            drained += written(read)
        assert drained[: len(filler)] == filler
        sink.close()
        rest = drained[len(filler) :] + written(read)
        assert [args for _, args, _ in calls(rest)] == [("warning", "first"), ("warning", "second")]
    finally:
        os.close(read)
        os.close(write)


def test_a_refused_cpu_is_logged_and_the_realtime_plant_runs_on(ros: RosGraph) -> None:
    """The tick process reports what the scheduler refused after it is ready (that report came first and
    hung the plant's start)."""
    plant = ros.add(
        PlantNode(
            context=ros.context,
            parameter_overrides=overrides(max_strides=2, clock_mode="realtime", realtime_cpu=1023),
        )
    )
    ros.add(ControllerNode(context=ros.context))
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome.kind == Status.KIND_RUN_COMPLETE


def test_a_tick_process_that_dies_ends_the_run_instead_of_hanging_it(ros: RosGraph) -> None:
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=0, clock_mode="realtime"))
    )
    ros.add(ControllerNode(context=ros.context))
    apexes = ros.collect(ApexEvent, topics.APEX)
    ros.spin_until(lambda: len(apexes) >= 2, "two apexes")
    assert plant.tick_process_id is not None
    # Named where ps -L and top -H show threads: the tick process, and the node's thread that replays it.
    assert Path(f"/proc/{plant.tick_process_id}/comm").read_text() == f"{TICK_THREAD}\n"
    assert f"{REPLAY_THREAD}\n" in {task.read_text() for task in Path("/proc/self/task").glob("*/comm")}
    os.kill(plant.tick_process_id, signal.SIGKILL)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome.kind == Status.KIND_PUBLISH_FAILED
    assert "the tick process ended unexpectedly" in plant.outcome.reason
