"""``tdslip robustness``: how large a perturbation each policy survives, on the study engine.

    tdslip robustness --out DIR [--samples 30] [--strides 50] [--policies open_loop energy ...]
                      [--kinds terrain noise mismatch step] [--step-sizes 0 1 2 ...] [--terrain-sizes ...]
                      [--touchdown-angle-deg 20] [--energy-bar 2.274]
                      [--mismatch-field stiffness] [--seed 0] [--map ours|paper] [--resume]
                      [--scheduler tcp://HOST:PORT | --workers N]

Every policy starts at the same operating point and would hop there on flat ground: the exact plant's fixed
point under energy regulation at the touchdown angle beta (``--touchdown-angle-deg``) with the goal energy
Ebar (``--energy-bar``, E/(m g r0)). energy and energy_exact aim at that energy (planned on the analytic map,
energy's fixed point is within 1 % of it; energy_exact, which holds it exactly, settles from there within a
few strides), open_loop applies the hip power at touchdown that energy regulation applies there, deadbeat
and apex_foot_placement aim at the fixed point's apex (with its default gains). Each kind of perturbation
is one study (DIR/terrain, ...): a grid of policy x size with ``--samples`` trajectories per cell, each with
its own random draws (seeds from the trajectory index); the closed loop keeps the command in force where a
policy has none, as the plant node does (:mod:`tdslip_ros.studies.perturbed`):

* terrain: random blocks 0.5 m long from x = 1 m, heights with standard deviation sigma (the size, m);
* noise: the apex the controller sees, with standard deviations s r0 in height and s sqrt(g r0) in speed
  (the size s);
* mismatch: the controller plans with the hopper's stiffness (``--mismatch-field``) times a factor (the
  size);
* step: a single step down of the size (m) at a position drawn in [1, 4] m (one stride at the operating
  point).

Each kind's sizes are an option (``--terrain-sizes``, ``--noise-sizes``, ``--mismatch-sizes``,
``--step-sizes``; defaults: :data:`~tdslip_ros.studies.robustness.KINDS`): increasing, and including the
unperturbed size (0, or 1 for mismatch), from which the sizes survived are counted. A trajectory survives when
it hops ``--strides`` strides. Written to DIR: ``robustness.png`` (the fraction
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

from tdslip_ros.commands.options import (
    add_analytic_map,
    add_energy_bar,
    add_hopper,
    add_policy_file,
    add_touchdown_angle,
    command_parser,
    hopper_of,
    policy_file,
    touchdown_angle_error,
)
from tdslip_ros.commands.study_command import add_engine_arguments, positive_int, run_study_command, where_of
from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ParameterError
from tdslip_ros.model.policies.registry import (
    DEFAULT_TARGET_ENERGY,
    LEARNED,
    POLICIES,
    PolicyError,
    check_policy_file,
)
from tdslip_ros.studies.design import StudyError
from tdslip_ros.studies.perturbed import MISMATCH_PARAMETERS
from tdslip_ros.studies.robustness import KINDS, chosen_kinds, write_robustness

DEFAULT_ENERGY_BAR = units.energy_to_bar(PAPER_PARAMS, DEFAULT_TARGET_ENERGY)
"""The operating point's apex energy: the default apex's (1 m, 5 m/s), Ebar = 2.274, inside the stable range
[1.12, 3.32] of energy regulation at the default 20 deg (docs/paper.md)."""

DESCRIPTION = """\
How large a perturbation each policy survives, on a local Dask cluster (or --scheduler). Every policy
starts at energy regulation's flat-ground fixed point at the touchdown angle and energy given.
Kinds and their sizes: terrain (block height std. dev. [m]), noise (apex sensor noise, in r0 and
sqrt(g r0)), mismatch (factor on the controller's model), step (a step down [m]).
Writes DIR/robustness.png, strides.png, spread.png, failures.png, summary.csv/json and robustness.md."""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("robustness", DESCRIPTION)
    parser.add_argument(
        "--out", type=Path, required=True, help="directory for the tables, figures and summary"
    )
    parser.add_argument("--samples", type=positive_int, default=30, help="trajectories per size and policy")
    parser.add_argument("--strides", type=positive_int, default=50, help="strides that count as surviving")
    parser.add_argument(
        "--policies",
        nargs="+",
        choices=POLICIES,
        default=[policy for policy in POLICIES if policy != LEARNED],
        help="the policies (learned: with --policy-file)",
    )
    add_policy_file(parser)
    parser.add_argument(
        "--kinds", nargs="+", choices=list(KINDS), default=list(KINDS), help="the kinds of perturbation"
    )
    for name, kind in KINDS.items():
        parser.add_argument(
            f"--{name}-sizes",
            nargs="+",
            type=float,
            default=list(kind.sizes),
            metavar="SIZE",
            help=f"the sizes of {name}: {kind.label}, increasing, with the unperturbed {kind.neutral:g}",
        )
    add_touchdown_angle(parser, "--touchdown-angle", what=" of the operating point")
    add_energy_bar(
        parser,
        DEFAULT_ENERGY_BAR,
        f"apex energy of the operating point (default: {DEFAULT_ENERGY_BAR:.4g}, the default apex's, 1 m and "
        "5 m/s)",
        "--energy",
    )
    parser.add_argument(
        "--mismatch-field",
        choices=[name.removeprefix("mismatch_") for name in MISMATCH_PARAMETERS],
        default="stiffness",
        help="the hopper parameter the mismatch kind scales",
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="of every random draw (with the trajectory index)"
    )
    add_analytic_map(parser, what=", the one the policies (and the operating point) plan on")
    add_hopper(parser, "the paper's, kbar 36, zeta0 0.08, 80 kg, 1 m")
    add_engine_arguments(parser)
    return parser


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    kinds, policies = list(dict.fromkeys(args.kinds)), list(dict.fromkeys(args.policies))

    def produce() -> None:
        try:
            params = hopper_of(args, PAPER_PARAMS)
        except ParameterError as error:
            raise StudyError(str(error)) from None
        if (reason := touchdown_angle_error(args.touchdown_angle_deg)) is not None:
            raise StudyError(reason)
        chosen = chosen_kinds(kinds, {name: getattr(args, f"{name}_sizes") for name in kinds})
        if LEARNED in policies:
            if args.policy_file is None:
                raise StudyError("the learned policy needs its file (--policy-file)")
            try:  # before the workers start
                check_policy_file(policy_file(args) or "")
            except PolicyError as error:
                raise StudyError(str(error)) from None
        write_robustness(
            args.out,
            params,
            math.radians(args.touchdown_angle_deg),
            units.energy_from_bar(params, args.energy_bar),
            chosen,
            policies,
            args.samples,
            args.strides,
            args.seed,
            args.mismatch_field,
            where_of(args),
            args.resume,
            args.map,
            policy_file(args) or "",
        )

    status = run_study_command("robustness", args.out, produce)
    if status:
        return status
    print((args.out / "robustness.md").read_text(), end="")
    return 0
