"""The realtime plant's scheduling and the statistics of its wall-clock tick.

The tick runs in a process of its own, on its only thread (:mod:`tdslip_ros.nodes.tick_process`): it sleeps
to absolute deadlines of the steady clock and shares the GIL with nothing. :func:`schedule_realtime` gives
that thread a real-time priority (SCHED_FIFO) and a CPU when asked; :class:`TickTiming` times the firings
and tells why ticks were missed.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import struct
from dataclasses import dataclass
from typing import Protocol


class CpuClocks(Protocol):
    """Two cumulative clocks [ns]: read at every firing, ``waited``; at the end of a window, ``stolen``."""

    def waited(self) -> int:
        """Time the timed thread waited for a CPU of this machine while runnable."""

    def stolen(self) -> int:
        """CPU time the hypervisor stole from this machine."""


class ProcCpuClocks:
    """:data:`CpuClocks` from Linux's /proc: the run-queue wait of /proc/thread-self/schedstat and the
    ``steal`` column of /proc/stat (all CPUs, in clock ticks; its read takes longer the more CPUs there
    are; docs/benchmarks.md). The files stay open and are re-read with pread; the thread's file is opened by
    the first :meth:`waited`, on the thread whose waits it then reports. Where /proc lacks them, both read 0
    (no explanation is given). Once that thread has ended (if a window is closed after it), its wait stays at
    the last value read: an ended thread waits no more."""

    def __init__(self) -> None:
        self._tick_ns = 1_000_000_000 // os.sysconf("SC_CLK_TCK")
        self._stat: int | None = None
        self._schedstat: int | None = None
        self._stat_opened = self._schedstat_opened = False
        self._wait = 0

    def waited(self) -> int:
        if not self._schedstat_opened:
            self._schedstat_opened = True
            self._schedstat = self._open("/proc/thread-self/schedstat")
        if self._schedstat is not None:
            try:
                self._wait = int(os.pread(self._schedstat, 128, 0).split()[1])
            except ProcessLookupError:  # the thread has ended
                os.close(self._schedstat)
                self._schedstat = None
        return self._wait

    def stolen(self) -> int:
        if not self._stat_opened:
            self._stat_opened = True
            self._stat = self._open("/proc/stat")
        if self._stat is None:
            return 0
        first_line = os.pread(self._stat, 256, 0).split(b"\n", 1)[0].split()
        return int(first_line[8]) * self._tick_ns if len(first_line) > 8 else 0

    @staticmethod
    def _open(path: str) -> int | None:
        try:
            return os.open(path, os.O_RDONLY)
        except OSError:
            return None


@dataclass(frozen=True)
class MissedTicks:
    """:class:`TickTiming`'s counts at one moment, small enough to go with every apex's counts
    (/diagnostics)."""

    ticks: int = 0
    missed: int = 0
    stolen: int = 0
    waiting: int = 0
    woken_late: int = 0
    unexplained: int = 0
    stolen_ns: int = 0
    interrupted: int = 0


class TickTiming:
    """Wall-clock timing of the tick, in constant memory (a 1 us histogram), and why ticks were missed.

    ``period_error`` is |interval between two firings - tick period|; a tick is ``missed`` when it
    had to be computed in a later firing than its own: its firing came a whole period late or more (the next
    tick was already due), or not at all, and the plant caught up. ``missed_by_half_period`` counts the
    ticks more than half a period late as missed too, as this class did until December 2026 (the plant then
    stepped such a firing's next tick half a period early): the count to compare older measurements with.

    A missed tick is explained by the CPU clocks (:class:`CpuClocks`: the wait at every firing, the steal per
    window) and, where the ticker says how long its process was at its own work past the deadline
    (``busy_ns``), by that:

    - ``missed_stolen``: the hypervisor stole CPU time from the machine in the firing's window of
      WINDOW_FIRINGS firings (steal is counted in clock ticks of 10 ms: finer windows would not see more);
    - ``missed_waiting``: the tick thread waited for a CPU (other work on this machine) so long since the
      firing before that it would have come within the period without that wait;
    - ``missed_interrupted``: else, the tick's own process was still at work more than half a period after
      the firing's deadline, but less than half a period of that work was its own on the CPU (the ticker
      says so, ``busy_cpu_ns``) and it did not wait for a CPU: the CPU was taken from it below the guest's
      scheduler (interrupts, or the hypervisor in slices shorter than the steal clock's 10 ms ticks), or it
      was catching up ticks already missed, which were counted with their own cause;
    - ``missed_unexplained``: else, the tick's own process was still at work more than half a period after
      the deadline, on the CPU (the firing before, the messages it took, the garbage collector): ours;
    - ``missed_woken_late``: else, the thread slept in the kernel past its deadline without waiting for a
      CPU: the kernel's timer, or the hypervisor's, woke it late (only with ``busy_ns``, which says that the
      process was idle; without, these count as unexplained).

    All but the unexplained are the machine's.
    """

    BIN_NS = 1_000
    BINS = 50_000  # errors of 50 ms and more share the last bin
    WINDOW_FIRINGS = 10

    def __init__(self, period_ns: int, cpu_clocks: CpuClocks | None = None) -> None:
        self._period_ns = period_ns
        self._histogram = [0] * (self.BINS + 1)
        self._last_ns: int | None = None
        self._cpu_clocks = ProcCpuClocks() if cpu_clocks is None else cpu_clocks
        self._waited: int | None = None  # the wait clock as read at the latest firing
        self._window_steal: int | None = None  # the steal clock at the start of the window
        self._window_firings = 0
        self._window_waiting = 0  # missed in the window, in time but for a wait for a CPU
        self._window_woken_late = 0  # missed in the window, the thread woken late by the kernel
        self._window_interrupted = 0  # missed in the window, the thread's work past the deadline off the CPU
        self._window_ours = 0  # missed in the window, otherwise
        self.firings = 0
        self.ticks = 0
        self.missed = 0
        self.missed_by_half_period = 0
        self.missed_stolen = 0
        self.missed_waiting = 0
        self.missed_woken_late = 0
        self.missed_interrupted = 0
        self.missed_unexplained = 0
        self.stolen_ns = 0
        """CPU time the hypervisor stole from the machine during the windows timed."""

    def __getstate__(self) -> dict[str, object]:
        """Pickled (the tick process sends its timing to the node): the counts, not the clocks of this
        process's thread."""
        state = self.__dict__.copy()
        state["_cpu_clocks"] = None
        return state

    def resume(self) -> None:
        """A new run: the next firing has no previous one to be timed against."""
        self._last_ns = None
        self._waited = None
        self._window_steal = None

    def record(
        self,
        now_ns: int,
        ticks: int,
        deadline_ns: int | None = None,
        busy_ns: int | None = None,
        busy_cpu_ns: int | None = None,
    ) -> None:
        """One firing at ``now_ns`` (steady clock) that computed ``ticks`` ticks (on the tick thread:
        the waits are that thread's); due at ``deadline_ns``, its process at its own work for ``busy_ns`` past
        that deadline before it fired (0: idle at the deadline), of which its thread ran on a CPU for its own
        work (not catching up) for ``busy_cpu_ns`` (its CPU clock), if the ticker knows."""
        waited_total = self._cpu_clocks.waited()
        late = (ticks - 1) * self._period_ns
        if self._last_ns is not None:
            error = abs(now_ns - self._last_ns - self._period_ns)
            self._histogram[min(error // self.BIN_NS, self.BINS)] += 1
            late = now_ns - self._last_ns - self._period_ns
        if deadline_ns is not None:
            late = now_ns - deadline_ns
        waited = waited_total - self._waited if self._waited is not None else 0
        self._last_ns = now_ns
        self._waited = waited_total
        self.firings += 1
        self.ticks += ticks
        half = self._period_ns // 2
        self.missed_by_half_period += max(0, (late + half) // self._period_ns)
        if ticks > 1:
            self.missed += ticks - 1
            if late - waited < self._period_ns:  # without the wait it would have come in time
                self._window_waiting += ticks - 1
            elif busy_ns is not None and busy_ns >= half and busy_cpu_ns is not None and busy_cpu_ns < half:
                self._window_interrupted += ticks - 1
            elif busy_ns is not None and busy_ns >= half:
                self._window_ours += ticks - 1
            elif busy_ns is not None:
                self._window_woken_late += ticks - 1
            else:
                self._window_ours += ticks - 1
        self._window_firings += 1
        if self._window_steal is None or self._window_firings >= self.WINDOW_FIRINGS:
            self.close_window()

    def close_window(self) -> None:
        """Explain the misses of the firings since the last window (also at the end of a run)."""
        steal = self._cpu_clocks.stolen()
        if self._window_steal is not None and steal > self._window_steal:
            self.stolen_ns += steal - self._window_steal
            self.missed_stolen += (
                self._window_waiting + self._window_woken_late + self._window_interrupted + self._window_ours
            )
        else:
            self.missed_waiting += self._window_waiting
            self.missed_woken_late += self._window_woken_late
            self.missed_interrupted += self._window_interrupted
            self.missed_unexplained += self._window_ours
        self._window_steal = steal
        self._window_firings = self._window_waiting = self._window_woken_late = 0
        self._window_interrupted = self._window_ours = 0

    def counts(self) -> MissedTicks:
        return MissedTicks(
            self.ticks,
            self.missed,
            self.missed_stolen,
            self.missed_waiting,
            self.missed_woken_late,
            self.missed_unexplained,
            self.stolen_ns,
            self.missed_interrupted,
        )

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
            f"the tick waited for a CPU, {self.missed_woken_late} woken late by the kernel, "
            f"{self.missed_interrupted} interrupted or catching up, {self.missed_unexplained} unexplained); "
            "period error "
            f"p50 {self.period_error(0.5) * 1e3:.3f} ms, p99 {self.period_error(0.99) * 1e3:.3f} ms"
        )


SHORT_SLICE_NS = 100_000
"""The time slice a tick under normal scheduling asks for: the shortest Linux grants (sched_attr's
sched_runtime; EEVDF, Linux 6.12 on). A thread with a short slice has an early deadline when it wakes, so it
preempts the programs of the same priority that run then instead of queueing behind them; no privilege needed.
"""
_SCHED_ATTR = struct.Struct("<IIQiIQQQII")  # struct sched_attr, SCHED_ATTR_SIZE_VER1
_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}


def name_this_thread(name: str) -> None:
    """Give the calling thread ``name`` (its first 15 characters) where ``ps -L``, ``top -H`` and the kernel's
    scheduler traces show threads (Python does not); nothing where there is no /proc (not Linux)."""
    with contextlib.suppress(OSError), open("/proc/thread-self/comm", "w") as comm:
        comm.write(name[:15])


def ask_short_slice() -> str | None:
    """Ask for :data:`SHORT_SLICE_NS` slices for the calling thread (normal scheduling); why not, if refused
    (an older kernel keeps its default slice and says nothing)."""
    number = _SYS_SCHED_SETATTR.get(os.uname().machine)
    if number is None:
        return f"no sched_setattr on {os.uname().machine}"
    libc = ctypes.CDLL(None, use_errno=True)
    attr = ctypes.create_string_buffer(
        _SCHED_ATTR.pack(_SCHED_ATTR.size, 0, 0, 0, 0, SHORT_SLICE_NS, 0, 0, 0, 0)
    )
    if libc.syscall(number, 0, attr, 0) != 0:
        return os.strerror(ctypes.get_errno())
    return None


def schedule_realtime(priority: int, cpu: int | None) -> list[str]:
    """Put the calling thread under SCHED_FIFO at ``priority`` (> 0; needs CAP_SYS_NICE or root), else give it
    short slices (:func:`ask_short_slice`), and pin it to ``cpu``; what was refused, and why (it then runs
    with normal scheduling, or on any CPU)."""
    refused = []
    if priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))  # this thread
        except OSError as error:
            refused.append(f"SCHED_FIFO priority {priority} refused ({error}); normal scheduling")
    if priority <= 0 or refused:
        refusal = ask_short_slice()
        if refusal is not None:
            refused.append(f"a short time slice refused ({refusal}); the default one")
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})  # this thread only
        except OSError as error:
            refused.append(f"CPU affinity {cpu} refused ({error}); any CPU")
    return refused
