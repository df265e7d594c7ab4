"""``tdslip viability``: which states and actions keep the hopper running (the viability kernel, its measure),
on the batched exact engine and Dask.

    tdslip viability apex|energy|regulation --out DIR [--kbar 36 | --stiffness N_PER_M] [--zeta0 0.08]
                     [--mass 80] [--r0 1] [--gravity 9.80665]
                     [--heights LO HI N] [--speeds LO HI N] [--angles-deg LO HI N] [--torques LO HI N]
                     [--t-f S]
                     [--fractions LO HI N] [--energy-bar EBAR | --energy-of-apex Y XDOT]
                     [--tau-max N_M] [--push M_PER_S] [--angle-error-deg DEG] [--terrain flat]
                     [--judge conservative|nearest] [--outside failure|edge] [--chunk-size N]
                     [--memory-limit-gb GB] [--scheduler tcp://HOST:PORT | --workers N] [--resume]

Spaces (:mod:`tdslip_ros.model.stability.viability_spaces`): ``apex``, the states (y, xdot) and the actions
(touchdown angle, tau0) at a given t_f; ``energy``, one energy level, the state the fraction of it in height,
the action the touchdown angle, the hip idle (with ``--zeta0 0`` the conservative SLIP); ``regulation``, the
same under energy regulation towards that energy. How a successor is judged: docs/viability.md. Writes
DIR/qmap.npz, viability.npz, viability.json and qmap.png, kernel.png, measure.png
(:mod:`tdslip_ros.studies.viability_outputs`).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from tdslip_ros.commands.options import add_energy_bar, command_parser
from tdslip_ros.commands.study_command import add_engine_arguments, positive_int, run_study_command, where_of
from tdslip_ros.model import units
from tdslip_ros.model.limits import check_hopper
from tdslip_ros.model.paper import PAPER_KBAR, PAPER_PARAMS, PAPER_ZETA0
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.plant.perturbations import StrideConditions
from tdslip_ros.model.stability.viability import JUDGES, OUTSIDE, viable_set
from tdslip_ros.model.stability.viability_spaces import ApexSpace, EnergySpace, ViabilitySpace, pair_count
from tdslip_ros.reporting.output import output_directory
from tdslip_ros.studies import engine, viability, viability_outputs

SPACES = ("apex", "energy", "regulation")
DEFAULT_ENERGY_BAR = 2.274
"""Ebar of the robustness studies' operating point (``tdslip robustness --energy-bar``)."""
GRID_DEFAULTS = {
    "heights": (0.9, 1.6, 36),
    "speeds": (1.0, 6.0, 36),
    "angles_deg": (5.0, 45.0, 41),
    "torques": (-800.0, 0.0, 17),
    "fractions": (0.3, 0.995, 140),
}
"""The default grids: the paper's apex range (figs 7-10), angles and torques around its fixed points."""

DESCRIPTION = """\
Which apex states and commands keep the hopper running: the Q-map of a state grid x action grid on the
exact plant, its viable set, the viability kernel and its measure (the fraction of viable actions per
state), in parallel on a local Dask cluster (or --scheduler). Writes qmap.npz, viability.npz,
viability.json and three figures into --out."""


def grid(text: list[str]) -> tuple[float, float, int]:
    return float(text[0]), float(text[1]), int(text[2])


def parser() -> argparse.ArgumentParser:
    parser = command_parser("viability", DESCRIPTION)
    parser.add_argument("space", choices=SPACES, help="the state and action space")
    parser.add_argument(
        "--out", type=Path, required=True, help="directory for the Q-map, viable set and figures"
    )
    stiffness = parser.add_mutually_exclusive_group()
    stiffness.add_argument(
        "--kbar", type=float, default=PAPER_KBAR, help="leg stiffness k r0/(m g) (dimensionless)"
    )
    stiffness.add_argument(
        "--stiffness", type=float, metavar="N_PER_M", help="leg stiffness k [N/m] (SI; default: from --kbar)"
    )
    parser.add_argument("--zeta0", type=float, default=PAPER_ZETA0, help="leg damping ratio (dimensionless)")
    parser.add_argument("--mass", type=float, default=PAPER_PARAMS.m, help="body mass m [kg]")
    parser.add_argument("--r0", type=float, default=PAPER_PARAMS.r0, help="leg rest length [m]")
    parser.add_argument("--gravity", type=float, default=PAPER_PARAMS.g, help="gravity g [m/s^2]")
    for name, unit in (("heights", "m"), ("speeds", "m/s"), ("angles-deg", "deg"), ("torques", "N m")):
        key = name.replace("-", "_")
        low, high, count = GRID_DEFAULTS[key]
        parser.add_argument(
            f"--{name}",
            nargs=3,
            metavar=("LO", "HI", "N"),
            help=f"grid of {name.replace('-deg', '')} [{unit}]: N points from LO to HI "
            f"(default {low:g} {high:g} {count})",
        )
    parser.add_argument(
        "--t-f", type=float, help="ramp duration of the apex space [s] (default: pi / omega0)"
    )
    parser.add_argument(
        "--fractions",
        nargs=3,
        metavar=("LO", "HI", "N"),
        help="grid of height fractions (default 0.3 0.995 140)",
    )
    energy = parser.add_mutually_exclusive_group()
    add_energy_bar(energy, DEFAULT_ENERGY_BAR, "the energy level of the energy and regulation spaces")
    energy.add_argument(
        "--energy-of-apex",
        nargs=2,
        type=float,
        metavar=("Y", "XDOT"),
        help="the energy level: that of this apex [m, m/s] (default: --energy-bar)",
    )
    parser.add_argument(
        "--tau-max",
        type=float,
        metavar="N_M",
        help="the hip torque saturates at +-N_M [N m] (default: no limit)",
    )
    parser.add_argument(
        "--push", type=float, default=0.0, metavar="M_PER_S", help="a push after every apex [m/s]"
    )
    parser.add_argument(
        "--angle-error-deg", type=float, default=0.0, help="the leg lands this much off [deg]"
    )
    parser.add_argument(
        "--terrain", default="flat", help="the ground: only flat (the spaces hold no position)"
    )
    parser.add_argument(
        "--judge",
        choices=JUDGES,
        default="conservative",
        help="how a successor between grid points is judged",
    )
    parser.add_argument(
        "--outside", choices=OUTSIDE, default="failure", help="how a successor beyond the grid is judged"
    )
    parser.add_argument(
        "--chunk-size", type=positive_int, default=viability.CHUNK_PAIRS, help="pairs per chunk"
    )
    parser.add_argument(
        "--memory-limit-gb",
        type=float,
        help="refuse a grid whose Q-map needs more (default: half the memory)",
    )
    add_engine_arguments(parser)
    return parser


def axis(args: argparse.Namespace, key: str) -> np.ndarray:
    text = getattr(args, key)
    if text is None:
        low, high, count = GRID_DEFAULTS[key]
    else:
        try:
            low, high, count = grid(text)
        except ValueError:
            raise ParameterError(
                f"--{key.replace('_', '-')} must be LO HI N (two numbers and a count), got {' '.join(text)}"
            ) from None
    option = f"--{key.replace('_', '-')}"
    if count < 1:
        raise ParameterError(f"{option} is empty: N = {count}")
    if count > 1 and not high > low:
        raise ParameterError(f"{option} is inverted or empty: HI {high:g} is not above LO {low:g}")
    return np.linspace(low, high, count)


def hopper(args: argparse.Namespace) -> HopperParams:
    if args.stiffness is None:
        params = HopperParams.from_dimensionless(
            args.kbar, args.zeta0, m=args.mass, r0=args.r0, g=args.gravity
        )
    else:  # SI as given, not through kbar's rounding
        damping = 2.0 * args.zeta0 * math.sqrt(args.mass * args.stiffness) if args.stiffness > 0 else 0.0
        params = HopperParams(m=args.mass, k=args.stiffness, r0=args.r0, c=damping, g=args.gravity)
    check_hopper(params)
    return params


def space_of(args: argparse.Namespace, params: HopperParams) -> ViabilitySpace:
    if args.terrain != "flat":
        raise ParameterError(
            f"--terrain {args.terrain}: the viability spaces hold no position x, only flat ground"
        )
    conditions = StrideConditions(
        tau_max=math.inf if args.tau_max is None else args.tau_max,
        push=args.push,
        angle_error=math.radians(args.angle_error_deg),
    )
    angles = np.radians(axis(args, "angles_deg"))
    if args.space == "apex":
        t_f = math.pi / params.omega0 if args.t_f is None else args.t_f
        return ApexSpace(
            params,
            axis(args, "heights"),
            axis(args, "speeds"),
            angles,
            axis(args, "torques"),
            t_f,
            conditions,
        )
    if args.energy_of_apex is not None:
        y, xdot = args.energy_of_apex
        energy = params.m * (params.g * y + 0.5 * xdot**2)
    else:
        energy = units.energy_from_bar(params, args.energy_bar)
    return EnergySpace(
        params, energy, axis(args, "fractions"), angles, args.space == "regulation", conditions
    )


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)

    def produce() -> None:
        params = hopper(args)
        space = space_of(args, params)
        limit = viability.memory_limit() if args.memory_limit_gb is None else int(args.memory_limit_gb * 1e9)
        viability.check_memory(space, limit)
        out = output_directory(args.out)
        print(
            f"tdslip viability: {pair_count(space):,} pairs ({args.space} space) on "
            f"{where_of(args).describe()}",
            file=sys.stderr,
        )
        with engine.connect(where_of(args)) as client:
            qmap = viability.run_q_map(
                space, out, client, args.resume, args.chunk_size, engine.Progress("Q-map", "strides")
            )
        result = viable_set(qmap, args.judge, args.outside)
        described = {
            "space": args.space,
            "hopper": {"m": params.m, "k": params.k, "r0": params.r0, "c": params.c, "g": params.g},
        }
        if isinstance(space, EnergySpace):
            described["energy_J"] = space.energy
        else:
            described["t_f_s"] = space.ramp_duration
        viability_outputs.write(out, qmap, result, described)

    status = run_study_command("viability", args.out, produce)
    if status:
        return status
    print(f"tdslip viability: {', '.join(str(args.out / name) for name in viability_outputs.OUTPUTS)}")
    return 0
