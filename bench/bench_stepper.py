"""Cost of one FixedStepStepper.step() (one 1 ms tick), by kind of tick and number of RK4 sub-steps.

    python bench/bench_stepper.py [--strides 30]

The plant node calls step() at 1 kHz from Python, so a tick must cost well under 1 ms; the target
is 150 us. The hopper runs under a proportional energy regulator (kbar = 36, zeta0 = 0.08,
beta = 20 deg), answering each apex with set_command as the controller node will. Every call is
timed; ticks are grouped into flight, stance and event ticks (those holding an event, whose root
finding costs extra). Printed per sub-step count: p50 / p99 / max in microseconds, and the p99 of
stance ticks as a fraction of the 150 us target.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from tdslip_ros.model.events import EventKind, Phase
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, StanceCommand
from tdslip_ros.model.plant.stepper import FixedStepStepper

PARAMS = PAPER_PARAMS
BETA = math.radians(20.0)
TARGET_ENERGY = ApexState(1.2, 4.0).energy(PARAMS)
TARGET_US = 150.0


def command_for(y: float, xdot: float) -> StanceCommand:
    return StanceCommand(BETA, -610.8 + 3.0 * (ApexState(y, xdot).energy(PARAMS) - TARGET_ENERGY), 0.15)


def time_ticks(substeps: int, strides: int) -> dict[str, np.ndarray]:
    stepper = FixedStepStepper(PARAMS, ApexState(1.25, 3.8), command_for(1.25, 3.8), substeps=substeps)
    costs: dict[str, list[float]] = {"flight": [], "stance": [], "event": []}
    while stepper.stride < strides and stepper.failed is None:
        phase = stepper.state.phase
        start = time.perf_counter_ns()
        events = stepper.step()
        elapsed = (time.perf_counter_ns() - start) / 1e3
        kind = "event" if events else ("stance" if phase is Phase.STANCE else "flight")
        costs[kind].append(elapsed)
        for event in events:
            if event.kind is EventKind.APEX:
                stepper.set_command(command_for(event.state.y, event.state.xdot))
    return {kind: np.array(values) for kind, values in costs.items()}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--strides", type=int, default=30)
    args = parser.parse_args()
    print(
        f"step() cost in us over {args.strides} strides (p50 / p99 / max); target {TARGET_US:g} us per tick"
    )
    print(f"{'substeps':>8}  {'flight':>22}  {'stance':>22}  {'event':>22}  stance p99 / target")
    for substeps in (1, 2, 4, 8):
        costs = time_ticks(substeps, args.strides)
        cells = []
        for kind in ("flight", "stance", "event"):
            values = costs[kind]
            p50, p99 = np.percentile(values, [50, 99])
            cells.append(f"{p50:6.1f} /{p99:6.1f} /{values.max():6.0f}")
        stance_p99 = np.percentile(costs["stance"], 99)
        print(f"{substeps:>8}  {'  '.join(cells)}  {stance_p99 / TARGET_US:.2f}")


if __name__ == "__main__":
    main()
