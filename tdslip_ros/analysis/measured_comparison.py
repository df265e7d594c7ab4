"""A recording this suite did not write, against the return maps: ``tdslip analyze BAG --topic-map MAP``.

From each usable stride (:mod:`.stride_detection`) the recorded apex and the command inferred from the data
give the next apex as the analytic map predicts it (ours, from the energy balance, and the paper's, from
eq. 7's liftoff velocity; one correction iteration) and as the exact map does
(:func:`~tdslip_ros.model.plant.batch.batch_apex_return_map`); the errors are those of the suite's own
analysis (:func:`.compare.error_stats`, dimensionless), as are the convergence and the fixed point fitted to
the recorded apexes (:func:`.compare.convergence`).

The command is inferred, and the report says how: the touchdown angle from the leg's geometry at touchdown;
the ramp (tau0, t_f) fitted by least squares to the measured hip torque over the stance
(tau0 (1 - s/t_f) for s < t_f, 0 after), or zero where no torque is recorded. The ground of each stance is
the toe's median height in it (the leg's geometry), else 0 in the map's frame. The hopper is the caller's
(:class:`~tdslip_ros.model.params.HopperParams`) and named in the report.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from tdslip_ros.analysis.compare import (
    CORRECTIONS,
    ErrorStats,
    FixedPoint,
    convergence,
    error_stats,
    error_summary,
)
from tdslip_ros.analysis.measured import FloatArray, MeasuredRun, MeasuredStride
from tdslip_ros.analysis.stride_detection import stance_signal
from tdslip_ros.model.analytic.apex_map import ANALYTIC_MAPS, approximate_map
from tdslip_ros.model.arrays import CommandArrays
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.plant.batch import batch_apex_return_map
from tdslip_ros.reporting.output import to_json, unit_key

PREDICTORS = (*ANALYTIC_MAPS, "exact")
"""The predictions compared: each analytic map by name (ours, paper) and the exact map."""


@dataclass(frozen=True)
class Ramp:
    """A ramp torque tau0 (1 - s/t_f) fitted to a stance's measured torque, and its RMS residual [N m]."""

    tau0: float
    t_f: float
    residual: float


def fit_ramp(since_touchdown: FloatArray, torque: FloatArray, stance_time: float) -> Ramp:
    """The least-squares ramp through the samples (s [s] after touchdown, torque [N m]) of one stance:
    for a given t_f the best tau0 is linear; t_f is searched on (0, 4 stance_time]."""

    def best(t_f: float) -> tuple[float, float]:
        shape = np.maximum(1.0 - since_touchdown / t_f, 0.0)
        norm = float(shape @ shape)
        tau0 = float(shape @ torque) / norm if norm > 0.0 else 0.0
        return tau0, float(np.sqrt(np.mean((torque - tau0 * shape) ** 2)))

    if not np.any(torque):
        return Ramp(0.0, stance_time, 0.0)
    grid = np.linspace(stance_time / 50.0, 4.0 * stance_time, 200)
    start = grid[int(np.argmin([best(t)[1] for t in grid]))]
    step = grid[1] - grid[0]
    found = minimize_scalar(
        lambda t: best(t)[1],
        bounds=(max(start - step, grid[0] / 2), start + step),
        method="bounded",
        options={"xatol": 1e-12},
    )
    tau0, residual = best(float(found.x))
    return Ramp(tau0, float(found.x), residual)


@dataclass(frozen=True)
class MeasuredComparison:
    """The usable strides' recorded apexes, inferred commands and predicted next apexes (rows by stride)."""

    params: HopperParams
    hopper_source: str
    strides: tuple[MeasuredStride, ...]
    used: tuple[int, ...]
    """Indices into ``strides`` of the strides compared (the usable ones)."""
    ground: FloatArray
    apex: FloatArray
    next_apex: FloatArray
    command: FloatArray
    """(n, 3): touchdown angle [rad], tau0 [N m], t_f [s]."""
    torque_residual: FloatArray
    predicted: dict[str, FloatArray]
    errors: dict[str, ErrorStats]
    converged_at: int | None
    fixed_point: FixedPoint | None
    measured: tuple[tuple[str, str], ...]
    inferred: tuple[tuple[str, str], ...]


def _at(time: FloatArray, values: FloatArray, when: float) -> float:
    return float(np.interp(when, time, values))


def compare_measured(
    run: MeasuredRun,
    strides: list[MeasuredStride],
    params: HopperParams,
    hopper_source: str,
    rest_length: float | None = None,
) -> MeasuredComparison:
    """Predict each usable stride of ``run`` (module docstring) with the hopper ``params``."""
    time = run.time
    used = tuple(i for i, stride in enumerate(strides) if stride.usable)
    rows = [strides[i] for i in used]
    ground, apex, next_apex, command, residual = [], [], [], [], []
    for stride in rows:
        stance = slice(stride.touchdown_index + 1, stride.liftoff_index + 1)
        if run.leg_length is not None and run.leg_angle is not None:
            toe_height = run.body_position[stance, 1] - run.leg_length[stance] * np.cos(run.leg_angle[stance])
            ground.append(float(np.median(toe_height)))
        else:
            ground.append(0.0)
        for when, into in ((stride.apex_time, apex), (stride.next_apex_time, next_apex)):
            into.append((_at(time, run.body_position[:, 1], when), _at(time, run.body_velocity[:, 0], when)))
        stance_time = stride.liftoff_time - stride.touchdown_time
        if run.hip_torque is None:
            ramp = Ramp(0.0, stance_time, math.nan)
        else:
            ramp = fit_ramp(time[stance] - stride.touchdown_time, run.hip_torque[stance], stance_time)
        command.append((stride.touchdown_angle, ramp.tau0, ramp.t_f))
        residual.append(ramp.residual)
    g = np.array(ground)
    apexes, nexts = np.array(apex).reshape(-1, 2), np.array(next_apex).reshape(-1, 2)
    commands = np.array(command).reshape(-1, 3)
    arrays = CommandArrays(commands[:, 0], commands[:, 1], commands[:, 2])
    predicted: dict[str, FloatArray] = {}
    for name, speed in ANALYTIC_MAPS.items():
        result = approximate_map(params, apexes[:, 0] - g, apexes[:, 1], arrays, CORRECTIONS[-1], speed=speed)
        predicted[name] = np.stack([g + result.y, result.xdot], axis=-1).reshape(-1, 2)
    if len(rows):
        exact = batch_apex_return_map(params, apexes[:, 0] - g, apexes[:, 1], *arrays)
        predicted["exact"] = np.stack([g + exact.y, exact.xdot], axis=-1)
    else:
        predicted["exact"] = np.empty((0, 2))
    # The apexes in order, above the ground of the stance before each (strides set aside break the sequence).
    sequence = np.stack(
        [np.append(apexes[:, 0] - g, nexts[-1:, 0] - g[-1:]), np.append(apexes[:, 1], nexts[-1:, 1])], -1
    )
    converged_at, fixed = convergence(params, sequence) if len(rows) > 2 else (None, None)
    measured = tuple((name, source) for name, source in run.sources if not source.startswith("inferred"))
    inferred = [
        (name, source.removeprefix("inferred: "))
        for name, source in run.sources
        if name not in dict(measured)
    ]
    inferred.append(("stance", f"from {stance_signal(run, rest_length).how}"))
    inferred.append(("touchdown_angle", "from the leg's geometry at touchdown"))
    inferred.append(
        ("ramp_torque", "fitted to the measured hip torque by least squares")
        if run.hip_torque is not None
        else ("ramp_torque", "zero: the map gives no hip torque")
    )
    inferred.append(
        ("ground", "the toe's median height in each stance")
        if run.leg_length is not None
        else ("ground", "0 in the map's frame")
    )
    return MeasuredComparison(
        params=params,
        hopper_source=hopper_source,
        strides=tuple(strides),
        used=used,
        ground=g,
        apex=apexes,
        next_apex=nexts,
        command=commands,
        torque_residual=np.array(residual),
        predicted=predicted,
        errors={name: error_stats(params, predicted[name], nexts) for name in PREDICTORS},
        converged_at=converged_at,
        fixed_point=fixed,
        measured=measured,
        inferred=tuple(inferred),
    )


def apex_energy(params: HopperParams, height: FloatArray, speed: FloatArray) -> FloatArray:
    """m g h + m xdot^2 / 2 [J] at apexes ``height`` above the ground."""
    return params.m * (params.g * height + 0.5 * speed**2)


def measured_summary(comparison: MeasuredComparison) -> dict[str, Any]:
    """The JSON summary: hopper, sources, each stride (those set aside with their reason), errors, fixed
    point."""
    c = comparison
    heights = c.apex[:, 0] - c.ground
    energy = apex_energy(c.params, heights, c.apex[:, 1])
    next_energy = apex_energy(c.params, c.next_apex[:, 0] - c.ground, c.next_apex[:, 1])
    rows: list[dict[str, Any]] = []
    for row, index in enumerate(c.used):
        stride = c.strides[index]
        rows.append(
            {
                "apex_time_s": stride.apex_time,
                "apex_height_m": float(heights[row]),
                "apex_speed_m_per_s": float(c.apex[row, 1]),
                "touchdown_angle_rad": float(c.command[row, 0]),
                unit_key("tau0", "N m"): float(c.command[row, 1]),
                "t_f_s": float(c.command[row, 2]),
                unit_key("torque_fit_rms", "N m"): float(c.torque_residual[row]),
                unit_key("energy", "J"): float(energy[row]),
                unit_key("energy_change", "J"): float(next_energy[row] - energy[row]),
                "next_apex_height_m": float(c.next_apex[row, 0] - c.ground[row]),
                "next_apex_speed_m_per_s": float(c.next_apex[row, 1]),
                **{
                    f"predicted_{name}_height_m": float(c.predicted[name][row, 0] - c.ground[row])
                    for name in PREDICTORS
                },
                **{
                    f"predicted_{name}_speed_m_per_s": float(c.predicted[name][row, 1]) for name in PREDICTORS
                },
            }
        )
    return {
        "hopper": {
            "source": c.hopper_source,
            "m_kg": c.params.m,
            "k_N_per_m": c.params.k,
            "r0_m": c.params.r0,
            "c_N_s_per_m": c.params.c,
        },
        "measured": dict(c.measured),
        "inferred": dict(c.inferred),
        "strides_found": len(c.strides),
        "strides_compared": len(c.used),
        "set_aside": [{"apex_time_s": s.apex_time, "reason": s.reason} for s in c.strides if not s.usable],
        "strides": rows,
        "errors": {name: error_summary(stats) for name, stats in c.errors.items()},
        "converged_at_stride": c.converged_at,
        "fixed_point": None
        if c.fixed_point is None
        else {
            "y_m": c.fixed_point.y,
            "xdot_m_per_s": c.fixed_point.xdot,
            "eigenvalue_moduli_factor": [abs(v) for v in c.fixed_point.eigenvalues],
        },
    }


def measured_headline(comparison: MeasuredComparison) -> str:
    """One line: strides compared, and each predictor's mean dimensionless errors."""
    parts = [
        f"{name}: height {stats.mean_height:.3g}, speed {stats.mean_speed:.3g}"
        for name, stats in comparison.errors.items()
    ]
    return (
        f"{len(comparison.used)} of {len(comparison.strides)} strides compared; mean next-apex errors "
        f"(dimensionless) {'; '.join(parts)}"
    )


def measured_markdown(summary: dict[str, Any]) -> str:
    """The report, from the summary."""
    hopper = summary["hopper"]
    lines = [
        "# A recording against the return maps",
        "",
        f"Hopper: {hopper['source']} (m = {hopper['m_kg']:g} kg, k = {hopper['k_N_per_m']:g} N/m, "
        f"r0 = {hopper['r0_m']:g} m, c = {hopper['c_N_s_per_m']:g} N s/m).",
        "",
        "## What was measured and what was inferred",
        "",
        *(f"- measured: {name} ({source})" for name, source in summary["measured"].items()),
        *(f"- inferred: {name}, {how}" for name, how in summary["inferred"].items()),
        "",
        f"## Strides: {summary['strides_compared']} compared of {summary['strides_found']} found",
        "",
        *(f"- set aside, apex at {s['apex_time_s']:.4f} s: {s['reason']}" for s in summary["set_aside"]),
        "",
        "| apex [s] | height [m] | speed [m/s] | angle [rad] | tau0 [N m] | t_f [s] | energy [J] "
        "| change [J] |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
        *(
            f"| {r['apex_time_s']:.4f} | {r['apex_height_m']:.4f} | {r['apex_speed_m_per_s']:.4f} | "
            f"{r['touchdown_angle_rad']:.4f} | {r['tau0_N_m']:.2f} | {r['t_f_s']:.4f} | "
            f"{r['energy_J']:.1f} | {r['energy_change_J']:.2f} |"
            for r in summary["strides"]
        ),
        "",
        "## Next-apex errors (dimensionless: height / r0, speed / sqrt(g r0))",
        "",
        "| map | strides | mean height | max height | mean speed | max speed |",
        "| --- | --- | --- | --- | --- | --- |",
        *(
            f"| {name} | {e['strides']} | {e['mean_error_ybar']:.3g} | {e['max_error_ybar']:.3g} | "
            f"{e['mean_error_xdotbar']:.3g} | {e['max_error_xdotbar']:.3g} |"
            for name, e in summary["errors"].items()
        ),
        "",
    ]
    fixed = summary["fixed_point"]
    if fixed is None:
        lines.append("The recorded apexes did not converge to a fixed point.")
    else:
        lines.append(
            f"Converged from stride {summary['converged_at_stride']} to the fixed point "
            f"y = {fixed['y_m']:.4f} m, xdot = {fixed['xdot_m_per_s']:.4f} m/s."
        )
    return "\n".join(lines) + "\n"


def write_measured_report(comparison: MeasuredComparison, out: Path) -> dict[str, Path]:
    """summary.json and report.md in ``out`` (which exists)."""
    summary = measured_summary(comparison)
    files = {"summary": out / "summary.json", "report": out / "report.md"}
    files["summary"].write_text(to_json(summary))
    files["report"].write_text(measured_markdown(summary))
    return files
