"""Time per call of the stance policies, one apex at a time as the controller node calls them.

    python bench/bench_controllers.py [--cases 40] [--repeat 3]

Random apex states (y in [0.95, 1.4] m, xdot in [2, 7] m/s) and targets (y* in [0.95, 1.3] m,
xdot* in [1.5, 7.5] m/s), kbar = 36, zeta0 = 0.08, m = 80 kg, r0 = 1 m. Times are CPU seconds of this
process (time.process_time), best of --repeat per case; printed as median, 90th percentile and maximum
over the cases, with each policy's median against energy regulation's, measured side by side in this run.
The deadbeat target is < 20 ms per call; the apex-to-touchdown flight it must fit in lasts ~0.2 s.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

import numpy as np

from tdslip_ros.model.analytic import ParamArrays
from tdslip_ros.model.controllers import deadbeat, energy_regulation, pd_speed_energy_height
from tdslip_ros.model.params import HopperParams

PARAMS = HopperParams.from_dimensionless(36.0, 0.08)


def per_call_times(policy: Callable[[int], object], cases: int, repeat: int) -> np.ndarray:
    times = np.empty(cases)
    for case in range(cases):
        best = np.inf
        for _ in range(repeat):
            start = time.process_time()
            policy(case)
            best = min(best, time.process_time() - start)
        times[case] = best
    return times


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--cases", type=int, default=40, help="random (apex, target) pairs")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions per case (best time counts)")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(3)
    y, xdot = rng.uniform(0.95, 1.4, args.cases), rng.uniform(2.0, 7.0, args.cases)
    target_y, target_xdot = rng.uniform(0.95, 1.3, args.cases), rng.uniform(1.5, 7.5, args.cases)
    params = ParamArrays.of(PARAMS)
    beta = np.radians(26.0)
    policies: dict[str, Callable[[int], object]] = {
        "energy regulation": lambda i: energy_regulation(params, y[i], xdot[i], beta),
        "PD baseline": lambda i: pd_speed_energy_height(
            params, y[i], xdot[i], xdot[i], target_y[i], target_xdot[i]
        ),
        "deadbeat": lambda i: deadbeat(params, y[i], xdot[i], target_y[i], target_xdot[i]),
    }
    print(f"ms per call over {args.cases} cases, best of {args.repeat} each:")
    reference = None
    for name, policy in policies.items():
        times = per_call_times(policy, args.cases, args.repeat) * 1e3
        median = float(np.median(times))
        reference = median if reference is None else reference
        print(
            f"  {name:<18} median {median:7.2f}  p90 {np.quantile(times, 0.9):7.2f}  max {times.max():7.2f}"
            f"   median / energy regulation = {median / reference:5.1f}x"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
