"""``tdslip terrain``: energy regulation against open loop over the same rough ground (the README figure).

Both policies hop the 1 kHz plant (:class:`~tdslip_ros.model.plant.stepper.FixedStepStepper`, the plant node's
physics) over the same random blocks (:class:`~tdslip_ros.model.plant.terrain.Blocks`), each apex answered as
the controller node answers it: the policy planned on the measured apex above the ground of the last stance.
Energy regulation (section IV.A) holds the apex energy above the ground at that of ``--height`` and
``--speed``; both start at its fixed point on flat ground, and open loop (section III) applies the fixed
hip power C at touchdown that energy regulation applies there. On flat ground the two would therefore hop
identically forever; blocks start at ``--start``, so what differs is the terrain's doing.

The figure shows the centre-of-mass paths over the ground and the apex energy above the ground per
stride; the run ends at ``--strides`` apexes or a failure (marked). With the defaults it draws the README's
figure (docs/rough_terrain.png), at the touchdown angle
:data:`~tdslip_ros.analysis.rough_terrain.TOUCHDOWN_ANGLE_DEG`, not the model's. The same runs are recorded
by the node suite with ``tdslip run --terrain blocks:... --policy energy --touchdown-angle-deg 22`` (or
``open_loop``).
"""

from __future__ import annotations

import argparse
import math
import sys
from datetime import datetime
from pathlib import Path

import numpy as np

from tdslip_ros.analysis.rough_terrain import LABELS, TOUCHDOWN_ANGLE_DEG, draw, hop, policies
from tdslip_ros.commands.options import TOUCHDOWN_ANGLE_DEG as TOUCHDOWN_ANGLE_DEG_MODEL
from tdslip_ros.commands.options import (
    add_initial_apex,
    add_touchdown_angle,
    check_strides_and_angle,
    command_parser,
)
from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, ParameterError
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.terrain import Blocks
from tdslip_ros.reporting.output import OutputError, output_directory, write_failed

DESCRIPTION = """\
Energy regulation against open loop over the same random blocks, on the 1 kHz plant (no ROS).
Both start at energy regulation's flat-ground fixed point for the initial apex's energy; the blocks begin
at --start. Draws the centre-of-mass paths and the apex energy above the ground per stride (PNG); the
defaults draw the README's figure. The node suite records the same runs with:
tdslip run --terrain blocks:... --policy energy --touchdown-angle-deg 22"""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("terrain", DESCRIPTION)
    parser.add_argument("--out", type=Path, help="the PNG to write (default: runs/terrain-<time>.png)")
    parser.add_argument("--sigma", type=float, default=0.03, help="block heights' standard deviation [m]")
    parser.add_argument("--length", type=float, default=0.5, help="block length [m]")
    parser.add_argument("--seed", type=int, default=1, help="terrain seed")
    parser.add_argument("--start", type=float, default=2.0, help="where the blocks begin [m]")
    parser.add_argument("--strides", type=int, default=40, help="apexes to hop")
    add_touchdown_angle(
        parser,
        "--angle",
        what=f" (default: {TOUCHDOWN_ANGLE_DEG:g}, the README figure's: at the model's "
        f"{TOUCHDOWN_ANGLE_DEG_MODEL:g} the toe stubs on the blocks within a dozen strides)",
        default=TOUCHDOWN_ANGLE_DEG,
    )
    add_initial_apex(parser)
    return parser


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    try:
        check_strides_and_angle(args.strides, args.touchdown_angle_deg)
        blocks = Blocks(args.sigma, args.length, args.seed, args.start)
        apex = ApexState(args.height, args.speed)
        params = PAPER_PARAMS
        start, specs = policies(params, apex, math.radians(args.touchdown_angle_deg))
        if args.out is None:
            args.out = Path("runs") / f"terrain-{datetime.now():%Y%m%d-%H%M%S}.png"
        output_directory(args.out.parent)
        ground = Perturbations(terrain=blocks)
        hops = [hop(params, spec, start, ground, args.strides) for spec in specs.values()]
        draw(params, blocks, hops, args.out)
    except (ParameterError, OutputError) as error:
        print(f"tdslip terrain: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        print(f"tdslip terrain: {write_failed(error)}", file=sys.stderr)
        return 1
    for h in hops:
        ended = "all strides" if h.failure is None else f"{h.failure.value} after {len(h.apexes) - 1} strides"
        spread = np.ptp(np.array(h.energies)) / units.energy_scale(params)
        print(f"{LABELS[h.policy]:<30} {ended}; apex energy above ground spans {spread:.4f} (Ebar)")
    print(f"figure: {args.out}")
    return 0
