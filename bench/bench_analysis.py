"""How long ``tdslip analyze`` takes against the length of the recording it analyses.

    python bench/bench_analysis.py [--minutes 1 10] [--keep DIR]

For each length it records a run with the real node suite (``tdslip run``'s runner, energy policy
from the default apex, every 1 kHz state and force sample recorded), in **lockstep** mode: the
recording holds exactly what a realtime recording of that simulated length holds (600,000 state and
600,000 force messages for 10 minutes) but takes about a fifth of the time to make. Then it times,
side by side: reading the run (:func:`read_run`), the comparison with the analytic and exact maps
(:func:`compare_run`), the whole ``analyze`` (figures, JSON and report included), and as a baseline
the plain ``mcap`` + ``mcap-ros2-support`` decoding of every message, which the reader's vectorised
1 kHz path replaces. Ratios are analysis time over recorded (simulated) time. ``--keep DIR`` keeps
the recordings in DIR and reuses them on the next call.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from tdslip_ros.analysis.compare import compare_run
from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.analysis.report import analyze
from tdslip_ros.bag.reader import mcap_file
from tdslip_ros.nodes.runner import RunOptions, run

T = TypeVar("T")
STRIDE_PERIOD = 0.26  # s, one stride of the default energy-regulated gait (to size the runs)


def record(directory: Path, minutes: float) -> Path:
    bag = directory / f"energy-{minutes:g}min"
    if not bag.exists():
        started = time.perf_counter()
        report = run(RunOptions(out=bag, strides=round(minutes * 60.0 / STRIDE_PERIOD)))
        wall = time.perf_counter() - started
        complete = report.recording_complete
        print(f"recorded {bag.name} in {wall:.1f} s: {report.outcome.kind}, complete: {complete}")
    return bag


def decode_everything(bag: Path) -> int:
    count = 0
    with open(mcap_file(bag), "rb") as stream:
        for _ in make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            count += 1
    return count


def timed(function: Callable[[], T]) -> tuple[T, float]:
    start = time.perf_counter()
    result = function()
    return result, time.perf_counter() - start


def measure(directory: Path, minutes: float) -> tuple[float, int, int, float, float, float, float]:
    """(recorded s, messages, strides, read s, compare s, analyze s, plain-decode s) for one length."""
    bag = record(directory, minutes)
    recorded, read_time = timed(lambda: read_run(bag))
    _, compare_time = timed(lambda: compare_run(recorded))
    _, analyze_time = timed(lambda: analyze(read_run(bag), directory / f"report-{minutes:g}min"))
    messages, baseline_time = timed(lambda: decode_everything(bag))
    length = float(recorded.samples.t[-1])
    return length, messages, len(recorded.strides), read_time, compare_time, analyze_time, baseline_time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=[1.0, 10.0], help="recording lengths")
    parser.add_argument("--keep", type=Path, help="directory for the recordings (reused when present)")
    args = parser.parse_args()
    directory = args.keep or Path(tempfile.mkdtemp(prefix="bench_analysis_"))
    directory.mkdir(parents=True, exist_ok=True)
    rows = [measure(directory, minutes) for minutes in args.minutes]
    print()
    print(
        f"{'recorded [s]':>12} {'messages':>9} {'strides':>7} | {'read [s]':>8} {'compare':>8} "
        f"{'analyze':>8} {'ratio':>7} | {'mcap_ros2 decode [s]':>20} {'ratio':>7} {'read speed-up':>13}"
    )
    for length, messages, strides, read_time, compare_time, analyze_time, baseline_time in rows:
        print(
            f"{length:>12.1f} {messages:>9d} {strides:>7d} | {read_time:>8.2f} {compare_time:>8.2f} "
            f"{analyze_time:>8.2f} {analyze_time / length:>7.4f} | {baseline_time:>20.2f} "
            f"{baseline_time / length:>7.4f} {baseline_time / read_time:>12.1f}x"
        )
    print("ratio: seconds of analysis per second of recording (analyze: read + compare + figures + report)")


if __name__ == "__main__":
    main()
