"""The report of an identification (:mod:`.identification`): summary.json, report.md and three figures.

* ``stance_fit.png``: each stance's measured and fitted force along the leg (force balance) or body height
  (exact stance) over the time since touchdown, under the identified hopper;
* ``residuals.png``: measured minus fitted, every stance;
* ``estimates.png``: k, c and r0 from each stance alone over the run's time, with the pooled estimate and its
  interval (drift shows as a trend).

Figures follow :mod:`tdslip_ros.reporting.style`; the JSON is strict (:func:`.reporting.output.to_json`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only

import numpy as np
from matplotlib.figure import Figure

from tdslip_ros.analysis.identification import (
    CONFIDENCE,
    FORCE_BALANCE,
    IdentificationResult,
    StanceData,
    stance_curves,
)
from tdslip_ros.reporting.output import to_json
from tdslip_ros.reporting.style import save_figure

PARAMETER_UNITS = {"k": "N/m", "c": "N s/m", "r0": "m", "m": "kg"}
"""The unit of each parameter an identification estimates."""
MAX_DRAWN_STANCES = 24
"""Stances drawn in stance_fit.png, evenly over the run (a long recording has thousands)."""
JSON_KEYS = {"k": "k_N_per_m", "c": "c_N_s_per_m", "r0": "r0_m", "m": "m_kg"}


def summary(result: IdentificationResult) -> dict[str, Any]:
    """JSON-ready account of ``result``: status, method, estimates with intervals, per-stance values."""
    return {
        "status": result.status,
        "message": result.message,
        "method": result.method,
        "confidence": CONFIDENCE,
        "condition_number": result.condition_number,
        "unidentified": list(result.unidentified),
        "estimates": {
            JSON_KEYS[name]: {"value": e.value, "stderr": e.stderr, "interval": [e.low, e.high]}
            for name, e in result.estimates.items()
        },
        "drift": {
            JSON_KEYS[name]: {"slope_per_s": d.slope, "t": d.t, "change": d.change, "drifts": d.drifts}
            for name, d in result.drift.items()
        },
        "stances": [
            {
                "stride": fit.stride,
                "time_s": fit.time,
                **{JSON_KEYS[name]: value for name, value in fit.values.items()},
                "residual_rms": fit.rms,
                "tau0_N_m": fit.ramp.tau0,
                "t_f_s": fit.ramp.t_f,
            }
            for fit in result.stances
        ],
        "set_aside": [{"stride": stride, "reason": reason} for stride, reason in result.set_aside],
        "residual_rms": result.residual_rms,
    }


def estimate_lines(result: IdentificationResult) -> list[str]:
    """One line per estimate: value, standard error and interval, in SI."""
    return [
        f"{name:<3} = {e.value:.6g} {PARAMETER_UNITS[name]} (std. err. {e.stderr:.3g}; "
        f"{CONFIDENCE:.0%} interval [{e.low:.6g}, {e.high:.6g}])"
        for name, e in result.estimates.items()
    ]


def _stance_figure(result: IdentificationResult, stances: list[StanceData], path: Path) -> Figure:
    assert result.params is not None
    force = result.method == FORCE_BALANCE
    figure = Figure(figsize=(10, 4))
    fit_axes, residual_axes = figure.subplots(1, 2)
    drawn = np.unique(np.linspace(0, len(stances) - 1, min(len(stances), MAX_DRAWN_STANCES)).astype(int))
    for index in drawn:
        data, fit = stances[index], result.stances[index]
        measured, fitted = stance_curves(result.params, result.method, data, fit)
        (line,) = fit_axes.plot(data.s, measured, ".", markersize=2)
        fit_axes.plot(data.s, fitted, "-", color=line.get_color(), linewidth=1)
        residual_axes.plot(data.s, measured - fitted, ".", markersize=2, color=line.get_color())
    label = "force along the leg [N]" if force else "body height [m]"
    fit_axes.set(
        xlabel="time since touchdown [s]", ylabel=label, title=f"measured (dots) and fitted ({result.method})"
    )
    residual_axes.set(
        xlabel="time since touchdown [s]", ylabel=f"residual, {label}", title="residuals per stance"
    )
    save_figure(figure, path)
    return figure


def _estimates_figure(result: IdentificationResult, path: Path) -> Figure:
    figure = Figure(figsize=(10, 3.5))
    times = np.array([fit.time for fit in result.stances])
    for axes, name in zip(figure.subplots(1, 3), ("k", "c", "r0"), strict=True):
        estimate = result.estimates[name]
        axes.axhspan(estimate.low, estimate.high, color="0.85", label=f"pooled, {CONFIDENCE:.0%} interval")
        axes.axhline(estimate.value, color="black", linewidth=1)
        axes.plot(times, [fit.values[name] for fit in result.stances], "o", markersize=3, label="one stance")
        drift = " (drifts)" if result.drift[name].drifts else ""
        axes.set(
            xlabel="time [s]", ylabel=f"{name} [{PARAMETER_UNITS[name]}]", title=f"{name} per stance{drift}"
        )
    figure.axes[0].legend(fontsize="small")
    save_figure(figure, path)
    return figure


def write_report(
    result: IdentificationResult, stances: list[StanceData], out: Path, source: str
) -> dict[str, Path]:
    """Write the report of a successful ``result`` into the directory ``out`` (which exists); ``stances`` are
    the stance samples it was fitted on, in its order; ``source`` names the recording. Returns the files."""
    files = {
        "summary": out / "summary.json",
        "report": out / "report.md",
        "stance_fit": out / "stance_fit.png",
        "estimates": out / "estimates.png",
    }
    files["summary"].write_text(to_json({"recording": source, **summary(result)}))
    for draw, name in ((_stance_figure, "stance_fit"), (_estimates_figure, "estimates")):
        figure = draw(result, stances, files[name]) if draw is _stance_figure else draw(result, files[name])
        figure.clear()
    drifting = [name for name, drift in result.drift.items() if drift.drifts]
    lines = [
        f"# Hopper identified from {source}",
        "",
        result.message,
        "",
        *(f"- {line}" for line in estimate_lines(result)),
        "",
        f"Residual rms over all stances: {result.residual_rms:.4g} "
        f"{'N' if result.method == FORCE_BALANCE else 'm'}; stances set aside: {len(result.set_aside)}.",
        f"Drift across the run: {', '.join(drifting) if drifting else 'none'}.",
        "",
        "![measured and fitted over each stance, and the residuals](stance_fit.png)",
        "",
        "![the estimates of each stance alone](estimates.png)",
        "",
    ]
    files["report"].write_text("\n".join(lines))
    return files
