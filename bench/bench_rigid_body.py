"""What a rigid body (issue 36) costs a stride beside the paper's point mass, in the exact map, the 1 kHz
stepper and the batched engine, side by side in one run.

    .venv/bin/python bench/bench_rigid_body.py [--rounds 5] [--strides 40] [--lanes 1000] [--batches 3]

One stride of the paper's hopper (kbar = 36, zeta0 = 0.08, 80 kg) from the same hip apex (1.25 m, 3.8 m/s)
under the same ramp (20 deg, tau0 = -607 N m, t_f = 0.15 s): the point mass, and a rigid body of inertia
20 kg m^2 with its hip 0.15 m behind and 0.1 m below the centre of mass, pitched 0.05 rad and turning at
-0.3 rad/s (test_plant_stepper_rigid_body.py's bodies hop such strides). Timed per stride: the exact map
(``apex_return_map``, DOP853 at rtol = atol = 1e-12, one call) and the stepper (the step() calls from the
apex to the next one at 4 sub-steps per tick, the stepper built untimed), per stepper tick: stance ticks
without an event, flight ticks and event ticks, and per stride of the batched engine
(``batch_apex_return_map`` at rtol = atol = 1e-12, ``--lanes`` lanes of that stride in one call, the call's
time over its lanes). ``--rounds`` rounds alternate the two hoppers (so that the machine's drift falls on
both alike), each timing ``--strides`` strides per engine, and ``--batches`` calls of the batched engine.
Printed: medians (and the stance ticks' p99) of this thread's CPU time, the wall time's medians beside, and
the ratio rigid / point of the CPU medians; the load average and the CPU time the hypervisor stole during the
run beside them. Numbers: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import numpy as np

from tdslip_ros.model.events import EventKind, Phase
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, RigidBody, StanceCommand
from tdslip_ros.model.plant.batch import batch_apex_return_map
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stepper import FixedStepStepper

BODY = RigidBody(20.0, hip_x=-0.15, hip_y=-0.1)
HOPPERS = {
    "point mass": (PAPER_PARAMS, ApexState(1.25, 3.8)),
    "rigid body": (
        HopperParams(PAPER_PARAMS.m, PAPER_PARAMS.k, PAPER_PARAMS.r0, PAPER_PARAMS.c, PAPER_PARAMS.g, BODY),
        ApexState(1.25 - BODY.hip_y, 3.8, 0.05, -0.3),
    ),
}
COMMAND = StanceCommand(math.radians(20.0), -607.0, 0.15)
UNITS = {
    "exact map stride": ("ms", 1e6),
    "stepper stride": ("ms", 1e6),
    "batched stride": ("us", 1e3),
    "stance tick": ("us", 1e3),
    "flight tick": ("us", 1e3),
    "event tick": ("us", 1e3),
}
QUANTITIES = tuple(UNITS)


def steal_seconds() -> float:
    """CPU time the hypervisor gave to others while this VM wanted it (Linux /proc/stat, all CPUs)."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    return int(fields[8]) / os.sysconf("SC_CLK_TCK")


def load() -> str:
    return "load average " + " ".join(f"{value:.2f}" for value in os.getloadavg())


Samples = dict[str, list[tuple[int, int]]]
"""(CPU ns, wall ns) per timed call, by quantity."""


def time_exact(params: HopperParams, apex: ApexState, strides: int, samples: Samples) -> None:
    for _ in range(strides):
        cpu, wall = time.thread_time_ns(), time.perf_counter_ns()
        result = apex_return_map(params, apex, COMMAND)
        samples["exact map stride"].append((time.thread_time_ns() - cpu, time.perf_counter_ns() - wall))
        assert result.failure is None, result.reason


def time_stepper(params: HopperParams, apex: ApexState, strides: int, samples: Samples) -> None:
    for _ in range(strides):
        stepper = FixedStepStepper(params, apex, COMMAND)
        stride_cpu = stride_wall = 0
        while stepper.stride == 0:
            phase = stepper.state.phase
            cpu, wall = time.thread_time_ns(), time.perf_counter_ns()
            events = stepper.step()
            cpu, wall = time.thread_time_ns() - cpu, time.perf_counter_ns() - wall
            stride_cpu, stride_wall = stride_cpu + cpu, stride_wall + wall
            kind = "event tick" if events else ("stance tick" if phase is Phase.STANCE else "flight tick")
            samples[kind].append((cpu, wall))
        assert stepper.failed is None and events[-1].kind is EventKind.APEX
        samples["stepper stride"].append((stride_cpu, stride_wall))


def time_batched(params: HopperParams, apex: ApexState, lanes: int, batches: int, samples: Samples) -> None:
    """Each call's time over its lanes: the cost of one stride of the batched engine."""
    y, xdot = np.full(lanes, apex.y), np.full(lanes, apex.xdot)
    for _ in range(batches):
        cpu, wall = time.thread_time_ns(), time.perf_counter_ns()
        result = batch_apex_return_map(
            params, y, xdot, COMMAND.touchdown_angle, COMMAND.tau0, COMMAND.t_f,
            pitch=apex.pitch, pitch_rate=apex.pitch_rate,
        )  # fmt: skip
        cpu, wall = time.thread_time_ns() - cpu, time.perf_counter_ns() - wall
        samples["batched stride"].append((cpu // lanes, wall // lanes))
        assert np.all(result.failure == -1)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--strides", type=int, default=40, help="strides per engine, hopper and round")
    parser.add_argument("--lanes", type=int, default=1000, help="lanes per call of the batched engine")
    parser.add_argument("--batches", type=int, default=3, help="batched calls per hopper and round")
    args = parser.parse_args()
    for params, apex in HOPPERS.values():  # warm up: imports, caches, the compiled stances
        time_exact(params, apex, 1, {"exact map stride": []})
        time_batched(params, apex, 1, 1, {"batched stride": []})
    print(f"before: {load()}")
    steal = steal_seconds()
    samples: dict[str, Samples] = {name: {q: [] for q in QUANTITIES} for name in HOPPERS}
    for _ in range(args.rounds):
        for name, (params, apex) in HOPPERS.items():
            time_exact(params, apex, args.strides, samples[name])
            time_stepper(params, apex, args.strides, samples[name])
            time_batched(params, apex, args.lanes, args.batches, samples[name])
    stolen = steal_seconds() - steal
    print(f"after: {load()}; steal during the run {stolen:.2f} s (all CPUs)")
    print(
        f"{args.rounds} rounds x {args.strides} strides per engine and hopper ({args.batches} calls of "
        f"{args.lanes} lanes for the batched engine); CPU median (wall median) of each, rigid / point of the "
        "CPU medians"
    )
    print(f"{'':22}{'point mass':>22}{'rigid body':>22}{'rigid / point':>15}")
    for quantity in QUANTITIES:
        unit, scale = UNITS[quantity]
        medians = {}
        cells = []
        for name in HOPPERS:
            values = np.array(samples[name][quantity], dtype=np.float64) / scale
            medians[name] = float(np.median(values[:, 0]))
            cells.append(f"{medians[name]:8.3f} ({float(np.median(values[:, 1])):8.3f})")
        ratio = medians["rigid body"] / medians["point mass"]
        print(f"{quantity + ' [' + unit + ']':22}{cells[0]:>22}{cells[1]:>22}{ratio:15.2f}")
    stance = {name: np.array(samples[name]["stance tick"])[:, 0] / 1e3 for name in HOPPERS}
    p99 = {name: float(np.percentile(values, 99)) for name, values in stance.items()}
    print(
        f"stance tick p99 [us]: point mass {p99['point mass']:.1f}, rigid body {p99['rigid body']:.1f} "
        f"(CPU; {len(stance['rigid body'])} rigid stance ticks)"
    )


if __name__ == "__main__":
    main()
