"""TickTiming's statistics on firing sequences whose errors and catch-ups are known by construction."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tdslip_ros.nodes.realtime import ProcCpuClocks, TickTiming

PERIOD = 1_000_000  # ns


def test_period_errors_and_missed_ticks_of_a_known_sequence() -> None:
    timing = TickTiming(PERIOD)
    # 101 firings: the first, 98 with errors 0..97 us in turn, one 2.5 ms late that catches up
    # 3 ticks (2 missed), then one 1.5 ms early relative to it (the schedule resumes).
    now, errors = 0, []
    timing.record(now, 1)
    for k in range(98):
        now += PERIOD + k * 1_000
        errors.append(k * 1_000)
        timing.record(now, 1)
    now += PERIOD + 2_500_000
    timing.record(now, 3)
    now += PERIOD - 1_500_000
    timing.record(now, 1)
    errors += [2_500_000, 1_500_000]

    assert (timing.firings, timing.ticks, timing.missed) == (101, 103, 2)
    ranked = sorted(errors)
    for quantile in (0.5, 0.9, 0.99):
        exact = ranked[max(0, int(quantile * len(ranked) + 0.999999) - 1)] * 1e-9
        assert timing.period_error(quantile) == pytest.approx(exact, abs=TickTiming.BIN_NS * 1e-9)
    assert timing.period_error(1.0) == pytest.approx(2.5e-3, abs=1e-6)


def test_a_new_run_is_not_timed_against_the_previous_one() -> None:
    timing = TickTiming(PERIOD)
    timing.record(0, 1)
    timing.record(PERIOD, 1)
    timing.resume()
    timing.record(60 * PERIOD, 1)  # a minute-long gap (a reset) is no period error
    timing.record(61 * PERIOD, 1)
    assert timing.period_error(1.0) < TickTiming.BIN_NS * 1e-9
    assert (timing.firings, timing.missed) == (4, 0)


def test_a_tick_is_missed_only_when_the_next_one_was_due_before_it_was_stepped() -> None:
    """Firings at their deadlines plus 0.3, 0.7, 1.2 and 1.6 ms, which step 1, 1, 2 and 2 ticks (as the plant
    does, none before its time: test_nodes_tick_process.py), miss 2 ticks; counted as until December 2026
    (more than half a period late is missed), 0 + 1 + 1 + 2 = 4."""
    timing = TickTiming(PERIOD, ScriptedClocks())
    deadline = 0
    for late, ticks in ((300_000, 1), (700_000, 1), (1_200_000, 2), (1_600_000, 2)):
        deadline += 3 * PERIOD
        timing.record(deadline + late, ticks, deadline, busy_ns=0)
    assert (timing.missed, timing.missed_by_half_period) == (2, 4)


def test_no_firings_no_statistics() -> None:
    assert math.isnan(TickTiming(PERIOD).period_error(0.5))


class ScriptedClocks:
    """CpuClocks that advance as the test says: (steal, wait) added at each firing's reading."""

    def __init__(self) -> None:
        self.increments: list[tuple[int, int]] = []
        self._steal = self._wait = 0

    def waited(self) -> int:
        steal, wait = self.increments.pop(0) if self.increments else (0, 0)
        self._steal += steal
        self._wait += wait
        return self._wait

    def stolen(self) -> int:
        return self._steal


def test_missed_ticks_are_told_apart_by_what_the_machine_was_doing() -> None:
    window = TickTiming.WINDOW_FIRINGS
    clocks = ScriptedClocks()
    timing = TickTiming(PERIOD, clocks)
    now = 0
    timing.record(now, 1)
    # In each window one firing comes 2.6 ms late and catches up: the hypervisor stole 10 ms in the first
    # window; in the second the tick thread waited 2.5 ms for a CPU before it (2.6 - 2.5 < a period: it would
    # have come in time); in the third only 1 ms (it would still have missed); the fourth is quiet.
    for steal, wait, missed in ((10_000_000, 0, 2), (0, 2_500_000, 3), (0, 1_000_000, 4), (0, 0, 0)):
        for firing in range(window):
            late = 2_600_000 if firing == 0 and missed else 0
            clocks.increments.append((steal, wait) if firing == 0 else (0, 0))
            now += PERIOD + late
            timing.record(now, 1 + (missed if firing == 0 else 0))
    timing.close_window()
    assert timing.missed == 9
    assert (timing.missed_stolen, timing.missed_waiting, timing.missed_unexplained) == (2, 3, 4)
    assert timing.stolen_ns == 10_000_000
    assert "2 while the hypervisor stole 0.01 s" in timing.summary()


def test_a_wait_for_a_cpu_explains_only_the_lateness_it_caused() -> None:
    """A firing 1.4 ms late after a 0.3 ms wait would have missed anyway (1.1 ms, more than a period, late):
    ours; one 1.4 ms late after a 0.7 ms wait would have come within its period (0.7 ms late): the
    machine's."""
    clocks = ScriptedClocks()
    timing = TickTiming(PERIOD, clocks)
    timing.record(0, 1)
    clocks.increments.append((0, 300_000))
    timing.record(PERIOD + 1_400_000, 2)
    clocks.increments.append((0, 700_000))
    timing.record(2 * PERIOD + 2_800_000, 2)  # 1.4 ms after its due time again
    timing.close_window()
    assert (timing.missed, timing.missed_waiting, timing.missed_unexplained) == (2, 1, 1)


def test_a_ticker_that_says_when_it_was_idle_tells_its_own_lateness_from_a_late_wake_up() -> None:
    """With the deadline and how long the ticker worked past it: a firing whose process worked
    past the deadline by more than half a period is ours, unless a wait for a CPU in that work explains the
    miss; one that slept past it without waiting for a CPU was woken late by the kernel."""
    clocks = ScriptedClocks()
    timing = TickTiming(PERIOD, clocks)
    timing.record(0, 1, 0, 0)
    deadline = 2 * PERIOD
    timing.record(deadline + 1_200_000, 2, deadline, busy_ns=700_000)  # busy until 0.7 ms late
    clocks.increments.append((0, 600_000))
    deadline = 3 * PERIOD
    timing.record(deadline + 1_200_000, 2, deadline, busy_ns=700_000)  # 0.6 ms of it queued
    deadline = 4 * PERIOD
    timing.record(deadline + 1_200_000, 2, deadline, busy_ns=0)  # idle, asleep 1.2 ms late
    clocks.increments.append((0, 1_000_000))
    deadline = 6 * PERIOD
    timing.record(deadline + 1_200_000, 2, deadline, busy_ns=0)  # 1 ms of it queued
    timing.close_window()
    assert timing.missed == 4
    assert (timing.missed_unexplained, timing.missed_woken_late, timing.missed_waiting) == (1, 1, 2)
    assert "1 woken late by the kernel" in timing.summary()


def test_work_past_the_deadline_that_did_not_run_on_the_cpu_is_the_machines() -> None:
    """The ticker's process was at work 1.2 ms past the deadline before: with 0.9 ms of it on the CPU that is
    ours; with 0.1 ms on the CPU and no wait for one, the CPU was taken from the thread below the guest's
    scheduler (interrupts, the hypervisor): interrupted, the machine's. Without the CPU time: ours."""
    clocks = ScriptedClocks()
    timing = TickTiming(PERIOD, clocks)
    timing.record(0, 1, 0, 0)
    for firing, cpu in enumerate((900_000, 100_000, None, 499_999), start=1):
        deadline = 3 * firing * PERIOD
        timing.record(deadline + 1_200_000, 2, deadline, busy_ns=1_200_000, busy_cpu_ns=cpu)
    timing.close_window()
    assert timing.missed == 4
    assert (timing.missed_unexplained, timing.missed_interrupted) == (2, 2)
    assert "2 interrupted or catching up, 2 unexplained" in timing.summary()
    assert timing.counts().interrupted == 2


def test_the_proc_clocks_see_this_thread_wait_for_a_cpu_that_others_take() -> None:
    clocks = ProcCpuClocks()
    steal_before, wait_before = clocks.stolen(), clocks.waited()
    # More busy processes than CPUs, while this thread wants a CPU too: it must queue for one.
    crowd = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range((os.cpu_count() or 1) * 2)
    ]
    try:
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            pass
    finally:
        for process in crowd:
            process.kill()
            process.wait()
    steal_after, wait_after = clocks.stolen(), clocks.waited()
    assert wait_after - wait_before > 20_000_000  # ns: at least 20 ms of the 0.5 s spent queueing
    assert steal_after >= steal_before >= 0


def test_the_proc_clocks_outlive_the_thread_they_time() -> None:
    """A run's last window is closed after its tick thread ended: the clocks then keep that thread's last
    wait (they used to raise ProcessLookupError, which ended a realtime run with a traceback)."""
    clocks = ProcCpuClocks()
    first: list[tuple[int, int]] = []
    ids: list[int] = []
    thread = threading.Thread(
        target=lambda: (
            ids.append(threading.get_native_id()),
            first.append((clocks.stolen(), clocks.waited())),
        )
    )
    thread.start()
    thread.join()
    deadline = time.monotonic() + 5.0
    while Path(f"/proc/self/task/{ids[0]}").exists() and time.monotonic() < deadline:
        time.sleep(0.01)  # the system thread outlives join() by a moment
    steal, wait = clocks.stolen(), clocks.waited()  # on this thread, the timed one gone
    assert wait == first[0][1]
    assert steal >= first[0][0]
    assert clocks.waited() == wait
