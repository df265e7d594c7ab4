"""The sweeps of the paper's basins (figs. 7 and 10) and parameter dependence (fig. 11) as studies at any
resolution (``tdslip sweep``): how each builds its studies on the grids of
:mod:`tdslip_ros.reporting.paper_grids`, draws their tables, and writes its figure and summary.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from matplotlib.figure import Figure

from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import ANALYTIC_MAPS, DEFAULT_ANALYTIC_MAP
from tdslip_ros.model.paper import PAPER_KBAR, PAPER_PARAMS, PAPER_ZETA0
from tdslip_ros.model.stability import analytic_fixed_points, basins
from tdslip_ros.reporting.output import output_directory, to_json
from tdslip_ros.reporting.paper_grids import (
    BASIN_BETA_DEG,
    FIG11_STUDIES,
    fig07_grid,
    fig10_grid,
    fig11_energies_bar,
    row_median,
)
from tdslip_ros.reporting.style import EXACT, STABLE, basin_colour_map, basin_colours, save_figure
from tdslip_ros.studies import engine, table
from tdslip_ros.studies.design import Study, analytic_map_fixed

PARAMS = PAPER_PARAMS


@dataclass(frozen=True)
class Sweep:
    """One of the sweeps: its default grid, strides, and how to build its studies and draw them."""

    grid: tuple[int, int]
    strides: int
    studies: Callable[[tuple[int, int], int, int | None, str], dict[str, Study]]
    draw: Callable[[dict[str, Study], dict[str, pa.Table]], tuple[Figure, dict[str, Any]]]


def chunk_size_for(size: int) -> int:
    """Trajectories per chunk: about 1/16 of the study within [100, 1000] (a batched call of fewer lanes
    runs slower per lane, one of more no faster). A function of the study alone, never of the cluster."""
    return min(1000, max(100, math.ceil(size / 16)))


def _chunked(chunk_size: int | None, size: int) -> int:
    return chunk_size or chunk_size_for(size)


# --- fig. 7: the open loop --------------------------------------------------------------------------


def fig07_studies(
    grid: tuple[int, int], strides: int, chunk_size: int | None, analytic_map: str = DEFAULT_ANALYTIC_MAP
) -> dict[str, Study]:
    alphas, heights = fig07_grid(*grid)
    study = Study.of(
        grid={"touchdown_power": units.power_from_alpha(PARAMS, alphas), "y0": heights},
        fixed={
            "policy": "open_loop",
            "touchdown_angle": math.radians(BASIN_BETA_DEG),
            **analytic_map_fixed(analytic_map),
        },
        start="open_loop_fixed_point",
        strides=strides,
        chunk_size=_chunked(chunk_size, alphas.size * heights.size),
    )
    return {"": study}


def fig07_draw(studies: dict[str, Study], tables: dict[str, pa.Table]) -> tuple[Figure, dict[str, Any]]:
    study, rows = studies[""], tables[""]
    alphas = units.power_to_alpha(PARAMS, np.asarray(dict(study.grid)["touchdown_power"]))
    heights = np.asarray(dict(study.grid)["y0"])
    shape = (alphas.size, heights.size)
    outcome, stride = _outcomes(rows, shape)
    figure, axes = _basin_figure(alphas, heights, outcome, stride, study.strides)
    y_fixed = table.column(rows, "y_fixed").reshape(shape)
    fixed = units.height_to_bar(PARAMS, row_median(y_fixed))
    axes.plot(alphas, fixed, ".", color=EXACT, label="fixed point reached (median)")
    axes.set(
        xlabel="alpha",
        ylabel="ybar0 (E0 = E*(y0))",
        title=f"exact plant, open loop, beta = {BASIN_BETA_DEG:g} deg, {study.strides} strides "
        "(blue: converged, lighter later; pale: sustained; white: failed)",
    )
    axes.legend(fontsize=7)
    data = {
        "alpha": alphas.tolist(),
        "ybar0": units.height_to_bar(PARAMS, heights).tolist(),
        "fixed_ybar_median": fixed.tolist(),
    }
    return figure, data


# --- fig. 10: the goal regulator ---------------------------------------------------------------------


def fig10_studies(
    grid: tuple[int, int], strides: int, chunk_size: int | None, analytic_map: str = DEFAULT_ANALYTIC_MAP
) -> dict[str, Study]:
    beta = math.radians(BASIN_BETA_DEG)
    energies_bar, heights = fig10_grid(*grid)
    energies = units.energy_from_bar(PARAMS, energies_bar)
    study = Study.of(
        grid={"energy0": energies, "y0": heights},
        fixed={"policy": "energy", "touchdown_angle": beta, **analytic_map_fixed(analytic_map)},
        strides=strides,
        chunk_size=_chunked(chunk_size, energies.size * heights.size),
    )
    return {"": study}


def fig10_draw(studies: dict[str, Study], tables: dict[str, pa.Table]) -> tuple[Figure, dict[str, Any]]:
    study, rows = studies[""], tables[""]
    energies = np.asarray(dict(study.grid)["energy0"])
    heights = np.asarray(dict(study.grid)["y0"])
    shape = (energies.size, heights.size)
    outcome, stride = _outcomes(rows, shape)
    energies_bar = units.energy_to_bar(PARAMS, energies)
    figure, axes = _basin_figure(energies_bar, heights, outcome, stride, study.strides)
    fixed = units.height_to_bar(PARAMS, row_median(table.column(rows, "y_fixed").reshape(shape)))
    axes.plot(energies_bar, fixed, "-", color=EXACT, lw=2, label="exact plant, fixed point reached (median)")
    fine = np.linspace(energies_bar[0], energies_bar[-1], 4 * energies_bar.size)
    analytic_map = str(study.values_of("analytic_map")[0])
    analytic = analytic_fixed_points.regulated_fixed_points(
        PARAMS,
        math.radians(BASIN_BETA_DEG),
        units.energy_from_bar(PARAMS, fine),
        speed=ANALYTIC_MAPS[analytic_map],
    )
    x, y, stable = np.broadcast_arrays(
        fine[:, None], units.height_to_bar(PARAMS, analytic.y), analytic.stable
    )
    axes.plot(
        x[stable], y[stable], "o", color=STABLE, markersize=2, label=f"analytic ({analytic_map}), stable"
    )
    axes.set(
        xlabel="Ebar (initial energy = goal)",
        ylabel="ybar (basin: initial ybar0)",
        title=f"goal regulator on the exact plant, beta = {BASIN_BETA_DEG:g} deg, {study.strides} strides "
        "(blue: converged, lighter later; pale: sustained; white: failed or no such apex)",
    )
    axes.legend(fontsize=7)
    return figure, {
        "Ebar": energies_bar.tolist(),
        "ybar0": units.height_to_bar(PARAMS, heights).tolist(),
        "fixed_ybar_median": fixed.tolist(),
    }


# --- fig. 11: parameter dependence --------------------------------------------------------------------


def fig11_studies(
    grid: tuple[int, int], strides: int, chunk_size: int | None, analytic_map: str = DEFAULT_ANALYTIC_MAP
) -> dict[str, Study]:
    energies_bar = fig11_energies_bar(grid[0])
    heights = np.linspace(1.0, 2.0, grid[1]) * PARAMS.r0
    studies = {}
    for name, values in FIG11_STUDIES.items():
        axis: dict[str, Any] = {
            "beta_deg": {"touchdown_angle": np.radians(values)},
            "kbar": {"kbar": values},
            "zeta0": {"zeta0": values},
        }[name]
        size = len(values) * energies_bar.size * heights.size
        studies[name] = Study.of(
            grid={**axis, "energy0": units.energy_from_bar(PARAMS, energies_bar), "y0": heights},
            fixed={"policy": "energy", **analytic_map_fixed(analytic_map)},
            strides=strides,
            chunk_size=_chunked(chunk_size, size),
        )
    return studies


def fig11_draw(studies: dict[str, Study], tables: dict[str, pa.Table]) -> tuple[Figure, dict[str, Any]]:
    figure = Figure(figsize=(14, 4.5))
    data: dict[str, Any] = {}
    for axes, (name, values) in zip(figure.subplots(1, 3), FIG11_STUDIES.items(), strict=True):
        study, rows = studies[name], tables[name]
        energies = np.asarray(dict(study.grid)["energy0"])
        shape = (len(values), energies.size, -1)
        data[name] = []
        for position, value in enumerate(values):
            kbar = value if name == "kbar" else PAPER_KBAR
            zeta0 = value if name == "zeta0" else PAPER_ZETA0
            params = study.params(kbar, zeta0)
            y = units.height_to_bar(
                params, row_median(table.column(rows, "y_fixed").reshape(shape)[position])
            )
            xdot = units.speed_to_bar(
                params, row_median(table.column(rows, "xdot_fixed").reshape(shape)[position])
            )
            (line,) = axes.plot(xdot, y, lw=1.2, label=f"{name} = {value:g}")
            finite = np.flatnonzero(np.isfinite(y))
            reached = units.energy_to_bar(params, energies[finite])
            if finite.size:
                axes.plot(xdot[finite[[0, -1]]], y[finite[[0, -1]]], "o", color=line.get_color(), mfc="none")
            data[name].append(
                {
                    "value": value,
                    "Ebar": units.energy_to_bar(params, energies).tolist(),
                    "ybar": y.tolist(),
                    "xdotbar": xdot.tolist(),
                    "reached_Ebar_range": [float(reached.min()), float(reached.max())]
                    if finite.size
                    else None,
                }
            )
        axes.set(xlabel="xdotbar*", ylabel="ybar*", title=f"fixed points reached, varying {name}")
        axes.legend(fontsize=7)
    figure.suptitle(
        "the goal regulator's exact plant: fixed points reached (median over the initial heights)"
    )
    return figure, data


SWEEPS = {
    "fig07": Sweep((17, 20), basins.OPEN_LOOP_STRIDES, fig07_studies, fig07_draw),
    "fig10": Sweep((21, 20), basins.REGULATED_STRIDES, fig10_studies, fig10_draw),
    "fig11": Sweep((57, 3), basins.REGULATED_STRIDES, fig11_studies, fig11_draw),
}


def _basin_figure(
    x: np.ndarray, heights: np.ndarray, outcome: np.ndarray, stride: np.ndarray, strides: int
) -> tuple[Figure, Any]:
    """A figure whose axes show a basin over (x, dimensionless height), coloured by outcome and stride."""
    figure = Figure(figsize=(10, 5))
    axes = figure.subplots()
    axes.pcolormesh(
        x,
        units.height_to_bar(PARAMS, heights),
        basin_colours(outcome, stride, strides).T,
        cmap=basin_colour_map(strides),
        vmin=0,
        vmax=strides + 1,
        shading="nearest",
    )
    return figure, axes


def _outcomes(rows: pa.Table, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Outcome indices (basins.OUTCOMES) and convergence strides in the grid's shape."""
    outcome = pc.index_in(rows["outcome"], value_set=pa.array(basins.OUTCOMES)).to_numpy()
    return outcome.reshape(shape), table.column(rows, "convergence_stride").reshape(shape)


def outcome_counts(rows: pa.Table) -> dict[str, int]:
    counts = dict.fromkeys(basins.OUTCOMES, 0)
    for entry in rows.group_by("outcome").aggregate([("outcome", "count")]).to_pylist():
        counts[entry["outcome"]] = entry["outcome_count"]
    return counts


def write_sweep(
    name: str,
    out: Path,
    grid: tuple[int, int] | None,
    strides: int | None,
    chunk_size: int | None,
    where: engine.Where,
    resume: bool,
    analytic_map: str = DEFAULT_ANALYTIC_MAP,
) -> None:
    """Run the sweep ``name`` (:data:`SWEEPS`; its default grid and strides where None), its policy planning
    on ``analytic_map``, into study directories under ``out`` on the engine ``where``, then write its figure
    (``out/<name>.png``) and ``out/summary.json``."""
    sweep = SWEEPS[name]
    studies = sweep.studies(grid or sweep.grid, strides or sweep.strides, chunk_size, analytic_map)
    output_directory(out)
    tables = engine.run_studies(studies, out, where, resume, f"sweep {name}")
    figure, data = sweep.draw(studies, tables)
    save_figure(figure, out / f"{name}.png")
    summary = {
        "sweep": name,
        "grid": list(grid or sweep.grid),
        "analytic_map": analytic_map,
        "studies": {
            study_name or name: {
                "directory": str(out / study_name),
                "trajectories": study.size,
                "strides": study.strides,
                "outcome_counts": outcome_counts(tables[study_name]),
            }
            for study_name, study in studies.items()
        },
        **data,
    }
    (out / "summary.json").write_text(to_json(summary))
