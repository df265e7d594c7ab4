"""fig13 (section V.B): the deadbeat controller against the baseline of the paper's ref. 36 on the exact
plant, tracking desired speeds from one apex, and deadbeat towards an apex below r0.

Both hop 50 strides per target speed from the same apex towards (target_y, xdot*). Deadbeat plans a ramp at
each apex on the analytic map (:func:`deadbeat_runs`). The baseline decides the hip torque during stance,
:class:`~tdslip_ros.model.policies.stance_pd.StancePDSpeedEnergy` (an energy term for the height, PD on the
forward speed, its default gains) sampled at 1 kHz on the batched engine, at one touchdown angle per target
speed: the angle at which one stride from the target apex ends at the target speed
(:func:`~tdslip_ros.model.stability.basins.speed_matching_angle`; the paper gives no rule, see docs/paper.md,
"The baseline of ref. 36"). The baseline plans on no analytic map, so ``--map`` changes deadbeat's runs alone.
A target loses stability where the runs fail, or do not converge (apex changes below 1e-4) within the 50
strides; for the baseline also where no angle matches its speed.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from matplotlib.figure import Figure

from tdslip_ros.analysis.figures.common import PARAMS, FigureData, Reporter, Resolution
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import SpeedSource
from tdslip_ros.model.arrays import Array, CommandArrays
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.policies.controllers import deadbeat
from tdslip_ros.model.policies.stance_pd import StancePDSpeedEnergy
from tdslip_ros.model.stability import basins
from tdslip_ros.reporting.style import CONTROLLER_STYLE

BASELINE = "stance_pd_speed_energy"
"""The name of ref. 36's baseline in the figure and its document (its law's)."""
TARGET_HEIGHT, START = 1.0, (1.0, 5.0)
"""m; (m, m/s): the target height and the apex every run starts from."""
SPEEDS_BAR = (0.25, 3.5)
"""The desired speeds xdotbar* (the paper's axis is not in its text): from where the baseline's angle rule
finds no angle to the last speed before both fail, measured on a grid to 4.5 when this one was chosen (at
3.75, deadbeat at the plant's state limit, the baseline by toe stubbing)."""


def deadbeat_runs(
    params: HopperParams,
    target_y: float,
    target_speeds: Array,
    start: tuple[float, float],
    strides: int,
    progress: basins.Progress | None = None,
    speed: SpeedSource = "energy",
) -> basins.Basin:
    """Exact-plant runs from ``start`` (y [m], xdot [m/s]) towards (target_y, each target speed) [m, m/s]
    under deadbeat, planning on the analytic map with the next-apex ``speed``, one lane per target speed."""
    speeds = np.asarray(target_speeds, dtype=float)

    def policy(stride: int, y: Array, xdot: Array, lanes: Array) -> CommandArrays:
        return deadbeat(params, y, xdot, target_y, speeds[lanes], speed=speed)

    y0 = np.full(speeds.shape, start[0])
    energy0 = params.m * (params.g * y0 + 0.5 * start[1] ** 2)
    return basins.basin(params, y0, energy0, policy, strides, progress)


def baseline_law(params: HopperParams, target_y: float, target_speeds: Array) -> basins.LawOf:
    """Ref. 36's baseline towards (target_y [m], each target speed [m/s]), for the lanes of those speeds."""

    def law_of(index: npt.NDArray[np.int64]) -> StancePDSpeedEnergy:
        return StancePDSpeedEnergy(params, target_y, target_speeds[index])

    return law_of


def baseline_touchdown_angles(params: HopperParams, target_y: float, target_speeds: Array) -> Array:
    """The baseline's touchdown angle [rad] per target speed [m/s] towards target_y [m] (NaN: none), by the
    rule of :func:`~tdslip_ros.model.stability.basins.speed_matching_angle`; ``tdslip compare`` runs it by
    this rule."""
    speeds = np.asarray(target_speeds, dtype=float)
    law_of = baseline_law(params, target_y, speeds)
    return basins.speed_matching_angle(params, np.full(speeds.shape, target_y), speeds, law_of)


def _tracked(run: basins.Basin, speeds_bar: Array, speeds: Array, target_y: float) -> dict[str, Any]:
    """A controller's runs in the document: outcomes, final apexes' errors [%] and its stable range."""
    stable = run.outcome == basins.CONVERGED
    final_y, final_xdot = run.history.y[-1], run.history.xdot[-1]
    return {
        "outcome": [basins.OUTCOMES[o] for o in run.outcome],
        "stable": stable.tolist(),
        "convergence_stride": run.convergence_stride.tolist(),
        "failure_stride": run.history.failure_stride.tolist(),
        "speed_error_percent": (100.0 * (final_xdot - speeds) / speeds).tolist(),
        "height_error_percent": (100.0 * (final_y - target_y) / target_y).tolist(),
        "stable_xdotbar_range": [float(speeds_bar[stable].min()), float(speeds_bar[stable].max())]
        if stable.any()
        else None,
    }


EDGE_HEIGHT, EDGE_SPEEDS, EDGE_STRIDES = 0.95, (1.5, 2.0, 2.5, 3.0, 3.5), 20
"""Deadbeat towards an apex below r0 (m, m/s, strides): the edges of leg placement and of the fall."""


def fig13(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    speeds_bar = np.round(np.arange(SPEEDS_BAR[0], SPEEDS_BAR[1] + 1e-9, resolution.speed_step), 3)
    speeds = np.asarray(units.speed_from_bar(PARAMS, speeds_bar))
    strides = basins.REGULATED_STRIDES
    data: dict[str, Any] = {
        "target_ybar": float(units.height_to_bar(PARAMS, TARGET_HEIGHT)),
        "start": {"ybar": START[0], "xdotbar": float(units.speed_to_bar(PARAMS, START[1]))},
        "strides": strides,
        "xdotbar_target": speeds_bar.tolist(),
        "baseline": BASELINE,
    }
    runs = {
        "deadbeat": deadbeat_runs(
            PARAMS, TARGET_HEIGHT, speeds, START, strides, reporter.strides("deadbeat"), speed
        )
    }
    reporter.stage(f"{BASELINE}: the touchdown angle of each target speed")
    angle = baseline_touchdown_angles(PARAMS, TARGET_HEIGHT, speeds)
    reporter.stage(f"{BASELINE}: {strides} strides at 1 kHz")
    law_of = baseline_law(PARAMS, TARGET_HEIGHT, speeds)
    runs[BASELINE] = basins.feedback_basin(PARAMS, START[0], START[1], angle, law_of, strides)
    for name, run in runs.items():
        data[name] = _tracked(run, speeds_bar, speeds, TARGET_HEIGHT)
    history = runs[BASELINE].history
    assert history.t is not None  # a feedback run keeps its apex times
    data[BASELINE] |= {
        "touchdown_angle_rad": angle.tolist(),
        # The last stride's apexes (SI; apex times on the 1 kHz sample clock): it replays on the exact map.
        "last_apexes": {
            "y_m": history.y[-2:].T.tolist(),
            "xdot_m_per_s": history.xdot[-2:].T.tolist(),
            "t_s": history.t[-2:].T.tolist(),
        },
    }
    figure = _draw(speeds_bar, data)
    reporter.stage(f"deadbeat towards y* = {EDGE_HEIGHT} m, below r0 (the edge of leg placement)")
    edge = deadbeat_runs(PARAMS, EDGE_HEIGHT, np.array(EDGE_SPEEDS), START, EDGE_STRIDES, speed=speed)
    data["edge"] = {
        "target_y": EDGE_HEIGHT,
        "target_xdot": list(EDGE_SPEEDS),
        "strides": EDGE_STRIDES,
        "outcome": [basins.OUTCOMES[o] for o in edge.history.outcome],
        "failure_stride": edge.history.failure_stride.tolist(),
        "last_y": edge.history.y[-1].tolist(),
        "last_xdot": edge.history.xdot[-1].tolist(),
    }
    return figure, data


def _draw(speeds_bar: Array, data: dict[str, Any]) -> Figure:
    """|percentage errors| of apex speed (top) and height (bottom) per desired speed, where a controller
    converged; crosses along the bottom where it loses stability, as the paper marks its baseline's."""
    figure = Figure(figsize=(7, 6.5))
    top, bottom = figure.subplots(2, 1, sharex=True)
    for offset, name in enumerate(("deadbeat", BASELINE)):
        colour, style = CONTROLLER_STYLE[name]
        stable = np.array(data[name]["stable"], dtype=bool)
        for axes, field in ((top, "speed_error_percent"), (bottom, "height_error_percent")):
            error = np.abs(np.array(data[name][field], dtype=float))
            axes.plot(speeds_bar[stable], error[stable], style, color=colour, marker=".", label=name)
            axes.plot(
                speeds_bar[~stable],
                np.full(np.sum(~stable), 0.04 + 0.06 * offset),
                "x",
                color=colour,
                markersize=9,
                mew=2,
                transform=axes.get_xaxis_transform(),
            )
    top.set(
        ylabel="|speed error| [%]",
        yscale="log",
        title="deadbeat vs ref. 36's stance PD, 50 strides (x: loses stability)",
    )
    bottom.set(xlabel="xdotbar*", ylabel="|height error| [%]", yscale="log")
    top.legend(fontsize=8)
    return figure
