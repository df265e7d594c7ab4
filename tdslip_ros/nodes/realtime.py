"""The realtime plant's wall-clock tick: a thread sleeping to absolute deadlines, and its statistics.

Why a thread and not an rclpy timer: every firing of a timer in rclpy's EventsExecutor crosses two
threads and re-inspects the callback's signature, ~120 us of CPU per firing on the development
machine (12% of a core at 1 kHz before any work), while a thread sleeping to the next deadline of
the steady clock costs ~30 us and can be given a real-time scheduling priority (SCHED_FIFO), which
keeps the tick on time on a loaded machine (see :class:`Ticker`). The thread needs the GIL only
while it works; the executor thread of the same process waits in C++ without it.
"""

from __future__ import annotations

import gc
import math
import os
import sys
import threading
import time
from collections.abc import Callable

SWITCH_INTERVAL = 1e-4
"""s: how soon another thread holding the GIL is asked to hand it to a due tick (Python's default: 5 ms)."""

CpuClocks = Callable[[], tuple[int, int]]
"""(CPU time the hypervisor stole from this machine [ns], time the calling thread waited for a CPU
of this machine while runnable [ns]), both cumulative."""


class ProcCpuClocks:
    """:data:`CpuClocks` from Linux's /proc: the ``steal`` column of /proc/stat (all CPUs, in clock
    ticks) and the run-queue wait of /proc/thread-self/schedstat. The files stay open and are re-read
    with pread (a few microseconds); the thread's file is opened by the first call, on the thread
    whose waits it then reports. Where /proc lacks them, both read 0 (no explanation is given). Once that
    thread has ended (a run's last window is closed after its tick thread stopped), its wait stays at
    the last value read: an ended thread waits no more."""

    def __init__(self) -> None:
        self._tick_ns = 1_000_000_000 // os.sysconf("SC_CLK_TCK")
        self._stat: int | None = None
        self._schedstat: int | None = None
        self._opened = False
        self._wait = 0

    def __call__(self) -> tuple[int, int]:
        if not self._opened:
            self._opened = True
            self._stat = self._open("/proc/stat")
            self._schedstat = self._open("/proc/thread-self/schedstat")
        steal = 0
        if self._stat is not None:
            first_line = os.pread(self._stat, 256, 0).split(b"\n", 1)[0].split()
            steal = int(first_line[8]) * self._tick_ns if len(first_line) > 8 else 0
        if self._schedstat is not None:
            try:
                self._wait = int(os.pread(self._schedstat, 128, 0).split()[1])
            except ProcessLookupError:  # the thread has ended
                os.close(self._schedstat)
                self._schedstat = None
        return steal, self._wait

    @staticmethod
    def _open(path: str) -> int | None:
        try:
            return os.open(path, os.O_RDONLY)
        except OSError:
            return None


class TickTiming:
    """Wall-clock timing of the tick, in constant memory (a 1 us histogram), and why ticks were missed.

    ``period_error`` is |interval between two firings - tick period|; a tick is ``missed`` when it
    had to be computed in a later firing than its own (the firing came more than half a period
    late, or not at all, and the plant caught up).

    Missed ticks are explained per window of WINDOW_FIRINGS firings by the CPU clocks
    (:data:`CpuClocks`): ``missed_stolen`` in a window in which the hypervisor stole CPU time from
    the machine, else ``missed_waiting`` in one in which the tick thread waited more than half a
    period for a CPU (other work on this machine), else ``missed_unexplained`` (this process: the
    GIL, the garbage collector, or the tick's own work). The first two are the machine's, the last
    is ours.
    """

    BIN_NS = 1_000
    BINS = 50_000  # errors of 50 ms and more share the last bin
    WINDOW_FIRINGS = 10

    def __init__(self, period_ns: int, cpu_clocks: CpuClocks | None = None) -> None:
        self._period_ns = period_ns
        self._histogram = [0] * (self.BINS + 1)
        self._last_ns: int | None = None
        self._cpu_clocks = ProcCpuClocks() if cpu_clocks is None else cpu_clocks
        self._window_clocks: tuple[int, int] | None = None
        self._window_firings = 0
        self._window_missed = 0
        self.firings = 0
        self.ticks = 0
        self.missed = 0
        self.missed_stolen = 0
        self.missed_waiting = 0
        self.missed_unexplained = 0
        self.stolen_ns = 0
        """CPU time the hypervisor stole from the machine during the timed windows."""

    def resume(self) -> None:
        """A new run: the next firing has no previous one to be timed against."""
        self._last_ns = None
        self._window_clocks = None

    def record(self, now_ns: int, ticks: int) -> None:
        """One firing at ``now_ns`` (steady clock) that computed ``ticks`` ticks (on the tick thread:
        the waits are that thread's)."""
        if self._last_ns is not None:
            error = abs(now_ns - self._last_ns - self._period_ns)
            self._histogram[min(error // self.BIN_NS, self.BINS)] += 1
        self._last_ns = now_ns
        self.firings += 1
        self.ticks += ticks
        if ticks > 1:
            self.missed += ticks - 1
            self._window_missed += ticks - 1
        self._window_firings += 1
        if self._window_clocks is None or self._window_firings >= self.WINDOW_FIRINGS:
            self.close_window()

    def close_window(self) -> None:
        """Explain the misses of the firings since the last window (also at the end of a run)."""
        clocks = self._cpu_clocks()
        if self._window_clocks is not None:
            stolen = clocks[0] - self._window_clocks[0]
            waited = clocks[1] - self._window_clocks[1]
            self.stolen_ns += stolen
            if stolen > 0:
                self.missed_stolen += self._window_missed
            elif waited > self._period_ns // 2:
                self.missed_waiting += self._window_missed
            else:
                self.missed_unexplained += self._window_missed
        else:  # misses before the first reading cannot be explained
            self.missed_unexplained += self._window_missed
        self._window_clocks = clocks
        self._window_firings = self._window_missed = 0

    def period_error(self, quantile: float) -> float:
        """The quantile (0..1) of the period error [s], to the bin width (1 us)."""
        total = sum(self._histogram)
        if total == 0:
            return math.nan
        rank, seen = quantile * total, 0
        for index, count in enumerate(self._histogram):
            seen += count
            if seen >= rank and count:
                return (index + 0.5) * self.BIN_NS * 1e-9
        return math.nan

    def summary(self) -> str:
        return (
            f"{self.ticks} ticks in {self.firings} firings, {self.missed} missed ({self.missed_stolen} "
            f"while the hypervisor stole {self.stolen_ns * 1e-9:.2f} s of CPU, {self.missed_waiting} while "
            f"the tick waited for a CPU, {self.missed_unexplained} unexplained); period error "
            f"p50 {self.period_error(0.5) * 1e3:.3f} ms, p99 {self.period_error(0.99) * 1e3:.3f} ms"
        )


class Ticker:
    """Calls ``callback(now_ns)`` on its own thread at ``start_ns + k * period_ns`` (steady clock).

    A late callback is not repeated for the deadlines it overran (the callback catches up by wall
    time); the next call is at the next deadline still ahead.

    ``priority`` > 0 puts the thread under SCHED_FIFO at that priority (needs CAP_SYS_NICE or root;
    ``on_error`` hears why if it is refused); ``cpu`` pins it to that CPU (its process's other threads
    stay where they are). The tick can still wait for other threads of its
    process that hold the GIL or a DDS lock; raising those too made no measurable difference.
    """

    def __init__(
        self,
        period_ns: int,
        callback: Callable[[int], None],
        *,
        priority: int = 0,
        cpu: int | None = None,
        on_error: Callable[[str], None] = lambda message: None,
    ) -> None:
        self._period_ns = period_ns
        self._callback = callback
        self._priority = priority
        self._cpu = cpu
        self._on_error = on_error
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, start_ns: int) -> None:
        # Everything alive now (modules, the node, its messages) is moved out of the collector's
        # reach: a full collection then walks only what the run allocates, not the whole process.
        gc.collect()
        gc.freeze()
        self._thread = threading.Thread(target=self._run, args=(start_ns,), name="tdslip-tick", daemon=True)
        self._thread.start()

    def request_stop(self) -> None:
        """Stop after the callback in progress, without waiting (safe from the callback itself)."""
        self._stop.set()

    def stop(self) -> None:
        """Stop after the callback in progress and wait for the thread (not from the callback)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def _run(self, start_ns: int) -> None:
        # A due tick waits for the GIL until the thread holding it is asked to let go, by default
        # after 5 ms: five ticks. Asked after SWITCH_INTERVAL instead, a callback of another thread
        # delays the tick by at most that. Process-wide, so only while this thread runs.
        switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(SWITCH_INTERVAL)
        try:
            self._tick_until_stopped(start_ns)
        finally:
            sys.setswitchinterval(switch_interval)

    def _tick_until_stopped(self, start_ns: int) -> None:
        if self._priority > 0:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self._priority))  # this thread
            except OSError as error:
                self._on_error(f"SCHED_FIFO priority {self._priority} refused ({error}); normal scheduling")
        if self._cpu is not None:
            try:
                os.sched_setaffinity(0, {self._cpu})  # this thread only
            except OSError as error:
                self._on_error(f"CPU affinity {self._cpu} refused ({error}); any CPU")
        period = self._period_ns
        deadline = start_ns + period
        while not self._stop.is_set():
            delay = deadline - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay * 1e-9)
            if self._stop.is_set():
                break
            now = time.monotonic_ns()
            self._callback(now)
            deadline += period
            overrun = time.monotonic_ns() - deadline
            if overrun > 0:
                deadline += (overrun // period + 1) * period
