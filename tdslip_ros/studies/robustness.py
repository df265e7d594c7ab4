"""How large a perturbation each policy survives (``tdslip robustness``), as studies on the engine: every
policy starts at energy regulation's flat-ground fixed point (the operating point, :func:`operating_point`),
and each kind of perturbation (:data:`KINDS`: rough terrain, sensor noise, model mismatch, a step down) is
one study, a grid of policy x size with samples per cell (:func:`studies`). A trajectory survives when it
hops all its strides. Written: the fraction surviving, the median strides survived, the spread of the
survivors' apex heights and the failure kinds per kind, size and policy (``robustness.png``, ``strides.png``,
``spread.png``, ``failures.png``, ``summary.csv``, ``summary.json``), and per kind and policy the sizes all
and half the trajectories survive (``robustness.md``).
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pyarrow as pa
from matplotlib.figure import Figure

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.analytic.apex_map import DEFAULT_ANALYTIC_MAP
from tdslip_ros.model.events import FAILURE_KINDS
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.policies.registry import PolicySpec
from tdslip_ros.reporting.output import output_directory, to_json
from tdslip_ros.reporting.style import POLICY_COLOURS, save_figure
from tdslip_ros.studies import chunk, engine, table
from tdslip_ros.studies.design import DEFAULTS, Study, StudyError, Uniform, analytic_map_fixed

SETTLING_STRIDES = 30
"""Flat-ground strides of energy regulation to its fixed point, the operating point (|lambda| << 1)."""
STEP_POSITIONS = Uniform(1.0, 4.0)
"""Where the step down is, m: over about one stride at the operating point."""
FAILURES = tuple(kind.value for kind in FAILURE_KINDS) + ("no_command",)
FAILURE_COLOURS = dict(zip(FAILURES, matplotlib.colormaps["tab10"].colors, strict=False))


@dataclass(frozen=True)
class Kind:
    """A kind of perturbation: its sizes, the axis label, and the design parameters of a size."""

    label: str
    sizes: tuple[float, ...]
    scale: str  # "linear" or "log" axis
    neutral: float = 0.0  # the size without perturbation (the sizes lie on one side of it, or on both)

    def axis(self, name: str, params: HopperParams, mismatch_field: str) -> tuple[str, list[Any]]:
        """The grid axis (parameter names, values) of this kind's sizes."""
        if name == "terrain":
            return "terrain_sigma", list(self.sizes)
        if name == "noise":
            speed = math.sqrt(params.g * params.r0)
            return "noise_height,noise_speed", [(size * params.r0, size * speed) for size in self.sizes]
        if name == "mismatch":
            return f"mismatch_{mismatch_field}", list(self.sizes)
        return "step_height", [-size for size in self.sizes]

    def size_error(self, sizes: Sequence[float]) -> str | None:
        """Why ``sizes`` cannot be this kind's, or None: they increase, lie in its domain (positive on a log
        axis, else >= 0), and include the unperturbed size (the sizes survived are counted from it)."""
        if not sizes:
            return "none given"
        if (
            any(not math.isfinite(size) for size in sizes)
            or min(sizes) < 0.0
            or (self.scale == "log" and min(sizes) <= 0.0)
        ):
            return f"they must be finite and {'> 0' if self.scale == 'log' else '>= 0'}"
        if any(later <= earlier for earlier, later in zip(sizes, sizes[1:], strict=False)):
            return "they must increase"
        if self.neutral not in sizes:
            return f"they must include {self.neutral:g}, the unperturbed size"
        return None


KINDS = {
    "terrain": Kind("block height sigma [m]", (0.0, 0.01, 0.02, 0.03, 0.04, 0.06, 0.08, 0.12), "linear"),
    "noise": Kind(
        "sensor noise s (height s r0, speed s sqrt(g r0))", (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3), "linear"
    ),
    "mismatch": Kind(
        "controller's model: factor on the plant's value", (0.3, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0), "log", 1.0
    ),
    "step": Kind("step down [m]", (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0), "linear"),
}
"""The kinds of perturbation, with their default sizes (``tdslip robustness --<kind>-sizes``)."""


def chosen_kinds(names: Sequence[str], sizes: Mapping[str, Sequence[float]] | None = None) -> dict[str, Kind]:
    """The kinds ``names``, with ``sizes`` where given (checked: StudyError naming the kind), else their
    default sizes."""
    chosen = {}
    for name in names:
        given = (sizes or {}).get(name)
        if given is not None and (reason := KINDS[name].size_error(given)) is not None:
            raise StudyError(f"{name} sizes {' '.join(f'{size:g}' for size in given)}: {reason}")
        chosen[name] = KINDS[name] if given is None else dataclasses.replace(KINDS[name], sizes=tuple(given))
    return chosen


@dataclass(frozen=True)
class OperatingPoint:
    """The apex (y [m], xdot [m/s]) every policy starts at and holds on flat ground, the policies' numeric
    settings there (by design parameter), and the analytic map they plan on."""

    y: float
    xdot: float
    settings: dict[str, float]
    analytic_map: str


def operating_point(
    params: HopperParams, beta: float, energy: float, analytic_map: str = DEFAULT_ANALYTIC_MAP
) -> OperatingPoint:
    """Energy regulation's flat-ground fixed point at touchdown angle beta [rad] and apex energy [J], planned
    on ``analytic_map`` (the module docstring), reached in SETTLING_STRIDES strides from the apex of that
    energy at r0 + 10 %."""
    start = Study.of(
        fixed={
            "policy": "energy",
            "touchdown_angle": beta,
            "target_energy": energy,
            "y0": 1.1 * params.r0,
            "energy0": energy,
            **analytic_map_fixed(analytic_map),
        },
        strides=SETTLING_STRIDES,
    )
    rows = chunk.run_chunk(start, 0)
    if rows["outcome"][0].as_py() != "converged":
        raise StudyError(
            f"energy regulation at {math.degrees(beta):g} deg does not settle at Ebar = "
            f"{units.energy_to_bar(params, energy):g} ({rows['outcome'][0].as_py()}): "
            "choose another operating point"
        )
    y, xdot = rows["y_fixed"][0].as_py(), rows["xdot_fixed"][0].as_py()
    values = {name: DEFAULTS[name] for name in PolicySpec.settings() if name in DEFAULTS}
    spec = PolicySpec(
        name="energy",
        corrections=1,
        **values | {"touchdown_angle": beta, "target_energy": energy, "analytic_map": analytic_map},
    )
    tau0 = float(spec.commands(params, y, xdot, xdot).tau0)
    thetadot = dynamics.touchdown_leg_rate(params, y, xdot, beta)
    settings = {
        "touchdown_angle": beta,
        "target_energy": energy,
        "touchdown_power": tau0 * thetadot,  # the hip power at touchdown energy regulation applies there
        "target_height": y,
        "target_speed": xdot,
    }
    return OperatingPoint(y, xdot, settings, analytic_map)


def studies(
    kinds: Mapping[str, Kind],
    policies: list[str],
    point: OperatingPoint,
    params: HopperParams,
    samples: int,
    strides: int,
    seed: int,
    mismatch_field: str,
    policy_file: str = "",
) -> dict[str, Study]:
    """One study per kind: a grid of policy x size, ``samples`` trajectories per cell with their own draws,
    from the operating point (the sizes of each kind as ``tdslip robustness --help`` describes them); the
    learned policy reads ``policy_file``."""
    made = {}
    for name, kind in kinds.items():
        axis, values = kind.axis(name, params, mismatch_field)
        made[name] = Study.of(
            grid={"policy": policies, axis: values},
            draws={"step_x": STEP_POSITIONS} if name == "step" else None,
            samples=samples,
            fixed=point.settings
            | analytic_map_fixed(point.analytic_map)
            | {"y0": point.y, "xdot0": point.xdot}
            | ({"policy_file": policy_file} if policy_file else {}),
            start="speed",
            strides=strides,
            seed=seed,
            hold_commands=True,
            chunk_size=min(1000, max(50, math.ceil(len(policies) * len(values) * samples / 16))),
        )
    return made


def summarise(name: str, kind: Kind, study: Study, rows: pa.Table) -> list[dict[str, Any]]:
    """One row per size and policy: trajectories, the fraction surviving all strides, the median strides
    survived, the failure kinds, the median apex spread of the survivors, strides without a command."""
    policies = list(study.values_of("policy"))
    sizes = kind.sizes
    per_cell = study.samples
    survived = table.column(rows, "strides_survived").reshape(len(policies), len(sizes), per_cell)
    outcome = table.column(rows, "outcome").reshape(survived.shape)
    y_std = table.column(rows, "y_std").reshape(survived.shape)
    xdot_std = table.column(rows, "xdot_std").reshape(survived.shape)
    held = table.column(rows, "strides_held").reshape(survived.shape)
    summary = []
    for p, policy in enumerate(policies):
        for s, size in enumerate(sizes):
            alive = survived[p, s] == study.strides
            summary.append(
                {
                    "kind": name,
                    "size": size,
                    "policy": policy,
                    "trajectories": per_cell,
                    "surviving": float(np.mean(alive)),
                    "median_strides": float(np.median(survived[p, s])),
                    "apex_height_spread": float(np.median(y_std[p, s][alive])) if alive.any() else math.nan,
                    "apex_speed_spread": float(np.median(xdot_std[p, s][alive])) if alive.any() else math.nan,
                    "strides_held": float(np.mean(held[p, s])),
                    **{failure: int(np.sum(outcome[p, s] == failure)) for failure in FAILURES},
                }
            )
    return summary


def survived_range(summary: list[dict[str, Any]], kind: str, policy: str, share: float) -> list[float] | None:
    """The sizes [low, high] around the kind's neutral size (every size between them included) at which at
    least ``share`` of the trajectories survive; None where even the neutral size is not."""
    rows = [r for r in summary if r["kind"] == kind and r["policy"] == policy]
    sizes = [r["size"] for r in rows]
    neutral = sizes.index(KINDS[kind].neutral)
    if rows[neutral]["surviving"] < share:
        return None
    low = high = neutral
    while low > 0 and rows[low - 1]["surviving"] >= share:
        low -= 1
    while high < len(rows) - 1 and rows[high + 1]["surviving"] >= share:
        high += 1
    return [sizes[low], sizes[high]]


def draw(
    summary: list[dict[str, Any]],
    kinds: Mapping[str, Kind],
    policies: list[str],
    value: str,
    ylabel: str,
    title: str,
) -> Figure:
    """One panel per kind: ``value`` against the size, a line per policy."""
    columns = min(2, len(kinds))
    rows = math.ceil(len(kinds) / columns)
    figure = Figure(figsize=(6.5 * columns, 4.2 * rows))
    axes_all = np.atleast_1d(figure.subplots(rows, columns)).ravel()
    for axes, kind in zip(axes_all, kinds, strict=False):
        for policy in policies:
            points = [r for r in summary if r["kind"] == kind and r["policy"] == policy]
            axes.plot(
                [r["size"] for r in points],
                [r[value] for r in points],
                "o-",
                color=POLICY_COLOURS.get(policy),
                label=policy,
                ms=3,
            )
        axes.set(xlabel=kinds[kind].label, ylabel=ylabel, title=kind, xscale=kinds[kind].scale)
        if kinds[kind].scale == "log":  # the sizes themselves as ticks, not powers of ten
            axes.set_xticks(kinds[kind].sizes, [f"{size:g}" for size in kinds[kind].sizes])
            axes.minorticks_off()
        axes.legend(fontsize=7)
    for axes in axes_all[len(kinds) :]:
        axes.set_visible(False)
    figure.suptitle(title)
    return figure


def draw_failures(summary: list[dict[str, Any]], kinds: Sequence[str], policies: list[str]) -> Figure:
    """Per kind, the failure kinds of each policy's trajectories over all sizes (stacked bars)."""
    columns = min(2, len(kinds))
    rows = math.ceil(len(kinds) / columns)
    figure = Figure(figsize=(6.5 * columns, 4.2 * rows))
    axes_all = np.atleast_1d(figure.subplots(rows, columns)).ravel()
    for axes, kind in zip(axes_all, kinds, strict=False):
        bottom = np.zeros(len(policies))
        for failure in FAILURES:
            counts = np.array(
                [sum(r[failure] for r in summary if r["kind"] == kind and r["policy"] == p) for p in policies]
            )
            if counts.any():
                axes.bar(policies, counts, bottom=bottom, label=failure, color=FAILURE_COLOURS[failure])
                bottom += counts
        axes.set(ylabel="trajectories failed (all sizes)", title=kind)
        axes.tick_params(axis="x", labelsize=7)
        axes.legend(fontsize=7)
    for axes in axes_all[len(kinds) :]:
        axes.set_visible(False)
    figure.suptitle("how the trajectories failed")
    return figure


def markdown(
    summary: list[dict[str, Any]],
    kinds: Mapping[str, Kind],
    policies: list[str],
    strides: int,
    analytic_map: str,
) -> str:
    lines = [
        f"# Robustness: the largest perturbation survived for {strides} strides",
        "",
        # Said where it is not ours, the default, as the analysis report does.
        *(
            []
            if analytic_map == DEFAULT_ANALYTIC_MAP
            else [f"Analytic map the policies plan on: {analytic_map}.", ""]
        ),
        "| kind | policy | sizes all survive | sizes half survive | failures (all sizes) |",
        "| --- | --- | --- | --- | --- |",
    ]
    for kind in kinds:
        for policy in policies:
            every, half = (survived_range(summary, kind, policy, share) for share in (1.0, 0.5))
            failures = {
                failure: sum(r[failure] for r in summary if r["kind"] == kind and r["policy"] == policy)
                for failure in FAILURES
            }
            text = ", ".join(f"{name} {count}" for name, count in failures.items() if count) or "none"
            lines.append(f"| {kind} | {policy} | {_size_text(every)} | {_size_text(half)} | {text} |")
    lines += ["", "Sizes: " + "; ".join(f"{name}: {kind.label}" for name, kind in kinds.items()), ""]
    return "\n".join(lines)


def _size_text(sizes: list[float] | None) -> str:
    """The sizes survived: "0 to 4", "0.5 to 2", or "none"."""
    return "none" if sizes is None else f"{sizes[0]:g} to {sizes[1]:g}"


def write_robustness(
    out: Path,
    params: HopperParams,
    beta: float,
    energy: float,
    kinds: Mapping[str, Kind],
    policies: list[str],
    samples: int,
    strides: int,
    seed: int,
    mismatch_field: str,
    where: engine.Where,
    resume: bool,
    analytic_map: str = DEFAULT_ANALYTIC_MAP,
    policy_file: str = "",
) -> None:
    """Run one study per kind from the operating point at touchdown angle beta [rad] and apex energy [J],
    the policies planning on ``analytic_map`` (the learned one reading ``policy_file``), into ``out/<kind>``
    on the engine ``where``, and write the figures, summary.csv, robustness.md and summary.json to ``out``
    (the module docstring)."""
    point = operating_point(params, beta, energy, analytic_map)
    made = studies(kinds, policies, point, params, samples, strides, seed, mismatch_field, policy_file)
    output_directory(out)
    tables = engine.run_studies(made, out, where, resume, "robustness")
    summary = [row for name, kind in kinds.items() for row in summarise(name, kind, made[name], tables[name])]
    figures = {
        "robustness": draw(
            summary,
            kinds,
            policies,
            "surviving",
            f"fraction surviving {strides} strides",
            "survival",
        ),
        "strides": draw(
            summary, kinds, policies, "median_strides", "median strides survived", "strides survived"
        ),
        "spread": draw(
            summary,
            kinds,
            policies,
            "apex_height_spread",
            "apex height spread [m] (survivors' median std)",
            "spread of the apex heights",
        ),
        "failures": draw_failures(summary, list(kinds), policies),
    }
    for name, figure in figures.items():
        save_figure(figure, out / f"{name}.png")
    with (out / "summary.csv").open("w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=list(summary[0]))
        writer.writeheader()
        writer.writerows(summary)
    (out / "robustness.md").write_text(markdown(summary, kinds, policies, strides, analytic_map))
    document = {
        "operating_point": {
            "y": point.y,
            "xdot": point.xdot,
            **point.settings,
            "analytic_map": point.analytic_map,
        },
        "samples": samples,
        "strides": strides,
        "sizes": {name: {"label": kind.label, "sizes": list(kind.sizes)} for name, kind in kinds.items()},
        "sizes_survived": {
            kind: {
                policy: {
                    "all": survived_range(summary, kind, policy, 1.0),
                    "half": survived_range(summary, kind, policy, 0.5),
                }
                for policy in policies
            }
            for kind in kinds
        },
        "rows": summary,
    }
    (out / "summary.json").write_text(to_json(document))
