"""Page faults of the realtime tick thread with the tick process's allocator (a heap written once and kept)
beside Python's and glibc's defaults, in two realtime runs of the suite, one after the other.

    .venv/bin/python bench/bench_tick_faults.py [--duration 120] [--warm-up 20] [--priority 50]

Each run is ``tdslip run --mode realtime`` for ``--duration`` s (plant, controller, recorder): once with
:data:`tdslip_ros.nodes.tick_process.ALLOCATOR`, once with none of it. The minor page faults of the thread
``tdslip-tick`` (``/proc/PID/task/TID/stat``) are read after ``--warm-up`` s and at the end, every fault a
page the guest kernel gave the tick for the first time, which on this VM can cost milliseconds
(bench_first_touch.py). Printed: the faults per minute of each run and their ratio, the missed ticks by
cause, the load average and the hypervisor's steal beside them. Numbers: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

from tdslip_ros.nodes import tick_process
from tdslip_ros.nodes.runner import RunOptions, run


def steal_seconds() -> float:
    """CPU time the hypervisor gave to others while this VM wanted it (Linux /proc/stat, all CPUs)."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    return int(fields[8]) / os.sysconf("SC_CLK_TCK")


def tick_thread_faults() -> int | None:
    """Minor faults of this process's tick process's tick thread so far (None: no tick process yet)."""
    for task in Path("/proc/self/task").iterdir():
        for child in (task / "children").read_text().split():
            for thread in Path(f"/proc/{child}/task").glob("*"):
                try:
                    if (thread / "comm").read_text().strip() == tick_process.TICK_THREAD:
                        return int((thread / "stat").read_text().rsplit(")", 1)[1].split()[7])
                except OSError:
                    continue
    return None


class FaultProbe(threading.Thread):
    """The tick thread's faults after the warm-up and at its latest reading."""

    def __init__(self, warm_up: float) -> None:
        super().__init__(daemon=True)
        self.warm_up = warm_up
        self.after_warm_up: tuple[float, int] | None = None
        self.latest: tuple[float, int] | None = None
        self.stop = threading.Event()

    def run(self) -> None:
        started = None
        while not self.stop.wait(0.5):
            faults = tick_thread_faults()
            if faults is None:
                continue
            now = time.monotonic()
            started = started or now
            if self.after_warm_up is None and now - started >= self.warm_up:
                self.after_warm_up = (now, faults)
            self.latest = (now, faults)

    def per_minute(self) -> float:
        assert self.after_warm_up is not None and self.latest is not None, "the run ended before the warm-up"
        (start, first), (end, last) = self.after_warm_up, self.latest
        return (last - first) / (end - start) * 60.0


def measured(arguments: argparse.Namespace, allocator: dict[str, str], out: Path) -> float:
    tick_process.ALLOCATOR = allocator
    probe = FaultProbe(arguments.warm_up)
    probe.start()
    steal, wall = steal_seconds(), time.monotonic()
    try:
        report = run(
            RunOptions(
                out,
                strides=0,
                mode="realtime",
                duration=arguments.duration,
                realtime_priority=arguments.priority,
            )
        )
    finally:
        probe.stop.set()
        probe.join()
    timing = report.tick_timing
    assert timing is not None
    per_minute = probe.per_minute()
    label = "kept heap" if allocator else "defaults"
    stolen, took = steal_seconds() - steal, time.monotonic() - wall
    print(
        f"  {label:<10} {per_minute:8.1f} faults/min   missed {timing.missed} of {timing.ticks}: steal "
        f"{timing.missed_stolen}, waiting {timing.missed_waiting}, woken late {timing.missed_woken_late}, "
        f"interrupted {timing.missed_interrupted}, unexplained {timing.missed_unexplained}   (steal "
        f"{stolen:.2f} s in {took:.0f} s, load average {' '.join(f'{v:.2f}' for v in os.getloadavg())})"
    )
    return per_minute


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=120.0, help="s of realtime hopping per run")
    parser.add_argument("--warm-up", type=float, default=20.0, help="s before the faults are counted")
    parser.add_argument("--priority", type=int, default=0, help="the tick's SCHED_FIFO priority (0: normal)")
    arguments = parser.parse_args()
    kept = dict(tick_process.ALLOCATOR)
    print(f"tick thread page faults after {arguments.warm_up:g} s, realtime runs of {arguments.duration:g} s")
    with tempfile.TemporaryDirectory(prefix="tdslip-faults-") as scratch:
        defaults = measured(arguments, {}, Path(scratch) / "defaults")
        ours = measured(arguments, kept, Path(scratch) / "kept")
    print(f"  ratio kept heap / defaults: {ours / defaults if defaults else float('nan'):.2f}")


if __name__ == "__main__":
    main()
