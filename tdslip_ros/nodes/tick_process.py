"""The realtime plant's tick in a process of its own.

Why a process: in the node's process the 1 kHz tick shared the GIL with rclpy. A publish that stalls in DDS
holds the GIL for milliseconds, and the executor's callbacks woke in the tick's way; about half of the ticks
missed were these, the other half late wake-ups (docs/realtime.md). Here a process with no executor and no
DDS participant steps the model (:class:`~tdslip_ros.nodes.plant_run.PlantRun`, its ``advance_to`` at each
deadline of the steady clock, on the process's only thread) and writes the calls of its sink down a pipe;
the node's process replays them on its own sink, which publishes. What reaches the node (commands, hip
torques, a reset, the end of a run) goes up another pipe, and the process takes it between two ticks.

Measured on the 2-core development VM (``bench/bench_nodes.py realtime --duration 60``; docs/realtime.md has
the numbers and a scheduler trace of the misses): a third to a half of the misses were the node process's
before; now nearly all are the machine's.

Each message is a length-prefixed pickle (from the process, a list of sink calls): both ends are this
module, in one Python installation.
"""

from __future__ import annotations

import fcntl
import gc
import os
import pickle
import queue
import select
import signal
import struct
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from typing import Any

from tdslip_ros.model.params import ApexState
from tdslip_ros.nodes.plant_run import SAMPLES_PER_BATCH, PlantRun, PlantSink, PublishFailed, RunSettings
from tdslip_ros.nodes.realtime import name_this_thread, schedule_realtime

_LENGTH = struct.Struct("<I")
PIPE_BYTES = 1 << 20
"""Each pipe's capacity asked for (Linux's default limit for a user): a tick's message is ~0.5 kB, so the
node's process may fall ~2 s behind before the tick would wait for it."""
SINK_CALLS = frozenset(name for name, value in vars(PlantSink).items() if callable(value) and name[0] != "_")
_ROUTINE_CALLS = frozenset({"tick", "counted"})
"""Sink calls that may wait for the next write (the rest are events, wanted at once)."""
TICK_THREAD = "tdslip-tick"  # the names ps -L and top -H show: the tick process,
WRITER_THREAD = "tdslip-write"  # its writer,
REPLAY_THREAD = "tdslip-replay"  # and the node's thread that publishes what it steps
CLOSE_TIMEOUT = 5.0  # s the process is given to end after "stop" before it is killed
RESET_TIMEOUT = 5.0  # s a reset waits for the process to have restarted the run
READY_TIMEOUT = 60.0  # s the process is given to start (a cold cache of compiled kernels: tens of seconds)


def framed(message: object) -> bytes:
    payload = pickle.dumps(message, pickle.HIGHEST_PROTOCOL)
    return _LENGTH.pack(len(payload)) + payload


def _write(fd: int, data: bytes) -> None:
    """All of ``data`` (a pipe may take it in parts)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


class FrameReader:
    """The messages in what arrives on a pipe (a message may come in pieces; one cut short by the writer's
    end is never complete, and is not read)."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[Any]:
        self._buffer += data
        messages = []
        while len(self._buffer) >= _LENGTH.size:
            end = _LENGTH.size + _LENGTH.unpack_from(self._buffer)[0]
            if len(self._buffer) < end:
                break
            messages.append(pickle.loads(self._buffer[_LENGTH.size : end]))
            del self._buffer[:end]
        return messages


def received(fd: int) -> Iterator[Any]:
    """The messages that arrive on ``fd``, until the writer closes its end."""
    frames = FrameReader()
    while data := os.read(fd, 1 << 16):
        yield from frames.feed(data)


def _enlarge(fd: int) -> None:
    try:
        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
    except OSError:  # a lower system limit: the default capacity (64 kB) will do, with less slack
        pass


class PipeSink:
    """A :class:`PlantSink` that writes its calls down a pipe, as lists of (name, args, kwargs).

    A list is written at the end of a firing of the tick when one of its calls must go out at once (an event,
    or samples someone takes live: :attr:`live`), else every :data:`SAMPLES_PER_BATCH` ticks: the node's
    process then wakes a tenth as often, and competes less with the tick for the CPU. One pickle a list costs
    less than one a call (the classes of a tick's state are named once).

    The tick pickles a list and hands it to a thread of the sink's own, which writes it (in order, whole):
    the write releases the GIL, so the tick steps on while the kernel takes its time. On this VM a write
    sometimes takes 1-2.6 ms of the writer's CPU, in the kernel (its pipe's fresh pages, which the hypervisor
    fills on first touch: docs/realtime.md); on the tick's thread those firings were the soak's unexplained
    misses. :meth:`close` writes what is left and ends the thread.
    """

    def __init__(self, fd: int) -> None:
        self._fd = fd
        self._lists: queue.Queue[bytes | None] = queue.Queue()
        # The writer inherits the tick's scheduling: one of normal priority holding the GIL would keep a
        # SCHED_FIFO tick waiting behind other programs.
        self._writer = threading.Thread(target=self._write_lists, name=WRITER_THREAD, daemon=True)
        self._writer.start()
        self._pending: list[tuple[str, tuple[object, ...], dict[str, object]]] = []
        self._ticks_pending = 0
        self._urgent = False
        self.live = False
        """Someone takes the tick's samples live (the node says so): every tick is written at once."""

    def __getattr__(self, name: str) -> Callable[..., None]:
        if name not in SINK_CALLS:
            raise AttributeError(name)

        def send(*args: object, **kwargs: object) -> None:
            self._pending.append((name, args, kwargs))
            if name == "tick":
                self._ticks_pending += 1
            elif name not in _ROUTINE_CALLS:
                self._urgent = True

        setattr(self, name, send)  # found directly from now on: several calls a tick
        return send

    def flush(self, *, unless_routine: bool = False) -> None:
        """Write what was gathered (``unless_routine``: only if a call must go out now, or the ticks
        gathered are due)."""
        if not self._pending or (
            unless_routine and not (self._urgent or self.live or self._ticks_pending >= SAMPLES_PER_BATCH)
        ):
            return
        self._lists.put(framed(self._pending))
        self._pending = []
        self._ticks_pending, self._urgent = 0, False

    def drain(self) -> None:
        """Until everything flushed so far is written."""
        self._lists.join()

    def close(self) -> None:
        """Write what was gathered and what waits, then end the writer."""
        self.flush()
        self._lists.put(None)
        self._writer.join()

    def _write_lists(self) -> None:
        name_this_thread(WRITER_THREAD)
        while (data := self._lists.get()) is not None:
            try:
                _write(self._fd, data)
            except BrokenPipeError:  # the node's process is gone: nobody is left to tick for
                os._exit(0)
            self._lists.task_done()


class TickProcess:
    """The node's side: starts the process for a run of ``settings`` from ``apex``, sends it what reaches
    the node, and replays its sink's calls on ``sink`` under ``lock``, on a thread of its own.

    ``priority`` and ``cpu`` are the tick's (:func:`~tdslip_ros.nodes.realtime.schedule_realtime`). If the
    process ends by itself, ``on_lost`` hears why (on the replaying thread).
    """

    def __init__(
        self,
        settings: RunSettings,
        apex: ApexState,
        sink: PlantSink,
        lock: threading.Lock,
        *,
        priority: int,
        cpu: int | None,
        on_lost: Callable[[str], None],
    ) -> None:
        inbox_read, self._inbox = os.pipe()
        outbox_read, outbox_write = os.pipe()
        for fd in (self._inbox, outbox_write):
            _enlarge(fd)
        self._process = subprocess.Popen(
            [sys.executable, "-m", __name__, str(inbox_read), str(outbox_write)],
            pass_fds=(inbox_read, outbox_write),
            stdin=subprocess.DEVNULL,
            # A session of its own is a scheduling group of its own (Linux's autogroup): the tick's CPU share
            # is not shared with the busy node's process, which misses fewer ticks (bench_nodes.py realtime;
            # docs/benchmarks.md). A Ctrl-C at the terminal does not reach it; the node stops it.
            start_new_session=True,
        )
        os.close(inbox_read)
        os.close(outbox_write)
        self._outbox = outbox_read
        self._received = received(outbox_read)
        self._send_lock = threading.Lock()
        self._send("settings", settings, apex, priority, cpu)
        # Its imports take the process about a second.
        ready = select.select([outbox_read], [], [], READY_TIMEOUT)[0] and next(self._received, None) == (
            "ready",
        )
        if not ready:
            self._process.kill()
            status = self._process.wait()
            os.close(self._inbox)
            os.close(outbox_read)
            raise RuntimeError(
                f"the tick process did not start within {READY_TIMEOUT:g} s (exit status {status})"
            )
        self._closing = False
        self._restarted = threading.Event()
        self._reset_message = ""
        self._replayer = threading.Thread(
            target=self._replay, args=(sink, lock, on_lost), name=REPLAY_THREAD, daemon=True
        )
        self._replayer.start()

    @property
    def pid(self) -> int:
        return self._process.pid

    def _send(self, *message: object) -> None:
        with self._send_lock:
            if self._inbox < 0:  # closed: what still reaches the node after the run is not for the tick
                return
            try:
                _write(self._inbox, framed(message))
            except OSError:  # the process has ended (a broken pipe): _replay says why
                pass

    def start(self, start_wall_ns: int) -> None:
        self._send("start", start_wall_ns)

    def take_command(self, data: bytes) -> None:
        self._send("command", data)

    def take_torque(self, data: bytes) -> None:
        self._send("torque", data)

    def end(self, kind: str, reason: str) -> None:
        self._send("end", kind, reason, None)

    def pause(self) -> None:
        """Stop the tick, holding the run's state, until :meth:`resume`."""
        self._send("pause", time.monotonic_ns())

    def resume(self) -> None:
        """Tick again from where the run was paused: the pause does not count as time the run was late."""
        self._send("resume", time.monotonic_ns())

    def reset(self, apex: ApexState) -> str:
        """Restart the run from ``apex`` in a new epoch; the reset's message once the process has."""
        self._restarted.clear()
        self._send("reset", apex)
        if not self._restarted.wait(RESET_TIMEOUT):
            raise TimeoutError(f"the tick process did not restart the run within {RESET_TIMEOUT:g} s")
        return self._reset_message

    def close(self) -> None:
        """Stop the process; every call it made before is replayed when this returns, unless it had to be
        killed after CLOSE_TIMEOUT s."""
        if self._closing:
            return
        self._closing = True
        self._send("stop")
        self._replayer.join(CLOSE_TIMEOUT)
        try:
            self._process.wait(CLOSE_TIMEOUT)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        with self._send_lock:
            os.close(self._inbox)
            self._inbox = -1

    def _replay(self, sink: PlantSink, lock: threading.Lock, on_lost: Callable[[str], None]) -> None:
        name_this_thread(REPLAY_THREAD)
        try:
            self._replay_until_the_end(sink, lock)
        except Exception as error:  # a bug of this side: say so, and end the run rather than hang
            traceback.print_exc()
            self._process.kill()
            on_lost(f"the node could not replay the tick process's output ({error!r})")
            return
        if not self._closing:
            status = self._process.wait()
            on_lost(f"the tick process ended unexpectedly (exit status {status})")

    def _replay_until_the_end(self, sink: PlantSink, lock: threading.Lock) -> None:
        live, epoch, failed = False, 0, False
        try:
            for calls in self._received:
                with lock:
                    for name, args, kwargs in calls:
                        try:
                            getattr(sink, name)(*args, **kwargs)
                        except PublishFailed as error:
                            if not failed:  # the run ends once
                                failed = True
                                self._send("end", "publish_failed", str(error), epoch)
                        if name == "restarted":
                            epoch, failed = args[0], False
                            self._reset_message = args[1]
                            self._restarted.set()
                    now_live = sink.live  # the node looks at the graph itself, e.g. after an apex
                if now_live != live:
                    live = now_live
                    self._send("live", live)
        finally:
            os.close(self._outbox)


class _TickServer:
    """The process's side: a run, ticked at its deadlines and told between them what reaches the node, on one
    thread (a reader thread of normal priority took the GIL from the tick: at SCHED_FIFO, the holder waited
    behind programs of normal priority). Only the sink's writes go to a thread of their own, scheduled as the
    tick is (:class:`PipeSink`)."""

    def __init__(self, run: PlantRun, sink: PipeSink) -> None:
        self._run = run
        self._sink = sink
        self._busy_ns = 0  # the process's own work past the deadline of the coming firing
        self._busy_cpu_ns = 0  # of which the thread ran on a CPU for its own work (its CPU clock)
        self._firing_cpu_ns = 0  # the CPU time of the firing before, its own share
        self._paused_ns: int | None = None  # when the node paused the run (steady clock), while it is

    @property
    def _deadline(self) -> int | None:
        """The next firing (steady clock), while the run runs and is not paused: the next tick's deadline,
        past already after a late firing (the next then comes at once, and no deadline is skipped)."""
        return self._run.next_deadline_ns if self._run.running and self._paused_ns is None else None

    def serve(self, inbox: int, frames: FrameReader) -> None:
        """Until "stop", or until the node's process is gone."""
        while True:
            deadline = self._deadline
            now = time.monotonic_ns()  # idle from now on, unless a message comes first
            self._busy_ns = 0 if deadline is None else max(0, now - deadline)  # the firing before ended late
            self._busy_cpu_ns = min(self._busy_ns, self._firing_cpu_ns)
            self._firing_cpu_ns = 0
            timeout = None if deadline is None else max(0.0, (deadline - now) * 1e-9)
            if select.select([inbox], [], [], timeout)[0]:
                woke, woke_cpu = time.monotonic_ns(), time.thread_time_ns()
                data = os.read(inbox, 1 << 16)
                if not data:
                    return
                for message in frames.feed(data):
                    if message[0] == "stop":
                        return
                    self._handle(*message)
                if (
                    deadline is not None
                ):  # handling them past the deadline was ours, waking past it the kernel's
                    handled = max(0, time.monotonic_ns() - max(woke, deadline))
                    self._busy_ns += handled
                    self._busy_cpu_ns += min(handled, time.thread_time_ns() - woke_cpu)
            deadline = self._deadline
            if deadline is not None and time.monotonic_ns() >= deadline:
                self._fire()

    def _fire(self) -> None:
        now, cpu = time.monotonic_ns(), time.thread_time_ns()
        run = self._run
        first = run.ticks
        run.advance_to(now, self._busy_ns, self._busy_cpu_ns)
        self._sink.flush(unless_routine=True)
        # The work of catching up ticks already missed is the consequence of what made them late, and is
        # counted with them: the firing's own share is one tick's.
        self._firing_cpu_ns = (time.thread_time_ns() - cpu) // max(1, run.ticks - first)

    def _handle(self, kind: str, *args: Any) -> None:
        run = self._run
        if kind == "live":
            self._sink.live = args[0]
        elif kind == "start":
            run.start(args[0])
        elif kind == "command":
            run.take_command(args[0])
        elif kind == "torque":
            run.take_torque(args[0])
        elif kind == "end":
            run.end(*args)
        elif kind == "reset":
            run.reset(args[0])
        elif kind == "pause":
            self._paused_ns = args[0]
        elif kind == "resume":
            if self._paused_ns is not None:  # the run's wall clock skips the pause
                run.start_wall_ns += args[0] - self._paused_ns
                self._paused_ns = None
        else:
            raise ValueError(f"unknown message {kind!r}")
        self._sink.flush()


def main(argv: list[str]) -> int:
    """``python -m tdslip_ros.nodes.tick_process INBOX_FD OUTBOX_FD``, as TickProcess starts it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the node decides when to stop
    name_this_thread(TICK_THREAD)
    inbox, outbox = int(argv[1]), int(argv[2])
    frames = FrameReader()
    first: list[Any] = []
    while not first:
        data = os.read(inbox, 1 << 16)
        if not data:
            return 0
        first = frames.feed(data)
    kind, settings, apex, priority, cpu = first[0]
    assert kind == "settings" and len(first) == 1  # the node waits for "ready" before it sends more
    refusals = schedule_realtime(priority, cpu)
    sink = PipeSink(outbox)  # its writer thread scheduled as the tick is
    server = _TickServer(PlantRun(settings, apex, sink), sink)
    PlantRun.load_message_support()
    # Everything alive now (modules, the run) is moved out of the collector's reach: a full collection then
    # walks only what the run allocates, not the whole process.
    gc.collect()
    gc.freeze()
    _write(outbox, framed(("ready",)))
    for refusal in refusals:
        sink.log("warning", refusal)
    sink.flush()
    try:
        server.serve(inbox, frames)
    finally:
        sink.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
