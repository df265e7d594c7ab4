"""The deadbeat controller against the baseline of the paper's ref. 36 over desired speeds (fig. 13's
tracking errors in the node suite; the model's fig. 13 is :mod:`tdslip_ros.analysis.figures.tracking`), from
recorded runs: the analysis side of ``tdslip compare``, which needs no ROS.

The sweep's recorded runs (one per controller and desired apex speed, from the same initial apex, for a
fixed number of strides; :mod:`tdslip_ros.commands.compare` records them) are listed in ``OUT/sweep.json``.
The baseline, ``stance_pd_speed_energy``, lands at the touchdown angle of its target speed by the model's
fig. 13 rule (:func:`~tdslip_ros.analysis.figures.tracking.baseline_touchdown_angles`); where the rule
finds no angle it is not run, and loses stability there (``no_touchdown_angle``). Apex foot placement
(``apex_foot_placement``, an apex-level policy) can be compared as well. Each recording is read back and
analysed (:mod:`tdslip_ros.analysis.compare`): a run tracks its target when it completed without failure and
converged (apex changes below 1e-4 that shrink); its tracking errors are the final apex's speed and height
relative to the target, in percent. A run that failed or did not converge is where the controller loses
stability; the figure marks it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from tdslip_ros.analysis.compare import compare_run, policy_for_run
from tdslip_ros.analysis.decoding import RunReadError, read_run
from tdslip_ros.analysis.figures.tracking import BASELINE
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.policies.registry import POLICIES
from tdslip_ros.reporting.style import CONTROLLER_STYLE, save_figure

CONTROLLERS = ("deadbeat", BASELINE, "apex_foot_placement")
"""The controllers ``tdslip compare`` can run."""
DEFAULT_CONTROLLERS = ("deadbeat", BASELINE)
"""Those it runs unless told: fig. 13's."""
NO_TOUCHDOWN_ANGLE = "no_touchdown_angle"
"""The outcome of a baseline's target speed at which the angle rule finds no angle (not run)."""
MANIFEST = "sweep.json"


@dataclass(frozen=True)
class SweepRun:
    """One run of the sweep: controller, target apex (SI, and the desired speed xdotbar* as requested),
    bag directory (relative to the sweep's directory; None: not run, the baseline has no touchdown angle
    there), the plant's hopper parameters (a run that fails before its first stance holds too little to
    infer them) and the baseline's touchdown angle [rad] (None for the other controllers)."""

    controller: str
    target_height: float
    target_speed: float
    target_speed_bar: float
    bag: str | None
    params: HopperParams
    stance_touchdown_angle: float | None = None

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
    bag: str | None
    stance_touchdown_angle: float | None


def save_sweep(out: Path, runs: Sequence[SweepRun]) -> None:
    """List the recorded runs in OUT/MANIFEST (rewritten as each run finishes, so that an interrupted sweep
    can still be analysed)."""
    (out / MANIFEST).write_text(json.dumps([asdict(r) for r in runs], indent=1) + "\n")


def load_sweep(out: Path) -> list[SweepRun]:
    try:
        return [SweepRun.from_json(entry) for entry in json.loads((out / MANIFEST).read_text())]
    except (OSError, ValueError, TypeError, KeyError) as error:
        raise RunReadError(f"{out / MANIFEST}: no readable sweep manifest ({error})") from None


def analyse_run(out: Path, entry: SweepRun) -> Tracking:
    """Read one recorded run back and measure how it tracked its target (lost, with no recording, where the
    baseline had no touchdown angle)."""
    outcome, converged_at = NO_TOUCHDOWN_ANGLE, None
    final_height = final_speed = math.nan
    if entry.bag is not None:
        recorded = read_run(out / entry.bag, entry.params)
        policy = None  # the baseline's law is no ramp policy: its runs are analysed without one
        if entry.controller in POLICIES:
            targets = {"target_height": entry.target_height, "target_speed": entry.target_speed}
            policy = policy_for_run(recorded, name=entry.controller, **targets)
        converged_at = compare_run(recorded, policy).converged_at
        outcome = recorded.outcome.kind if recorded.outcome is not None else "incomplete recording"
        final_height, final_speed = recorded.strides[-1].y, recorded.strides[-1].xdot
    stable = outcome == "run_complete" and converged_at is not None
    return Tracking(
        controller=entry.controller,
        target_height=entry.target_height,
        target_speed=entry.target_speed,
        target_speed_bar=entry.target_speed_bar,
        outcome=outcome,
        stable=stable,
        converged_at=converged_at,
        final_height=final_height,
        final_speed=final_speed,
        speed_error_percent=100.0 * (final_speed - entry.target_speed) / entry.target_speed
        if stable
        else math.nan,
        height_error_percent=100.0 * (final_height - entry.target_height) / entry.target_height
        if stable
        else math.nan,
        bag=entry.bag,
        stance_touchdown_angle=entry.stance_touchdown_angle,
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
    save_figure(figure, path)
    return figure


def stable_range(results: Sequence[Tracking], controller: str) -> tuple[float, float] | None:
    """Smallest and largest desired speed xdotbar* at which ``controller`` tracked its target."""
    speeds = [r.target_speed_bar for r in results if r.controller == controller and r.stable]
    return (min(speeds), max(speeds)) if speeds else None


def table(results: Sequence[Tracking]) -> str:
    """One row per run; ``td deg``: the baseline's touchdown angle in degrees."""
    rows = [
        f"{'controller':<22} {'xdotbar*':>8} {'td deg':>6} {'outcome':<18} {'stable':<6} {'conv.':>5} "
        f"{'speed %':>9} {'height %':>9}"
    ]
    for r in results:
        converged = "-" if r.converged_at is None else str(r.converged_at)
        angle = "-" if r.stance_touchdown_angle is None else f"{math.degrees(r.stance_touchdown_angle):.2f}"
        rows.append(
            f"{r.controller:<22} {r.target_speed_bar:>8.3f} {angle:>6} {r.outcome:<18} "
            f"{'yes' if r.stable else 'NO':<6} {converged:>5} {r.speed_error_percent:>9.3f} "
            f"{r.height_error_percent:>9.3f}"
        )
    return "\n".join(rows)
