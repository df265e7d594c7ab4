"""Batched exact engine against a loop of scipy solve_ivp (with events), at equal apex accuracy.

    python bench/bench_batch.py [--lanes-per-side 32] [--strides 20]

The grid is lanes-per-side^2 initial apex states (y in [1.0, 1.35] m, xdot in [3, 5] m/s;
default 32^2 = 1,024), hopping under a proportional energy regulator at beta = 20 deg, with
kbar = 36, zeta0 = 0.08: the kind of basin sweep issue 3 runs.

Equal accuracy: each engine runs at the loosest tolerance (rtol = atol, from 1e-7 to 1e-12) whose
one-stride apex error meets a common target (--target, dimensionless, default 1e-10; basins are
judged at 1e-4), errors measured on a subset of the grid against solve_ivp at rtol = atol = 1e-13.
The loop is ``exact_map.apex_return_map`` (DOP853 with event location, closed-form flight), stride
by stride and lane by lane. Both runs are timed in this process, one after the other, and the
ratio of their stride rates is printed.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, StanceCommand
from tdslip_ros.model.plant.batch import simulate_strides
from tdslip_ros.model.plant.exact_map import apex_return_map

PARAMS = PAPER_PARAMS
BETA = math.radians(20.0)
TARGET_ENERGY = ApexState(1.2, 4.0).energy(PARAMS)
TOLERANCES = (1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12)
REFERENCE_TOLERANCE = 1e-13


def policy(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[float, np.ndarray, float]:
    energy = PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)
    return BETA, -610.8 + 3.0 * (energy - TARGET_ENERGY), 0.15


def command_for(apex: ApexState) -> StanceCommand:
    angle, tau0, t_f = policy(0, np.array(apex.y), np.array(apex.xdot))
    return StanceCommand(angle, float(tau0), t_f)


def apex_error(y: float, xdot: float, reference: ApexState) -> float:
    """Dimensionless apex error, the larger of height and speed."""
    return max(
        abs(units.height_to_bar(PARAMS, y - reference.y)),
        abs(units.speed_to_bar(PARAMS, xdot - reference.xdot)),
    )


def loop_strides(y0: np.ndarray, xdot0: np.ndarray, strides: int, tolerance: float) -> int:
    done = 0
    for y, xdot in zip(y0, xdot0, strict=True):
        apex: ApexState | None = ApexState(float(y), float(xdot))
        for _ in range(strides):
            assert apex is not None
            apex = apex_return_map(PARAMS, apex, command_for(apex), rtol=tolerance, atol=tolerance).apex
            if apex is None:
                break
            done += 1
    return done


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--lanes-per-side", type=int, default=32)
    parser.add_argument("--strides", type=int, default=20)
    parser.add_argument("--check-lanes", type=int, default=64, help="grid subset for the accuracy match")
    parser.add_argument("--target", type=float, default=1e-10, help="apex accuracy both engines must meet")
    args = parser.parse_args()

    y_grid, xdot_grid = np.meshgrid(
        np.linspace(1.0, 1.35, args.lanes_per_side), np.linspace(3.0, 5.0, args.lanes_per_side)
    )
    y0, xdot0 = y_grid.ravel(), xdot_grid.ravel()
    lanes = y0.size

    # Accuracy of one stride on a subset, against a tight solve.
    check = np.linspace(0, lanes - 1, min(args.check_lanes, lanes)).astype(int)
    starts = [ApexState(y0[i], xdot0[i]) for i in check]
    tight = REFERENCE_TOLERANCE
    references = [apex_return_map(PARAMS, a, command_for(a), rtol=tight, atol=tight).apex for a in starts]
    batch_errors, loop_errors = {}, {}
    for tol in TOLERANCES:
        batch_one = simulate_strides(PARAMS, y0[check], xdot0[check], policy, 1, rtol=tol, atol=tol)
        batch_errors[tol] = max(
            apex_error(batch_one.y[1, j], batch_one.xdot[1, j], ref)
            for j, ref in enumerate(references)
            if ref
        )
        loop_one = [apex_return_map(PARAMS, a, command_for(a), rtol=tol, atol=tol).apex for a in starts]
        loop_errors[tol] = max(
            apex_error(new.y, new.xdot, ref)
            for new, ref in zip(loop_one, references, strict=True)
            if ref and new
        )
    batch_tolerance = next((tol for tol in TOLERANCES if batch_errors[tol] <= args.target), TOLERANCES[-1])
    loop_tolerance = next((tol for tol in TOLERANCES if loop_errors[tol] <= args.target), TOLERANCES[-1])

    start = time.perf_counter()
    run = simulate_strides(
        PARAMS, y_grid, xdot_grid, policy, args.strides, rtol=batch_tolerance, atol=batch_tolerance
    )
    batch_seconds = time.perf_counter() - start
    batch_strides = int(np.isfinite(run.y[1:]).sum())

    start = time.perf_counter()
    loop_done = loop_strides(y0, xdot0, args.strides, loop_tolerance)
    loop_seconds = time.perf_counter() - start

    print(
        f"grid: {lanes} initial conditions x {args.strides} strides, kbar = 36, zeta0 = 0.08, beta = 20 deg"
    )
    print(f"one-stride apex error (dimensionless) vs rtol {tight:g} on {check.size} lanes:")
    print(
        f"  rtol = atol    batched     solve_ivp loop    (each timed at the loosest meeting {args.target:g})"
    )
    for tol in TOLERANCES:
        marks = " <- batched timed" if tol == batch_tolerance else ""
        marks += " <- loop timed" if tol == loop_tolerance else ""
        print(f"  {tol:<12g}  {batch_errors[tol]:.2e}    {loop_errors[tol]:.2e}{marks}")
    batch_rate, loop_rate = batch_strides / batch_seconds, loop_done / loop_seconds
    print(
        f"batched engine : {batch_seconds:8.2f} s for {batch_strides} strides ({batch_rate:9.0f} strides/s)"
    )
    print(f"solve_ivp loop : {loop_seconds:8.2f} s for {loop_done} strides ({loop_rate:9.0f} strides/s)")
    print(f"speed-up (stride rate, batched / loop): {batch_rate / loop_rate:.1f}x")


if __name__ == "__main__":
    main()
