"""Write analytic_reference.npz: inputs and outputs of the analytic map and the policies, as a fixed record.

    python test/data/make_analytic_reference.py

The file was written once by the numpy implementation of the analytic map and the policies (commit
48c37ba) before they moved to the compiled kernels; test_analytic_reference.py checks that the kernels
give the same strides, failures, commands and no-command reasons to 1e-12. Run this again only where the
maths is meant to change, and say so in the commit.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from tdslip_ros.model.analytic.apex_map import approximate_map
from tdslip_ros.model.analytic.closed_loop import map_jacobian
from tdslip_ros.model.arrays import CommandArrays, ParamArrays
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.policies.controllers import (
    apex_foot_placement,
    deadbeat,
    energy_regulation,
    fixed_power,
    ramp_to_liftoff,
)

OUT = Path(__file__).with_name("analytic_reference.npz")
PARAMS = PAPER_PARAMS
MAP_CASES = (("1_paper", 1, "paper"), ("0_paper", 0, "paper"), ("2_force_root", 2, "force_root"))


def _lane_params(rng: np.random.Generator, lanes: int) -> dict[str, np.ndarray]:
    """Per-lane hopper parameters: kbar 10-60, zeta0 0-0.5, m 50-90 kg, r0 0.8-1.1 m, g 9.81."""
    kbar, zeta0 = rng.uniform(10.0, 60.0, lanes), rng.uniform(0.0, 0.5, lanes)
    m, r0 = rng.uniform(50.0, 90.0, lanes), rng.uniform(0.8, 1.1, lanes)
    p = ParamArrays.from_dimensionless(kbar, zeta0, m=m, r0=r0, g=np.full(lanes, 9.81))
    return {name: np.asarray(getattr(p, name)) for name in ("m", "k", "r0", "c", "g")}


def main() -> int:
    rng = np.random.default_rng(20260613)
    data: dict[str, np.ndarray] = {}

    # The map on wide ranges (many lanes fail: every failure kind occurs), per-lane parameters.
    lanes = 1200
    params = _lane_params(rng, lanes)
    r0 = params["r0"]
    inputs = {
        "y": r0 * rng.uniform(0.7, 1.8, lanes),
        "xdot": rng.uniform(0.5, 7.5, lanes),
        "angle": rng.uniform(0.15, 0.8, lanes),
        "tau0": rng.uniform(-1.0, 0.2, lanes) * params["m"] * 9.81 * r0,
        "t_f": rng.uniform(0.03, 0.4, lanes),
    }
    data |= {f"map_{k}": v for k, v in (params | inputs).items()}
    command = CommandArrays(inputs["angle"], inputs["tau0"], inputs["t_f"])
    for name, corrections, liftoff in MAP_CASES:
        stride = approximate_map(
            ParamArrays(**params), inputs["y"], inputs["xdot"], command, corrections, liftoff
        )
        data |= {
            f"map{name}_y": stride.y,
            f"map{name}_xdot": stride.xdot,
            f"map{name}_energy": stride.energy,
            f"map{name}_failure": stride.failure,
            f"map{name}_t_lo": stride.stance.t_lo,
            f"map{name}_momentum": stride.stance.momentum,
            f"map{name}_hip_energy": stride.stance.hip_energy,
            f"map{name}_energy_loss": stride.stance.energy_loss,
        }

    # Policies at the gaits of the paper's parameters: apexes over the range of the controller benchmarks.
    lanes = 600
    y, xdot = rng.uniform(0.85, 1.9, lanes), rng.uniform(0.5, 7.5, lanes)
    beta = np.radians(rng.uniform(15.0, 35.0, lanes))
    energy = PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)
    target = energy * rng.uniform(0.9, 1.1, lanes)
    alpha = rng.uniform(0.2, 3.0, lanes)
    torque = rng.uniform(-1.2, 0.2, lanes) * PARAMS.m * PARAMS.g * PARAMS.r0
    data |= {"policy_y": y, "policy_xdot": xdot, "policy_beta": beta, "policy_target_energy": target}
    data |= {"policy_alpha": alpha, "policy_tau0": torque}
    commands = {
        "energy": energy_regulation(PARAMS, y, xdot, beta),
        "energy_target": energy_regulation(PARAMS, y, xdot, beta, target),
        "energy_target_0": energy_regulation(PARAMS, y, xdot, beta, target, corrections=0),
        "energy_target_2": energy_regulation(PARAMS, y, xdot, beta, target, corrections=2),
        "open_loop": fixed_power(PARAMS, y, xdot, beta, alpha),
        "ramp": ramp_to_liftoff(PARAMS, y, xdot, beta, torque),
    }
    # Target apexes of deadbeat and PD (the controller benchmark's ranges).
    lanes = 300
    y, xdot = rng.uniform(0.95, 1.4, lanes), rng.uniform(2.0, 7.0, lanes)
    previous = xdot * rng.uniform(0.9, 1.1, lanes)
    target_y, target_xdot = rng.uniform(0.95, 1.3, lanes), rng.uniform(1.5, 7.5, lanes)
    data |= {"target_y": y, "target_xdot": xdot, "target_previous_xdot": previous}
    data |= {"target_target_y": target_y, "target_target_xdot": target_xdot}
    commands["deadbeat"] = deadbeat(PARAMS, y, xdot, target_y, target_xdot)
    commands["apex_foot_placement"] = apex_foot_placement(PARAMS, y, xdot, previous, target_y, target_xdot)
    for name, fields in commands.items():
        assert fields.no_command is not None
        data |= {
            f"command_{name}_angle": fields.touchdown_angle,
            f"command_{name}_tau0": fields.tau0,
            f"command_{name}_t_f": fields.t_f,
            f"command_{name}_reason": fields.no_command,
        }

    # Complex-step Jacobians of the closed loops (the policies differentiated through their solvers).
    lanes = 150
    y, xdot = rng.uniform(1.0, 1.3, lanes), rng.uniform(3.0, 6.0, lanes)
    beta = np.radians(26.0)
    data |= {"jacobian_y": y, "jacobian_xdot": xdot}
    data["jacobian_energy_speed"] = map_jacobian(
        PARAMS, y, xdot, lambda p, y_, x_: energy_regulation(p, y_, x_, beta)
    )
    energy = PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)
    data["jacobian_open_loop_energy"] = map_jacobian(
        PARAMS, y, energy, lambda p, y_, x_: fixed_power(PARAMS, y_, x_, beta, 1.5), "energy"
    )
    np.savez_compressed(OUT, **data)
    print(f"wrote {OUT} ({OUT.stat().st_size / 1024:.0f} KiB, {len(data)} arrays)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
