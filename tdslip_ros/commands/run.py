"""``tdslip run``: one hop of the node suite (:func:`tdslip_ros.nodes.runner.run`), recorded, checked and
summarised: progress on stderr, then the apex table, the messages published and recorded per topic, and the
run's outcome. ``--out`` is the bag directory; the exit status is 0 only for a complete run whose recording
is complete (130 for an interrupted one).
"""

from __future__ import annotations

import argparse
import math
import sys
from datetime import datetime
from pathlib import Path

from tdslip_msgs.msg import ApexEvent

from tdslip_ros.model import units
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.perturbations import Mismatch, Perturbations, PlacementNoise, Pushes, SensingNoise
from tdslip_ros.model.policies import DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED, POLICIES
from tdslip_ros.model.terrain import TERRAIN_FORMS, parse_terrain
from tdslip_ros.nodes.entry import stop_on_signals
from tdslip_ros.nodes.plant_node import CLOCK_MODES
from tdslip_ros.nodes.runner import RunError, RunOptions, run


def apex_table(params: HopperParams, apexes: list[ApexEvent], ground: bool = False) -> str:
    """The apex states, SI (world frame) and dimensionless (eq. 24), one row per stride; with ``ground``,
    the ground height of the stance before each apex too."""
    header = (
        f"{'stride':>6} {'t [s]':>9} {'y [m]':>9} {'xdot [m/s]':>11} {'E [J]':>10}"
        f" | {'ybar':>8} {'xdotbar':>8} {'Ebar':>8}" + (f" | {'ground [m]':>10}" if ground else "")
    )
    rows = [header, "-" * len(header)]
    for apex in apexes:
        rows.append(
            f"{apex.stride:>6d} {apex.sim_time:>9.4f} {apex.height:>9.5f} {apex.forward_speed:>11.5f}"
            f" {apex.energy:>10.3f} | {units.height_to_bar(params, apex.height):>8.5f}"
            f" {units.speed_to_bar(params, apex.forward_speed):>8.5f}"
            f" {units.energy_to_bar(params, apex.energy):>8.5f}"
            + (f" | {apex.ground_height:>10.5f}" if ground else "")
        )
    return "\n".join(rows)


def counts_table(published_counts: dict[str, int], recorded_counts: dict[str, int]) -> str:
    """Messages published and recorded per topic, marking the topics where they differ."""
    names = sorted(set(published_counts) | set(recorded_counts))
    width = max(len("topic"), *map(len, names))
    rows = [f"{'topic':<{width}} {'published':>10} {'recorded':>10}"]
    for topic in names:
        published, recorded = published_counts.get(topic, 0), recorded_counts.get(topic, 0)
        mark = "" if published == recorded else "  LOST" if recorded < published else "  EXTRA"
        rows.append(f"{topic:<{width}} {published:>10d} {recorded:>10d}{mark}")
    return "\n".join(rows)


def recording_note(bag: Path) -> str:
    """What became of the recording of a run that ended early."""
    if not (bag / "metadata.yaml").is_file():
        return f"The recording in {bag} was not finalised; make it readable with: tdslip recover {bag}"
    return f"The recording so far is in {bag} (finalised: tdslip analyze and replay read it)."


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tdslip run",
        description="Run the plant, controller and recorder nodes for one hop and record it.",
    )
    parser.add_argument("--strides", type=int, default=50, help="the run ends at this apex (default 50)")
    parser.add_argument("--policy", choices=POLICIES, default="energy")
    parser.add_argument("--mode", choices=CLOCK_MODES, default="lockstep")
    parser.add_argument(
        "--out", type=Path, help="bag directory to create (default runs/<policy>-<mode>-<time>)"
    )
    parser.add_argument("--height", type=float, default=DEFAULT_APEX_HEIGHT, help="initial apex [m]")
    parser.add_argument("--speed", type=float, default=DEFAULT_APEX_SPEED, help="initial apex [m/s]")
    parser.add_argument("--angle", type=float, help="touchdown angle [deg] (default 20)")
    parser.add_argument(
        "--target-energy", type=float, help="energy policy [J] (default: initial apex energy)"
    )
    parser.add_argument("--target-height", type=float, help="deadbeat/pd target apex height [m]")
    parser.add_argument("--target-speed", type=float, help="deadbeat/pd target apex speed [m/s]")
    parser.add_argument("--timeout", type=float, help="lockstep command timeout [s wall]")
    parser.add_argument("--duration", type=float, help="end the run after this wall time [s]")
    parser.add_argument(
        "--realtime-priority", type=int, help="SCHED_FIFO priority 1-99 of the realtime tick (needs root)"
    )
    parser.add_argument("--record-clock", action="store_true", help="also record /clock")
    parser.add_argument("--domain-id", type=int, help="ROS domain id (default: a free one from 120-229)")
    parser.add_argument(
        "--namespace", default="/", help="ROS namespace of the nodes (default /: topics /tdslip/...)"
    )
    perturb = parser.add_argument_group("perturbations (default: none; see docs/perturbations.md)")
    perturb.add_argument("--terrain", metavar="SPEC", help=f"ground [m]: {TERRAIN_FORMS}")
    perturb.add_argument(
        "--apex-noise",
        metavar="height=M,speed=M_PER_S,seed=N",
        help="the controller's sensor noise (std. dev.)",
    )
    perturb.add_argument(
        "--angle-noise", metavar="sigma=DEG,seed=N", help="touchdown angle error (std. dev., degrees)"
    )
    perturb.add_argument(
        "--mismatch",
        metavar="mass=F,stiffness=F,damping=F,rest_length=F",
        help="the controller plans with the plant's parameters times these factors",
    )
    perturb.add_argument(
        "--tau-max", type=float, metavar="N_M", help="the hip torque saturates at +-N_M [N m]"
    )
    perturb.add_argument(
        "--push",
        action="append",
        default=[],
        metavar="STRIDE:DV | random:size=DV,rate=P,seed=N",
        help="a push of DV m/s right after the apex of STRIDE, or random ones (repeatable)",
    )
    return parser


def perturbations_of(args: argparse.Namespace) -> Perturbations:
    """The perturbations of the command line's options; RunError naming the option of a malformed one."""
    try:
        terrain = None if args.terrain is None else parse_terrain(args.terrain)
        sensing = None if args.apex_noise is None else SensingNoise.parse(args.apex_noise)
        placement = None if args.angle_noise is None else PlacementNoise.parse_degrees(args.angle_noise)
        mismatch = None if args.mismatch is None else Mismatch.parse(args.mismatch)
        pushes = Pushes.parse(";".join(args.push))
        defaults = Perturbations()
        return Perturbations(
            terrain=terrain or defaults.terrain,
            sensing=sensing or defaults.sensing,
            placement=placement or defaults.placement,
            tau_max=math.inf if args.tau_max is None else args.tau_max,
            pushes=pushes,
            mismatch=mismatch or defaults.mismatch,
        )
    except ParameterError as error:
        raise RunError(str(error)) from None


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    out = args.out or Path("runs") / f"{args.policy}-{args.mode}-{datetime.now():%Y%m%d-%H%M%S}"
    try:
        perturbations = perturbations_of(args)
    except RunError as error:
        print(f"tdslip run: {error}", file=sys.stderr)
        return 1
    options = RunOptions(
        out=out,
        strides=args.strides,
        policy=args.policy,
        mode=args.mode,
        height=args.height,
        speed=args.speed,
        touchdown_angle=None if args.angle is None else math.radians(args.angle),
        target_energy=args.target_energy,
        target_height=args.target_height,
        target_speed=args.target_speed,
        command_timeout=args.timeout,
        realtime_priority=args.realtime_priority,
        record_clock=args.record_clock,
        duration=args.duration,
        domain_id=args.domain_id,
        namespace=args.namespace,
        perturbations=perturbations,
    )
    interactive = sys.stderr.isatty()

    def progress(apex: ApexEvent) -> None:
        line = f"stride {apex.stride}/{args.strides}  t = {apex.sim_time:.3f} s"
        if interactive:
            print(
                f"\r{line}  y = {apex.height:.4f} m  xdot = {apex.forward_speed:.4f} m/s",
                end="",
                file=sys.stderr,
            )
        elif apex.stride % max(1, args.strides // 10) == 0:
            print(line, file=sys.stderr)

    stop = stop_on_signals()
    ours = not options.out.exists()  # a bag directory there afterwards is this run's recording
    try:
        report = run(options, progress, stop.is_set)
    except RunError as error:
        print(f"\ntdslip run: {error}", file=sys.stderr)
        if error.published is not None:
            recorded = error.recorded or {}
            print(counts_table(error.published, {topic: recorded.get(topic, 0) for topic in error.published}))
        if ours and options.out.exists():
            print(recording_note(options.out), file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # a second Ctrl-C: the children were stopped on the way out
        note = recording_note(options.out) if ours and options.out.exists() else "Nothing was recorded."
        print(f"\ntdslip run: interrupted. {note}", file=sys.stderr)
        return 130
    if interactive:
        print(file=sys.stderr)
    print(apex_table(report.params, report.apexes, ground=not options.perturbations.terrain.is_flat))
    print()
    print(counts_table(report.published, report.recorded))
    print()
    outcome = report.outcome
    speed_up = outcome.sim_time / outcome.wall_time if outcome.wall_time > 0 else math.inf
    print(options.perturbations.summary())
    if options.perturbations.saturates:
        print(f"the hip saturated in {report.saturated_strides} stride(s)")
    if report.late_commands:
        print(f"{report.late_commands} command(s) arrived after their touchdown; the previous command held")
    print(
        f"{options.mode} run, policy {options.policy}: {outcome.stride} strides, "
        f"{outcome.sim_time:.3f} s simulated in {outcome.wall_time:.3f} s wall ({speed_up:.2f}x)"
        f"; bag: {report.bag}"
    )
    for problem in report.problems:
        print(f"problem: {problem}", file=sys.stderr)
    if not report.recording_complete:
        lost = sum(max(0, n - report.recorded.get(topic, 0)) for topic, n in report.published.items())
        total = sum(report.published.values())
        why = (
            " (realtime: the recorder fell more than a publisher's history behind; the plant did not wait)"
            if options.mode == "realtime"
            else ""
        )
        print(
            f"recording INCOMPLETE: {lost} of {total} published messages are not in the bag{why}",
            file=sys.stderr,
        )
    if not outcome.ok:
        if report.controller_log.strip():
            print(f"controller output:\n{report.controller_log.rstrip()}", file=sys.stderr)
        print(
            f"run FAILED at stride {outcome.stride}, t = {outcome.sim_time:.6f} s: "
            f"{outcome.kind}: {outcome.reason}",
            file=sys.stderr,
        )
    return 0 if report.ok else 1
