"""``tdslip identify BAG [--topic-map robot.yaml]``: the hopper's k, c and r0 (and m) estimated from a
recording's stances (:mod:`tdslip_ros.analysis.identification`), a report
(:mod:`tdslip_ros.analysis.identification_report`) and a hopper file that every command and node accepts
(``--hopper FILE``, ``-p hopper_file:=FILE``).

BAG is read through the topic map (:func:`.analysis.measured_reading.measured_run_from_bag`; the suite's own
topics by default) and its strides found in the data (:func:`.analysis.stride_detection.find_strides`), as
``tdslip analyze --topic-map`` does; :func:`identify_recording` is everything after the reading.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from datetime import UTC, datetime
from pathlib import Path

from tdslip_ros.analysis.identification import identify, usable_stances
from tdslip_ros.analysis.identification_report import JSON_KEYS, estimate_lines, write_report
from tdslip_ros.analysis.measured import MeasuredRun, MeasuredStride
from tdslip_ros.analysis.measured_reading import MeasuredDataError, measured_run_from_bag
from tdslip_ros.analysis.stride_detection import find_strides
from tdslip_ros.analysis.topic_map import TopicMapError, load_topic_map, suite_topic_map
from tdslip_ros.bag.reader import BagReadError
from tdslip_ros.commands.options import add_hopper, command_parser, hopper_given, hopper_of
from tdslip_ros.interfaces import write_hopper_file
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ParameterError
from tdslip_ros.reporting.output import OutputError, check_output_directory, output_directory, write_failed

DESCRIPTION = """\
Estimate the hopper (k, c, r0, and m where force and acceleration are both recorded) from a recording's
stances, with confidence intervals: least squares on the leg-axis force balance where force is recorded,
else the exact stance fitted from each touchdown. Writes OUT/hopper.yaml (give it to tdslip run, simulate,
analyze and the studies as --hopper FILE) and a report with figures. A problem that this data cannot
answer (too short, too noisy, ill-conditioned) is one line, exit status 1, and nothing is written."""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("identify", DESCRIPTION)
    parser.add_argument("bag", type=Path, help="bag directory or .mcap file of the recording")
    parser.add_argument(
        "--topic-map",
        type=Path,
        help="the YAML topic map that says where each quantity lives in BAG (docs/identify.md) (default: the "
        "suite's own topics, config/topic_map_suite.yaml)",
    )
    parser.add_argument(
        "--out", type=Path, help="report directory (default: BAG/identify, or next to an .mcap)"
    )
    add_hopper(
        parser,
        "the paper's; the exact-stance fit starts from it and takes its mass, which kinematics cannot give",
    )
    return parser


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    try:  # usage errors: exit status 2
        if not args.bag.exists():
            raise OutputError(f"{args.bag}: no such file or directory")
        topic_map = suite_topic_map() if args.topic_map is None else load_topic_map(args.topic_map)
        rest_length = hopper_of(args, PAPER_PARAMS).r0 if hopper_given(args) else None
    except (OutputError, TopicMapError, ParameterError) as error:
        print(f"tdslip identify: {error}", file=sys.stderr)
        return 2
    try:
        run = measured_run_from_bag(args.bag, topic_map)
        strides = find_strides(run, rest_length)
    except TopicMapError as error:  # a map that names what the bag does not have
        print(f"tdslip identify: {error}", file=sys.stderr)
        return 2
    except (MeasuredDataError, BagReadError) as error:
        print(f"tdslip identify: {error}", file=sys.stderr)
        return 1
    return identify_recording(args, run, strides)


def default_out(bag: Path) -> Path:
    return bag / "identify" if bag.is_dir() else bag.with_suffix("") / "identify"


def identify_recording(args: argparse.Namespace, run: MeasuredRun, strides: list[MeasuredStride]) -> int:
    """Identify ``run`` (read from ``args.bag``) from ``strides``; print the estimates and write the report
    and the hopper file into ``args.out``. Exit status: 0 identified, 1 the data cannot serve (one line,
    nothing written), 2 a usage mistake."""
    out = args.out or default_out(args.bag)
    try:
        guess = hopper_of(args, PAPER_PARAMS)
        check_output_directory(out)
    except (ParameterError, OutputError) as error:
        print(f"tdslip identify: {error}", file=sys.stderr)
        return 2
    interactive = sys.stderr.isatty()

    def progress(done: int, total: int) -> None:
        if interactive:
            print(f"\r{done}/{total}", end="", file=sys.stderr)

    result = identify(run, strides, guess, progress)
    if interactive:
        print(file=sys.stderr)
    if not result.success or result.params is None:
        print(f"tdslip identify: {args.bag}: {result.message}", file=sys.stderr)
        return 1
    created = not out.exists()
    try:
        output_directory(out)
        stances, _ = usable_stances(run, strides)
        files = write_report(result, stances, out, str(args.bag))
        provenance = {
            "made_by": "tdslip identify",
            "recording": str(args.bag.resolve()),
            "method": result.method,
            "when": datetime.now(UTC).isoformat(timespec="seconds"),
            "intervals_95": {JSON_KEYS[n]: [e.low, e.high] for n, e in result.estimates.items()},
            "estimated": list(result.estimates),
        }
        write_hopper_file(out / "hopper.yaml", result.params, provenance)
    except (OSError, OutputError) as error:
        if created and out.is_dir():
            shutil.rmtree(out)  # nothing half-written is left
        print(
            f"tdslip identify: {write_failed(error) if isinstance(error, OSError) else error}",
            file=sys.stderr,
        )
        return 1
    print(result.message)
    print("\n".join(estimate_lines(result)))
    if not {"m"} <= result.estimates.keys():
        print(f"m   = {result.params.m:.6g} kg (given, not estimated)")
    print(f"hopper file: {out / 'hopper.yaml'}; report: {files['report']}")
    return 0
