"""The picture of a stride (``render_mode="rgb_array"``): body path, leg at touchdown and liftoff, ground.

The stride is run again on the exact map (:func:`tdslip_ros.model.plant.exact_map.apex_return_map`) from the
inputs the batched engine was given, for its events. Flight is drawn exactly (a parabola); the stance as the
chord through touchdown, bottom and liftoff (the map locates these events, not the path between them).
Matplotlib's Agg canvas, no pyplot state.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from tdslip_ros.envs.config import HopConfig
from tdslip_ros.model.events import HopperState
from tdslip_ros.model.params import ApexState, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.perturbations import StrideConditions
from tdslip_ros.model.plant.terrain import Terrain

FRAME_INCHES, FRAME_DPI = (6.0, 3.0), 80
"""A frame of 480 x 240 pixels."""
FLIGHT_POINTS = 40


def _flight(x: float, y: float, xdot: float, ydot: float, duration: float, g: float) -> tuple[Any, Any]:
    t = np.linspace(0.0, duration, FLIGHT_POINTS)
    return x + xdot * t, y + ydot * t - 0.5 * g * t**2


def _leg(axes: Any, state: HopperState, label: str) -> None:
    axes.plot([state.toe_x, state.x], [state.toe_y, state.y], color="tab:orange", lw=2.0, label=label)


def draw_stride(
    config: HopConfig, inputs: dict[str, float] | None, apex: tuple[float, float, float], terrain: Terrain
) -> Any:
    """An RGB frame (height, width, 3) of uint8: the last stride of ``inputs`` (the lane's
    :attr:`~.lanes.HopperLanes.last_inputs`), or, before any stride, the apex (x, y above ground, ground)."""
    figure = Figure(figsize=FRAME_INCHES, dpi=FRAME_DPI)
    canvas = FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    params = config.params
    xs: list[float] = [apex[0]]
    if inputs is None:
        axes.plot([apex[0]], [apex[2] + apex[1]], "o", color="tab:blue", label="apex")
    else:
        x0, ground0 = inputs["x"], inputs["ground"]
        stride = apex_return_map(
            params,
            ApexState(inputs["y"], inputs["xdot"]),
            StanceCommand(inputs["touchdown_angle"], inputs["tau0"], inputs["t_f"]),
            rtol=config.tolerance,
            atol=config.tolerance,
            conditions=StrideConditions(
                x=x0,
                ground=ground0,
                terrain=terrain,
                tau_max=float(config.perturbations.tau_max),
                push=inputs["push"],
                angle_error=inputs["angle_error"],
            ),
        )
        speed = inputs["xdot"] + inputs["push"]
        end = stride.touchdown or stride.failure_state
        descent = _flight(x0, ground0 + inputs["y"], speed, 0.0, end.t if end else 0.0, params.g)
        axes.plot(*descent, color="tab:blue", label="body")
        xs += [float(descent[0][-1])]
        events = [s for s in (stride.touchdown, stride.bottom, stride.liftoff) if s is not None]
        if events:
            axes.plot([s.x for s in events], [s.y for s in events], "--", color="tab:blue")
            _leg(axes, events[0], "leg")
        if stride.liftoff is not None and stride.apex is not None:
            lo = stride.liftoff
            ascent = _flight(lo.x, lo.y, lo.xdot, lo.ydot, lo.ydot / params.g, params.g)
            axes.plot(*ascent, color="tab:blue")
            _leg(axes, lo, "")
            xs += [float(ascent[0][-1])]
        if stride.failure is not None and stride.failure_state is not None:
            failed = stride.failure_state
            axes.plot([failed.x], [failed.y], "x", color="tab:red", ms=10, label=stride.failure.value)
            xs += [failed.x]
    ground_x = np.linspace(min(xs) - 0.5, max(xs) + 0.5, 400)
    axes.plot(ground_x, terrain.height(ground_x), color="black", lw=1.0, label="ground")
    axes.set_aspect("equal", adjustable="datalim")
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    axes.legend(loc="upper right", fontsize="small")
    figure.tight_layout()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
