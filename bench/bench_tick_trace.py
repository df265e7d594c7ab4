"""Where the tick's unexplained misses come from: the soak with the tick process probed and the kernel traced.
One command, as root (ftrace):

    .venv/bin/python bench/bench_tick_trace.py [--duration 300] [--realtime-priority 50] [--out DIR]

It runs ``bench/bench_soak.py`` (its ``--duration`` and ``--realtime-priority``) with two observers:

* **the tick process probed** (``bench/tick_probe/sitecustomize.py``): each firing that
  :class:`~tdslip_ros.nodes.realtime.TickTiming` counts as the process's own work (busy past the deadline for
  half a period or more, on the CPU for half a period or more: the unexplained misses are such firings) is
  written with where its thread's CPU time went: stepping, the messages it took, the garbage collector, the
  rest (the sink's flush and the wait for the next deadline), and the thread's page faults and context
  switches;
* **the kernel's events on both CPUs** (ftrace, clock ``mono``, the clock of ``time.monotonic_ns``): the
  scheduler's switches, and every hard interrupt, timer interrupt, IPI and softirq with its duration.

It prints, beside the soak's missed ticks, steal and load:

* the probed firings, by where their CPU time went;
* how many of their windows (from the start of the firing before to their own) hold a stretch of 0.5 ms or
  more in which neither CPU shows a single event, against windows of the same lengths that start where the
  tick was switched in at random (the same thread, the same load; a CPU at work for the soak shows events
  every few tens of microseconds);
* the durations of the timer interrupts taken while the tick's thread was current, against those taken while
  another thread was.

A firing whose own code is a few sink calls yet whose thread clock ran on for milliseconds, inside a stretch
in which the whole VM showed no event, is time the host took from the VM without the guest seeing it as
steal. Results: docs/realtime.md.
"""

from __future__ import annotations

import argparse
import bisect
import json
import os
import random
import re
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
TRACING = Path("/sys/kernel/tracing")
EVENTS = ["sched:sched_switch", "irq:irq_handler_entry", "irq:irq_handler_exit", "irq:softirq_entry"]
EVENTS += ["irq:softirq_exit"] + [
    f"irq_vectors:{vector}_{end}"
    for vector in ("local_timer", "call_function", "call_function_single", "reschedule", "irq_work")
    for end in ("entry", "exit")
]
TRACE_KB_PER_SECOND = 1_500  # per CPU: a soak's events took about 1.2 MB a second on each of two CPUs
SILENCE_NS = 500_000  # half a period: the stretch without an event that is looked for
SLOW_HANDLER_NS = 200_000
BASELINE_WINDOWS = 20_000
LINE = re.compile(rb"-(\d+)\s+\[(\d+)\]\s+\S+\s+(\d+)\.(\d{6}): (\w+): ?(.*)$")
SWITCHED_IN = re.compile(rb"next_pid=(\d+)")


def configure_tracing(duration: float) -> None:
    if not (TRACING / "trace_clock").exists():
        subprocess.run(["mount", "-t", "tracefs", "nodev", str(TRACING)], check=True)
    (TRACING / "tracing_on").write_text("0")
    (TRACING / "trace").write_text("")
    (TRACING / "trace_clock").write_text("mono")
    (TRACING / "buffer_size_kb").write_text(str(int((duration + 120) * TRACE_KB_PER_SECOND)))
    (TRACING / "set_event").write_text("\n".join(EVENTS) + "\n")


def read_probe(out: Path) -> tuple[int, list[dict[str, Any]], list[dict[str, int]]]:
    """The tick thread's id, its probed firings, and those of them counted unexplained (the tick process of
    the soak's one run)."""
    files = sorted(out.glob("tick.*"), key=lambda path: path.stat().st_size)
    if not files:
        raise SystemExit("the tick process wrote no probe file: was it started?")
    path = files[-1]
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    firings = [row for row in rows if "firing" in row]
    unexplained = [row for row in rows if "unexplained" in row]
    return int(path.suffix[1:]), firings, unexplained


def scan_trace(tick_tid: int, windows: list[tuple[int, int]]) -> dict[str, Any]:
    """One pass over the trace: every silence of both CPUs, the tick's switch-ins, handler durations by whose
    time they took, and the handler time each window's tick thread was charged."""
    silences: list[tuple[int, int]] = []
    switch_ins: list[int] = []
    durations: dict[tuple[str, bool], list[int]] = defaultdict(list)
    opened: dict[tuple[int, str], int] = {}
    starts = [start for start, _ in windows]
    charged = [0] * len(windows)
    previous = first = None
    with (TRACING / "trace").open("rb") as trace:
        for line in trace:
            match = LINE.search(line)
            if match is None:
                continue
            pid, cpu = int(match[1]), int(match[2])
            now = int(match[3]) * 1_000_000_000 + int(match[4]) * 1_000
            event = match[5].decode()
            first = now if first is None else first
            if previous is not None and now - previous >= SILENCE_NS:
                silences.append((previous, now))
            previous = now
            if event == "sched_switch":
                switched = SWITCHED_IN.search(match[6])
                if switched and int(switched[1]) == tick_tid:
                    switch_ins.append(now)
                continue
            kind, _, end = event.rpartition("_")
            if end == "entry":
                opened[(cpu, kind)] = now
            elif end == "exit" and (cpu, kind) in opened:
                began = opened.pop((cpu, kind))
                durations[(kind, pid == tick_tid)].append(now - began)
                index = bisect.bisect_right(starts, now) - 1
                if pid == tick_tid and index >= 0 and now <= windows[index][1]:
                    charged[index] += now - max(began, windows[index][0])
    return {
        "silences": silences,
        "switch_ins": switch_ins,
        "durations": durations,
        "charged": charged,
        "span": (first, previous),
    }


def longest_silence(silences: list[tuple[int, int]], starts: list[int], window: tuple[int, int]) -> int:
    begin, end = window
    index = bisect.bisect_right(starts, end) - 1
    longest = 0
    while index >= 0 and silences[index][1] > begin:
        longest = max(longest, min(end, silences[index][1]) - max(begin, silences[index][0]))
        index -= 1
    return longest


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=300.0, help="s of the soak's realtime hopping")
    parser.add_argument("--realtime-priority", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", help="directory for the probe's files and the soak's figures")
    arguments = parser.parse_args()
    if os.geteuid() != 0:
        print("bench_tick_trace.py needs root: the kernel's events are read from ftrace", file=sys.stderr)
        return 2
    out = Path(arguments.out or tempfile.mkdtemp(prefix="tdslip-tick-trace-"))
    out.mkdir(parents=True, exist_ok=True)
    configure_tracing(arguments.duration)
    environment = dict(os.environ)
    environment["PYTHONPATH"] = os.pathsep.join(
        filter(None, [str(ROOT / "bench" / "tick_probe"), environment.get("PYTHONPATH")])
    )
    environment["TDSLIP_TICK_PROBE"] = str(out / "tick")
    soak = [sys.executable, str(ROOT / "bench" / "bench_soak.py"), "--duration", str(arguments.duration)]
    soak += ["--realtime-priority", str(arguments.realtime_priority), "--seed", str(arguments.seed)]
    soak += ["--json", str(out / "soak.json")]
    (TRACING / "tracing_on").write_text("1")
    try:
        with (out / "soak.log").open("w") as log:
            status = subprocess.run(soak, env=environment, stdout=log, stderr=subprocess.STDOUT).returncode
    finally:
        (TRACING / "tracing_on").write_text("0")
    if status != 0:
        print(f"the soak failed (exit status {status}); its output: {out / 'soak.log'}", file=sys.stderr)
        return 1
    figures = json.loads((out / "soak.json").read_text())
    tick_tid, rows, unexplained = read_probe(out)
    windows = sorted(
        (row["previous"]["start_ns"], row["firing"]["start_ns"]) for row in rows if row["previous"]
    )
    scan = scan_trace(tick_tid, windows)
    first, last = scan["span"]
    print(
        f"soak of {arguments.duration:g} s in {out}: steal {figures['steal_s']:.1f} s, load {figures['load']}"
    )
    print(f"  missed ticks: {json.dumps(figures['missed_ticks'])}")
    print(f"  the trace covers {(last - first) * 1e-9:.0f} s\n")

    print(f"firings the tick's timing counts as its own work: {len(rows)}")
    if not windows:
        return 0
    parts = {"stepping": [], "messages": [], "garbage collector": [], "flush and wait": []}
    faults = switches = 0
    for row in rows:
        before, firing = row["previous"], row["firing"]
        if before is None:
            continue
        parts["stepping"].append(before["step_cpu_ns"])
        parts["messages"].append(firing["messages_cpu_ns"])
        parts["garbage collector"].append(firing["gc_cpu_ns"])
        rest = firing["between_cpu_ns"] - firing["messages_cpu_ns"] - firing["gc_cpu_ns"]
        parts["flush and wait"].append(rest)
        faults += before["step_usage"][0] + firing["between_usage"][0]
        switches += firing["between_usage"][2] + before["step_usage"][2]
    for part, values in parts.items():
        times = np.array(values) * 1e-6
        print(f"  CPU time in {part:18s} median {np.median(times):6.3f} ms, max {times.max():6.3f} ms")
    print(f"  minor page faults in them: {faults}; involuntary context switches: {switches}\n")

    silences = scan["silences"]
    silence_starts = [begin for begin, _ in silences]
    inside = [w for w in windows if first <= w[0] and w[1] <= last]
    with_silence = sum(longest_silence(silences, silence_starts, w) >= SILENCE_NS for w in inside)
    rng = random.Random(arguments.seed)
    lengths = [end - begin for begin, end in inside]
    switch_ins = [t for t in scan["switch_ins"] if t + max(lengths, default=0) <= last]
    baseline = 0
    for _ in range(BASELINE_WINDOWS):
        begin = rng.choice(switch_ins)
        window = (begin, begin + rng.choice(lengths))
        baseline += longest_silence(silences, silence_starts, window) >= SILENCE_NS
    print(
        f"windows with a stretch of {SILENCE_NS * 1e-6:g} ms or more without an event on either CPU: "
        f"{with_silence} of {len(inside)} ({100 * with_silence / max(1, len(inside)):.0f} %); windows of the "
        f"same lengths from {BASELINE_WINDOWS:,} of the tick's {len(scan['switch_ins']):,} switch-ins: "
        f"{100 * baseline / BASELINE_WINDOWS:.1f} %"
    )
    ends = [end for _, end in windows]
    in_silence = silent_firings = 0
    for row in unexplained:  # the probed firing is timed a few microseconds after the timing's own clock
        index = bisect.bisect_left(ends, row["at_ns"])
        if index < len(windows) and longest_silence(silences, silence_starts, windows[index]) >= SILENCE_NS:
            in_silence += row["unexplained"]
            silent_firings += 1
    print(
        f"  the unexplained missed ticks: {sum(row['unexplained'] for row in unexplained)} in "
        f"{len(unexplained)} firings; in such windows: {in_silence} in {silent_firings} firings"
    )
    charged = [c for c, w in zip(scan["charged"], windows, strict=True) if first <= w[0] and w[1] <= last]
    print(
        "  interrupt handlers charged to the tick's thread inside them: median "
        f"{np.median(charged) * 1e-6 if charged else 0:.3f} ms, max {max(charged, default=0) * 1e-6:.3f} ms\n"
    )
    print("interrupt and softirq handlers, by the thread whose time they took")
    for (kind, tick_current), values in sorted(scan["durations"].items()):
        times = np.array(values) * 1e-3
        whose = "the tick" if tick_current else "others"
        print(
            f"  {kind:22s} {whose:8s} {len(times):8d}: p50 {np.percentile(times, 50):6.1f} us, p99 "
            f"{np.percentile(times, 99):7.1f} us, max {times.max():8.1f} us; "
            f"{100 * np.mean(times >= SLOW_HANDLER_NS * 1e-3):.2f} % over {SLOW_HANDLER_NS * 1e-3:.0f} us"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
