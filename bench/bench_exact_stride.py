"""One exact stride per call, scipy's DOP853 driven from Python against the compiled stride, and
energy_exact's planning on the latter, side by side in one process.

    python bench/bench_exact_stride.py [--states 300] [--apexes 1000]

Strides: the same random apexes and ramps (y in [1.0, 1.35] m, xdot in [2, 6] m/s, theta_td in [18, 28]
deg, tau0 in [-900, -300] N m, t_f in [0.1, 0.25] s, kbar = 36, zeta0 = 0.08, m = 80 kg, r0 = 1 m) through
``exact_map.apex_return_map`` (solve_ivp DOP853, dense-output event location) and
``exact_kernels.apex_stride`` (the compiled stride of one apex), both at rtol = atol = 1e-12. Printed: the
per-call p50 and p99 of each (wall time, time.perf_counter, the fastest of REPEATS calls per state), the
ratio of the p50s against the 50x target, how far the two apexes lie apart (dimensionless, against the
exact map's 1e-11) and whether their failures agree. Planning: energy_exact on --apexes apexes as
bench_controllers.py measures it, p50 and p99 of CPU and wall time against the 1 ms target. The load
average is printed before and after: the machine is shared, and a busy core shows in the wall times (and
the p99s) first.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np
from bench_controllers import EXACT_TARGET_MS, measure

from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stride_kernels import apex_stride

PARAMS = PAPER_PARAMS
TOLERANCE = 1e-12
SPEEDUP_TARGET = 50.0
APEX_TOLERANCE = 1e-11
REPEATS = 3
"""Calls per state and engine, the fastest kept: a preempted call measures the machine, not the engine."""


def _load() -> str:
    return "load average " + " ".join(f"{value:.2f}" for value in os.getloadavg())


def _states(count: int) -> list[tuple[float, ...]]:
    rng = np.random.default_rng(21)
    columns = (
        rng.uniform(1.0, 1.35, count),
        rng.uniform(2.0, 6.0, count),
        np.radians(rng.uniform(18.0, 28.0, count)),
        rng.uniform(-900.0, -300.0, count),
        rng.uniform(0.1, 0.25, count),
    )
    return [tuple(float(column[i]) for column in columns) for i in range(count)]


def _strides(count: int) -> None:
    states = _states(count)
    first = states[0]
    apex_stride(
        PARAMS, ApexState(*first[:2]), StanceCommand(*first[2:])
    )  # loaded (or compiled) before timing
    scipy_times, compiled_times, distance, disagreements = [], [], 0.0, 0
    for y, xdot, angle, tau0, t_f in states:
        apex, command = ApexState(y, xdot), StanceCommand(angle, tau0, t_f)
        exact_seconds, compiled_seconds = math.inf, math.inf
        for _ in range(REPEATS):
            start = time.perf_counter()
            exact = apex_return_map(PARAMS, apex, command, rtol=TOLERANCE, atol=TOLERANCE)
            exact_seconds = min(exact_seconds, time.perf_counter() - start)
            start = time.perf_counter()
            compiled = apex_stride(PARAMS, apex, command, rtol=TOLERANCE, atol=TOLERANCE)
            compiled_seconds = min(compiled_seconds, time.perf_counter() - start)
        scipy_times.append(exact_seconds)
        compiled_times.append(compiled_seconds)
        disagreements += compiled.failure is not exact.failure
        if exact.apex is not None and compiled.apex is not None:
            distance = max(
                distance,
                abs(units.height_to_bar(PARAMS, compiled.apex.y - exact.apex.y)),
                abs(units.speed_to_bar(PARAMS, compiled.apex.xdot - exact.apex.xdot)),
            )
    scipy_ms, compiled_ms = np.asarray(scipy_times) * 1e3, np.asarray(compiled_times) * 1e3
    print(f"one exact stride per call, rtol = atol = {TOLERANCE:g}, {count} states [ms]")
    print(f"  {'engine':<34} {'p50':>8} {'p99':>8}")
    for name, times in (("exact_map.apex_return_map", scipy_ms), ("exact_kernels.apex_stride", compiled_ms)):
        print(f"  {name:<34} {np.median(times):8.4f} {np.quantile(times, 0.99):8.4f}")
    ratio = float(np.median(scipy_ms) / np.median(compiled_ms))
    verdict = "ok" if ratio >= SPEEDUP_TARGET else "MISSED"
    print(f"  p50 ratio {ratio:6.1f}x, target >= {SPEEDUP_TARGET:g}x: {verdict}")
    agree = "ok" if distance <= APEX_TOLERANCE and disagreements == 0 else "MISSED"
    within = f"apexes within {distance:.2g} (target {APEX_TOLERANCE:g})"
    print(f"  {within}, failures differing: {disagreements}: {agree}")


def _planning(apexes: int) -> None:
    times = measure(0, apexes, ("energy_exact",))["energy_exact"]
    cpu, wall = np.asarray(times["cpu"]) * 1e3, np.asarray(times["wall"]) * 1e3
    p99 = float(np.quantile(cpu, 0.99))
    print(f"energy_exact planning per apex, {cpu.size} apexes, {times['answered'][0]} answered [ms]")
    print(
        f"  cpu p50 {np.median(cpu):.3f}  p99 {p99:.3f}  max {cpu.max():.3f};"
        f"  wall p50 {np.median(wall):.3f}  p99 {np.quantile(wall, 0.99):.3f}"
    )
    verdict = "ok" if p99 < EXACT_TARGET_MS else "MISSED"
    print(f"  cpu p99 / target ({EXACT_TARGET_MS:g} ms) = {p99 / EXACT_TARGET_MS:.2f}: {verdict}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--states", type=int, default=300, help="strides timed per engine")
    parser.add_argument("--apexes", type=int, default=1000, help="apexes energy_exact plans")
    args = parser.parse_args(argv)
    print(_load())
    _strides(args.states)
    _planning(args.apexes)
    print(_load())
    return 0


if __name__ == "__main__":
    sys.exit(main())
