"""Benchmark of the analytic apex return map, and its accuracy against the exact plant.

    python bench/bench_analytic.py [--lanes N] [--repeat R] [--no-accuracy] [--baseline DIR] [--breakdown]
    python bench/bench_analytic.py --domain [--coarse]

Times are CPU seconds of this single-threaded process (time.process_time), best of several runs. Prints (1)
vectorised analytic-map evaluations per second on one core (corrections 0 and 1) for several lanes per call,
beside the target of issue 13 (1e7 per second) and, with --baseline DIR, beside the same measurement of the
tdslip_ros of another checkout (e.g. ``git worktree add /tmp/tdslip-main main``) in a child process, (2) the
time per stride of the analytic map against the exact plant (exact_map.apex_return_map), measured side by side
in this run, as a ratio, and (3) the accuracy table: mean and max relative errors of the next apex height and
speed, analytic vs exact, for corrections 0 and 1, on a broad grid and on the operating region of the paper's
energy-regulated gaits (kbar = 36, zeta0 = 0.08, m = 80 kg, r0 = 1 m), and (4) the accuracy domain: the
next-apex errors of both maps (the next speed from the energy balance, ours, and from eq. 7's liftoff
velocity, the paper's) over the stance's maximum leg compression and the touchdown angle, and per angle the
largest compression up to which every stride errs less than 1 % and 5 %, as Markdown tables
(docs/paper.md#accuracy-domain quotes them). --domain prints only (4), on the fine grid (FINE_DOMAIN_GRID;
with --coarse, on the tests' DOMAIN_GRID).

--breakdown adds where a lane's time goes: the compiled lane loop alone against the whole call (the rest
is packaging: broadcasting, the result block, the Stride's arrays), and the C library's functions the
kernels call, each timed alone in a compiled loop over independent arguments (its best case: the kernels
also wait on the chain of divisions and square roots between the calls), and what the calls of one stride
(LIBRARY_CALLS) cost at those rates: the floor of a scalar kernel, whatever its arithmetic.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from tdslip_ros.model.analytic.apex_map import SpeedSource, approximate_map
from tdslip_ros.model.analytic.map_kernels import STRIDE_ROWS, stride_lanes
from tdslip_ros.model.arrays import CommandArrays, Lanes, ParamArrays
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.stability.analytic_accuracy import (
    BROAD_GRID,
    DOMAIN_GRID,
    ERROR_LEVELS,
    FINE_DOMAIN_GRID,
    OPERATING_GRID,
    SPEED_SOURCES,
    Boundary,
    DomainErrors,
    Quantity,
    StrideGrid,
    accuracy,
    boundaries,
    domain_errors,
    domain_table,
    exact_strides,
    first_mismatches,
)

PARAMS = PAPER_PARAMS


def _best_time(run: object, repeat: int) -> float:
    assert callable(run)
    best = np.inf
    for _ in range(repeat):
        # CPU time of this process: what one core spends, whatever else the shared machine runs.
        start = time.process_time()
        run()
        best = min(best, time.process_time() - start)
    return float(best)


def _random_strides(lanes: int) -> tuple[np.ndarray, np.ndarray, CommandArrays]:
    rng = np.random.default_rng(1)
    y, xdot = rng.uniform(1.0, 1.2, lanes), rng.uniform(3.5, 5.5, lanes)
    command = CommandArrays(
        rng.uniform(np.radians(20.0), np.radians(30.0), lanes),
        rng.uniform(-700.0, -400.0, lanes),
        np.full(lanes, 0.14),
    )
    return y, xdot, command


TARGET_RATE = 1e7
"""Analytic-map evaluations per second on one core that issue 13 asks for."""


def throughput(lanes: int, blocks: list[int], repeat: int) -> dict[str, float]:
    """Evaluations per second of the same ``lanes`` evaluations in calls of ``block`` lanes each, keyed
    "block/corrections": past the CPU caches (tens of thousands of lanes) every array operation of a numpy
    implementation waits on memory, so moderate blocks were its fastest."""
    params = ParamArrays.of(PARAMS)
    y, xdot, command = _random_strides(lanes)

    def evaluate(block: int, corrections: int) -> None:
        for i in range(0, lanes, block):
            part = CommandArrays(*(field[i : i + block] for field in command))
            approximate_map(params, y[i : i + block], xdot[i : i + block], part, corrections)

    evaluate(16, 0)  # load (or compile) the kernels before timing
    evaluate(16, 1)
    return {
        f"{block}/{corrections}": lanes / _best_time(lambda b=block, c=corrections: evaluate(b, c), repeat)
        for block in blocks
        for corrections in (0, 1)
    }


def _baseline_throughput(directory: Path, lanes: int, blocks: list[int], repeat: int) -> dict[str, float]:
    """throughput() in a child process that imports tdslip_ros from ``directory``."""
    command = [sys.executable, __file__, "--throughput-json", "--lanes", str(lanes), "--repeat", str(repeat)]
    command += ["--blocks", *map(str, blocks)]
    environment = dict(os.environ, PYTHONPATH=str(directory.resolve()))
    child = subprocess.run(command, env=environment, capture_output=True, text=True, check=True, timeout=3600)
    rates: dict[str, float] = json.loads(child.stdout)
    return rates


def print_throughput(lanes: int, blocks: list[int], repeat: int, baseline: Path | None) -> None:
    rates = throughput(lanes, blocks, repeat)
    old = _baseline_throughput(baseline, lanes, blocks, repeat) if baseline else None
    print(
        f"analytic map, {lanes} lanes in calls of `block` lanes, best of {repeat} (evaluations/s, one core):"
    )
    print(f"  {'block':>8} {'corr':>4} {'this':>10} {'/ 1e7':>6}", end="")
    print(f" {'baseline':>10} {'this/baseline':>13}" if old else "")
    for block in blocks:
        for corrections in (0, 1):
            key = f"{block}/{corrections}"
            print(
                f"  {block:>8} {corrections:>4} {rates[key]:>10.4g} {rates[key] / TARGET_RATE:>6.2f}", end=""
            )
            print(f" {old[key]:>10.4g} {rates[key] / old[key]:>12.2f}x" if old else "")


def speed_ratio(strides: int) -> None:
    y, xdot, command = _random_strides(strides)
    params = ParamArrays.of(PARAMS)
    exact_seconds = _best_time(
        lambda: [
            apex_return_map(PARAMS, ApexState(y[i], xdot[i]), command.command(i)) for i in range(strides)
        ],
        1,
    )
    single_seconds = _best_time(
        lambda: [approximate_map(params, y[i], xdot[i], command.command(i)) for i in range(strides)], 1
    )
    vector_seconds = _best_time(lambda: approximate_map(params, y, xdot, command), 5)
    print(f"per stride, {strides} strides (exact plant: DOP853, rtol = atol = 1e-12):")
    print(f"  exact plant                  {exact_seconds / strides * 1e6:10.2f} us")
    for name, seconds in (("one call a stride", single_seconds), ("vectorised", vector_seconds)):
        per_stride = seconds / strides * 1e6
        print(
            f"  analytic, {name:<18} {per_stride:10.4f} us   exact/analytic = {exact_seconds / seconds:8.1f}x"
        )


LIBRARY_CALLS = {
    0: {"sincos": 4.0, "exp": 3.0, "atan2": 2.0, "acos": 1.0, "sqrt (chained)": 6.0},
    1: {"sincos": 5.5, "exp": 5.0, "atan2": 4.0, "acos": 2.0, "sqrt (chained)": 10.0},
}
"""C library calls of one stride (paper liftoff) per lane by corrections, counted on the bench's strides
(a sine and a cosine of one angle make one sincos; a lone sine counts half)."""


def _library_loops() -> dict[str, object]:
    """Compiled loops calling one C library function per element (compiled here, on first use)."""
    import math

    import numba

    @numba.njit
    def sincos(x: np.ndarray, out: np.ndarray) -> None:
        for i in range(x.size):
            out[i] = math.sin(x[i]) + math.cos(x[i])

    @numba.njit
    def exp(x: np.ndarray, out: np.ndarray) -> None:
        for i in range(x.size):
            out[i] = math.exp(-x[i])

    @numba.njit
    def atan2(x: np.ndarray, out: np.ndarray) -> None:
        for i in range(x.size):
            out[i] = math.atan2(x[i], 1.0 - x[i])

    @numba.njit
    def acos(x: np.ndarray, out: np.ndarray) -> None:
        for i in range(x.size):
            out[i] = math.acos(x[i] - 0.5)

    @numba.njit
    def chained_sqrt(x: np.ndarray, out: np.ndarray) -> None:
        previous = 0.0
        for i in range(x.size):  # each root waits for the one before, as in the stance's closed forms
            previous = math.sqrt(x[i] + 1e-300 * previous)
            out[i] = previous

    return {"sincos": sincos, "exp": exp, "atan2": atan2, "acos": acos, "sqrt (chained)": chained_sqrt}


def breakdown(lanes: int, repeat: int) -> None:
    params = ParamArrays.of(PARAMS)
    y, xdot, command = _random_strides(lanes)
    packed = Lanes.of(params, y, xdot, *command)
    block = packed.rows(STRIDE_ROWS)
    print(f"where a lane's time goes, {lanes} lanes in one call, best of {repeat} (ns per lane):")
    for corrections in (0, 1):
        packed.run(stride_lanes, corrections, 0, block)
        loop = _best_time(lambda c=corrections: packed.run(stride_lanes, c, 0, block), repeat)
        whole = _best_time(lambda c=corrections: approximate_map(params, y, xdot, command, c), repeat)
        print(
            f"  corrections {corrections}: whole call {whole / lanes * 1e9:6.1f}, compiled lane loop "
            f"{loop / lanes * 1e9:6.1f}, packaging {(whole - loop) / lanes * 1e9:6.1f}"
            f"   (1e7 per second: 100 ns)"
        )
    argument = np.random.default_rng(2).uniform(0.1, 0.9, lanes)
    out = np.empty(lanes)
    unit = {}
    for name, function in _library_loops().items():
        assert callable(function)
        function(argument, out)
        unit[name] = _best_time(lambda f=function: f(argument, out), repeat) / lanes * 1e9
    print("  C library, each alone: " + ", ".join(f"{name} {ns:.1f}" for name, ns in unit.items()))
    for corrections, calls in LIBRARY_CALLS.items():
        floor = sum(count * unit[name] for name, count in calls.items())
        print(f"  corrections {corrections}: the stride's library calls alone {floor:6.1f}")


def accuracy_table() -> None:
    print("accuracy of the analytic map vs the exact plant, |analytic/exact - 1| of the next apex")
    print("(ramp t_f = the analytic liftoff time with 1 correction; 'eq7 speed' = liftoff speed of eq. 7)")
    print("  grid        corr liftoff     lanes  height mean/max      speed mean/max", end="")
    print("       eq7 speed mean/max  mismatches")
    for name, grid in (("broad", BROAD_GRID), ("operating", OPERATING_GRID)):
        exact = exact_strides(PARAMS, grid)
        for corrections in (0, 1):
            for liftoff in ("paper", "force_root"):
                row = accuracy(PARAMS, exact, corrections, liftoff)
                print(
                    f"  {name:<11} {corrections:>4} {liftoff:<11} {row.lanes:>5}"
                    f"  {row.mean_height_error:8.4f} {row.max_height_error:8.4f}"
                    f"   {row.mean_speed_error:8.4f} {row.max_speed_error:8.4f}"
                    f"   {row.mean_liftoff_speed_error:8.4f} {row.max_liftoff_speed_error:8.4f}"
                    f"   {row.failure_mismatches:>5}"
                )


def _percent(error: float) -> str:
    return "-" if np.isnan(error) else f"{100 * error:.0f}" if error >= 1.0 else f"{100 * error:.1f}"


def _compression(value: float | None) -> str:
    return "none" if value is None else f"{value:.2f}"


def _boundary(found: Boundary) -> str:
    """The largest compression below the level: 'none' if not even the least compressed stride is, '>= c'
    where no stride of the grid leaves the level."""
    return f">= {found.below:.2f}" if found.leaves is None else _compression(found.below)


def _grid_text(grid: StrideGrid) -> str:
    def span(values: tuple[float, ...]) -> str:
        return f"{min(values):g}-{max(values):g}"

    return (
        f"touchdown angles {span(tuple(np.degrees(grid.angles).round(1)))} deg, apex heights "
        f"{span(grid.heights)} m, speeds {span(grid.speeds)} m/s, taubar {', '.join(map(str, grid.torques))}"
    )


DOMAIN_TABLES: tuple[tuple[str, SpeedSource, Quantity], ...] = (
    (
        "next apex height (the same eq. 7 in both maps; on the strides the paper's map completes)",
        "liftoff",
        "height",
    ),
    ("next apex speed, ours (the energy balance)", "energy", "speed"),
    ("next apex speed, the paper's (eq. 7's liftoff velocity)", "liftoff", "speed"),
)

BOUNDARY_COLUMNS: tuple[tuple[str, SpeedSource, Quantity], ...] = (
    ("height, ours", "energy", "height"),
    ("height, paper's", "liftoff", "height"),
    ("speed, ours", "energy", "speed"),
    ("speed, paper's", "liftoff", "speed"),
)


def domain_markdown(domain: DomainErrors) -> str:
    """The accuracy domain as Markdown: a table of median / max errors per quantity, and the boundaries."""
    degrees = [f"{angle:g} deg" for angle in np.degrees(domain.grid.angles).round(1)]
    lines = []
    for title, speed, quantity in DOMAIN_TABLES:
        table = domain_table(domain, speed, quantity)
        lines += [f"{title}: median / max |map/exact - 1| in %", ""]
        lines += ["| compression | " + " | ".join(degrees) + " |", "|---" * (len(degrees) + 1) + "|"]
        for row, (low, high) in enumerate(zip(table.edges[:-1], table.edges[1:], strict=True)):
            if table.count[row].sum():
                cells = [
                    "-" if not count else f"{_percent(median)} / {_percent(worst)}"
                    for count, median, worst in zip(
                        table.count[row], table.median[row], table.worst[row], strict=True
                    )
                ]
                lines.append(f"| {low:.2f}-{high:.2f} | " + " | ".join(cells) + " |")
        lines.append("")
    levels = " / ".join(f"{100 * level:g} %" for level in ERROR_LEVELS)
    found = {
        name: [boundaries(domain, speed, quantity, level) for level in ERROR_LEVELS]
        for name, speed, quantity in BOUNDARY_COLUMNS
    }
    mismatches = [first_mismatches(domain, speed) for speed in SPEED_SOURCES]
    compared = ~np.isnan(domain.errors["liftoff", "height"])  # the paper's map compares a superset of ours
    lines += [f"the largest compression up to which every stride errs less than {levels}", ""]
    names = ["compared", *(name for name, _, _ in BOUNDARY_COLUMNS), "first failure mismatch, ours / paper's"]
    lines += ["| angle | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for index, (angle, degree) in enumerate(zip(domain.grid.angles, degrees, strict=True)):
        here = domain.compression[compared & (domain.angle == angle)]
        cells = [f"{here.min():.2f}-{here.max():.2f}" if here.size else "-"]
        cells += [
            " / ".join(_boundary(level[index]) for level in found[name]) for name, _, _ in BOUNDARY_COLUMNS
        ]
        cells.append(" / ".join(_compression(first[index]) for first in mismatches))
        lines.append(f"| {degree} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def domain_report(grid: StrideGrid) -> None:
    domain = domain_errors(PARAMS, exact_strides(PARAMS, grid))
    compared = domain.compression[~np.isnan(domain.errors["liftoff", "height"])]
    ours = np.count_nonzero(~np.isnan(domain.errors["energy", "height"]))
    print(
        f"accuracy domain, 1 correction, ramp t_f = the predicted liftoff; {_grid_text(grid)}: "
        f"{len(domain.index)} strides with a bottom on the exact plant; {compared.size} compared (the "
        f"paper's map; ours: {ours}), compression {compared.min():.2f}-{compared.max():.2f}"
    )
    print()
    print(domain_markdown(domain), end="")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--lanes", type=int, default=200_000, help="lanes of the throughput run")
    parser.add_argument(
        "--blocks", type=int, nargs="+", default=[4096, 16384, 200_000], help="lanes per call to compare"
    )
    parser.add_argument("--repeat", type=int, default=5, help="repetitions (best time counts)")
    parser.add_argument("--strides", type=int, default=300, help="strides of the exact-vs-analytic timing")
    parser.add_argument("--no-accuracy", action="store_true", help="skip the accuracy table")
    parser.add_argument("--breakdown", action="store_true", help="where a lane's time goes")
    parser.add_argument("--domain", action="store_true", help="only the accuracy domain (fine grid)")
    parser.add_argument("--coarse", action="store_true", help="with --domain: the tests' coarse grid")
    parser.add_argument("--baseline", type=Path, help="checkout whose tdslip_ros to measure beside")
    parser.add_argument(
        "--throughput-json", action="store_true", help=argparse.SUPPRESS
    )  # the child's report
    args = parser.parse_args(argv)
    if args.throughput_json:
        print(json.dumps(throughput(args.lanes, args.blocks, args.repeat)))
        return 0
    if args.domain:
        domain_report(DOMAIN_GRID if args.coarse else FINE_DOMAIN_GRID)
        return 0
    print_throughput(args.lanes, args.blocks, args.repeat, args.baseline)
    if args.breakdown:
        breakdown(args.lanes, args.repeat)
    speed_ratio(args.strides)
    if not args.no_accuracy:
        accuracy_table()
        print()
        domain_report(FINE_DOMAIN_GRID)
    return 0


if __name__ == "__main__":
    sys.exit(main())
