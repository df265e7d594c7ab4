"""``tdslip compare``: the deadbeat controller against the baseline of the paper's ref. 36,
``stance_pd_speed_energy``, over desired speeds (the tracking errors of the paper's fig. 13), from recorded
runs: fig. 13 in the node suite, beside the model's (``tdslip figures --only fig13``).

For every controller and desired apex speed the node suite runs in lockstep (``tdslip run``'s
:func:`tdslip_ros.nodes.runner.run`, every run recorded into ``OUT/runs/<controller>-<xdotbar*>``) from the
model's fig. 13 apex (the node suite's default, 1 m at 5 m/s), for a fixed number of strides, as the paper's
50-step runs. The baseline's stance controller node answers every tick with its hip torque and lands at the
touchdown angle of its target speed by the model's fig. 13 rule; a target speed without one is not run
(:mod:`tdslip_ros.analysis.controller_comparison`). ``--controllers`` adds apex foot placement
(``apex_foot_placement``). Each recording is then analysed. ``OUT/sweep.json`` lists the runs as they
finish, so ``--analyse-only`` can redo the analysis and figure without running anything;
``OUT/comparison.json`` holds the results and ``OUT/tracking_error.png`` the figure. The recording step
needs ROS 2 (rclpy); the analysis does not.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict
from datetime import datetime
from pathlib import Path

import numpy as np

from tdslip_ros.analysis.controller_comparison import (
    CONTROLLERS,
    DEFAULT_CONTROLLERS,
    SweepRun,
    analyse_run,
    load_sweep,
    plot_tracking,
    save_sweep,
    stable_range,
    table,
)
from tdslip_ros.analysis.decoding import RunReadError
from tdslip_ros.analysis.figures.tracking import BASELINE, baseline_touchdown_angles
from tdslip_ros.commands.options import command_parser, deprecated
from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.reporting.output import OutputError, output_directory, to_json, write_failed

DEFAULT_SPEEDS = tuple(float(v) for v in np.round(np.arange(0.5, 3.001, 0.25), 3))
"""Desired apex speeds xdotbar* of the default sweep (dimensionless)."""
DEFAULT_STRIDES = 50
COMMAND_TIMEOUT = 2.0
"""s wall: a ramp controller that finds no command ends its run quickly. The baseline answers every apex, so
its runs keep the plant's own wait (config/plant.yaml), which a slow start under load does not outlast."""


def record_sweep(
    out: Path,
    speeds_bar: Sequence[float],
    target_height: float,
    strides: int,
    controllers: Sequence[str] = DEFAULT_CONTROLLERS,
    progress: Callable[[str], None] = print,
) -> list[SweepRun]:
    """Run and record every (controller, desired speed) in lockstep; returns the runs (also in MANIFEST)."""
    # Imported here so that analysing recorded sweeps (--analyse-only) needs no ROS 2 installation.
    from tdslip_ros.nodes.runner import RunError, RunOptions, run

    out.mkdir(parents=True, exist_ok=True)
    speeds = np.asarray(units.speed_from_bar(PAPER_PARAMS, np.asarray(speeds_bar, dtype=float)))
    angles = None
    if BASELINE in controllers:
        angles = baseline_touchdown_angles(PAPER_PARAMS, target_height, speeds)
    runs: list[SweepRun] = []
    for controller in controllers:
        for index, speed_bar in enumerate(speeds_bar):
            speed = float(speeds[index])
            angle = None if angles is None or controller != BASELINE else float(angles[index])
            if angle is not None and math.isnan(angle):
                runs.append(SweepRun(controller, target_height, speed, speed_bar, None, PAPER_PARAMS))
                save_sweep(out, runs)
                progress(f"not run  {controller:<22} xdotbar* = {speed_bar:.3f}: no touchdown angle")
                continue
            bag = out / "runs" / f"{controller}-xdotbar{speed_bar:.3f}"
            options = RunOptions(
                out=bag,
                strides=strides,
                policy=controller,
                stance_touchdown_angle=angle,
                target_height=target_height,
                target_speed=speed,
                command_timeout=None if controller == BASELINE else COMMAND_TIMEOUT,
            )
            try:
                report = run(options)
            except RuntimeError as error:  # RunError, or an rclpy error out of the node suite
                raise RunError(f"{controller} at xdotbar* = {speed_bar}: {error}") from None
            if not report.recording_complete:
                progress(
                    f"warning: {bag} lost messages: published {report.published}, recorded {report.recorded}"
                )
            relative = str(bag.relative_to(out))
            runs.append(SweepRun(controller, target_height, speed, speed_bar, relative, report.params, angle))
            save_sweep(out, runs)
            outcome = report.outcome
            progress(
                f"recorded {controller:<22} xdotbar* = {speed_bar:.3f}: {outcome.kind} ({outcome.reason})"
            )
    return runs


DESCRIPTION = """\
Deadbeat against the baseline of the paper's ref. 36 (stance_pd_speed_energy) over desired apex speeds
(fig. 13's errors), from recorded runs. Every controller and desired speed is run by the node suite in
lockstep and recorded into OUT/runs; the baseline lands at the touchdown angle of its target speed by the
model's fig. 13 rule. Each recording is then analysed into OUT/comparison.json and OUT/tracking_error.png.
--analyse-only redoes the analysis of the runs listed in OUT/sweep.json without ROS."""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("compare", DESCRIPTION)
    parser.add_argument("--out", type=Path, help="output directory (default: runs/compare-<time>)")
    speeds = parser.add_argument(
        "--speeds-bar",
        type=float,
        nargs="+",
        default=list(DEFAULT_SPEEDS),
        metavar="XDOTBAR",
        help="desired apex speeds xdot*/sqrt(g r0) (dimensionless; default: 0.5 to 3 in steps of 0.25)",
    )
    deprecated(parser, speeds, "--speeds")
    height = parser.add_argument(
        "--target-height", type=float, default=1.0, metavar="M", help="desired apex height [m]"
    )
    deprecated(parser, height, "--height")
    parser.add_argument("--strides", type=int, default=DEFAULT_STRIDES, help="strides per run")
    parser.add_argument(
        "--controllers",
        nargs="+",
        choices=CONTROLLERS,
        default=list(DEFAULT_CONTROLLERS),
        help=f"the controllers run (default: {' '.join(DEFAULT_CONTROLLERS)})",
    )
    parser.add_argument(
        "--analyse-only", action="store_true", help="re-analyse the runs listed in OUT/sweep.json"
    )
    return parser


def check_sweep_options(args: argparse.Namespace) -> None:
    """ValueError naming the first sweep option that no run can use."""
    if args.strides < 1:
        raise ValueError(f"--strides must be at least 1, not {args.strides}")
    if not 0.0 < args.target_height < math.inf:
        raise ValueError(f"--target-height must be a finite height > 0 m, not {args.target_height}")
    bad = [speed for speed in args.speeds_bar if not 0.0 <= speed < math.inf]
    if bad:
        raise ValueError(f"--speeds-bar must be finite speeds >= 0, not {', '.join(map(str, bad))}")


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    out = args.out or Path("runs") / f"compare-{datetime.now():%Y%m%d-%H%M%S}"
    try:  # usage errors: exit status 2, as argparse's
        if not args.analyse_only:
            check_sweep_options(args)
            output_directory(out)
    except (OutputError, ValueError) as error:
        print(f"tdslip compare: {error}", file=sys.stderr)
        return 2
    try:
        if args.analyse_only:
            entries = load_sweep(out)
        else:
            entries = record_sweep(out, args.speeds_bar, args.target_height, args.strides, args.controllers)
        results = [analyse_run(out, entry) for entry in entries]
        (out / "comparison.json").write_text(to_json([asdict(r) for r in results]))
        plot_tracking(results, out / "tracking_error.png")
    except (RunReadError, OutputError, RuntimeError, ValueError) as error:
        print(f"tdslip compare: {error}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # the progress lines' reader is gone: tdslip's cli.main ends quietly
        raise
    except OSError as error:
        print(f"tdslip compare: {write_failed(error)}", file=sys.stderr)
        return 1
    print(table(results))
    for controller in dict.fromkeys(r.controller for r in results):
        span = stable_range(results, controller)
        text = "nowhere" if span is None else f"xdotbar* in [{span[0]:.3f}, {span[1]:.3f}]"
        print(f"{controller}: tracks its target {text}")
    print(f"figure: {out / 'tracking_error.png'}; numbers: {out / 'comparison.json'}")
    return 0
