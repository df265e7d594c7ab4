"""The claims table (paper_comparison.ROWS) against docs/paper.md and the paper's text, and the numbers of the
claims of sections II.D-V measured again on tiny figure documents and on the model."""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import test_cli_figures

from tdslip_ros.analysis import figure_claims, figure_parameters, model_claims, paper_comparison
from tdslip_ros.analysis.figures import exact_basins, open_loop, parameter_dependence, regulated, tracking
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import approximate_map
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stance_laws import StanceFeedback
from tdslip_ros.model.policies.controllers import ramp_to_liftoff
from tdslip_ros.model.policies.stance_pd import StancePDSpeedEnergy
from tdslip_ros.model.stability import analytic_accuracy, analytic_fixed_points, basins
from tdslip_ros.reporting.output import to_json
from tdslip_ros.reporting.paper_grids import FIG11_STUDIES

PARAMS = PAPER_PARAMS
REPO_ROOT = Path(__file__).resolve().parents[1]
DOCS = REPO_ROOT / "docs" / "paper.md"
PAPER_TEXT = Path(
    os.environ.get(
        "TDSLIP_PAPER_TEXT", REPO_ROOT.parent / "shared" / "paper" / "td-slip-energy-regulation-2010.md"
    )
)
"""The paper's text (converted from the PDF; not part of the repository: beside it, in ../shared/paper/)."""
NUMBER = re.compile(r"\d+(?:\.\d+)?")
TINY = dataclasses.replace(test_cli_figures.TINY, betas=4, exact_energies=12)
"""test_cli_figures.TINY with four touchdown angles in fig05 (20, 24, 28, 32 deg), so that it has a band, and
12 goal energies over Ebar 0.8-22 for fig11's exact stable ranges (at 6 the narrowest fall between two)."""


def _cells(line: str) -> list[str]:
    return [cell.strip().replace("\\|", "|") for cell in re.split(r"(?<!\\)\|", line.strip().strip("|"))]


def _docs_claims_table() -> dict[str, list[str]]:
    """docs/paper.md's claims table: claim -> its cells."""
    lines = DOCS.read_text().splitlines()
    start = lines.index("| claim | paper | ours, analytic map | ours, exact plant | reproduce | explained |")
    table = {}
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        cells = _cells(line)
        table[cells[0]] = cells
    return table


def test_every_claim_of_the_comparison_is_a_row_of_the_docs_table_with_the_same_paper_cell() -> None:
    table = _docs_claims_table()
    for claim, paper, figures, explanation, _ in paper_comparison.ROWS:
        assert claim in table, f"docs/paper.md's claims table lacks {claim!r}"
        cells = table[claim]
        assert cells[1] == paper, claim
        assert cells[4] == f"`{paper_comparison.Row(claim, paper, '', '', figures, explanation).command}`"
        if explanation:
            assert f"(#{explanation})" in cells[5], claim
    assert len(table) == len(paper_comparison.ROWS)


def test_the_docs_quote_the_parameters_of_every_figure() -> None:
    text = DOCS.read_text()
    for line in figure_parameters.parameters_markdown().splitlines():
        assert line in text


@pytest.mark.skipif(not PAPER_TEXT.exists(), reason="the paper's text is not here")
def test_the_paper_cells_hold_only_numbers_the_paper_prints() -> None:
    printed = set(NUMBER.findall(PAPER_TEXT.read_text()))
    for cells in _docs_claims_table().values():
        for number in NUMBER.findall(cells[1]):
            assert number in printed, f"{number} of {cells[1]!r} is not in the paper"
    for _, paper, *_ in paper_comparison.ROWS:
        assert set(NUMBER.findall(paper)) <= printed, paper


def test_the_corrections_converge_on_every_stride_and_one_is_within_the_map_s_own_error() -> None:
    """II.D on the operating grid: every stride converges (the map's own stopping rule, checked against the
    kernel's count on single strides); one correction's next apex is within 0.5 % of the converged one's."""
    found = analytic_accuracy.correction_convergence(PARAMS, analytic_accuracy.OPERATING_GRID)
    assert found.index.size == len(analytic_accuracy.OPERATING_GRID.points())
    assert np.all((found.iterations >= 3) & (found.iterations <= 13))
    assert np.nanmax(found.height_change) < 0.005 and np.nanmax(found.speed_change) < 0.005
    assert 1e-5 < np.nanmedian(found.height_change)  # one correction is not yet converged
    points = np.array(analytic_accuracy.OPERATING_GRID.points())
    commands = ramp_to_liftoff(
        PARAMS, points[:, 0], points[:, 1], points[:, 2], units.torque_from_bar(PARAMS, points[:, 3])
    )
    for lane in (0, 50, 107):
        command, most = commands.command(lane), analytic_accuracy.CORRECTION_LIMIT
        stride = approximate_map(PARAMS, points[lane, 0], points[lane, 1], command, most)
        assert stride.stance.corrections_done == found.iterations[lane]
    analytic, exact = model_claims.corrections(PARAMS)
    assert analytic.startswith("converge: 108 of 108 in ")
    assert "1 correction 0.57 / 0.90 %" in exact


def test_eq_27_has_one_solution_and_none_where_the_map_fails_first() -> None:
    """III.A: at 26 deg exactly one sign change of E' - E along E, the root energy_fixed_point finds; at
    20 deg none at some (alpha, y), where the map has no stride before E' falls to E."""
    beta = math.radians(26.0)
    alphas, heights = (
        np.array([0.5, 1.5, 2.5])[:, None],
        analytic_fixed_points.height_grid(PARAMS, beta, points=6),
    )
    count, last = analytic_fixed_points.energy_fixed_point_count(PARAMS, beta, alphas, heights)
    assert np.all(count == 1) and np.all(last < 0)
    root = analytic_fixed_points.energy_fixed_point(PARAMS, beta, alphas, heights)
    assert np.all(np.isfinite(root))
    count, last = analytic_fixed_points.energy_fixed_point_count(
        PARAMS,
        math.radians(20.0),
        np.array([0.5, 1.5, 2.5])[:, None],
        analytic_fixed_points.height_grid(PARAMS, math.radians(20.0), points=20),
    )
    assert set(count.ravel().tolist()) == {0, 1} and np.all(last[count == 0] > 0)
    analytic, _ = model_claims.eq27_solutions(PARAMS)
    assert "2 or more at 0" in analytic and "all where the map fails" in analytic


FIGURES = {
    "fig05": open_loop.fig05,
    "fig06": open_loop.fig06,
    "fig07": exact_basins.fig07,
    "fig08": regulated.fig08,
    "fig10": exact_basins.fig10,
    "fig13": tracking.fig13,
    "fig11": parameter_dependence.fig11,
}
"""The figures whose documents the rows read, drawn here at TINY."""


def draw(name: str) -> dict[str, Any]:
    """The document of figure ``name`` at TINY."""
    return FIGURES[name](TINY, test_cli_figures.quiet(), "energy")[1]


@functools.cache
def _document(name: str) -> dict[str, Any]:
    # In one test process the background child draws the documents the selected tests read (conftest.py).
    background = getattr(sys.modules.get("support.analysis_runs"), "BACKGROUND", None)
    drawn = None if background is None else background.drawn(__name__, name)
    return draw(name) if drawn is None else drawn


def documents(*names: str) -> dict[str, dict[str, Any]]:
    """The documents of ``names``, each drawn once per test process. The tests that read a figure share its
    xdist group (conftest.py), so that the fast tier's two workers do not both draw it."""
    return {name: _document(name) for name in names}


@pytest.mark.xdist_group("fig05")
def test_fig05_three_fixed_points_are_two_stable_and_one_unstable_and_the_band_of_beta() -> None:
    data = documents("fig05")["fig05"]
    count, stable = np.array(data["fixed_point_count"]), np.array(data["stable_fixed_point_count"])
    assert np.all(stable <= count) and np.all(np.array(data["exact_stable_fixed_point_count"]) <= 3)
    assert np.any(count == 3) and np.any((count == 3) & (stable == 2))
    # The most stable fixed point of fig05 is stable exactly where a cell has a stable one.
    radius = np.array(data["spectral_radius"], dtype=float)
    assert np.array_equal(stable > 0, radius < 1.0)
    analytic, exact = figure_claims.fig05_counts(documents("fig05"))
    assert re.match(r"1 in \d+ of 44 cells; 3 in \d+ \(\d+ of them 2 stable \+ 1 unstable\)", analytic)
    analytic, exact = figure_claims.fig05_beta_band(documents("fig05"))
    # At alpha 0.5 only 20 deg is stable; at 2.5 the steep angles; unstable on both sides in between.
    assert analytic.startswith("stable beta 20 deg at alpha 0.5, 28-32 at 2.5; unstable below them at ")
    below, above = (int(n) for n in re.findall(r"(?:below them|above) at (\d+)", analytic))
    assert below > 0 and above > 0


@pytest.mark.xdist_group("fig06")
def test_fig06_saddle_nodes_bound_the_three_fixed_points() -> None:
    panel = documents("fig06")["fig06"]["a"]
    low, high = panel["saddle_node_alpha"]
    alphas = np.array(panel["parameter"])
    three = alphas[np.sum(np.isfinite(np.array(panel["ybar"], dtype=float)), axis=1) == 3]
    assert three.size and low < three.min() and three.max() < high
    analytic, _ = figure_claims.saddle_nodes(documents("fig06"))
    assert analytic.startswith(f"saddle-nodes at alpha {low:.3f}, {high:.3f}; 3 fixed points at ")


@pytest.mark.xdist_group("fig07")
def test_fig07_fast_at_alpha_1_slow_at_1_5_at_the_rate_of_its_eigenvalue() -> None:
    data = documents("fig07")["fig07"]
    fast, slow = data["runs"]
    assert (fast["alpha"], slow["alpha"]) == (1.0, 1.5)
    assert 0 <= fast["convergence_stride"] <= 30 and slow["convergence_stride"] == -1
    _, exact = figure_claims.fig07_speed(documents("fig07"))
    found = re.search(r"shrinks ([\d.]+) per stride \(\|lambda\| ([\d.]+)\)", exact)
    assert found is not None
    rate, radius = (float(x) for x in found.groups())
    assert rate == pytest.approx(radius, abs=0.005) and 0.95 < radius < 1.0
    assert np.array(data["last_ybar"]).shape == np.array(data["outcome"]).shape
    analytic, exact = figure_claims.fig07_basin(documents("fig07"))
    assert re.match(r"stable fixed points below ybar 1.1: \|lambda\| 0.9\d\d-0.9\d\d", analytic)
    assert re.match(r"\d+ lanes settle on them in 150 strides", exact)


@pytest.mark.xdist_group("fig08")
def test_regulated_maps_have_no_unstable_fixed_point_below_the_flip() -> None:
    """Figs 9, 10: at most one fixed point per energy, no eigenvalue at +1 or above, unstable only by the
    flip at high energy (22 deg)."""
    figs_8_9 = figure_claims.fig08_unstable(documents("fig08"))
    fig10 = figure_claims.fig10_unstable(documents("fig10"))
    for cell, angles in [*((cell, "22 / 30") for cell in figs_8_9), *((cell, "26") for cell in fig10)]:
        assert cell.startswith("at most 1 per Ebar; lambda >= 1 at 0; largest ")
        found = re.search(r"largest ([-\d./ ]+) \((.*) deg\)", cell)
        assert found is not None and found.group(2) == angles
        assert all(float(x) < 1.0 for x in found.group(1).split(" / "))
    assert "22 deg: Ebar >= " in figs_8_9[0]


@pytest.mark.xdist_group("fig10")
def test_fig10_cavities_are_leg_placement_failures_and_the_basin_s_other_edges() -> None:
    data = documents("fig10")["fig10"]
    outcome = np.array(data["outcome"])
    failed_from = np.array(data["failed_from_ybar"], dtype=float)
    lowest = units.height_to_bar(
        PARAMS, analytic_fixed_points.lowest_height(PARAMS, math.radians(data["beta_deg"]))
    )
    cavity = outcome == "toe_stubbing"
    assert cavity.any() and np.all(failed_from[cavity] < lowest)
    assert np.all(np.isnan(failed_from[np.isin(outcome, ["converged", "sustained"])]))
    analytic, exact = figure_claims.fig10_cavities(documents("fig10"), PARAMS)
    found = re.match(r"1st stride below r0 cos\(beta\) from (\d+) starts .*, (\d+) of", analytic)
    assert found is not None
    below, inside = (int(n) for n in found.groups())
    assert below == inside
    assert re.match(rf"{cavity.sum()} starts \(Ebar 6.0\) fail at stride 2 ", exact)
    assert exact.endswith(f"{cavity.sum()} below the placement height {lowest:.4f}")
    analytic, exact = figure_claims.fig10_basin(documents("fig10"))
    assert analytic.startswith("1 fixed point per Ebar, stable")
    assert exact.startswith(f"{data['outcome_counts']['converged']} of 9 starts converge")


def _fig11_ranges(study: str, key: str) -> np.ndarray:
    """(values, 2) the stable Ebar ranges of fig11's curves varying ``study``, the analytic map's
    (``stable_Ebar_range``) or the exact plant's (``exact_stable_Ebar_range``)."""
    curves = documents("fig11")["fig11"][study]
    assert [curve["value"] for curve in curves] == list(FIG11_STUDIES[study])
    ends = np.array([curve[key] for curve in curves], dtype=float)
    assert np.all(np.isfinite(ends)), (study, key, ends)
    return ends


FIG11_RANGES = ("stable_Ebar_range", "exact_stable_Ebar_range")


@pytest.mark.xdist_group("fig11")
@pytest.mark.parametrize("study", ["beta_deg", "kbar"])
def test_fig11_the_stable_range_grows_with_beta_and_with_the_stiffness(study: str) -> None:
    """IV.C, fig. 11: the range of stable energies grows with the touchdown angle beta and with the leg
    stiffness kbar (the others at 26 deg, 36, 0.08), on the analytic map and on the exact plant; its upper end
    rises with them."""
    for key in FIG11_RANGES:
        ends = _fig11_ranges(study, key)
        assert np.all(np.diff(ends[:, 1] - ends[:, 0]) > 0), (key, ends)
        assert np.all(np.diff(ends[:, 1]) > 0), (key, ends)


@pytest.mark.xdist_group("fig11")
def test_fig11_more_damping_widens_the_stable_range_where_the_paper_has_it_shrink_slightly() -> None:
    """The paper (IV.C): "increasing the amount of damping causes a slight decrease in the range of stable
    energy levels". Ours differ, on the analytic map and on the exact plant alike: more damping widens the
    range at both ends, its flip moving to higher energies and its low-energy fixed point away from y_max(E)
    (docs/paper.md, damping, where an independent computation of the exact plant agrees)."""
    for key in FIG11_RANGES:
        ends = _fig11_ranges("zeta0", key)
        assert np.all(np.diff(ends[:, 0]) < 0) and np.all(np.diff(ends[:, 1]) > 0), (key, ends)


@pytest.mark.xdist_group("fig11")
def test_fig11_draws_fixed_points_of_each_hopper_s_regulated_map_over_its_stable_range() -> None:
    """Each curve of fig11 is its hopper's stable fixed points (ybar*, xdotbar*) over the goal energies: they
    map to themselves under that hopper's regulated map at its angle, their speed is the energy's
    (xdotbar^2 = 2 (Ebar - ybar), eq. 24), and they are drawn at the energies inside the legend's stable
    range and at none outside it."""
    data = documents("fig11")["fig11"]
    margin = 0.01  # Ebar: the range's ends are bisected to ~0.008 (RANGE_EBAR over 12 energies, 8 halvings)
    for study, value, kbar, zeta0, beta_deg in parameter_dependence.fig11_hoppers():
        curve = next(curve for curve in data[study] if curve["value"] == value)
        params = HopperParams.from_dimensionless(kbar, zeta0)
        energy_bar = np.array(curve["Ebar"])
        y_bar, xdot_bar = (np.array(curve[name], dtype=float) for name in ("ybar", "xdotbar"))
        drawn = np.isfinite(y_bar)
        low, high = curve["stable_Ebar_range"]
        inside = (energy_bar > low + margin) & (energy_bar < high - margin)
        outside = (energy_bar < low - margin) | (energy_bar > high + margin)
        assert inside.any() and np.all(drawn[inside]) and not np.any(drawn[outside]), (study, value)
        y = units.height_from_bar(params, y_bar[drawn])
        mapped = analytic_fixed_points.regulated_height_map(
            params, math.radians(beta_deg), units.energy_from_bar(params, energy_bar[drawn]), y
        )
        np.testing.assert_allclose(mapped, y, rtol=1e-9)
        np.testing.assert_allclose(xdot_bar[drawn] ** 2, 2.0 * (energy_bar[drawn] - y_bar[drawn]), rtol=1e-9)


@pytest.mark.xdist_group("fig13")
def test_fig13_deadbeat_tracks_more_targets_than_the_stance_pd_baseline_and_the_height_better() -> None:
    """TINY's targets xdotbar* 0.25, 1.5, 2.75: deadbeat holds all three within 1 %; the baseline has no
    touchdown angle that holds 0.25 (its mark), and holds the others with smaller speed errors (its angle is
    matched to the speed), its height error smaller at 1.5 and larger at 2.75."""
    data = documents("fig13")["fig13"]
    assert data["xdotbar_target"] == [0.25, 1.5, 2.75] and data["baseline"] == tracking.BASELINE
    deadbeat, baseline = data["deadbeat"], data[tracking.BASELINE]
    assert all(deadbeat["stable"])
    assert np.max(np.abs([*deadbeat["speed_error_percent"], *deadbeat["height_error_percent"]])) < 1.0
    assert baseline["stable"] == [False, True, True] and baseline["outcome"][0] == "no_command"
    _, exact = figure_claims.tracking(documents("fig13"))
    deadbeat_part, baseline_part, smaller = exact.split("; ")
    assert deadbeat_part.startswith("deadbeat: 0.25-2.75 (3 of 3), max ")
    assert baseline_part.startswith("baseline: 1.5-2.75 (2 of 3), max ")
    # Deadbeat's error is the smaller in height at the faster target, in speed at neither: the paper's "better
    # tracking of apex speed and height" holds for the height only (docs/paper.md, fig. 13).
    both = np.array(deadbeat["stable"]) & np.array(baseline["stable"])
    counts = [
        int(np.sum(np.abs(deadbeat[name])[both] < np.abs(baseline[name])[both]))
        for name in ("speed_error_percent", "height_error_percent")
    ]
    assert smaller == f"deadbeat's smaller: {counts[0]}, {counts[1]} of {both.sum()}"
    assert counts == [0, 1] and both.sum() == 2


@pytest.mark.xdist_group("fig13")
def test_fig13_baseline_replays_on_the_exact_map_and_is_marked_where_it_fails_or_diverges() -> None:
    """Truth: the exact map (DOP853 with located events, the law sampled on the same 1 kHz grid) replays the
    baseline's 50th stride from its 49th apex and apex time to 1e-9, and from the final apex maps a stable
    target's apex onto itself within the convergence tolerance: a fixed point, not a slow drift. One stride
    from the target apex at the target's angle ends at the target speed, as the angle rule promises. A
    target marked as lost has no angle and no strides, or failed in a stride, or did not settle."""
    data = documents("fig13")["fig13"]
    baseline = data[tracking.BASELINE]
    target_y = units.height_from_bar(PARAMS, data["target_ybar"])
    speeds = units.speed_from_bar(PARAMS, np.array(data["xdotbar_target"]))
    last = baseline["last_apexes"]
    for lane, (outcome, angle) in enumerate(
        zip(baseline["outcome"], baseline["touchdown_angle_rad"], strict=True)
    ):
        (y_before, y_last), (xdot_before, xdot_last) = last["y_m"][lane], last["xdot_m_per_s"][lane]
        last_change = max(
            abs(units.height_to_bar(PARAMS, y_last - y_before)),
            abs(units.speed_to_bar(PARAMS, xdot_last - xdot_before)),
        )
        if outcome != "converged":
            assert not baseline["stable"][lane]
            if outcome == "no_command":  # no angle: not run at all
                assert math.isnan(angle) and math.isnan(y_last)
            elif outcome == "sustained":  # hopping, but not settled: still moving at the last stride
                assert last_change >= basins.CONVERGENCE_TOLERANCE
            else:  # a failure of the plant, in a stride before the last apex
                assert baseline["failure_stride"][lane] >= 0 and math.isnan(y_last)
            continue
        assert last_change < basins.CONVERGENCE_TOLERANCE
        command = StanceFeedback(angle, StancePDSpeedEnergy(PARAMS, target_y, float(speeds[lane])))
        calibration = apex_return_map(PARAMS, ApexState(target_y, float(speeds[lane])), command).apex
        assert calibration is not None
        assert calibration.xdot == pytest.approx(speeds[lane], rel=basins.SPEED_MATCH_TOLERANCE)
        t_before, t_last = last["t_s"][lane]
        stride = apex_return_map(PARAMS, ApexState(y_before, xdot_before), command, apex_time=t_before)
        assert stride.apex is not None and stride.apex_time is not None
        assert (stride.apex.y, stride.apex.xdot) == pytest.approx((y_last, xdot_last), abs=1e-9)
        assert t_before + stride.apex_time == pytest.approx(t_last, abs=1e-9)
        onward = apex_return_map(PARAMS, ApexState(y_last, xdot_last), command, apex_time=t_last).apex
        assert onward is not None
        change = max(
            abs(units.height_to_bar(PARAMS, onward.y - y_last)),
            abs(units.speed_to_bar(PARAMS, onward.xdot - xdot_last)),
        )
        assert change < basins.CONVERGENCE_TOLERANCE
        error = 100.0 * (xdot_last - speeds[lane]) / speeds[lane]
        assert baseline["speed_error_percent"][lane] == pytest.approx(error, rel=1e-12)


@pytest.mark.xdist_group("fig10")
def test_the_figures_json_says_what_the_text_says() -> None:
    """The text's numbers, read from the figures' JSON documents: fig. 10's protocol (beta 26 deg, Ebar in
    [2, 6], 50 steps) and its convergence, "at most 8 steps for most initial conditions" (IV.B), which holds
    where the exact fixed point's |lambda| is small (docs/paper.md#convergence); fig. 8 at 30 deg is stable
    over the part of "[3.45, 11.9]" (IV.C) it draws."""
    written = {name: json.loads(to_json(data)) for name, data in documents("fig08", "fig10").items()}
    fig10 = written["fig10"]
    assert (fig10["beta_deg"], fig10["strides"]) == (26.0, 50)
    assert (min(fig10["Ebar0"]), max(fig10["Ebar0"])) == (2.0, 6.0)
    converged = np.array(fig10["outcome"]) == "converged"
    strides = np.array(fig10["convergence_stride"])
    within = converged & (strides <= 8)
    assert fig10["converged_within_8_strides"] == within.sum() > converged.sum() / 2
    radius = np.array(fig10["exact_by_eigenvalue"]["spectral_radius"], dtype=float)[:, 0]
    fast = radius < 0.25  # per goal energy, the rows of the basin
    assert fast.any() and np.all(within[fast] == converged[fast]) and converged[fast].any()
    panel = written["fig08"]["beta_30"]["fixed_points"]
    energies = np.array(panel["parameter"])
    inside = (energies >= 3.45) & (energies <= 11.9)
    assert inside.sum() >= 3 and all(panel["stable"][i][0] for i in np.flatnonzero(inside))


@pytest.mark.skipif(not PAPER_TEXT.exists(), reason="the paper's text is not here")
def test_the_ranges_figure_draws_the_paper_s_ranges_as_the_text_prints_them() -> None:
    printed = re.findall(
        r"\\beta = (\d+)\^\{\\circ\}\$ ,\s*\$\\bar\{E\}_a \\in \[([\d.]+), ([\d.]+)\]", PAPER_TEXT.read_text()
    )
    assert {float(beta): (float(low), float(high)) for beta, low, high in printed} == regulated.PAPER_RANGES


@pytest.mark.parametrize(
    "row",
    [
        pytest.param(row, id=row[0], marks=pytest.mark.xdist_group(row[2][0]))
        for row in paper_comparison.ROWS
        if row[2] and set(row[2]) <= set(FIGURES)
    ],
)
def test_the_rows_read_a_figure_s_data_and_its_json_document_alike(row: paper_comparison.RowSpec) -> None:
    """``tdslip figures`` hands the rows the figures' data (complex eigenvalues, NaN); a reader of the JSON
    documents gets [re, im] and null: the rows say the same of both."""
    claim, _, figures, _, compute = row
    drawn = documents(*figures)
    written = {name: json.loads(to_json(data)) for name, data in drawn.items()}
    assert compute(drawn, PARAMS) == compute(written, PARAMS), claim
