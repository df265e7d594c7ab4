"""Viability Q-maps: the batched exact engine against a solve_ivp loop of the same strides, on Dask, and
against vibly's algorithm on vibly's own SLIP demo grid.

    python bench/bench_viability.py [--loop-strides 600] [--vibly-grid] [--dask-pairs N] [--scaling-pairs N]

The grid is vibly's SLIP demo (docs/viability.md, question 1): m = 80 kg, k = 8,200 N/m, r0 = 1 m, c = 0,
g = 9.81 m/s^2, the energy of the apex (0.85 m, 5.5 m/s), height fractions linspace(0.1, 1, 181)[:-1],
touchdown angles linspace(-10, 70, 161) deg from the vertical (180 x 161 = 28,980 strides).

1. Cost per stride, side by side in this process: the Q-map of the whole grid on the batched engine
   (viability_spaces.transitions, DOP853 at rtol = atol = 1e-12; numba compiled before the clock), against
   ``--loop-strides`` of the same strides (spread evenly over the grid) through the loop a user would
   write, and vibly does: scipy.integrate.solve_ivp (RK45 at its default rtol 1e-3, atol 1e-6, stance
   max_step 1 ms), stride by stride. Both per core (one process); the ratio is printed.
2. ``--vibly-grid``: the loop over the whole grid (about 3 min on one core), its kernel by vibly's
   algorithm, written here from the paper and vibly's documented semantics (successors binned with
   numpy.digitize; a pair viable while both grid points around its successor are; successors below the
   first grid point never viable, above the last judged by it), against ours (judge="conservative",
   outside="edge"): failure cells and kernel cell by cell; each differing pair listed with its successor's
   distance to the nearest grid point (the edge of the cells it is binned between).
3. ``--dask-pairs N``: a Q-map of about N strides of the damped hopper's apex space (kbar 36, zeta0 0.08, a
   4-D grid: heights x speeds x angles x torques) through tdslip_ros.studies.viability on a local cluster of
   2 workers: its wall time (the cluster started before the clock). ``--scaling-pairs N``: the same on 1
   then 2 workers, the scaling efficiency t1 / (2 t2).

The load average (and the steal share of /proc/stat over each run) is printed beside each timing.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.stability.viability import NO_FAILURE_CODE, viable_set
from tdslip_ros.model.stability.viability_spaces import EnergySpace, assemble, transitions

SLIP = HopperParams(m=80.0, k=8200.0, r0=1.0, c=0.0, g=9.81)
ENERGY = SLIP.m * (SLIP.g * 0.85 + 0.5 * 5.5**2)
FRACTIONS = np.linspace(0.1, 1.0, 181)[:-1]
ANGLES = np.radians(np.linspace(-10.0, 70.0, 161))
DEMO = EnergySpace(SLIP, ENERGY, FRACTIONS, ANGLES)
REVERSAL_MARGIN = 1e-5
"""m/s: vibly's reversal event fires at xdot = -1e-5 (it lets a stride go straight up)."""


def cpu_times() -> tuple[int, int]:
    """(steal, total) jiffies of /proc/stat."""
    with open("/proc/stat") as stat:
        values = [int(v) for v in stat.readline().split()[1:]]
    return values[7], sum(values)


def conditions(before: tuple[int, int]) -> str:
    steal, total = cpu_times()
    share = 100.0 * (steal - before[0]) / max(total - before[1], 1)
    return "load {:.1f} {:.1f} {:.1f}, steal {:.1f} %".format(*os.getloadavg(), share)


def slip_stride(fraction: float, angle: float) -> tuple[float, bool]:
    """vibly's SLIP stride from the apex of height fraction ``fraction`` at touchdown angle ``angle`` [rad]:
    the next apex's height fraction and whether the stride failed. Flights are ballistic (closed form);
    the stance is integrated by solve_ivp's RK45 at its defaults, stance max_step 1 ms, in Cartesian
    coordinates with the toe fixed, with vibly's events: the body at the ground (fall), the leg back at
    its rest length while extending (liftoff), xdot crossing -1e-5 downwards (reversal)."""
    m, k, r0, g = SLIP.m, SLIP.k, SLIP.r0, SLIP.g
    y = fraction * ENERGY / (m * g)
    xdot = math.sqrt(2.0 * ENERGY * (1.0 - fraction) / m)
    toe_x, toe_y = math.sin(angle) * r0, y - math.cos(angle) * r0  # toe relative to the apex's x
    if toe_y < 0.0:
        return math.nan, True
    fall_time = math.sqrt(2.0 * toe_y / g)
    start = np.array([0.0, y - toe_y, xdot, -g * fall_time])  # x, y at touchdown (toe at ground level)
    toe_x, toe_y = toe_x, 0.0

    def stance(t: float, state: np.ndarray) -> np.ndarray:
        dx, dy = state[0] - toe_x, state[1] - toe_y
        length = math.hypot(dx, dy)
        force = k / m * (r0 - length)
        return np.array([state[2], state[3], force * dx / length, force * dy / length - g])

    def fall(t: float, state: np.ndarray) -> float:
        return float(state[1])

    def liftoff(t: float, state: np.ndarray) -> float:
        return math.hypot(state[0] - toe_x, state[1] - toe_y) - r0

    def reversal(t: float, state: np.ndarray) -> float:
        return float(state[2]) + REVERSAL_MARGIN

    fall.terminal = True  # type: ignore[attr-defined]
    liftoff.terminal, liftoff.direction = True, 1  # type: ignore[attr-defined]
    reversal.terminal, reversal.direction = True, -1  # type: ignore[attr-defined]
    solution = solve_ivp(stance, (0.0, 5.0), start, events=(fall, liftoff, reversal), max_step=1e-3)
    if solution.t_events[0].size or solution.t_events[2].size or not solution.t_events[1].size:
        return math.nan, True
    _, y_lo, xdot_lo, ydot_lo = solution.y[:, -1]
    if ydot_lo <= 0.0:  # no apex ahead: the flight ends on the ground
        return math.nan, True
    y_next = y_lo + ydot_lo**2 / (2.0 * g)
    if y_next <= 0.0 or math.isclose(y_next, 0.0) or xdot_lo <= 0.0:
        return math.nan, True
    return g * y_next / (g * y_next + 0.5 * xdot_lo**2), False


def vibly_kernel(
    successor: np.ndarray, failed: np.ndarray, grid: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """vibly's viable pairs and kernel of a 1-D Q-map (successor fractions, failed: states x actions)."""
    bins = np.where(failed, 0, np.digitize(np.nan_to_num(successor), grid))
    viable = ~failed & (bins != 0)
    kernel = viable.any(axis=1)
    while True:
        lower = kernel[np.clip(bins - 1, 0, grid.size - 1)]
        upper = np.where(bins < grid.size, kernel[np.clip(bins, 0, grid.size - 1)], True)
        viable &= lower & upper
        updated = viable.any(axis=1)
        if np.array_equal(updated, kernel):
            return viable, kernel
        kernel = updated


def loop(pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    shape = (FRACTIONS.size, ANGLES.size)
    successor, failed = np.full(pairs.size, np.nan), np.zeros(pairs.size, dtype=bool)
    for position, pair in enumerate(pairs):
        state, action = np.unravel_index(pair, shape)
        successor[position], failed[position] = slip_stride(float(FRACTIONS[state]), float(ANGLES[action]))
    return successor, failed


def cost_per_stride(loop_strides: int) -> None:
    transitions(DEMO, 0, 64)  # numba's compilation (or its cache) outside the clock
    before = cpu_times()
    started = time.process_time()
    transitions(DEMO)
    batched = (time.process_time() - started) / (FRACTIONS.size * ANGLES.size)
    print(
        f"batched engine, Q-map of the demo grid: {1e3 * batched:.4f} ms per stride (CPU), "
        f"{conditions(before)}"
    )
    pairs = np.linspace(0, FRACTIONS.size * ANGLES.size - 1, loop_strides).astype(int)
    before = cpu_times()
    started = time.process_time()
    loop(pairs)
    looped = (time.process_time() - started) / pairs.size
    print(
        f"solve_ivp loop (RK45, rtol 1e-3), {pairs.size} strides: {1e3 * looped:.3f} ms per stride, "
        f"{conditions(before)}"
    )
    print(f"ratio per core: {looped / batched:.0f}x (goal >= 300x)")


def verdict(failed: bool, viable: bool) -> str:
    return "fails" if failed else "viable" if viable else "not viable"


def compare_with_vibly() -> None:
    ours = assemble(DEMO, *transitions(DEMO))
    before = cpu_times()
    started = time.perf_counter()
    successor, failed = loop(np.arange(FRACTIONS.size * ANGLES.size))
    successor, failed = successor.reshape(ours.failure.shape), failed.reshape(ours.failure.shape)
    print(f"reference loop over the demo grid: {time.perf_counter() - started:.0f} s, {conditions(before)}")
    viable, kernel = vibly_kernel(successor, failed, FRACTIONS)
    result = viable_set(ours, "conservative", "edge")
    ours_failed = ours.failure != NO_FAILURE_CODE
    positive = ANGLES > 0.0
    print(f"failure pairs: ours {ours_failed.sum()} ({ours.failure_counts}), reference {failed.sum()}")
    differ = ours_failed != failed
    print(
        f"failure verdicts differ at {differ.sum()} pairs, {differ[:, positive].sum()} of them at angles > 0"
    )
    print(
        f"kernel: ours {result.kernel.sum()} states (indices {np.flatnonzero(result.kernel)[[0, -1]]}), "
        f"reference {kernel.sum()} states; differing states: {np.flatnonzero(result.kernel != kernel)}"
    )
    print(
        f"viable pairs: ours {result.viable.sum()}, reference {viable.sum()} "
        f"({viable[:, ~positive].sum()} at angles <= 0); at angles > 0 they differ at "
        f"{(result.viable != viable)[:, positive].sum()} pairs"
    )
    for state, action in zip(*np.nonzero(differ | (result.viable != viable)), strict=True):
        if not positive[action]:
            continue
        value = (
            ours.successor[state, action, 0] if not ours_failed[state, action] else successor[state, action]
        )
        edge = np.min(np.abs(FRACTIONS - value)) if np.isfinite(value) else math.nan
        print(
            f"  s = {FRACTIONS[state]:.3f}, angle = {math.degrees(ANGLES[action]):.1f} deg: ours "
            f"{verdict(ours_failed[state, action], result.viable[state, action])} "
            f"(successor {ours.successor[state, action, 0]:.6f}), reference "
            f"{verdict(failed[state, action], viable[state, action])} "
            f"(successor {successor[state, action]:.6f}); distance to the nearest grid point {edge:.2e}"
        )


def dask_q_map(pairs: int, workers: int) -> float:
    from tdslip_ros.model.paper import PAPER_PARAMS
    from tdslip_ros.model.stability.viability_spaces import ApexSpace
    from tdslip_ros.studies import engine
    from tdslip_ros.studies.viability import run_q_map

    side = round(pairs**0.25)
    space = ApexSpace(
        PAPER_PARAMS,
        np.linspace(0.9, 1.6, side),
        np.linspace(1.0, 6.0, side),
        np.radians(np.linspace(10.0, 40.0, side)),
        np.linspace(-600.0, 0.0, side),
        0.2,
    )
    scratch = Path(tempfile.mkdtemp(prefix="bench_viability_"))
    try:
        with engine.connect(engine.Where(workers=workers)) as client:
            client.run(lambda: transitions(DEMO, 0, 8))  # every worker up, numba loaded
            before = cpu_times()
            started = time.perf_counter()
            run_q_map(space, scratch, client)
            seconds = time.perf_counter() - started
        print(
            f"Q-map of {side}^4 = {side**4:,} strides on {workers} worker(s): {seconds:.1f} s, "
            f"{conditions(before)}"
        )
        return seconds
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--loop-strides", type=int, default=600, help="strides of the solve_ivp loop")
    parser.add_argument(
        "--vibly-grid", action="store_true", help="also the whole demo grid against vibly's algorithm"
    )
    parser.add_argument("--dask-pairs", type=int, help="a Q-map of about this many strides on 2 workers")
    parser.add_argument(
        "--scaling-pairs", type=int, help="a Q-map of about this many strides on 1, then 2 workers"
    )
    args = parser.parse_args()
    cost_per_stride(args.loop_strides)
    if args.vibly_grid:
        compare_with_vibly()
    if args.scaling_pairs:
        one, two = dask_q_map(args.scaling_pairs, 1), dask_q_map(args.scaling_pairs, 2)
        print(f"scaling 1 -> 2 workers: {100 * one / (2 * two):.0f} %")
    if args.dask_pairs:
        dask_q_map(args.dask_pairs, 2)


if __name__ == "__main__":
    main()
