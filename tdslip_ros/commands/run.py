"""``tdslip run``: one hop of the node suite (:func:`tdslip_ros.nodes.runner.run`), recorded, checked and
summarised: progress on stderr, then the apex table, the messages published and recorded per topic, and the
run's outcome. ``--out`` is the bag directory; the exit status is 0 only for a complete run whose recording
is complete (130 for an interrupted one).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from tdslip_msgs.msg import ApexEvent

from tdslip_ros.commands.options import (
    add_analytic_map,
    add_body,
    add_hopper,
    add_initial_apex,
    add_policy_file,
    add_touchdown_angle,
    body_given,
    body_of,
    command_parser,
    hopper_given,
    hopper_of,
    policy_file,
    touchdown_angle_error,
)
from tdslip_ros.interfaces import hopper_from_parameters, installed_parameters, resolve
from tdslip_ros.model import units
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.plant.perturbations import Mismatch, Perturbations, PlacementNoise, Pushes, SensingNoise
from tdslip_ros.model.plant.terrain import TERRAIN_FORMS, parse_terrain
from tdslip_ros.model.policies.registry import POLICIES, STANCE_FEEDBACK_POLICIES
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.entry import stop_on_signals
from tdslip_ros.nodes.plant_parameters import CLOCK_MODES
from tdslip_ros.nodes.run_options import RunError, RunOptionError, RunOptions, check_options
from tdslip_ros.nodes.runner import run


def apex_table(params: HopperParams, apexes: Sequence[Any], ground: bool = False) -> str:
    """The apex states, SI (world frame) and dimensionless (eq. 24), one row per stride; with ``ground``,
    the ground height of the stance before each apex too, and a rigid body's pitch and its rate."""
    rigid = params.body is not None
    header = (
        f"{'stride':>6} {'t [s]':>9} {'y [m]':>9} {'xdot [m/s]':>11} {'E [J]':>10}"
        f" | {'ybar':>8} {'xdotbar':>8} {'Ebar':>8}"
        + (f" | {'ground [m]':>10}" if ground else "")
        + (f" | {'pitch [rad]':>11} {'rate [rad/s]':>12}" if rigid else "")
    )
    rows = [header, "-" * len(header)]
    for apex in apexes:
        rows.append(
            f"{apex.stride:>6d} {apex.sim_time:>9.4f} {apex.height:>9.5f} {apex.forward_speed:>11.5f}"
            f" {apex.energy:>10.3f} | {units.height_to_bar(params, apex.height):>8.5f}"
            f" {units.speed_to_bar(params, apex.forward_speed):>8.5f}"
            f" {units.energy_to_bar(params, apex.energy):>8.5f}"
            + (f" | {apex.ground_height:>10.5f}" if ground else "")
            + (f" | {apex.pitch:>11.5f} {apex.pitch_rate:>12.5f}" if rigid else "")
        )
    return "\n".join(rows)


def counts_table(
    published_counts: dict[str, int],
    recorded_counts: dict[str, int],
    heading: str = "recorded",
    shortfall: str = "LOST",
) -> str:
    """Messages published and recorded (or ``heading``) per topic, marking the topics where they differ:
    ``shortfall`` where fewer are in the bag than were published."""
    names = sorted(set(published_counts) | set(recorded_counts))
    width = max(len("topic"), *map(len, names))
    rows = [f"{'topic':<{width}} {'published':>10} {heading:>11}"]
    for topic in names:
        published, recorded = published_counts.get(topic, 0), recorded_counts.get(topic, 0)
        mark = "" if published == recorded else f"  {shortfall}" if recorded < published else "  EXTRA"
        rows.append(f"{topic:<{width}} {published:>10d} {recorded:>11d}{mark}")
    return "\n".join(rows)


def early_end_table(error: RunError) -> str:
    """The counts of a run that a node ended early. When the recorder stopped, what it did not record
    was published after it stopped, not lost in a running recording; an unfinalised bag is counted by
    what ``tdslip recover`` gets back."""
    published = error.published or {}
    if error.recoverable is not None:
        in_bag, heading = error.recoverable, "recoverable"
    else:
        in_bag, heading = error.recorded or {}, "recorded"
    shortfall = "after the recorder stopped" if error.recorder_stopped else "LOST"
    return counts_table(published, {topic: in_bag.get(topic, 0) for topic in published}, heading, shortfall)


def recording_note(bag: Path, recoverable: dict[str, int] | None = None) -> str:
    """What became of the recording of a run that ended early (``recoverable``: what ``tdslip recover``
    gets back from an unfinalised bag, by topic)."""
    if not (bag / "metadata.yaml").is_file():
        kept = "" if recoverable is None else f" ({sum(recoverable.values())} messages)"
        return f"The recording in {bag} was not finalised; make it readable{kept} with: tdslip recover {bag}"
    return f"The recording so far is in {bag} (finalised: tdslip analyze and replay read it)."


DESCRIPTION = """\
Run the plant, controller and recorder nodes (ROS 2) for one hop and record it as a bag.
Progress goes to stderr; then the apex table, the messages published and recorded per topic and the
run's outcome. The exit status is 0 only for a complete run with a complete recording (2: a usage error,
nothing started; 130: interrupted)."""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("run", DESCRIPTION)
    parser.add_argument(
        "--strides", type=int, default=50, help="the run ends at this apex (0: no limit, needs --duration)"
    )
    parser.add_argument(
        "--policy",
        choices=(*POLICIES, *STANCE_FEEDBACK_POLICIES),
        default="energy",
        help=f"the controller's policy ({', '.join(STANCE_FEEDBACK_POLICIES)}: stance feedback at 1 kHz, "
        "by stance_controller_node)",
    )
    parser.add_argument(
        "--mode",
        choices=CLOCK_MODES,
        default="lockstep",
        help="lockstep: the plant waits for each command; realtime: 1 kHz on the wall clock",
    )
    parser.add_argument(
        "--out", type=Path, help="bag directory to create (default: runs/<policy>-<mode>-<time>)"
    )
    parser.add_argument(
        "--controller",
        choices=("suite", "none"),
        default="suite",
        help="suite: the package's controller_node with --policy; none: start none and wait for your own, "
        "which answers tdslip/apex on tdslip/command (examples/my_controller.py)",
    )
    parser.add_argument(
        "--wait-for-controller",
        type=float,
        default=300.0,
        metavar="SECONDS",
        help="with --controller none: how long to wait for your controller to connect [s]",
    )
    add_initial_apex(parser)
    add_touchdown_angle(parser, "--angle", what=" (open_loop, energy, energy_exact)")
    parser.add_argument(
        "--target-energy", type=float, help="energy policies' goal [J] (default: the initial apex's energy)"
    )
    parser.add_argument(
        "--target-height",
        type=float,
        help=(
            "target apex height [m] of deadbeat, apex_foot_placement and stance_pd_speed_energy "
            "(default: config/controller.yaml's, 1)"
        ),
    )
    parser.add_argument(
        "--target-speed",
        type=float,
        help=(
            "target apex speed [m/s] of deadbeat, apex_foot_placement and stance_pd_speed_energy "
            "(default: config/controller.yaml's, 5)"
        ),
    )
    add_analytic_map(
        parser, what=", the one the policy plans on", unset="config/controller.yaml's analytic_map, ours"
    )
    add_policy_file(parser)
    parser.add_argument(
        "--timeout",
        type=float,
        help="lockstep: wait this long for a command [s wall] (default: the plant's command_timeout, 5)",
    )
    parser.add_argument("--duration", type=float, help="end the run after this wall time [s] (default: none)")
    parser.add_argument(
        "--realtime-priority",
        type=int,
        help="SCHED_FIFO priority 1-99 of the realtime tick, needs root (default: normal scheduling)",
    )
    parser.add_argument(
        "--realtime-cpu",
        type=int,
        help="realtime: pin the tick to this CPU, one the machine's busy programs avoid (default: any)",
    )
    parser.add_argument("--record-clock", action="store_true", help="also record /clock")
    parser.add_argument("--domain-id", type=int, help="ROS domain id (default: a free one from 120-229)")
    parser.add_argument(
        "--namespace", default="/", help="ROS namespace of the nodes (default: /, topics /tdslip/...)"
    )
    perturb = parser.add_argument_group("perturbations (default: none; see docs/perturbations.md)")
    perturb.add_argument("--terrain", metavar="SPEC", help=f"ground [m]: {TERRAIN_FORMS} (default: flat)")
    perturb.add_argument(
        "--apex-noise",
        metavar="height=M,speed=M_PER_S,seed=N",
        help="the controller's sensor noise, std. dev. [m], [m/s] (default: none)",
    )
    perturb.add_argument(
        "--angle-noise",
        metavar="sigma=DEG,seed=N",
        help="touchdown angle error, std. dev. [deg] (default: none)",
    )
    perturb.add_argument(
        "--mismatch",
        metavar="mass=F,stiffness=F,damping=F,rest_length=F",
        help="the controller plans with the plant's parameters times these factors (default: all 1)",
    )
    perturb.add_argument(
        "--tau-max",
        type=float,
        metavar="N_M",
        help="the hip torque saturates at +-N_M [N m] (default: no limit)",
    )
    perturb.add_argument(
        "--push",
        action="append",
        default=[],
        metavar="STRIDE:DV | random:size=DV,rate=P,seed=N",
        help="a push of DV [m/s] right after the apex of STRIDE, or random ones (repeatable; default: none)",
    )
    add_hopper(parser, "config/plant.yaml's, the paper's; the plant's and the controller's model alike")
    add_body(parser)
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
        raise RunOptionError(str(error)) from None


def own_controller_domain(args: argparse.Namespace) -> int:
    """The ROS domain a run with a controller of one's own uses: --domain-id, else the environment's
    ROS_DOMAIN_ID (0 if unset), where that controller runs too."""
    if args.domain_id is not None:
        return int(args.domain_id)
    value = os.environ.get("ROS_DOMAIN_ID", "").strip() or "0"
    if not value.isdigit():
        raise RunOptionError(f"ROS_DOMAIN_ID={value!r} is not a domain id; give --domain-id")
    return int(value)


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    out = args.out or Path("runs") / f"{args.policy}-{args.mode}-{datetime.now():%Y%m%d-%H%M%S}"
    try:
        angle_error = touchdown_angle_error(args.touchdown_angle_deg)
        if angle_error is not None:
            raise RunOptionError(angle_error)
        perturbations = perturbations_of(args)
        hopper = None  # the installed files'
        if hopper_given(args) or body_given(args):
            hopper = body_of(
                args, hopper_of(args, hopper_from_parameters(installed_parameters("plant.yaml")))
            )
        domain_id = own_controller_domain(args) if args.controller == "none" else args.domain_id
    except (RunError, ParameterError) as error:
        print(f"tdslip run: {error}", file=sys.stderr)
        return 2
    options = RunOptions(
        out=out,
        strides=args.strides,
        policy=args.policy,
        mode=args.mode,
        height=args.height,
        speed=args.speed,
        touchdown_angle=math.radians(args.touchdown_angle_deg),
        target_energy=args.target_energy,
        target_height=args.target_height,
        target_speed=args.target_speed,
        analytic_map=args.map,
        policy_file=policy_file(args),
        command_timeout=args.timeout,
        realtime_priority=args.realtime_priority,
        realtime_cpu=args.realtime_cpu,
        record_clock=args.record_clock,
        duration=args.duration,
        domain_id=domain_id,
        namespace=args.namespace,
        perturbations=perturbations,
        hopper=hopper,
        own_controller=args.controller == "none",
        controller_wait=args.wait_for_controller,
    )
    try:
        check_options(options)
    except RunOptionError as error:
        print(f"tdslip run: {error}", file=sys.stderr)
        return 2
    if options.own_controller:
        print(
            f"tdslip run: waiting up to {args.wait_for_controller:g} s for your controller in ROS domain "
            f"{options.domain_id}: it answers {resolve(topics.APEX, args.namespace)} on "
            f"{resolve(topics.COMMAND, args.namespace)}",
            file=sys.stderr,
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
    except RunOptionError as error:  # a usage error: nothing started, nothing written
        print(f"tdslip run: {error}", file=sys.stderr)
        return 2
    except RunError as error:
        print(f"\ntdslip run: {error}", file=sys.stderr)
        if error.published is not None:
            print(early_end_table(error))
        if ours and options.out.exists():
            print(recording_note(options.out, error.recoverable), file=sys.stderr)
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
    if report.published.get(resolve(topics.APPLIED_TORQUE, options.namespace)):
        print(
            f"stance feedback: {report.late_torques} torque(s) came after their tick (realtime: held at the "
            f"next ticks while fresh), {report.stale_torques} stance tick(s) stale (no fresh torque: held 0)"
        )
    controlled_by = "your own controller" if options.own_controller else f"policy {options.policy}"
    print(
        f"{options.mode} run, {controlled_by}: {outcome.stride} strides, "
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
            f"{failure_cause(outcome.kind, outcome.reason, outcome.stride, report.controller_log)}",
            file=sys.stderr,
        )
    return 0 if report.ok else 1


def failure_cause(kind: str, reason: str, stride: int, controller_log: str) -> str:
    """Why the run failed: the plant's failure kind and reason, led by the controller's own reason where
    the plant waited in vain for a command that the controller found none for (its log line of that
    apex, controller_node's "no command for apex N (...): why")."""
    refusal = re.search(rf"no command for apex {stride} \(.*?\): (.+)$", controller_log, re.MULTILINE)
    if kind == "command_timeout" and refusal is not None:
        return f"the controller found no command: {refusal[1]} ({kind}: {reason})"
    return f"{kind}: {reason}"
