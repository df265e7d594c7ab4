"""The realtime plant's wall-clock tick: a thread sleeping to absolute deadlines, and its statistics.

Why a thread and not an rclpy timer: every firing of a timer in rclpy's EventsExecutor crosses two
threads and re-inspects the callback's signature, ~120 us of CPU per firing on the development
machine (12% of a core at 1 kHz before any work), while a thread sleeping to the next deadline of
the steady clock costs ~30 us and can be given a real-time scheduling priority (SCHED_FIFO), which
keeps the tick on time on a loaded machine (see :class:`Ticker`). The thread needs the GIL only
while it works; the executor thread of the same process waits in C++ without it.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable


class TickTiming:
    """Wall-clock timing of the tick, in constant memory (a 1 us histogram).

    ``period_error`` is |interval between two firings - tick period|; a tick is ``missed`` when it
    had to be computed in a later firing than its own (the firing came more than half a period
    late, or not at all, and the plant caught up).
    """

    BIN_NS = 1_000
    BINS = 50_000  # errors of 50 ms and more share the last bin

    def __init__(self, period_ns: int) -> None:
        self._period_ns = period_ns
        self._histogram = [0] * (self.BINS + 1)
        self._last_ns: int | None = None
        self.firings = 0
        self.ticks = 0
        self.missed = 0

    def resume(self) -> None:
        """A new run: the next firing has no previous one to be timed against."""
        self._last_ns = None

    def record(self, now_ns: int, ticks: int) -> None:
        """One firing at ``now_ns`` (steady clock) that computed ``ticks`` ticks."""
        if self._last_ns is not None:
            error = abs(now_ns - self._last_ns - self._period_ns)
            self._histogram[min(error // self.BIN_NS, self.BINS)] += 1
        self._last_ns = now_ns
        self.firings += 1
        self.ticks += ticks
        if ticks > 1:
            self.missed += ticks - 1

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
            f"{self.ticks} ticks in {self.firings} firings, {self.missed} missed; period error "
            f"p50 {self.period_error(0.5) * 1e3:.3f} ms, p99 {self.period_error(0.99) * 1e3:.3f} ms"
        )


class Ticker:
    """Calls ``callback(now_ns)`` on its own thread at ``start_ns + k * period_ns`` (steady clock).

    A late callback is not repeated for the deadlines it overran (the callback catches up by wall
    time); the next call is at the next deadline still ahead.

    ``priority`` > 0 puts the thread under SCHED_FIFO at that priority (needs CAP_SYS_NICE or root;
    ``on_error`` hears why if it is refused). The tick can still wait for other threads of its
    process that hold the GIL or a DDS lock; raising those too made no measurable difference.
    """

    def __init__(
        self,
        period_ns: int,
        callback: Callable[[int], None],
        *,
        priority: int = 0,
        on_error: Callable[[str], None] = lambda message: None,
    ) -> None:
        self._period_ns = period_ns
        self._callback = callback
        self._priority = priority
        self._on_error = on_error
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, start_ns: int) -> None:
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
        if self._priority > 0:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self._priority))  # this thread
            except OSError as error:
                self._on_error(f"SCHED_FIFO priority {self._priority} refused ({error}); normal scheduling")
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
