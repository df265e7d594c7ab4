"""Batched engine: stride rate under a stance feedback law beside the ramp's, in one run.

    python bench/bench_stance_feedback.py [--lanes-per-side 32] [--strides 20] [--tolerance 1e-12]

The grid is lanes-per-side^2 initial apex states (y in [1.0, 1.35] m, xdot in [3, 5] m/s; default 32^2 =
1,024) of the paper's hopper (kbar = 36, zeta0 = 0.08), run by ``simulate_strides`` twice, at the same
DOP853 tolerance: under the ramp of a proportional energy regulator at beta = 20 deg (the policy of
bench_batch.py), and under the stance law of ref. 36's baseline (``StancePDSpeedEnergy``, default gains,
target 1.2 m at 4 m/s) sampled at 1 kHz, at beta = 22 deg. A law's stance is split at every sample instant,
so each lane takes at least one DOP853 step per millisecond of stance (about 150 a stance when the steps
were last counted, before the stance was compiled), where a ramp's takes a few dozen steps in all (about 22
then), and the law is evaluated at every sample. Both runs are timed in this process, one after the other,
each the better of --repeats; printed: strides/s of each and their ratio.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState
from tdslip_ros.model.plant.batch import simulate_strides
from tdslip_ros.model.policies.stance_pd import StancePDSpeedEnergy

PARAMS = PAPER_PARAMS
TARGET_ENERGY = ApexState(1.2, 4.0).energy(PARAMS)
LAW = StancePDSpeedEnergy(PARAMS, target_y=1.2, target_xdot=4.0)


def ramp_policy(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[float, np.ndarray, float]:
    energy = PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)
    return math.radians(20.0), -610.8 + 3.0 * (energy - TARGET_ENERGY), 0.15


def law_policy(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[float, StancePDSpeedEnergy]:
    return math.radians(22.0), LAW


def timed(policy: Callable[..., Any], y0: np.ndarray, xdot0: np.ndarray, args: Any) -> tuple[float, int]:
    """Seconds of a run and the strides it completed."""
    start = time.perf_counter()
    run = simulate_strides(PARAMS, y0, xdot0, policy, args.strides, rtol=args.tolerance, atol=args.tolerance)
    return time.perf_counter() - start, int(np.isfinite(run.y[1:]).sum())


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--lanes-per-side", type=int, default=32)
    parser.add_argument("--strides", type=int, default=20)
    parser.add_argument("--tolerance", type=float, default=1e-12, help="rtol = atol of both runs")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    y_grid, xdot_grid = np.meshgrid(
        np.linspace(1.0, 1.35, args.lanes_per_side), np.linspace(3.0, 5.0, args.lanes_per_side)
    )
    y0, xdot0 = y_grid.ravel(), xdot_grid.ravel()

    rows = []
    for name, policy in (("ramp (energy regulator)", ramp_policy), ("stance law, 1 kHz", law_policy)):
        seconds, strides = min(timed(policy, y0, xdot0, args) for _ in range(args.repeats))
        rows.append((name, seconds, strides))

    print(
        f"grid: {y0.size} initial conditions x {args.strides} strides, kbar = 36, zeta0 = 0.08, "
        f"rtol = atol = {args.tolerance:g}"
    )
    for name, seconds, strides in rows:
        print(f"{name:<24}: {seconds:7.2f} s for {strides} strides ({strides / seconds:8.0f} strides/s)")
    (_, ramp_s, ramp_n), (_, law_s, law_n) = rows
    print(f"stride rate, stance law / ramp: {(law_n / law_s) / (ramp_n / ramp_s):.2f}")


if __name__ == "__main__":
    main()
