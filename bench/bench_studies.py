"""The study engine on Dask against the batched engine called directly, side by side in one run.

    python bench/bench_studies.py [--grid 100x80] [--repeats 3] [--memory-grid 1000x1000]

The study is ``tdslip sweep fig10``'s: the goal regulator at beta = 26 deg on the exact plant, 50 strides
from a grid of initial energies x heights (default 100 x 80 = 8,000 trajectories, chunks of
sweep.chunk_size_for(8,000) = 500). Measured, in this order:

1. direct: the same chunks' lanes through basins.run_strides and basins.settle in this process, no Dask,
   no table (the batched engine with per-stride policy calls, as a user would call it);
2. the engine on a LocalCluster of 1 worker process, then of 2 (each started before its clock runs):
   trajectories per second, the scaling efficiency t1 / (2 t2), and the engine's overhead t1 / t_direct - 1
   (design, rows, Parquet, scheduling and transfers; 1 worker process against this one process).
   Steps 1 and 2 are repeated ``--repeats`` times in turn and the ratios taken round by round, their
   median reported: on a shared machine one run's time moves by 10-20 %;
3. with ``--memory-grid``: that study (1000x1000 is a million trajectories) on 2 workers, and every worker
   process's peak resident memory (getrusage's ru_maxrss, read in the worker at the end).

Each run is timed by the wall clock and by the CPU time it used (this process, plus every worker's). On a
machine that other work shares the wall clock measures the share the run got; the CPU times still compare the
work done, so the overhead is also given in CPU time. The load average before each run is printed with it.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from tdslip_ros.commands.sweep import grid_size
from tdslip_ros.model.paper import PAPER_KBAR, PAPER_ZETA0
from tdslip_ros.model.stability import basins
from tdslip_ros.studies import engine, sweep
from tdslip_ros.studies.chunk import lane_policy
from tdslip_ros.studies.design import CHOICE_SETTINGS, POLICY_PARAMETERS, Study


def load() -> str:
    return "load average {:.1f} {:.1f} {:.1f}".format(*os.getloadavg())


def direct(study: Study) -> tuple[float, float]:
    """Wall and CPU seconds for the study's chunks through the batched engine in this process."""
    params = study.params(PAPER_KBAR, PAPER_ZETA0)
    lanes = study.lanes(0, study.size)  # the design's parameters, computed outside the clock
    started, cpu = time.perf_counter(), time.process_time()
    for index in range(study.chunks):
        start, stop = study.chunk_range(index)
        settings = {
            name: lanes[name][start:stop] for name in POLICY_PARAMETERS if name not in CHOICE_SETTINGS
        }
        shared = {"corrections": study.corrections, **{name: lanes[name][start] for name in CHOICE_SETTINGS}}
        xdot0 = lanes["xdot0"][start:stop]
        policy = lane_policy("energy", params, settings, shared, xdot0)
        history = basins.run_strides(params, lanes["y0"][start:stop], xdot0, policy, study.strides)
        basins.settle(params, history)
    return time.perf_counter() - started, time.process_time() - cpu


def on_engine(study: Study, workers: int, directory: Path) -> tuple[float, float, dict[str, int]]:
    """Wall and CPU seconds (this process and the workers) for the study on a local cluster of ``workers``
    (started before the clocks), and each worker's peak resident memory [bytes]."""
    shutil.rmtree(directory, ignore_errors=True)
    with engine.connect(engine.Where(workers=workers)) as client:
        before = client.run(time.process_time)  # every worker up and answering
        started, cpu = time.perf_counter(), time.process_time()
        engine.run_study(study, directory, client)
        seconds, cpu = time.perf_counter() - started, time.process_time() - cpu
        after = client.run(time.process_time)
        peaks = client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
    return seconds, cpu + sum(after[worker] - before[worker] for worker in after), peaks


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--grid", type=grid_size, default=(100, 80), help="energies x heights (default 100x80)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="rounds of direct, 1 worker, 2 workers")
    parser.add_argument(
        "--memory-grid", type=grid_size, help="also run this study on 2 workers for peak memory"
    )
    args = parser.parse_args()
    study = sweep.fig10_studies(args.grid, basins.REGULATED_STRIDES, None)[""]
    print(
        f"study: tdslip sweep fig10 --grid {args.grid[0]}x{args.grid[1]}: {study.size:,} trajectories x "
        f"{study.strides} strides, {study.chunks} chunks of {study.chunk_size}"
    )
    scratch = Path(tempfile.mkdtemp(prefix="bench_studies_"))
    try:
        rounds = []
        for round_ in range(1, args.repeats + 1):
            print(f"round {round_}: direct ({load()}) ...", flush=True)
            t_direct, cpu_direct = direct(study)
            print(f"round {round_}: 1 worker ({load()}) ...", flush=True)
            t1, cpu1, _ = on_engine(study, 1, scratch / "one")
            print(f"round {round_}: 2 workers ({load()}) ...", flush=True)
            t2, cpu2, _ = on_engine(study, 2, scratch / "two")
            rounds.append((t_direct, cpu_direct, t1, cpu1, t2, cpu2))
        print()
        print(
            f"{'run (median of the rounds)':<32}{'wall s':>9}{'trajectories/s':>16}{'CPU s':>9}"
            f"{'per CPU s':>11}"
        )
        columns = [statistics.median(values) for values in zip(*rounds, strict=True)]
        for index, name in enumerate(
            ("batched engine, this process", "study engine, 1 worker", "study engine, 2 workers")
        ):
            seconds, cpu = columns[2 * index], columns[2 * index + 1]
            print(
                f"{name:<32}{seconds:>9.1f}{study.size / seconds:>16.1f}{cpu:>9.1f}{study.size / cpu:>11.1f}"
            )
        efficiency = [100 * t1 / (2 * t2) for _, _, t1, _, t2, _ in rounds]
        overhead_wall = [100 * (t1 / t_direct - 1) for t_direct, _, t1, _, _, _ in rounds]
        overhead_cpu = [100 * (cpu1 / cpu_direct - 1) for _, cpu_direct, _, cpu1, _, _ in rounds]
        print(
            "per round: "
            + "; ".join(
                f"{e:.0f} %, {w:+.1f} %, {c:+.1f} %"
                for e, w, c in zip(efficiency, overhead_wall, overhead_cpu, strict=True)
            )
        )
        print(
            f"scaling efficiency 1 -> 2 workers (wall): {statistics.median(efficiency):.0f} % (goal >= 85 %)"
        )
        print(
            "engine overhead, 1 worker against this process: "
            f"wall {statistics.median(overhead_wall):+.1f} %, ",
            end="",
        )
        print(f"CPU {statistics.median(overhead_cpu):+.1f} % (goal <= 10 %)")
        if args.memory_grid:
            big = sweep.fig10_studies(args.memory_grid, basins.REGULATED_STRIDES, None)[""]
            print(f"\nmemory: {big.size:,} trajectories x {big.strides} strides on 2 workers ({load()}) ...")
            seconds, _, peaks = on_engine(big, 2, scratch / "memory")
            print(f"{big.size:,} trajectories in {seconds / 60:.1f} min ({big.size / seconds:.0f}/s)")
            for worker, peak in sorted(peaks.items()):
                print(f"peak resident memory of worker {worker}: {peak / 2**20:.0f} MiB")
            size = sum(part.stat().st_size for part in (scratch / "memory").rglob("*.parquet"))
            print(f"the table: {size / 2**20:.0f} MiB of Parquet")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"this process' peak resident memory: {peak:.0f} MiB")


if __name__ == "__main__":
    main()
