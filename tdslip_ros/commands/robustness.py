"""``tdslip robustness``: how large a perturbation each policy survives, on the study engine.

    tdslip robustness --out DIR [--samples 30] [--strides 50] [--policies open_loop energy ...]
                      [--kinds terrain noise mismatch step] [--touchdown-angle 26] [--energy 3.5]
                      [--mismatch-field stiffness] [--seed 0] [--resume]
                      [--scheduler tcp://HOST:PORT | --workers N]

Every policy starts at the same operating point and would hop there on flat ground: the exact plant's fixed
point under energy regulation at the touchdown angle beta (``--touchdown-angle``, deg) with the goal energy
Ebar (``--energy``, E/(m g r0)). energy and energy_exact aim at that energy (planned on the analytic map,
energy's fixed point is within 1 % of it; energy_exact, which holds it exactly, settles from there within a
few strides), open_loop applies the hip power at touchdown that energy regulation applies there, deadbeat
and pd aim at the fixed point's apex (pd with its default gains). Each kind of perturbation is one study
(DIR/terrain, ...): a grid of policy x size with ``--samples`` trajectories per cell, each with its own
random draws (seeds from the trajectory index); the closed loop keeps the command in force where a policy
has none, as the plant node does (:mod:`tdslip_ros.studies.perturbed`):

* terrain: random blocks 0.5 m long from x = 1 m, heights with standard deviation sigma (the size, cm);
* noise: the apex the controller sees, with standard deviations s r0 in height and s sqrt(g r0) in speed
  (the size s);
* mismatch: the controller plans with the hopper's stiffness (``--mismatch-field``) times a factor (the
  size);
* step: a single step down of the size (m) at a position drawn in [1, 4] m (one stride at the operating
  point).

A trajectory survives when it hops ``--strides`` strides. Written to DIR: ``robustness.png`` (the fraction
surviving, per kind and policy, against the size), ``strides.png`` (the median strides survived),
``spread.png`` (the spread of the apex heights of the survivors: the median over them of each one's
standard deviation), ``failures.png`` (the failure kinds), ``summary.csv`` (one row per kind, size and
policy), ``robustness.md`` (per kind and policy the sizes all and half the trajectories survive, from the
unperturbed size on, and the failure kinds) and ``summary.json``; every trajectory's row is in
DIR/<kind>/table.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from tdslip_ros.commands.study_command import add_engine_arguments, positive_int, run_study_command, where_of
from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.policies import POLICIES
from tdslip_ros.studies.design import StudyError
from tdslip_ros.studies.perturbed import MISMATCH_PARAMETERS
from tdslip_ros.studies.robustness import KINDS, write_robustness


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="tdslip robustness", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--out", type=Path, required=True, help="directory for the tables, figures and summary"
    )
    parser.add_argument("--samples", type=positive_int, default=30, help="trajectories per size and policy")
    parser.add_argument("--strides", type=positive_int, default=50, help="strides that count as surviving")
    parser.add_argument("--policies", nargs="+", choices=POLICIES, default=list(POLICIES))
    parser.add_argument("--kinds", nargs="+", choices=list(KINDS), default=list(KINDS))
    parser.add_argument(
        "--touchdown-angle", type=float, default=26.0, help="beta of the operating point [deg]"
    )
    parser.add_argument("--energy", type=float, default=3.5, help="apex energy Ebar of the operating point")
    parser.add_argument(
        "--mismatch-field",
        choices=[name.removeprefix("mismatch_") for name in MISMATCH_PARAMETERS],
        default="stiffness",
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="of every random draw (with the trajectory index)"
    )
    add_engine_arguments(parser)
    args = parser.parse_args(argv)
    kinds, policies = list(dict.fromkeys(args.kinds)), list(dict.fromkeys(args.policies))

    def produce() -> None:
        params = PAPER_PARAMS
        if not 0.0 < args.touchdown_angle < 90.0:
            raise StudyError(f"--touchdown-angle must be in (0, 90) deg, got {args.touchdown_angle:g}")
        write_robustness(
            args.out,
            params,
            math.radians(args.touchdown_angle),
            units.energy_from_bar(params, args.energy),
            kinds,
            policies,
            args.samples,
            args.strides,
            args.seed,
            args.mismatch_field,
            where_of(args),
            args.resume,
        )

    status = run_study_command("robustness", args.out, produce)
    if status:
        return status
    print((args.out / "robustness.md").read_text(), end="")
    return 0
