"""Planning time of each policy, one apex at a time as the controller node plans, against its target (0.2 ms;
energy_exact 1 ms).

    python bench/bench_controllers.py [--apexes 1000] [--exact-apexes 1000] [--baseline DIR]

Each policy answers the same random apexes (y in [0.95, 1.4] m, xdot in [2, 7] m/s; targets y* in
[0.95, 1.3] m, xdot* in [1.5, 7.5] m/s; kbar = 36, zeta0 = 0.08, m = 80 kg, r0 = 1 m) through
PolicySpec.commands(...).command(), the controller node's call (an apex without a command costs its
ParameterError). Settings: beta = 26 deg, alpha = 1.5 (open_loop), the apex's own energy as the target
(energy, energy_exact), the declared PD gains and corrections (model.policies). Kernels are loaded first,
as the node does before it subscribes. Printed per policy: p50, p99 and the maximum of the CPU time of this
process (time.process_time: what one core spends, whatever else the shared machine runs) and of the wall
time (time.perf_counter: what the apex waits, preemption included), and p99 CPU against the target.
energy_exact plans on the exact plant (about 3 x 4 exact strides, compiled: model.exact_kernels) and runs on
the first --exact-apexes apexes (a checkout from before the compiled plan takes about 40 ms an apex).

--baseline DIR measures the same apexes with the tdslip_ros of another checkout (e.g. ``git worktree add
/tmp/tdslip-main main``) in a child process and prints it beside, with the ratio of the p99s.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, ParameterError
from tdslip_ros.model.policies.registry import PolicySpec

PARAMS = PAPER_PARAMS
TARGET_MS = 0.2
"""p99 planning time [ms] issue 13 asks of open_loop, energy, apex_foot_placement and deadbeat."""
EXACT_TARGET_MS = 1.0
"""p99 planning time [ms] issue 21 asks of energy_exact."""
POLICY_ORDER = ("open_loop", "energy", "apex_foot_placement", "deadbeat", "energy_exact")


def _apexes(count: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    xdot = rng.uniform(2.0, 7.0, count)
    return {
        "y": rng.uniform(0.95, 1.4, count),
        "xdot": xdot,
        "previous_xdot": xdot * rng.uniform(0.95, 1.05, count),
        "target_y": rng.uniform(0.95, 1.3, count),
        "target_xdot": rng.uniform(1.5, 7.5, count),
    }


def _spec(name: str, target_y: float, target_xdot: float, energy: float) -> PolicySpec:
    return replace(
        PolicySpec.default(name),
        touchdown_angle=float(np.radians(26.0)),
        touchdown_power=float(units.power_from_alpha(PARAMS, 1.5)),
        target_energy=energy,
        target_height=target_y,
        target_speed=target_xdot,
    )


def target_ms(policy: str) -> float:
    return EXACT_TARGET_MS if policy == "energy_exact" else TARGET_MS


def measure(
    apexes: int, exact_apexes: int, policies: tuple[str, ...] = POLICY_ORDER
) -> dict[str, dict[str, list[float]]]:
    """Per policy: CPU and wall seconds of each apex's plan, and how many apexes got a command."""
    data = _apexes(max(apexes, exact_apexes))
    results: dict[str, dict[str, list[float]]] = {}
    for name in policies:
        count = exact_apexes if name == "energy_exact" else apexes
        cpu, wall, answered = [], [], 0
        for i in range(-3, count):  # three unmeasured calls first: the kernels are loaded
            lane = max(i, 0)
            y, xdot = float(data["y"][lane]), float(data["xdot"][lane])
            spec = _spec(
                name,
                float(data["target_y"][lane]),
                float(data["target_xdot"][lane]),
                ApexState(y, xdot).energy(PARAMS),
            )
            start_cpu, start_wall = time.process_time(), time.perf_counter()
            try:
                spec.commands(PARAMS, y, xdot, float(data["previous_xdot"][lane])).command()
                answered += i >= 0
            except ParameterError:
                pass
            if i >= 0:
                wall.append(time.perf_counter() - start_wall)
                cpu.append(time.process_time() - start_cpu)
        results[name] = {"cpu": cpu, "wall": wall, "answered": [answered]}
    return results


def _baseline(directory: Path, apexes: int, exact_apexes: int) -> dict[str, dict[str, list[float]]]:
    """The measurement in a child process that imports tdslip_ros from ``directory``."""
    command = [
        sys.executable,
        __file__,
        "--json",
        "--apexes",
        str(apexes),
        "--exact-apexes",
        str(exact_apexes),
    ]
    environment = dict(os.environ, PYTHONPATH=str(directory.resolve()))
    child = subprocess.run(command, env=environment, capture_output=True, text=True, check=True, timeout=3600)
    reported: dict[str, dict[str, list[float]]] = json.loads(child.stdout)
    return reported


def _row(times: dict[str, list[float]]) -> str:
    cpu, wall = np.asarray(times["cpu"]) * 1e3, np.asarray(times["wall"]) * 1e3
    return (
        f"{np.median(cpu):8.3f} {np.quantile(cpu, 0.99):8.3f} {cpu.max():8.3f}"
        f" {np.median(wall):8.3f} {np.quantile(wall, 0.99):8.3f} {cpu.size:6d} {times['answered'][0]:6d}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--apexes", type=int, default=1000, help="apexes per policy")
    parser.add_argument("--exact-apexes", type=int, default=1000, help="apexes for energy_exact")
    parser.add_argument("--baseline", type=Path, help="checkout whose tdslip_ros to measure beside")
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)  # the child's report
    args = parser.parse_args(argv)
    results = measure(args.apexes, args.exact_apexes)
    if args.json:
        print(json.dumps(results))
        return 0
    baseline = _baseline(args.baseline, args.apexes, args.exact_apexes) if args.baseline else None
    print(f"planning time per apex [ms], target p99 < {TARGET_MS} ms (energy_exact: {EXACT_TARGET_MS} ms)")
    columns = ("cpu p50", "cpu p99", "cpu max", "wall p50", "wall p99")
    header = " ".join(f"{column:>8}" for column in columns) + f" {'apexes':>6} {'answered':>6}"
    print(f"  {'policy':<13} {'code':<9} {header}   p99/target")
    for name in POLICY_ORDER:
        p99 = float(np.quantile(results[name]["cpu"], 0.99)) * 1e3
        target = target_ms(name)
        verdict = f"   {p99 / target:5.2f}  {'ok' if p99 < target else 'MISSED'}"
        print(f"  {name:<13} {'this':<9} {_row(results[name])}{verdict}")
        if baseline is not None:
            old = float(np.quantile(baseline[name]["cpu"], 0.99)) * 1e3
            print(
                f"  {'':<13} {'baseline':<9} {_row(baseline[name])}   p99 baseline/this = {old / p99:6.1f}x"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
