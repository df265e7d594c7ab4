"""``tdslip compare``: the deadbeat controller against the PD baseline over desired speeds (paper fig. 13),
from recorded runs.

For every controller and desired apex speed the node suite runs in lockstep (``tdslip run``'s
:func:`tdslip_ros.nodes.runner.run`, every run recorded into ``OUT/runs/<controller>-<xdotbar*>``)
from the same initial apex, for a fixed number of strides, as the paper's 50-step runs. Each
recording is then read back and analysed (:mod:`tdslip_ros.analysis.compare`): a run tracks its
target when it completed without failure and converged (apex changes below 1e-4 that shrink); its
tracking errors are the final apex's speed and height relative to the target, in percent. A run
that failed or did not converge is where the controller loses stability; the figure marks it.

``OUT/sweep.json`` lists the recorded runs as they finish, so ``--analyse-only`` can redo the
analysis and figure without running anything; ``OUT/comparison.json`` holds the results and
``OUT/tracking_error.png`` the figure. The recording step needs ROS 2 (rclpy); the analysis does not.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from tdslip_ros.analysis.compare import compare_run, policy_for_run
from tdslip_ros.analysis.reader import RunReadError, read_run
from tdslip_ros.model import units
from tdslip_ros.model.params import HopperParams
from tdslip_ros.reporting.output import OutputError, output_directory, to_json, write_failed
from tdslip_ros.reporting.style import CONTROLLER_STYLE, DPI

CONTROLLERS = ("deadbeat", "pd")
DEFAULT_SPEEDS = tuple(float(v) for v in np.round(np.arange(0.5, 3.001, 0.25), 3))
"""Desired apex speeds xdotbar* of the default sweep (dimensionless)."""
DEFAULT_STRIDES = 50
COMMAND_TIMEOUT = 2.0  # s wall: a controller that finds no command ends its run quickly
MANIFEST = "sweep.json"


@dataclass(frozen=True)
class SweepRun:
    """One recorded run of the sweep: controller, target apex (SI, and the desired speed xdotbar* as
    requested), bag directory (relative to the sweep's directory) and the plant's hopper parameters
    (a run that fails before its first stance holds too little to infer them)."""

    controller: str
    target_height: float
    target_speed: float
    target_speed_bar: float
    bag: str
    params: HopperParams

    @classmethod
    def from_json(cls, entry: dict[str, Any]) -> SweepRun:
        return cls(**{**entry, "params": HopperParams(**entry["params"])})


@dataclass(frozen=True)
class Tracking:
    """The outcome of one run: stable (completed and converged), final apex and tracking errors [%]."""

    controller: str
    target_height: float
    target_speed: float
    target_speed_bar: float
    outcome: str
    stable: bool
    converged_at: int | None
    final_height: float
    final_speed: float
    speed_error_percent: float
    height_error_percent: float
    bag: str


def record_sweep(
    out: Path,
    speeds_bar: Sequence[float],
    target_height: float,
    strides: int,
    controllers: Sequence[str] = CONTROLLERS,
    progress: Callable[[str], None] = print,
) -> list[SweepRun]:
    """Run and record every (controller, desired speed) in lockstep; returns the runs (also in MANIFEST)."""
    # Imported here so that analysing recorded sweeps needs no ROS 2 installation.
    from tdslip_ros.model.paper import PAPER_PARAMS
    from tdslip_ros.nodes.runner import RunError, RunOptions, run

    out.mkdir(parents=True, exist_ok=True)
    runs: list[SweepRun] = []
    for controller in controllers:
        for speed_bar in speeds_bar:
            speed = float(units.speed_from_bar(PAPER_PARAMS, speed_bar))
            bag = out / "runs" / f"{controller}-xdotbar{speed_bar:.3f}"
            options = RunOptions(
                out=bag,
                strides=strides,
                policy=controller,
                target_height=target_height,
                target_speed=speed,
                command_timeout=COMMAND_TIMEOUT,
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
            runs.append(SweepRun(controller, target_height, speed, speed_bar, relative, report.params))
            (out / MANIFEST).write_text(json.dumps([asdict(r) for r in runs], indent=1) + "\n")
            outcome = report.outcome
            progress(
                f"recorded {controller:<8} xdotbar* = {speed_bar:.3f}: {outcome.kind} ({outcome.reason})"
            )
    return runs


def load_sweep(out: Path) -> list[SweepRun]:
    try:
        return [SweepRun.from_json(entry) for entry in json.loads((out / MANIFEST).read_text())]
    except (OSError, ValueError, TypeError, KeyError) as error:
        raise RunReadError(f"{out / MANIFEST}: no readable sweep manifest ({error})") from None


def analyse_run(out: Path, entry: SweepRun) -> Tracking:
    """Read one recorded run back and measure how it tracked its target."""
    recorded = read_run(out / entry.bag, entry.params)
    policy = policy_for_run(
        recorded, name=entry.controller, target_height=entry.target_height, target_speed=entry.target_speed
    )
    comparison = compare_run(recorded, policy)
    last = recorded.strides[-1]
    completed = recorded.outcome is not None and recorded.outcome.kind == "run_complete"
    stable = completed and comparison.converged_at is not None
    return Tracking(
        controller=entry.controller,
        target_height=entry.target_height,
        target_speed=entry.target_speed,
        target_speed_bar=entry.target_speed_bar,
        outcome=recorded.outcome.kind if recorded.outcome is not None else "incomplete recording",
        stable=stable,
        converged_at=comparison.converged_at,
        final_height=last.y,
        final_speed=last.xdot,
        speed_error_percent=100.0 * (last.xdot - entry.target_speed) / entry.target_speed
        if stable
        else math.nan,
        height_error_percent=100.0 * (last.y - entry.target_height) / entry.target_height
        if stable
        else math.nan,
        bag=entry.bag,
    )


def plot_tracking(results: Sequence[Tracking], path: Path) -> Figure:
    """Absolute percentage tracking errors of apex speed (top) and height (bottom) against the desired
    speed, one line per controller; crosses on the axis where a controller loses stability."""
    figure = Figure(figsize=(8, 6))
    axes = figure.subplots(2, 1, sharex=True)
    for ax, field, label in zip(
        axes,
        ("speed_error_percent", "height_error_percent"),
        ("apex speed error [%]", "apex height error [%]"),
        strict=True,
    ):
        for controller in dict.fromkeys(r.controller for r in results):
            rows = sorted(
                (r for r in results if r.controller == controller), key=lambda r: r.target_speed_bar
            )
            colour, style = CONTROLLER_STYLE.get(controller, ("black", ":"))
            speeds = np.array([r.target_speed_bar for r in rows])
            errors = np.abs(np.array([getattr(r, field) for r in rows]))
            ax.plot(speeds, errors, style, marker="o", ms=4, color=colour, label=controller)
            lost = np.array([not r.stable for r in rows])
            if np.any(lost):
                ax.plot(
                    speeds[lost],
                    np.zeros(np.count_nonzero(lost)),
                    "x",
                    color=colour,
                    ms=10,
                    mew=2,
                    label=f"{controller} loses stability",
                )
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[1].set_xlabel("desired apex speed xdotbar*")
    axes[0].set_title("tracking error per desired speed (recorded lockstep runs)")
    figure.tight_layout()
    figure.savefig(path, dpi=DPI)
    return figure


def stable_range(results: Sequence[Tracking], controller: str) -> tuple[float, float] | None:
    """Smallest and largest desired speed xdotbar* at which ``controller`` tracked its target."""
    speeds = [r.target_speed_bar for r in results if r.controller == controller and r.stable]
    return (min(speeds), max(speeds)) if speeds else None


def table(results: Sequence[Tracking]) -> str:
    rows = [
        f"{'controller':<10} {'xdotbar*':>8} {'outcome':<16} {'stable':<6} {'conv.':>5} "
        f"{'speed %':>9} {'height %':>9}"
    ]
    for r in results:
        converged = "-" if r.converged_at is None else str(r.converged_at)
        rows.append(
            f"{r.controller:<10} {r.target_speed_bar:>8.3f} {r.outcome:<16} {'yes' if r.stable else 'NO':<6} "
            f"{converged:>5} {r.speed_error_percent:>9.3f} {r.height_error_percent:>9.3f}"
        )
    return "\n".join(rows)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tdslip compare",
        description="Deadbeat vs PD over desired speeds, recorded in lockstep and analysed (paper fig. 13).",
    )
    parser.add_argument("--out", type=Path, help="output directory (default runs/compare-<time>)")
    parser.add_argument(
        "--speeds", type=float, nargs="+", default=list(DEFAULT_SPEEDS), help="desired apex speeds xdotbar*"
    )
    parser.add_argument("--height", type=float, default=1.0, help="desired apex height [m] (default 1)")
    parser.add_argument("--strides", type=int, default=DEFAULT_STRIDES, help="strides per run (default 50)")
    parser.add_argument("--controllers", nargs="+", choices=CONTROLLERS, default=list(CONTROLLERS))
    parser.add_argument(
        "--analyse-only", action="store_true", help="re-analyse the runs listed in OUT/sweep.json"
    )
    return parser


def check_sweep_options(args: argparse.Namespace) -> None:
    """ValueError naming the first sweep option that no run can use."""
    if args.strides < 1:
        raise ValueError(f"--strides must be at least 1, not {args.strides}")
    if not 0.0 < args.height < math.inf:
        raise ValueError(f"--height must be a finite height > 0 m, not {args.height}")
    bad = [speed for speed in args.speeds if not 0.0 <= speed < math.inf]
    if bad:
        raise ValueError(f"--speeds must be finite speeds >= 0, not {', '.join(map(str, bad))}")


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    out = args.out or Path("runs") / f"compare-{datetime.now():%Y%m%d-%H%M%S}"
    try:
        if args.analyse_only:
            entries = load_sweep(out)
        else:
            check_sweep_options(args)
            output_directory(out)
            entries = record_sweep(out, args.speeds, args.height, args.strides, args.controllers)
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
