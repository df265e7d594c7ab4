"""The paper's claims beside ours: the table ``tdslip figures`` prints and writes as comparison.md.

Each row is one claim or figure of the paper: the paper's value, ours on the analytic map and on the exact
plant, the command that reproduces ours, and where they differ a pointer to the explanation in
docs/paper.md (which shows the exact-plant evidence). Our values are read from the figure documents of the
same run (their JSON), so a row needs its figures computed; rows whose figures were not are listed with
the command that computes them. Three rows compute their own small numbers (the open-loop t_f at alpha = 1,
the analytic map's prediction error on the accuracy grids, and its accuracy domain, a few seconds).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tdslip_ros.model import analytic_accuracy, units
from tdslip_ros.model.analytic import SpeedSource
from tdslip_ros.model.analytic_accuracy import Quantity
from tdslip_ros.model.controllers import fixed_power
from tdslip_ros.model.exact_map import apex_return_map
from tdslip_ros.model.params import ApexState, HopperParams

Documents = dict[str, dict[str, Any]]


@dataclass(frozen=True)
class Row:
    claim: str
    paper: str
    analytic: str
    exact: str
    figures: tuple[str, ...]
    """The figures whose documents the row reads (``tdslip figures --only ...``)."""
    explanation: str
    """The section of docs/paper.md that explains a difference ("" where there is none)."""

    @property
    def command(self) -> str:
        return (
            f"tdslip figures --out DIR --only {' '.join(self.figures)}" if self.figures else "tdslip figures"
        )


def _range(ends: Any) -> str:
    if ends is None or not all(isinstance(end, float) and math.isfinite(end) for end in ends):
        return "none"
    return f"[{ends[0]:.2f}, {ends[1]:.2f}]"


def _stable_ranges(documents: Documents, beta: str) -> tuple[str, str]:
    ranges = documents["ranges"]
    exact = f"energy {_range(ranges['energy'][beta])}; energy_exact {_range(ranges['energy_exact'][beta])}"
    return _range(ranges["analytic"][beta]), exact


def _trend(documents: Documents, study: str) -> tuple[str, str]:
    """The stable ranges of fig. 11 over the values of one parameter, analytic and exact."""
    entries = documents["fig11"][study]

    def listed(key: str) -> str:
        return "; ".join(f"{entry['value']:g}: {_range(entry[key])}" for entry in entries)

    return listed("stable_Ebar_range"), listed("exact_stable_Ebar_range")


def _three_fixed_points(documents: Documents) -> tuple[str, str]:
    panel = documents["fig06"]["b"]
    alphas = np.array(panel["parameter"])
    analytic = np.sum(np.isfinite(np.array(panel["ybar"], dtype=float)), axis=1)
    exact = np.sum(np.isfinite(np.array(panel["exact"]["ybar"], dtype=float)), axis=1)
    three = alphas[analytic >= 3]
    step = alphas[1] - alphas[0]
    found = (
        f"3 fixed points at {three.size} alpha(s) of the grid (step {step:.3f}): "
        f"{three.min():.3f}-{three.max():.3f}"
        if three.size
        else "at most 2"
    )
    exists = np.array(panel["analytic_exists_on_exact_plant"])
    missing = int(np.sum(~exists[analytic >= 3] & np.isfinite(np.array(panel["ybar"], float)[analytic >= 3])))
    return found, f"at most {int(exact.max())} per alpha; {missing} of the analytic ones there do not exist"


def _families(documents: Documents) -> tuple[str, str]:
    """Open loop, beta = 26 deg: the most stable high fixed point (ybar > 1.5) and the range of |lambda|
    of the stable realistic ones (ybar < 1.1) over alpha."""
    panel = documents["fig04"]["c"]
    alphas = np.array(panel["parameter"])

    def families(points: dict[str, Any]) -> str:
        y = np.array(points["ybar"], dtype=float)
        radius = np.where(
            np.array(points["stable"], dtype=bool), np.array(points["spectral_radius"], float), np.inf
        )
        high = np.where(y > 1.5, radius, np.inf)
        low = radius[(y < 1.1) & np.isfinite(radius)]
        if not np.isfinite(high).any() or low.size == 0:
            return "one of the families is missing"
        row, column = np.unravel_index(np.argmin(high), y.shape)
        return (
            f"(i) ybar {y[row, column]:.2f}, |lambda| {high[row, column]:.2f} at alpha {alphas[row]:g}; "
            f"(ii) ybar < 1.1, |lambda| {low.min():.3f}-{low.max():.3f}"
        )

    return families(panel), families(panel["exact"])


def _open_loop_tf(documents: Documents, params: HopperParams) -> tuple[str, str]:
    """alpha = 1: the paper's t_f (the analytic liftoff) against the stance the exact plant produces with
    it, at the exact plant's fixed point; alpha = 1.5: how far the exact fixed points move in Ebar when t_f
    is that stance duration instead."""
    runs = documents["fig07"]["exact_by_eigenvalue"]
    alphas = np.array(runs["open_loop"]["parameter"])
    paper_tf, stance_tf = (np.array(runs[name]["Ebar"], dtype=float) for name in runs)
    at = int(np.argmin(np.abs(alphas - 1.0)))
    y = units.height_from_bar(params, float(np.nanmax(np.array(runs["open_loop"]["ybar"], float)[at])))
    xdot = units.speed_from_bar(params, float(np.nanmax(np.array(runs["open_loop"]["xdotbar"], float)[at])))
    command = fixed_power(params, y, xdot, math.radians(26.0), alphas[at]).command()
    result = apex_return_map(params, ApexState(y, xdot), command)
    assert result.liftoff is not None and result.touchdown is not None
    scale = units.length_scale(params) / units.speed_scale(params)  # sqrt(r0/g): tbar = t sqrt(g/r0)
    stance = (result.liftoff.t - result.touchdown.t) / scale
    near = int(np.argmin(np.abs(alphas - 1.5)))
    paper_points, stance_points = (
        points[near][np.isfinite(points[near])] for points in (paper_tf, stance_tf)
    )
    # Each fixed point with the paper's t_f against the nearest one with t_f = the stance.
    distance = np.abs(paper_points[:, None] - stance_points[None, :])
    shift = float(np.max(np.min(distance, axis=1))) if distance.size else math.nan
    analytic = f"alpha {alphas[at]:g}: tbar_f = {command.t_f / scale:.4f} (the analytic liftoff)"
    exact = (
        f"stance {stance:.4f} with that ramp; with t_f = stance the fixed points move by {shift:.3f} in "
        f"Ebar at alpha {alphas[near]:g}"
    )
    return analytic, exact


def _convergence(documents: Documents) -> tuple[str, str]:
    data = documents["fig10"]
    converged = sum(1 for row in data["outcome"] for outcome in row if outcome == "converged")
    within = data["converged_within_8_strides"]
    exact = f"{within} of {converged} converged lanes ({100 * within / max(converged, 1):.0f} %) within 8"
    return "-", exact


def _fig10_match(documents: Documents) -> tuple[str, str]:
    data = documents["fig10"]
    analytic = data["analytic"]
    exact = data["exact_by_eigenvalue"]
    goals, exact_y = np.array(exact["parameter"]), np.array(exact["ybar"], dtype=float)
    analytic_y = np.array(analytic["ybar"], dtype=float)
    analytic_stable = np.array(analytic["stable"], dtype=bool)
    analytic_stable_y = np.where(analytic_stable, analytic_y, -np.inf).max(axis=1)
    lines = np.interp(
        goals,
        np.array(analytic["parameter"]),
        np.where(np.isfinite(analytic_stable_y), analytic_stable_y, np.nan),
    )
    exact_stable_y = np.where(np.array(exact["stable"], dtype=bool), exact_y, -np.inf).max(axis=1)
    difference = np.abs(lines - np.where(np.isfinite(exact_stable_y), exact_stable_y, np.nan))
    worst = int(np.nanargmax(difference)) if np.isfinite(difference).any() else 0
    return (
        "stable fixed points over Ebar 2-6",
        f"largest |d ybar*| {np.nanmax(difference):.3f} at Ebar {goals[worst]:.2f}; "
        f"median {np.nanmedian(difference):.4f}",
    )


def _deadbeat_edge(documents: Documents) -> tuple[str, str]:
    edge = documents["fig13"]["edge"]
    outcomes = ", ".join(
        f"{speed:g} m/s: {outcome}" + (f" (stride {stride})" if stride >= 0 else "")
        for speed, outcome, stride in zip(
            edge["target_xdot"], edge["outcome"], edge["failure_stride"], strict=True
        )
    )
    return "-", f"y* = {edge['target_y']} m, {edge['strides']} strides: {outcomes}"


def _ground_reaction(documents: Documents) -> tuple[str, str]:
    """fig. 12 (3 m/s, m = 65.4 kg): TD-SLIP's braking peak beside the SLIP's, and where its footfalls lie."""
    td_slip, slip = documents["fig12"]["td_slip"], documents["fig12"]["slip"]
    braking, slip_braking = td_slip["peak_braking"], slip["peak_braking"]["grf_x_N"]
    touchdown, liftoff = td_slip["footfall_at_touchdown_m"], td_slip["footfall_at_liftoff_m"]
    return "-", (
        f"braking peak {braking['grf_x_N']:.0f} N at {100 * braking['stance_ratio']:.0f} % of stance "
        f"(SLIP {slip_braking:.0f} N); footfall {touchdown:.2f} m at touchdown, {liftoff:.3f} m at liftoff; "
        f"SLIP's {slip['largest_footfall_offset_m']:.0e} m"
    )


def _prediction_error(params: HopperParams) -> tuple[str, str]:
    exact = analytic_accuracy.exact_strides(params, analytic_accuracy.OPERATING_GRID)
    accuracy = analytic_accuracy.accuracy(params, exact, corrections=1)
    analytic = (
        f"mean {100 * accuracy.mean_height_error:.2f} % (height), "
        f"{100 * accuracy.mean_speed_error:.2f} % (speed); "
        f"max {100 * accuracy.max_height_error:.1f} %, {100 * accuracy.max_speed_error:.1f} %; "
        f"the paper's eq. 7 speed: mean {100 * accuracy.mean_liftoff_speed_error:.2f} %, "
        f"max {100 * accuracy.max_liftoff_speed_error:.1f} %"
    )
    return analytic, f"truth: the exact plant, {accuracy.lanes} strides of the operating grid"


def _accuracy_domain(params: HopperParams) -> tuple[str, str]:
    """Per map and quantity, the compressions up to which every stride of the fine domain grid errs less
    than 5 %, over the touchdown angles where the least compressed stride does (docs/paper.md has 1 %)."""
    grid = analytic_accuracy.FINE_DOMAIN_GRID
    domain = analytic_accuracy.domain_errors(params, analytic_accuracy.exact_strides(params, grid))
    parts: list[str] = []
    columns: tuple[tuple[str, SpeedSource, Quantity], ...] = (
        ("height", "liftoff", "height"),
        ("speed, ours", "energy", "speed"),
        ("eq. 7 speed", "liftoff", "speed"),
    )
    for name, speed, quantity in columns:
        found = analytic_accuracy.boundaries(domain, speed, quantity, 0.05)
        below = [boundary.below for boundary in found if boundary.below is not None]
        where = f"{min(below):.2f}-{max(below):.2f}" if below else "none"
        parts.append(f"{where} ({name}, {len(below)} of {len(found)}{' angles' if not parts else ''})")
    compared = domain.compression[~np.isnan(domain.errors["liftoff", "height"])]
    degrees = np.degrees(grid.angles)
    return (
        "every stride within 5 % up to compression " + ", ".join(parts),
        f"truth: the exact plant, {compared.size} strides, {degrees.min():g}-{degrees.max():g} deg, "
        f"compression {compared.min():.2f}-{compared.max():.2f}",
    )


def _speed_scale(params: HopperParams) -> tuple[str, str]:
    return (
        f"xdotbar 1.5 = {units.speed_from_bar(params, 1.5):.2f} m/s (g = {params.g}, r0 = {params.r0} m)",
        "-",
    )


RowSpec = tuple[str, str, tuple[str, ...], str, Callable[[Documents, HopperParams], tuple[str, str]]]
ROWS: tuple[RowSpec, ...] = (
    (
        "stable Ebar range, beta = 20 deg (IV.C)",
        "[1.1, 3.4]",
        ("ranges",),
        "stable-ranges",
        lambda documents, params: _stable_ranges(documents, "20"),
    ),
    (
        "stable Ebar range, beta = 22 deg (figs 8, 9)",
        "figure only",
        ("ranges",),
        "stable-ranges",
        lambda documents, params: _stable_ranges(documents, "22"),
    ),
    (
        "stable Ebar range, beta = 26 deg (fig. 10)",
        "figure only",
        ("ranges",),
        "stable-ranges",
        lambda documents, params: _stable_ranges(documents, "26"),
    ),
    (
        "stable Ebar range, beta = 30 deg (IV.C)",
        "[3.45, 11.9]",
        ("ranges",),
        "stable-ranges",
        lambda documents, params: _stable_ranges(documents, "30"),
    ),
    (
        "fig. 11: the range grows with beta",
        "grows",
        ("fig11",),
        "",
        lambda documents, params: _trend(documents, "beta_deg"),
    ),
    (
        "fig. 11: the range grows with stiffness kbar",
        "grows",
        ("fig11",),
        "",
        lambda documents, params: _trend(documents, "kbar"),
    ),
    (
        "fig. 11: more damping zeta0 slightly shrinks the range",
        "shrinks slightly",
        ("fig11",),
        "damping",
        lambda documents, params: _trend(documents, "zeta0"),
    ),
    (
        "open loop, beta = 26 deg: a robust ~2 r0 family and a realistic marginal one (III.B)",
        "(i) ~2 r0, |lambda| well below 1; (ii) realistic, |lambda| ~ 1",
        ("fig04",),
        "",
        lambda documents, params: _families(documents),
    ),
    (
        "open loop, beta = 32 deg (fig. 6b)",
        "no region with three fixed points",
        ("fig06",),
        "beta-32",
        lambda documents, params: _three_fixed_points(documents),
    ),
    (
        "open loop: t_f = the predicted liftoff time (II.D, III.A)",
        "t_f = t_lo",
        ("fig07",),
        "open-loop-tf",
        _open_loop_tf,
    ),
    (
        "fig. 10: exact fixed points match the analytic ones",
        "almost exact, except near the low-energy saddle node",
        ("fig10",),
        "stable-ranges",
        lambda documents, params: _fig10_match(documents),
    ),
    (
        "convergence of the regulated exact plant (IV.B)",
        "at most ~8 strides from most initial conditions",
        ("fig10",),
        "convergence",
        lambda documents, params: _convergence(documents),
    ),
    (
        "deadbeat towards an apex below r0 (V, issue 9)",
        "-",
        ("fig13",),
        "deadbeat-edge",
        lambda documents, params: _deadbeat_edge(documents),
    ),
    (
        "fig. 12: TD-SLIP's GRF and virtual footfalls at 3 m/s against the SLIP's (IV.D)",
        "large braking early; footfalls behind the toe, meeting it at liftoff; SLIP's at the toe",
        ("fig12",),
        "fig-12",
        lambda documents, params: _ground_reaction(documents),
    ),
    (
        "analytic map's next-apex error (II.C)",
        "no number",
        (),
        "prediction-error",
        lambda documents, params: _prediction_error(params),
    ),
    (
        "analytic map's accuracy domain (II.C)",
        '"accurate for leg compressions up to %75 of the spring rest length as well as deviations of up to '
        '30 deg away from the vertical"',
        (),
        "accuracy-domain",
        lambda documents, params: _accuracy_domain(params),
    ),
    ("xdotbar = 1.5 (IV.B)", "about 4.7 m/s", (), "", lambda documents, params: _speed_scale(params)),
)


def rows(documents: Documents, params: HopperParams) -> list[Row]:
    """The table's rows from the figure documents of one run (rows lacking a figure say so)."""
    table = []
    for claim, paper, figures, explanation, compute in ROWS:
        if all(name in documents for name in figures):
            analytic, exact = compute(documents, params)
        else:
            analytic = exact = "not computed in this run"
        table.append(Row(claim, paper, analytic, exact, figures, explanation))
    return table


def markdown(table: list[Row]) -> str:
    """The table as Markdown (comparison.md; docs/paper.md quotes it)."""
    lines = [
        "| claim | paper | ours, analytic map | ours, exact plant | reproduce | explained |",
        "|---|---|---|---|---|---|",
    ]
    for row in table:
        where = f"docs/paper.md#{row.explanation}" if row.explanation else ""
        cells = (row.claim, row.paper, row.analytic, row.exact, f"`{row.command}`", where)
        lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |")
    return "\n".join(lines) + "\n"


def text(table: list[Row]) -> str:
    """The table as plain text for the terminal: one block per claim."""
    blocks = []
    for row in table:
        blocks.append(
            f"{row.claim}\n  paper:    {row.paper}\n  analytic: {row.analytic}\n  exact:    {row.exact}\n"
            f"  command:  {row.command}"
            + (f"\n  see:      docs/paper.md#{row.explanation}" if row.explanation else "")
        )
    return "\n".join(blocks) + "\n"
