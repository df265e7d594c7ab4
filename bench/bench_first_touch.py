"""What this machine charges a thread the first time it writes to a page of memory, beside writing it again.

    .venv/bin/python bench/bench_first_touch.py [--mib 512] [--rounds 2]

A fresh anonymous mapping of ``--mib`` MiB is written one byte per 4 kB page, each write timed (the guest
kernel allocates and zeroes the page, and on a VM the hypervisor may have to back it first), then the same
pages are written again (warm). Printed per round: the median, p99, p99.9 and largest write time of each
pass, the pages over 0.1 ms and 0.5 ms, and the ratio first / again of the medians and of the p99.9; the
load average and the CPU time the hypervisor stole during the run beside them. The time lands on the thread
that touches the page, as its own CPU time: a 1 kHz tick that touches fresh memory (a pipe's new buffer page
in the kernel, the heap growing) pays it (docs/realtime.md). Numbers: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import mmap
import os
import time
from pathlib import Path

import numpy as np

PAGE = 4096


def steal_seconds() -> float:
    """CPU time the hypervisor gave to others while this VM wanted it (Linux /proc/stat, all CPUs)."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    return int(fields[8]) / os.sysconf("SC_CLK_TCK")


def timed_pass(memory: mmap.mmap, pages: int) -> np.ndarray:
    """The time [ns] of one write to each page, in order."""
    times = np.empty(pages)
    clock = time.perf_counter_ns
    for page in range(pages):
        start = clock()
        memory[page * PAGE] = 1
        times[page] = clock() - start
    return times


def describe(times: np.ndarray) -> str:
    return (
        f"median {np.median(times) / 1e3:6.2f} us, p99 {np.percentile(times, 99) / 1e3:6.2f} us, "
        f"p99.9 {np.percentile(times, 99.9) / 1e3:7.1f} us, max {times.max() / 1e3:7.0f} us, "
        f"> 0.1 ms: {int((times > 1e5).sum()):4d}, > 0.5 ms: {int((times > 5e5).sum()):4d}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mib", type=int, default=512, help="size of the fresh mapping [MiB] (default 512)")
    parser.add_argument("--rounds", type=int, default=2, help="fresh mappings, one after another (default 2)")
    args = parser.parse_args()
    pages = (args.mib << 20) // PAGE
    steal_before = steal_seconds()
    for round_number in range(1, args.rounds + 1):
        memory = mmap.mmap(-1, pages * PAGE, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
        first, again = timed_pass(memory, pages), timed_pass(memory, pages)
        memory.close()
        ratio = np.median(first) / np.median(again)
        tail = np.percentile(first, 99.9) / np.percentile(again, 99.9)
        print(f"round {round_number}, {args.mib} MiB in {pages} pages:")
        print(f"  first write  {describe(first)}")
        print(f"  again        {describe(again)}")
        print(f"  first / again: median {ratio:.1f}x, p99.9 {tail:.0f}x")
    load = ", ".join(f"{value:.2f}" for value in os.getloadavg())
    print(f"load average {load}; steal during the run {steal_seconds() - steal_before:.2f} s")


if __name__ == "__main__":
    main()
