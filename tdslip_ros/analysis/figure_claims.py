"""Our side of the paper's claims, read from the figure documents of one ``tdslip figures`` run: the rows of
:mod:`.paper_comparison` that name figures. Each function takes the documents by figure name (a figure's data
as drawn, or its JSON document: complex eigenvalues or [re, im], NaN or null) and returns our cells, on the
analytic map and on the exact plant, as text. A few compute small numbers of their own from the model, with
their figure: the open-loop t_f at alpha = 1 (fig. 7), the first strides of fig. 10's starts.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tdslip_ros.model import units
from tdslip_ros.model.params import ApexState, HopperParams
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.policies.controllers import fixed_power
from tdslip_ros.model.stability import analytic_fixed_points

Documents = dict[str, dict[str, Any]]
"""Figure documents by figure name (fig04, ..., ranges)."""


def _range(ends: Any) -> str:
    if ends is None or not all(isinstance(end, float) and math.isfinite(end) for end in ends):
        return "none"
    return f"[{ends[0]:.2f}, {ends[1]:.2f}]"


def stable_ranges(documents: Documents, beta: str) -> tuple[str, str]:
    ranges = documents["ranges"]
    exact = f"energy {_range(ranges['energy'][beta])}; energy_exact {_range(ranges['energy_exact'][beta])}"
    return _range(ranges["analytic"][beta]), exact


def trend(documents: Documents, study: str) -> tuple[str, str]:
    """The stable ranges of fig. 11 over the values of one parameter, analytic and exact."""
    entries = documents["fig11"][study]

    def listed(key: str) -> str:
        return "; ".join(f"{entry['value']:g}: {_range(entry[key])}" for entry in entries)

    return listed("stable_Ebar_range"), listed("exact_stable_Ebar_range")


def three_fixed_points(documents: Documents) -> tuple[str, str]:
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


def families(documents: Documents) -> tuple[str, str]:
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


def open_loop_tf(documents: Documents, params: HopperParams) -> tuple[str, str]:
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


def convergence(documents: Documents) -> tuple[str, str]:
    data = documents["fig10"]
    converged = sum(1 for row in data["outcome"] for outcome in row if outcome == "converged")
    within = data["converged_within_8_strides"]
    exact = f"{within} of {converged} converged lanes ({100 * within / max(converged, 1):.0f} %) within 8"
    return "-", exact


def fig10_match(documents: Documents) -> tuple[str, str]:
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


def deadbeat_edge(documents: Documents) -> tuple[str, str]:
    edge = documents["fig13"]["edge"]
    outcomes = ", ".join(
        f"{speed:g} m/s: {outcome}" + (f" (stride {stride})" if stride >= 0 else "")
        for speed, outcome, stride in zip(
            edge["target_xdot"], edge["outcome"], edge["failure_stride"], strict=True
        )
    )
    return "-", f"y* = {edge['target_y']} m, {edge['strides']} strides: {outcomes}"


def ground_reaction(documents: Documents) -> tuple[str, str]:
    """fig. 12 (3 m/s, m = 65.4 kg): TD-SLIP's braking peak beside the SLIP's, and where its footfalls lie."""
    td_slip, slip = documents["fig12"]["td_slip"], documents["fig12"]["slip"]
    braking, slip_braking = td_slip["peak_braking"], slip["peak_braking"]["grf_x_N"]
    touchdown, liftoff = td_slip["footfall_at_touchdown_m"], td_slip["footfall_at_liftoff_m"]
    return "-", (
        f"braking peak {braking['grf_x_N']:.0f} N at {100 * braking['stance_ratio']:.0f} % of stance "
        f"(SLIP {slip_braking:.0f} N); footfall {touchdown:.2f} m at touchdown, {liftoff:.3f} m at liftoff; "
        f"SLIP's {slip['largest_footfall_offset_m']:.0e} m"
    )


def fig05_counts(documents: Documents) -> tuple[str, str]:
    """III.B: how many fixed points each (beta, alpha) cell of fig. 5 has, and how many of them are stable."""
    data = documents["fig05"]

    def counted(prefix: str) -> str:
        count = np.array(data[f"{prefix}fixed_point_count"])
        stable = np.array(data[f"{prefix}stable_fixed_point_count"])
        three = count >= 3
        pattern = np.sum(three & (stable == 2) & (count == 3))
        return (
            f"1 in {np.sum(count == 1)} of {count.size} cells; 3 in {np.sum(three)} ({pattern} of them 2 "
            f"stable + 1 unstable); 2 in {np.sum(count == 2)}; none in {np.sum(count == 0)}"
        )

    return counted(""), counted("exact_")


def fig05_beta_band(documents: Documents) -> tuple[str, str]:
    """III.B: at each alpha of fig. 5, the cells with a fixed point but no stable one, below and above the
    touchdown angles with a stable one."""
    data = documents["fig05"]
    betas, alphas = np.array(data["beta_deg"]), np.array(data["alpha"])

    def band(prefix: str) -> str:
        count = np.array(data[f"{prefix}fixed_point_count"])
        stable = np.array(data[f"{prefix}stable_fixed_point_count"]) > 0
        unstable = (count > 0) & ~stable
        below = above = columns = 0
        for column in range(alphas.size):
            rows = np.flatnonzero(stable[:, column])
            if rows.size == 0:
                continue
            columns += 1
            below += bool(unstable[: rows.min(), column].any())
            above += bool(unstable[rows.max() + 1 :, column].any())
        first, last = (np.flatnonzero(stable[:, column]) for column in (0, alphas.size - 1))

        def ends(rows: np.ndarray) -> str:
            return span(betas[rows]) if rows.size else "none"

        return (
            f"stable beta {ends(first)} deg at alpha {alphas[0]:g}, {ends(last)} at {alphas[-1]:g}; unstable "
            f"below them at {below}, above at {above} of {columns} alphas"
        )

    return band(""), band("exact_")


def span(values: Any, digits: int = 0) -> str:
    """'low-high' of some values, or the one value."""
    low, high = (
        f"{value:.{digits}f}" if digits else f"{value:g}" for value in (np.min(values), np.max(values))
    )
    return low if low == high else f"{low}-{high}"


def _stable_alphas(points: dict[str, Any]) -> str:
    alphas = np.array(points["parameter"])
    stable = np.array(points["stable"], dtype=bool).any(axis=1)
    return f"{alphas[stable].min():.2f}-{alphas[stable].max():.2f}" if stable.any() else "none"


def _three_alphas(points: dict[str, Any]) -> str:
    alphas = np.array(points["parameter"])
    three = np.sum(np.isfinite(np.array(points["ybar"], dtype=float)), axis=1) >= 3
    return f"{alphas[three].min():.2f}-{alphas[three].max():.2f}" if three.any() else "nowhere"


def saddle_nodes(documents: Documents) -> tuple[str, str]:
    """Fig. 6a: the saddle-nodes bounding the three fixed points, and where a fixed point is stable."""
    panel = documents["fig06"]["a"]
    nodes = ", ".join(f"{alpha:.3f}" for alpha in panel["saddle_node_alpha"]) or "none"
    step = panel["parameter"][1] - panel["parameter"][0]
    return (
        f"saddle-nodes at alpha {nodes}; 3 fixed points at {_three_alphas(panel)}; "
        f"stable for alpha {_stable_alphas(panel)} only",
        f"3 fixed points at alpha {_three_alphas(panel['exact'])} (step {step:.2f}); "
        f"stable for alpha {_stable_alphas(panel['exact'])} only",
    )


def fig07_speed(documents: Documents) -> tuple[str, str]:
    """Fig. 7 (b), (c): the runs from the two crosses, and the eigenvalues of their fixed points."""
    data = documents["fig07"]
    analytic = data["analytic"]
    alphas = np.array(analytic["parameter"])
    exact = data["exact_by_eigenvalue"]["open_loop"]
    exact_alphas = np.array(exact["parameter"])

    def most_stable(points: dict[str, Any], row: int) -> tuple[float, float]:
        radius = np.array(points["spectral_radius"], dtype=float)[row]
        radius = np.where(np.isfinite(radius), radius, np.inf)
        column = int(np.argmin(radius))
        return float(np.array(points["ybar"], dtype=float)[row, column]), float(radius[column])

    analytic_parts, exact_parts = [], []
    for run in data["runs"]:
        y, r = most_stable(analytic, int(np.argmin(np.abs(alphas - run["alpha"]))))
        analytic_parts.append(f"alpha {run['alpha']:g}: |lambda| {r:.2f} (ybar* {y:.2f})")
        _, exact_r = most_stable(exact, int(np.argmin(np.abs(exact_alphas - run["alpha"]))))
        if run["convergence_stride"] >= 0:
            exact_parts.append(f"alpha {run['alpha']:g} settles at stride {run['convergence_stride']}")
        else:
            change = np.maximum(np.abs(np.diff(run["ybar"])), np.abs(np.diff(run["xdotbar"])))
            rate = (change[-1] / change[-51]) ** (1 / 50)
            exact_parts.append(
                f"alpha {run['alpha']:g} not in {data['strides']}: its change shrinks {rate:.3f} per stride "
                f"(|lambda| {exact_r:.3f})"
            )
    return "; ".join(analytic_parts), "; ".join(exact_parts)


REALISTIC_YBAR = 1.1
"""Open-loop fixed points below this apex height are the paper's realistic family (ii)."""


def fig07_basin(documents: Documents) -> tuple[str, str]:
    """Fig. 7: lanes settled on the realistic fixed points, and at the alphas where those are the exact
    plant's only (stable) ones, the lanes that end within 0.01 of them after the run."""
    data = documents["fig07"]
    analytic = data["analytic"]
    y = np.array(analytic["ybar"], dtype=float)
    stable = np.array(analytic["stable"], dtype=bool)
    radius = np.array(analytic["spectral_radius"], dtype=float)[stable & (y < REALISTIC_YBAR)]
    settled_y = np.array(data["exact_fixed_ybar"], dtype=float)
    settled = np.sum(settled_y < REALISTIC_YBAR)
    exact = data["exact_by_eigenvalue"]["open_loop"]
    exact_y = np.array(exact["ybar"], dtype=float)
    exact_stable = np.array(exact["stable"], dtype=bool)
    only = (np.sum(np.isfinite(exact_y), axis=1) == 1) & exact_stable.any(axis=1)
    only &= np.nanmax(exact_y, axis=1, initial=-np.inf, where=np.isfinite(exact_y)) < REALISTIC_YBAR
    alphas = np.array(data["alpha"])[only]
    star = np.nanmax(np.where(np.isfinite(exact_y), exact_y, -np.inf), axis=1)[only]
    last = np.array(data["last_ybar"], dtype=float)[only]
    near = np.abs(last - star[:, None]) < 0.01
    exact_radius = np.array(exact["spectral_radius"], dtype=float)[only, 0]
    return (
        f"stable fixed points below ybar {REALISTIC_YBAR}: |lambda| {radius.min():.3f}-{radius.max():.3f}"
        if radius.size
        else "no stable fixed point below ybar 1.1",
        f"{settled} lanes settle on them in {data['strides']} strides; at alpha "
        f"{alphas.min():.2f}-{alphas.max():.2f} (|lambda| {exact_radius.min():.2f}-{exact_radius.max():.2f}) "
        f"{near.sum()} of {near.size} end within 0.01 of them"
        if alphas.size
        else f"{settled} lanes settle on them in {data['strides']} strides",
    )


def _real(value: Any) -> float:
    """The real part of an eigenvalue as a figure holds it (complex) or its JSON document does ([re, im],
    null for NaN)."""
    if isinstance(value, complex):
        return value.real
    return math.nan if value is None or value[0] is None else float(value[0])


def _unstable(panels: list[tuple[dict[str, Any], str]]) -> tuple[str, str]:
    """Per touchdown angle (a panel of fixed points with their exact check, and the angle in degrees): the
    most fixed points at one energy, the eigenvalues at +1 or above (a saddle-node needs one), the largest
    eigenvalue, and the energy from which one is below -1 (a flip)."""

    def summary(points: dict[str, Any], beta: str) -> tuple[int, float, int, str]:
        y = np.array(points["ybar"], dtype=float)
        eigenvalue = np.array([[_real(values[0]) for values in row] for row in points["eigenvalues"]])
        saddles = int(np.sum(eigenvalue >= 1.0))
        energies = np.array(points["parameter"])[np.any(eigenvalue <= -1.0, axis=1)]
        flips = f"{beta} deg: Ebar >= {energies.min():.2f}" if energies.size else ""
        return int(np.sum(np.isfinite(y), axis=1).max()), float(np.nanmax(eigenvalue)), saddles, flips

    def cell(exact: bool) -> str:
        found = [summary(points["exact"] if exact else points, beta) for points, beta in panels]
        flips = "; ".join(flips for *_, flips in found if flips) or "none"
        return (
            f"at most {max(most for most, *_ in found)} per Ebar; lambda >= 1 at "
            f"{sum(saddles for _, _, saddles, _ in found)}; largest "
            + " / ".join(f"{largest:.2f}" for _, largest, *_ in found)
            + f" ({' / '.join(beta for _, beta in panels)} deg); flips: {flips}"
        )

    return cell(False), cell(True)


def fig08_unstable(documents: Documents) -> tuple[str, str]:
    """Figs 8, 9 at 22 and 30 deg (:func:`_unstable`)."""
    fig08 = documents["fig08"]
    return _unstable([(fig08["beta_22"]["fixed_points"], "22"), (fig08["beta_30"]["fixed_points"], "30")])


def fig10_unstable(documents: Documents) -> tuple[str, str]:
    """Fig. 10 at 26 deg, the exact plant's fixed points by eigenvalue (:func:`_unstable`)."""
    fig10 = documents["fig10"]
    return _unstable([(fig10["analytic"] | {"exact": fig10["exact_by_eigenvalue"]}, "26")])


def fig10_basin(documents: Documents) -> tuple[str, str]:
    data = documents["fig10"]
    counts = data["outcome_counts"]
    lanes = sum(counts.values())
    analytic_count = np.sum(np.isfinite(np.array(data["analytic"]["ybar"], dtype=float)), axis=1)
    analytic = (
        f"{analytic_count.max()} fixed point per Ebar, stable"
        if np.all(np.array(data["analytic"]["stable"], dtype=bool)[analytic_count > 0].any(axis=1))
        else f"at most {analytic_count.max()} fixed points per Ebar"
    )
    others = ", ".join(
        f"{count} {name.replace('_', ' ')}" for name, count in counts.items() if count and name != "converged"
    )
    return (
        analytic + ": no unstable one bounds the basin",
        f"{counts['converged']} of {lanes} starts converge; the others: {others}",
    )


def fig10_cavities(documents: Documents, params: HopperParams) -> tuple[str, str]:
    """Fig. 10's cavities: the exact plant's leg-placement failures (the apex they fail from against
    r0 cos beta), and the starts whose first stride the analytic map sends below it."""
    data = documents["fig10"]
    beta = math.radians(data["beta_deg"])
    energy = units.energy_from_bar(params, np.array(data["Ebar0"]))[:, None]
    y0 = units.height_from_bar(params, np.array(data["ybar0"]))[None, :]
    below = analytic_fixed_points.regulated_height_map(
        params, beta, energy, y0
    ) < analytic_fixed_points.lowest_height(params, beta)
    outcome = np.array(data["outcome"])
    cavity = outcome == "toe_stubbing"
    energies = np.array(data["Ebar0"])

    def where(mask: np.ndarray) -> str:
        rows = np.flatnonzero(mask.any(axis=1))
        return f"Ebar {span(energies[rows], 1)}" if rows.size else "nowhere"

    failed_from = np.array(data["failed_from_ybar"], dtype=float)[cavity]
    strides = np.array(data["failure_stride"])[cavity] + 1
    lowest = float(units.height_to_bar(params, analytic_fixed_points.lowest_height(params, beta)))
    return (
        f"1st stride below r0 cos(beta) from {below.sum()} starts ({where(below)}), "
        f"{np.sum(below & cavity)} of them exact cavities",
        f"{cavity.sum()} starts ({where(cavity)}) fail at stride {span(strides)} from ybar "
        f"{failed_from.min():.3f}-{failed_from.max():.4f}, {np.sum(failed_from < lowest)} below the "
        f"placement height {lowest:.4f}"
        if cavity.any()
        else "no leg-placement failure",
    )


def tracking(documents: Documents) -> tuple[str, str]:
    """Fig. 13: the xdotbar* deadbeat and ref. 36's baseline converge to, their largest errors there (speed,
    height), and at how many of the targets both reach deadbeat's are the smaller."""
    data = documents["fig13"]
    names = ("deadbeat", data["baseline"])
    stable = [np.array(data[name]["stable"], dtype=bool) for name in names]
    errors = [
        [np.abs(np.array(data[name][f"{q}_error_percent"], dtype=float)) for q in ("speed", "height")]
        for name in names
    ]
    parts = []
    for label, name, ok, (speed, height) in zip(("deadbeat", "baseline"), names, stable, errors, strict=True):
        where = span(data[name]["stable_xdotbar_range"]) if ok.any() else "none"
        worst = f", max {speed[ok].max():.2g} %, {height[ok].max():.2g} %" if ok.any() else ""
        parts.append(f"{label}: {where} ({ok.sum()} of {ok.size}){worst}")
    both = stable[0] & stable[1]
    smaller = [str(np.sum(errors[0][i][both] < errors[1][i][both])) for i in (0, 1)]
    return "-", "; ".join([*parts, f"deadbeat's smaller: {', '.join(smaller)} of {both.sum()}"])
