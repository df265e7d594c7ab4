"""PNG figures of a recorded run and its comparison with the analytic map.

Each function draws one figure, saves it to ``path`` and returns the matplotlib Figure (the caller
closes it; tests read the drawn data back from it). Axes are in the paper's dimensionless units
(eq. 24) except the centre-of-mass figure, which is in metres like the paper's fig. 12.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display needed (or wanted) in analysis runs and tests

import numpy as np
from matplotlib.figure import Figure

from tdslip_ros.analysis.compare import Comparison, closed_loop_step, dimensionless
from tdslip_ros.analysis.records import Run
from tdslip_ros.model import units
from tdslip_ros.model.dynamics import speed_from_energy
from tdslip_ros.reporting.style import save_figure

MAP_CURVE_POINTS = 200
LONG_RUN = 100
"""Strides above which the per-stride axis is drawn linear up to 10, logarithmic beyond."""
GRF_LINE_PERIOD = 5
"""Draw the ground reaction force of every 5th stance sample (every 5 ms at 1 kHz), as fig. 12 does."""
GRF_LINE_ID = "grf"
"""gid of the force lines of :func:`com_trajectory`."""
RECORDED = "tab:blue"
ANALYTIC = ("tab:orange", "tab:red")  # 0 and 1 corrections
EXACT = "tab:green"


def _save(figure: Figure, path: Path) -> Figure:
    save_figure(figure, path)
    return figure


def apex_sequence(comparison: Comparison, path: Path) -> Figure:
    """Apex height and speed per stride: recorded, the analytic one-stride predictions from each
    recorded apex (0 and 1 corrections), the analytic fixed point and the target, and the stride
    where the run converged."""
    run, predictions = comparison.run, comparison.predictions
    params = run.params
    recorded = dimensionless(params, run.apex_array())
    strides = np.array([s.stride for s in run.strides])
    figure = Figure(figsize=(8, 6))
    axes = figure.subplots(2, 1, sharex=True)
    labels = ("apex height ybar", "apex speed xdotbar")
    for column, ax in enumerate(axes):
        ax.plot(strides, recorded[:, column], "o-", color=RECORDED, ms=3, label="recorded")
        for corrections, colour in enumerate(ANALYTIC):
            predicted = dimensionless(params, predictions.analytic[corrections])
            ax.plot(
                predictions.stride + 1,
                predicted[:, column],
                "x",
                color=colour,
                ms=5,
                label=f"analytic map, {corrections} correction{'s' if corrections != 1 else ''}",
            )
        fixed = comparison.analytic_fixed_point
        if fixed is not None:
            value = dimensionless(params, (fixed.y, fixed.xdot))[column]
            ax.axhline(value, color="black", ls="--", lw=1, label="analytic fixed point")
        target = None if comparison.policy is None else comparison.policy.target
        if target is not None:
            ax.axhline(dimensionless(params, target)[column], color="grey", ls=":", lw=1, label="target")
        if comparison.converged_at is not None:
            ax.axvline(comparison.converged_at, color="grey", lw=1, label="converged (1e-4)")
        ax.set_ylabel(labels[column])
        ax.grid(alpha=0.3)
        if len(strides) > LONG_RUN:
            ax.set_xscale("symlog", linthresh=10.0)  # the transient and the long tail both visible
    axes[0].legend(fontsize=7, loc="best")
    axes[1].set_xlabel("stride")
    axes[0].set_title(f"{run.path.name}: apex states per stride ({comparison.policy_name})")
    return _save(figure, path)


def return_map(comparison: Comparison, path: Path) -> Figure:
    """Cobweb of the recorded apex heights over the analytic closed-loop height map, the latter
    drawn on the energy level of the fixed point (the paper's 1-D energy-regulated map) if the
    comparison has a policy to close the loop with."""
    run = comparison.run
    params = run.params
    heights = run.apex_array()[:, 0]
    low, high = float(heights.min()), float(heights.max())
    margin = max(0.1 * (high - low), 0.02 * params.r0)
    y = np.linspace(low - margin, high + margin, MAP_CURVE_POINTS)
    scale = units.length_scale(params)
    figure = Figure(figsize=(6, 6))
    ax = figure.subplots()
    if comparison.ramp_policy is not None:
        fixed = comparison.analytic_fixed_point or comparison.recorded_fixed_point
        level = (
            params.m * (params.g * fixed.y + 0.5 * fixed.xdot**2)
            if fixed is not None
            else run.strides[-1].energy
        )
        xdot = speed_from_energy(params, y, level)
        with np.errstate(invalid="ignore"):
            mapped = closed_loop_step(params, comparison.ramp_policy, y, xdot, xdot)[:, 0]
        ax.plot(
            y / scale,
            mapped / scale,
            color=ANALYTIC[1],
            label=f"analytic map at Ebar = {units.energy_to_bar(params, level):.4f}",
        )
    ax.plot(y / scale, y / scale, color="grey", lw=1, label="y' = y")
    steps_x, steps_y = [heights[0]], [heights[0]]
    for before, after in zip(heights[:-1], heights[1:], strict=True):
        steps_x += [before, after]
        steps_y += [after, after]
    ax.plot(
        np.array(steps_x) / scale, np.array(steps_y) / scale, color=RECORDED, lw=1, label="recorded (cobweb)"
    )
    ax.plot(heights[:-1] / scale, heights[1:] / scale, "o", color=RECORDED, ms=3)
    ax.set_xlabel("apex height ybar_k")
    ax.set_ylabel("apex height ybar_k+1")
    ax.set_title(f"{run.path.name}: return map ({comparison.policy_name})")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return _save(figure, path)


def last_complete_stride(run: Run) -> int | None:
    """The latest stride whose next apex was recorded."""
    recorded = {s.stride for s in run.strides}
    complete = [s.stride for s in run.strides if s.stride + 1 in recorded]
    return complete[-1] if complete else None


def com_trajectory(run: Run, path: Path, stride: int | None = None) -> Figure:
    """Centre-of-mass path over one stride (apex k to apex k + 1; default the last complete one) with
    the ground reaction force direction through the COM in stance, down to its "virtual footfall"
    on the ground, and the actual toe (paper fig. 12). x is measured from the stride's toe."""
    stride = last_complete_stride(run) if stride is None else stride
    by_stride = {s.stride: s for s in run.strides}
    if stride is None or stride not in by_stride or stride + 1 not in by_stride:
        raise ValueError(f"stride {stride} is not a complete recorded stride")
    samples = run.samples
    start, end = by_stride[stride].t, by_stride[stride + 1].t
    window = (samples.t >= start) & (samples.t <= end)
    if not np.any(window):
        raise ValueError(f"no 1 kHz samples recorded in stride {stride}")
    stance = window & (samples.phase == 1)
    toe = float(samples.toe_x[stance][0]) if np.any(stance) else float(samples.x[window][0])
    force_index = np.searchsorted(samples.grf_t, samples.t[stance])
    force_index = np.clip(force_index, 0, max(len(samples.grf_t) - 1, 0))
    fx, fy = samples.grf_x[force_index], samples.grf_y[force_index]
    x, y = samples.x[stance] - toe, samples.y[stance]
    pushing = fy > 0.0  # a force line only reaches the ground while the leg pushes up
    footfall = x - y * np.divide(fx, fy, out=np.zeros_like(fx), where=pushing)
    drawn = np.flatnonzero(pushing)[::GRF_LINE_PERIOD]
    figure = Figure(figsize=(8, 4))
    ax = figure.subplots()
    for i in drawn:
        ax.plot([x[i], footfall[i]], [y[i], 0.0], color="tab:green", lw=0.8, alpha=0.8, gid=GRF_LINE_ID)
    ax.plot(footfall[drawn], np.zeros(len(drawn)), "|", color="tab:green", ms=8, label="virtual footfalls")
    ax.plot(samples.x[window] - toe, samples.y[window], color="black", lw=1.5, label="centre of mass")
    ax.plot([0.0], [0.0], "^", color="tab:red", ms=9, label="toe")
    ax.axhline(0.0, color="grey", lw=1)
    ax.set_aspect("equal")
    ax.set_xlabel("x - x_toe [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{run.path.name}: stride {stride}, COM and ground reaction force directions")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3)
    return _save(figure, path)


TERRAIN_POINTS = 4000
"""Points at which the terrain is drawn under a COM path."""
SATURATED = "tab:red"


def terrain_path(run: Run, path: Path) -> Figure:
    """Above, the centre of mass over the whole run and the ground; below, the ground magnified: the run's
    terrain, the ground height under the body the plant recorded (which must lie on it), the toe's landing
    points. Stances in which the hip saturated are drawn red, and a failure is marked where it happened."""
    samples = run.samples
    if len(samples) == 0:
        raise ValueError("no 1 kHz samples recorded: no path to draw")
    figure = Figure(figsize=(10, 6))
    body, ground = figure.subplots(2, 1, sharex=True, height_ratios=(2, 1))
    low, high = float(samples.x.min()), float(samples.x.max())
    margin = 0.02 * max(high - low, run.params.r0)
    x = np.linspace(low - margin, high + margin, TERRAIN_POINTS)
    terrain = run.perturbations.terrain.height(x)
    for ax in (body, ground):
        ax.fill_between(x, terrain, np.min(terrain) - 0.05 * run.params.r0, color="tan", alpha=0.6, lw=0)
        ax.plot(x, terrain, color="saddlebrown", lw=0.8, label=f"ground ({run.perturbations.terrain.kind})")
        ax.grid(alpha=0.3)
    body.plot(samples.x, samples.y, color="black", lw=1.2, label="centre of mass")
    saturated = {s.stride for s in run.strides if s.saturated}
    if saturated:
        inside = (samples.phase == 1) & np.isin(samples.stride, sorted(saturated))
        body.plot(
            np.where(inside, samples.x, np.nan),
            np.where(inside, samples.y, np.nan),
            color=SATURATED,
            lw=2.5,
            label=f"stance with the hip saturated ({len(saturated)})",
        )
    if run.outcome is not None and run.outcome.kind != "run_complete":
        body.plot(
            samples.x[-1], samples.y[-1], "X", color=SATURATED, ms=10, label=f"failure: {run.outcome.kind}"
        )
    ground.plot(
        samples.x, samples.ground_height, ".", color="tab:green", ms=1, label="recorded under the body"
    )
    touchdowns = [c for c in run.contacts if c.kind == "touchdown"]
    ground.plot(
        [c.state.toe_x for c in touchdowns],
        [c.state.toe_y for c in touchdowns],
        "^",
        color="tab:blue",
        ms=5,
        label="toe at touchdown",
    )
    span = max(float(np.ptp(terrain)), 1e-3 * run.params.r0)
    ground.set_ylim(float(np.min(terrain)) - 0.2 * span, float(np.max(terrain)) + 0.2 * span)
    body.set_ylabel("y [m]")
    ground.set_ylabel("ground [m]")
    ground.set_xlabel("x [m]")
    body.set_title(f"{run.path.name}: centre of mass over the ground ({len(run.strides)} apexes)")
    body.legend(fontsize=7, loc="lower right")
    ground.legend(fontsize=7, loc="lower right")
    return _save(figure, path)


def measured_apex(comparison: Comparison, path: Path) -> Figure:
    """Per stride: the true apex (height above the ground of the last stance, speed) against the apex the
    controller's sensor reported, and the strides in which the hip saturated (shaded)."""
    run = comparison.run
    params = run.params
    strides = np.array([s.stride for s in run.strides])
    true = dimensionless(params, run.apex_array())
    measured = dimensionless(
        params, np.array([(s.measured_y - s.ground, s.measured_xdot) for s in run.strides]).reshape(-1, 2)
    )
    figure = Figure(figsize=(8, 6))
    axes = figure.subplots(2, 1, sharex=True)
    labels = ("apex height above ground ybar", "apex speed xdotbar")
    saturated = [s.stride for s in run.strides if s.saturated]
    for column, ax in enumerate(axes):
        ax.plot(strides, true[:, column], "o-", color=RECORDED, ms=3, label="true")
        ax.plot(
            strides, measured[:, column], "x", color="tab:orange", ms=5, label="measured (the controller's)"
        )
        for index, stride in enumerate(saturated):
            ax.axvspan(
                stride - 0.5,
                stride + 0.5,
                color=SATURATED,
                alpha=0.15,
                lw=0,
                label="hip saturated" if index == 0 else None,
            )
        ax.set_ylabel(labels[column])
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    axes[1].set_xlabel("stride")
    axes[0].set_title(f"{run.path.name}: true and measured apexes")
    return _save(figure, path)


def energy_flows(comparison: Comparison, path: Path) -> Figure:
    """Recorded hip work (input) against damping and leftover-spring losses per stride (filled steps,
    one artist per series whatever the number of strides), the net apex energy change, and the
    analytic map's predictions of input and loss (1 correction)."""
    run, predictions = comparison.run, comparison.predictions
    params = run.params
    complete = [s for s in run.strides if np.isfinite(s.hip_work)]
    if not complete:
        raise ValueError("no complete stride: no energy flows recorded")
    k = np.array([s.stride for s in complete])
    hip = units.energy_to_bar(params, np.array([s.hip_work for s in complete]))
    damping = units.energy_to_bar(params, np.array([s.damping_loss for s in complete]))
    spring = units.energy_to_bar(params, np.array([s.spring_loss for s in complete]))
    figure = Figure(figsize=(8, 4.5))
    ax = figure.subplots()
    edges = np.append(k, k[-1] + 1) - 0.5
    ax.stairs(hip, edges, fill=True, color="tab:green", label="hip work (input)")
    ax.stairs(-damping, edges, fill=True, color="tab:purple", label="damping loss")
    ax.stairs(
        -damping - spring,
        edges,
        baseline=-damping,
        fill=True,
        color="tab:pink",
        label="spring energy left at liftoff",
    )
    ax.plot(k, hip - damping - spring, "k.-", lw=1, ms=4, label="net apex energy change")
    predicted = units.energy_to_bar(params, predictions.analytic_energy[1])
    ax.plot(predictions.stride, predicted[:, 0], "_", color=ANALYTIC[1], ms=10, mew=2, label="analytic input")
    ax.plot(
        predictions.stride,
        -(predicted[:, 1] + predicted[:, 2]),
        "_",
        color="tab:brown",
        ms=10,
        mew=2,
        label="analytic loss",
    )
    ax.axhline(0.0, color="grey", lw=1)
    ax.set_xlabel("stride")
    ax.set_ylabel("energy per stride Ebar")
    ax.set_title(f"{run.path.name}: energy input and losses per stride")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3, axis="y")
    return _save(figure, path)


def body_pitch(comparison: Comparison, path: Path) -> Figure:
    """A rigid body's pitch and pitch rate at each apex: recorded, and each stride's stance replayed on the
    exact map from the recorded apex before it (stance feedback; a ramp stride has no pitch prediction
    drawn), with the body's tip limit."""
    run, replay = comparison.run, comparison.stance_feedback
    body = run.params.body
    if body is None:
        raise ValueError("the fixed body has no pitch to draw")
    strides = np.array([s.stride for s in run.strides])
    recorded = np.array([(s.pitch, s.pitch_rate) for s in run.strides]).reshape(-1, 2)
    figure = Figure(figsize=(8, 5))
    axes = figure.subplots(2, 1, sharex=True)
    for column, (ax, label) in enumerate(zip(axes, ("pitch [rad]", "pitch rate [rad/s]"), strict=True)):
        ax.plot(strides, recorded[:, column], "o-", color=RECORDED, ms=3, label="recorded")
        ax.plot(replay.stride + 1, replay.exact_pitch[:, column], "x", color=EXACT, ms=5, label="exact map")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for limit in (-body.tip_limit, body.tip_limit):
        axes[0].axhline(limit, color="tab:red", ls="--", lw=1, label="tip limit" if limit > 0 else None)
    axes[0].legend(fontsize=7, loc="best")
    axes[1].set_xlabel("stride")
    axes[0].set_title(f"{run.path.name}: the body's pitch at each apex ({comparison.policy_name})")
    return _save(figure, path)
