"""What ``tdslip viability`` writes: the Q-map and the viable set (npz), a summary (JSON) and three figures.

* ``qmap.npz``: the grids (``state_<name>``, ``action_<name>``, SI), ``successor`` (*states, *actions, state
  dims; NaN where the pair failed) and ``failure`` (codes of ``failure_kinds``, -1 none);
* ``viability.npz``: the grids, ``viable`` (*states, *actions), ``kernel`` and ``measure`` (*states);
* ``viability.json``: the space, the hopper, the grids' bounds and sizes, how successors were judged, the
  fixed point's iterations, failure counts, and the kernel's size and measure;
* ``qmap.png`` (per pair, or per state for a 2-D state: the share of actions that do not fail),
  ``kernel.png`` (the viable pairs over a 1-D state, the kernel over a 2-D one) and ``measure.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from tdslip_ros.model.events import NO_FAILURE_CODE
from tdslip_ros.model.stability.viability import QMAP_FAILURES, QMap, ViabilityResult
from tdslip_ros.reporting.output import to_json
from tdslip_ros.reporting.style import save_figure

OUTPUTS = ("qmap.npz", "viability.npz", "viability.json", "qmap.png", "kernel.png", "measure.png")


def _grids(qmap: QMap) -> dict[str, np.ndarray]:
    grids = {f"state_{name}": axis for name, axis in zip(qmap.state_names, qmap.states, strict=True)}
    grids.update({f"action_{name}": axis for name, axis in zip(qmap.action_names, qmap.actions, strict=True)})
    return grids


def summary(qmap: QMap, result: ViabilityResult, described: dict[str, Any]) -> dict[str, Any]:
    """The JSON summary; ``described``: the space and hopper as the command states them."""
    return {
        **described,
        "grid": {
            name: {"min": float(axis[0]), "max": float(axis[-1]), "size": int(axis.size)}
            for name, axis in _grids(qmap).items()
        },
        "pairs": int(qmap.failure.size),
        "judge": result.judge,
        "outside": result.outside,
        "iterations": result.iterations,
        "failure_pairs": int(np.count_nonzero(qmap.failure != NO_FAILURE_CODE)),
        "failures": qmap.failure_counts,
        "viable_pairs": int(np.count_nonzero(result.viable)),
        "kernel_states": int(np.count_nonzero(result.kernel)),
        "states": int(result.kernel.size),
        "mean_measure_in_kernel": float(result.measure[result.kernel].mean()) if result.kernel.any() else 0.0,
    }


def write(out: Path, qmap: QMap, result: ViabilityResult, described: dict[str, Any]) -> None:
    """Every file of :data:`OUTPUTS` into ``out`` (an existing directory)."""
    grids = _grids(qmap)
    np.savez_compressed(
        out / "qmap.npz",
        successor=qmap.successor,
        failure=qmap.failure,
        failure_kinds=np.array(QMAP_FAILURES),
        **grids,
    )
    np.savez_compressed(
        out / "viability.npz", viable=result.viable, kernel=result.kernel, measure=result.measure, **grids
    )
    (out / "viability.json").write_text(to_json(summary(qmap, result, described)))
    _figures(out, qmap, result)


def _extent(x: np.ndarray, y: np.ndarray, x_scale: float, y_scale: float) -> list[float]:
    return [x[0] * x_scale, x[-1] * x_scale, y[0] * y_scale, y[-1] * y_scale]


def _axis_label(name: str) -> tuple[str, float]:
    """Label and scale of a grid axis in a figure (angles in degrees)."""
    labels = {
        "height_fraction": ("height fraction of the energy", 1.0),
        "touchdown_angle": ("touchdown angle [deg]", 180.0 / np.pi),
        "y": ("apex height y [m]", 1.0),
        "xdot": ("apex speed [m/s]", 1.0),
        "tau0": ("tau0 [N m]", 1.0),
    }
    return labels.get(name, (name, 1.0))


def figures(qmap: QMap, result: ViabilityResult) -> dict[str, Figure]:
    """The figures of a Q-map and its viable set, by file name: the Q-map, the kernel and the measure."""
    if len(qmap.states) == 1 and len(qmap.actions) == 1:
        return _pair_figures(qmap, result)
    return _state_figures(qmap, result)


def _figures(out: Path, qmap: QMap, result: ViabilityResult) -> None:
    for name, figure in figures(qmap, result).items():
        save_figure(figure, out / name)


KERNEL_CLASSES = (
    ("fails in one stride", "0.85"),
    ("does not fail at once, not viable", "0.55"),
    ("viable", "tab:blue"),
)
"""The classes of a pair space's kernel figure, in the order of their codes 0, 1, 2, with their colours."""


def _pair_figures(qmap: QMap, result: ViabilityResult) -> dict[str, Figure]:
    (state,), (action,) = qmap.states, qmap.actions
    (s_label, s_scale), (a_label, a_scale) = (
        _axis_label(qmap.state_names[0]),
        _axis_label(qmap.action_names[0]),
    )
    extent = _extent(action, state, a_scale, s_scale)
    drawn = {}
    figure = Figure(figsize=(7.0, 5.0))
    axes = figure.subplots()
    shown = np.where(qmap.failure == NO_FAILURE_CODE, qmap.successor[..., 0], np.nan)
    image = axes.imshow(shown, origin="lower", aspect="auto", extent=extent, cmap="viridis")
    figure.colorbar(image, ax=axes, label=f"next {s_label}")
    axes.set(
        xlabel=a_label, ylabel=s_label, title="Q-map: the next state of each pair (blank: the pair fails)"
    )
    drawn["qmap.png"] = figure
    figure = Figure(figsize=(7.0, 5.0))
    axes = figure.subplots()
    classes = np.where(result.viable, 2, np.where(qmap.failure == NO_FAILURE_CODE, 1, 0))
    colours = [colour for _, colour in KERNEL_CLASSES]
    axes.imshow(classes, origin="lower", aspect="auto", extent=extent, cmap=ListedColormap(colours))
    axes.legend(
        handles=[Patch(facecolor=colour, label=label) for label, colour in reversed(KERNEL_CLASSES)],
        loc="upper right",
        fontsize="small",
    )
    axes.set(xlabel=a_label, ylabel=s_label, title="the viable pairs")
    drawn["kernel.png"] = figure
    figure = Figure(figsize=(6.0, 4.0))
    axes = figure.subplots()
    axes.plot(state * s_scale, result.measure, color="tab:blue")
    axes.set(xlabel=s_label, ylabel="fraction of viable actions", title="measure of each state")
    drawn["measure.png"] = figure
    return drawn


def _state_figures(qmap: QMap, result: ViabilityResult) -> dict[str, Figure]:
    first, second = qmap.states[0], qmap.states[1]
    (x_label, x_scale), (y_label, y_scale) = (
        _axis_label(qmap.state_names[0]),
        _axis_label(qmap.state_names[1]),
    )
    extent = _extent(second, first, y_scale, x_scale)
    action_axes = tuple(range(len(qmap.states), qmap.failure.ndim))
    rest = tuple(range(2, len(qmap.states)))
    panels = (
        (
            "qmap.png",
            (qmap.failure == NO_FAILURE_CODE).mean(axis=action_axes),
            "share of actions that do not fail",
        ),
        ("kernel.png", result.kernel.astype(float), "viability kernel (1: viable)"),
        ("measure.png", result.measure, "fraction of viable actions"),
    )
    drawn = {}
    for name, values, label in panels:
        figure = Figure(figsize=(6.5, 5.0))
        axes = figure.subplots()
        image = axes.imshow(
            values.mean(axis=rest) if rest else values,
            origin="lower",
            aspect="auto",
            extent=extent,
            vmin=0,
            vmax=1,
        )
        figure.colorbar(image, ax=axes, label=label)
        axes.set(xlabel=y_label, ylabel=x_label, title=label)
        drawn[name] = figure
    return drawn
