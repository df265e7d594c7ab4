"""``tdslip analyze RUN [--out DIR] [--map ours|paper]``: compare a recorded run with the analytic map, write
the summary JSON, the figures and the report (:mod:`tdslip_ros.analysis.report`), and print the headline
numbers. ``--map`` is the analytic map of the predictions and of the policy's replay and closed loop (default:
the recorded controller's ``analytic_map``, else ours). Policy options outside their domain are refused before
anything is read."""

from __future__ import annotations

import argparse
import math
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

from tdslip_ros.analysis.compare import KNOWN_POLICIES
from tdslip_ros.analysis.decoding import RunReadError, read_run
from tdslip_ros.analysis.measured_comparison import compare_measured, measured_headline, write_measured_report
from tdslip_ros.analysis.measured_reading import MeasuredDataError, measured_run_from_bag
from tdslip_ros.analysis.report import analyze, hopper_params_from_yaml
from tdslip_ros.analysis.report_text import headline
from tdslip_ros.analysis.stride_detection import find_strides
from tdslip_ros.analysis.topic_map import TopicMapError, load_topic_map
from tdslip_ros.bag.reader import BagReadError
from tdslip_ros.commands.options import (
    add_analytic_map,
    add_hopper,
    add_policy_file,
    add_touchdown_angle,
    command_parser,
    deprecated,
    hopper_given,
    hopper_of,
    policy_file,
)
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ParameterError
from tdslip_ros.model.policies.registry import PolicyError
from tdslip_ros.reporting.output import OutputError, check_output_directory, output_directory, write_failed

DESCRIPTION = """\
Compare a recorded run with the analytic return map: write summary.json, the figures and report.md,
and print the headline numbers. The policy the controller ran is read from the recording; the options
below replay it with other settings. Options outside their domain are refused before anything is read."""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("analyze", DESCRIPTION)
    parser.add_argument("run", type=Path, help="bag directory or .mcap file of a run")
    parser.add_argument(
        "--out", type=Path, help="report directory (default: RUN/report, or next to an .mcap)"
    )
    parser.add_argument(
        "--params",
        type=Path,
        help="ROS parameter file with the hopper (default: stored in the bag, or inferred)",
    )
    add_hopper(
        parser, "stored in the recording, else inferred; with --topic-map the paper's; not with --params"
    )
    parser.add_argument("--stride", type=int, help="stride drawn in the COM figure (default: last complete)")
    parser.add_argument(
        "--topic-map",
        type=Path,
        help="a recording this suite did not write: the YAML topic map that says where each quantity lives "
        "in it (docs/identify.md); the strides are found in the data and the hopper is --params' or the "
        "hopper options', else the paper's; the policy options do not apply (default: none, RUN is a "
        "recording of this suite)",
    )
    policy = parser.add_argument_group(
        "policy settings (default: as stored in the bag, else the recording and config/controller.yaml; "
        "a recorded policy the package does not know is not replayed)"
    )
    recorded = "default: the recording's"
    policy.add_argument(
        "--policy", dest="name", choices=KNOWN_POLICIES, help=f"the policy to replay ({recorded})"
    )
    add_touchdown_angle(policy, "--angle", what=" (open_loop, energy, energy_exact)", unset="the recording's")
    policy.add_argument(
        "--touchdown-power", type=float, help=f"hip power at touchdown [W] (open_loop; {recorded})"
    )
    policy.add_argument(
        "--target-energy", type=float, help=f"goal energy [J] (energy, energy_exact; {recorded})"
    )
    policy.add_argument(
        "--target-height",
        type=float,
        help=f"target apex height [m] (deadbeat, apex_foot_placement; {recorded})",
    )
    policy.add_argument(
        "--target-speed",
        type=float,
        help=f"target apex speed [m/s] (deadbeat, apex_foot_placement; {recorded})",
    )
    for gain, what in (("kp", "on the speed error"), ("kd", "on the speed change per stride")):
        action = policy.add_argument(
            f"--foot-placement-{gain}",
            type=float,
            help=f"foot placement gain {what} [rad/(m/s)] (apex_foot_placement; {recorded})",
        )
        deprecated(policy, action, f"--pd-{gain}")  # the policy's name was pd
    policy.add_argument(
        "--corrections", type=int, help=f"analytic-map corrections the controller planned with ({recorded})"
    )
    add_analytic_map(
        policy,
        what="; the per-stride predictions, the policy's replay and its closed loop use it",
        unset="the recording's, else ours",
    )
    add_policy_file(policy)
    return parser


POLICY_OPTION_DOMAINS: dict[str, tuple[str, Callable[[float], bool]]] = {
    "touchdown_angle_deg": ("in (0, 90) deg", lambda value: 0.0 < value < 90.0),
    "touchdown_power": ("a finite power >= 0 W", lambda value: 0.0 <= value < math.inf),
    "target_energy": ("a finite energy > 0 J", lambda value: 0.0 < value < math.inf),
    "target_height": ("a finite height > 0 m", lambda value: 0.0 < value < math.inf),
    "target_speed": ("a finite speed >= 0 m/s", lambda value: 0.0 <= value < math.inf),
    "foot_placement_kp": ("a finite gain >= 0", lambda value: 0.0 <= value < math.inf),
    "foot_placement_kd": ("a finite gain >= 0", lambda value: 0.0 <= value < math.inf),
    "corrections": ("a count >= 0", lambda value: value >= 0),
}
"""What each policy option of ``tdslip analyze`` accepts: a value outside its domain has no
meaning for the policy (NaN commands, an empty fixed point), so it is refused up front."""


def check_policy_options(args: argparse.Namespace) -> None:
    """PolicyError naming the first policy option given outside its domain."""
    for name, (domain, valid) in POLICY_OPTION_DOMAINS.items():
        value = getattr(args, name)
        if value is not None and not valid(value):
            raise PolicyError(f"--{name.replace('_', '-')} must be {domain}, not {value}")


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    out = args.out or (args.run / "report" if args.run.is_dir() else args.run.with_suffix("") / "report")
    if args.topic_map is not None:
        return analyze_measured(args, out)
    overrides = {
        "name": args.name,
        "touchdown_angle": None
        if args.touchdown_angle_deg is None
        else math.radians(args.touchdown_angle_deg),
        "touchdown_power": args.touchdown_power,
        "target_energy": args.target_energy,
        "target_height": args.target_height,
        "target_speed": args.target_speed,
        "foot_placement_kp": args.foot_placement_kp,
        "foot_placement_kd": args.foot_placement_kd,
        "corrections": args.corrections,
        "analytic_map": args.map,
        "policy_file": policy_file(args),
    }
    created = not out.exists()
    try:  # usage errors: exit status 2, as argparse's
        if args.params is not None and hopper_given(args):
            raise PolicyError("give --params or the hopper options (--hopper FILE, --mass, ...), not both")
        check_policy_options(args)
        check_output_directory(out)
    except (PolicyError, OutputError) as error:
        print(f"tdslip analyze: {error}", file=sys.stderr)
        return 2
    if not args.run.exists():
        print(f"tdslip analyze: {args.run}: no such file or directory", file=sys.stderr)
        return 2
    try:
        # Everything that can be checked is, before the report folder comes into being.
        params = None if args.params is None else hopper_params_from_yaml(args.params)
        if hopper_given(args):  # values given alone replace the recording's (a first read finds them)
            params = hopper_of(args, read_run(args.run).params if args.hopper is None else PAPER_PARAMS)
        run = read_run(args.run, params, full_rate_strides=() if args.stride is None else (args.stride,))
        output_directory(out)
        analysis = analyze(run, out, overrides, args.stride)
    except (RunReadError, PolicyError, OutputError, ValueError, OSError) as error:
        if created and out.is_dir():
            shutil.rmtree(out)  # a failed analysis leaves the file system as it found it
        message = write_failed(error) if isinstance(error, OSError) else str(error)
        print(f"tdslip analyze: {message}", file=sys.stderr)
        return 1
    print(headline(analysis.comparison))
    figures = sum(1 for path in analysis.files.values() if path.suffix == ".png")
    print(f"report: {analysis.files['report']} (summary.json and {figures} figures beside it)")
    return 0


PAPER_HOPPER = "the paper's (section IV.B: m = 80 kg, r0 = 1 m, kbar = 36, zeta0 = 0.08)"


def analyze_measured(args: argparse.Namespace, out: Path) -> int:
    """``--topic-map``: a recording this suite did not write (analysis/measured_comparison.py)."""
    given = [name for name in POLICY_OPTION_DOMAINS if getattr(args, name) is not None]
    given += [name for name in ("name", "map", "policy_file", "stride") if getattr(args, name) is not None]
    created = not out.exists()
    try:  # usage errors: exit status 2, as argparse's
        if given:
            options = ", ".join(f"--{name.replace('_', '-')}" for name in given).replace("--name", "--policy")
            raise PolicyError(f"{options} do not apply to a recording read through --topic-map")
        check_output_directory(out)
        if not args.run.exists():
            raise OutputError(f"{args.run}: no such file or directory")
        topic_map = load_topic_map(args.topic_map)
        if args.params is not None and hopper_given(args):
            raise PolicyError("give --params or the hopper options (--hopper FILE, --mass, ...), not both")
        params = PAPER_PARAMS if args.params is None else hopper_params_from_yaml(args.params)
        hopper = PAPER_HOPPER if args.params is None else f"from {args.params}"
        if hopper_given(args):
            params = hopper_of(args, PAPER_PARAMS)
            hopper = f"from {args.hopper}" if args.hopper is not None else "given on the command line"
        run = measured_run_from_bag(args.run, topic_map)
    except (PolicyError, OutputError, TopicMapError, RunReadError, ParameterError) as error:
        print(f"tdslip analyze: {error}", file=sys.stderr)
        return 2
    except (MeasuredDataError, BagReadError) as error:
        print(f"tdslip analyze: {error}", file=sys.stderr)
        return 1
    try:
        strides = find_strides(run)
        if not any(stride.usable for stride in strides):
            reasons = sorted({stride.reason for stride in strides})
            raise MeasuredDataError(f"no usable stride among the {len(strides)} found: {'; '.join(reasons)}")
        comparison = compare_measured(run, strides, params, hopper)
        output_directory(out)
        files = write_measured_report(comparison, out)
    except (MeasuredDataError, OutputError, ValueError, OSError) as error:
        if created and out.is_dir():
            shutil.rmtree(out)  # a failed analysis leaves the file system as it found it
        print(
            f"tdslip analyze: {write_failed(error) if isinstance(error, OSError) else error}", file=sys.stderr
        )
        return 1
    print(measured_headline(comparison))
    print(f"report: {files['report']} (summary.json beside it)")
    return 0
