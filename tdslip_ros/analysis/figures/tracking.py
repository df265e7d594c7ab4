"""fig13 (section V): the deadbeat controller against the PD baseline on the exact plant, tracking desired
speeds from one apex, and deadbeat towards an apex below r0."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from tdslip_ros.analysis.figures.common import PARAMS, FigureData, Reporter, Resolution
from tdslip_ros.model import basins, units
from tdslip_ros.model.analytic import SpeedSource
from tdslip_ros.model.arrays import Array, CommandArrays
from tdslip_ros.model.controllers import apex_foot_placement, deadbeat
from tdslip_ros.model.params import HopperParams
from tdslip_ros.reporting.style import CONTROLLER_STYLE


def track_targets(
    params: HopperParams,
    controller: str,
    target_y: float,
    target_speeds: Array,
    start: tuple[float, float],
    strides: int,
    progress: basins.Progress | None = None,
    speed: SpeedSource = "energy",
) -> basins.Basin:
    """Exact-plant runs from ``start`` (y [m], xdot [m/s]) towards (target_y, each target speed) [m, m/s]
    under ``controller`` ("deadbeat" or "apex_foot_placement", its default gains, planning on the analytic map
    with the next-apex ``speed``), one lane per target speed."""
    speeds = np.asarray(target_speeds, dtype=float)
    previous = np.full(speeds.shape, start[1])

    def policy(stride: int, y: Array, xdot: Array, lanes: Array) -> CommandArrays:
        if controller == "deadbeat":
            return deadbeat(params, y, xdot, target_y, speeds[lanes], speed=speed)
        command = apex_foot_placement(params, y, xdot, previous[lanes], target_y, speeds[lanes], speed=speed)
        previous[lanes] = xdot
        return command

    y0 = np.full(speeds.shape, start[0])
    energy0 = params.m * (params.g * y0 + 0.5 * start[1] ** 2)
    return basins.basin(params, y0, energy0, policy, strides, progress)


EDGE_HEIGHT, EDGE_SPEEDS, EDGE_STRIDES = 0.95, (1.5, 2.0, 2.5, 3.0, 3.5), 20
"""Deadbeat towards an apex below r0 (m, m/s, strides): the edges of leg placement and of the fall."""


def fig13(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    speeds_bar = np.round(np.arange(0.5, 3.0 + 1e-9, resolution.speed_step), 3)
    target_y, start = 1.0, (1.0, 5.0)
    speeds = np.asarray(units.speed_from_bar(PARAMS, speeds_bar))
    figure = Figure(figsize=(7, 6.5))
    top, bottom = figure.subplots(2, 1, sharex=True)
    data: dict[str, Any] = {
        "target_ybar": target_y,
        "start": {"ybar": start[0], "xdotbar": float(units.speed_to_bar(PARAMS, start[1]))},
        "strides": basins.REGULATED_STRIDES,
        "xdotbar_target": speeds_bar.tolist(),
    }
    for controller, (colour, style) in CONTROLLER_STYLE.items():
        run = track_targets(
            PARAMS,
            controller,
            target_y,
            speeds,
            start,
            basins.REGULATED_STRIDES,
            reporter.strides(controller),
            speed,
        )
        final_y, final_xdot = run.history.y[-1], run.history.xdot[-1]
        speed_error = 100.0 * (final_xdot - speeds) / speeds
        height_error = 100.0 * (final_y - target_y) / target_y
        stable = run.outcome == basins.CONVERGED
        for axes, error in ((top, speed_error), (bottom, height_error)):
            axes.plot(
                speeds_bar[stable], np.abs(error[stable]), style, color=colour, marker=".", label=controller
            )
            # Losses of stability as crosses along the bottom of the (log) axes.
            bottom_edge = np.full(np.sum(~stable), 0.04 if controller == "deadbeat" else 0.1)
            axes.plot(
                speeds_bar[~stable],
                bottom_edge,
                "x",
                color=colour,
                markersize=9,
                mew=2,
                transform=axes.get_xaxis_transform(),
            )
        data[controller] = {
            "outcome": [basins.OUTCOMES[o] for o in run.outcome],
            "stable": stable.tolist(),
            "convergence_stride": run.convergence_stride.tolist(),
            "speed_error_percent": speed_error.tolist(),
            "height_error_percent": height_error.tolist(),
            "stable_xdotbar_range": [float(speeds_bar[stable].min()), float(speeds_bar[stable].max())]
            if stable.any()
            else None,
        }
    reporter.stage(f"deadbeat towards y* = {EDGE_HEIGHT} m, below r0 (the edge of leg placement)")
    edge = track_targets(
        PARAMS, "deadbeat", EDGE_HEIGHT, np.array(EDGE_SPEEDS), start, EDGE_STRIDES, speed=speed
    )
    data["edge"] = {
        "target_y": EDGE_HEIGHT,
        "target_xdot": list(EDGE_SPEEDS),
        "strides": EDGE_STRIDES,
        "outcome": [basins.OUTCOMES[o] for o in edge.history.outcome],
        "failure_stride": edge.history.failure_stride.tolist(),
        "last_y": edge.history.y[-1].tolist(),
        "last_xdot": edge.history.xdot[-1].tolist(),
    }
    top.set(ylabel="|speed error| [%]", yscale="log", title="deadbeat vs PD, 50 strides (x: loses stability)")
    bottom.set(xlabel="xdotbar*", ylabel="|height error| [%]", yscale="log")
    top.legend(fontsize=8)
    return figure, data
