"""``tdslip figures``: the figure data checked by content on tiny grids (never by pixels)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from support.helpers import assert_png, strict_json

from tdslip_ros.analysis import figure_claims, paper_comparison
from tdslip_ros.analysis.figures import catalogue, exact_basins, open_loop, regulated
from tdslip_ros.analysis.figures.common import Reporter, Resolution
from tdslip_ros.analysis.figures.shared import SHARED
from tdslip_ros.commands import cli
from tdslip_ros.commands import figures as figures_command
from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.policies.controllers import exact_energy_regulation
from tdslip_ros.model.stability import analytic_fixed_points, basins, exact_fixed_points
from tdslip_ros.studies import engine

TINY = Resolution(
    heights=24,
    alphas=9,
    betas=2,
    basin_alphas=3,
    basin_heights=3,
    energies=8,
    basin_energies=3,
    speed_step=1.25,
    exact_heights=16,
    exact_energies=6,
    bisections=2,
)
PARAMS = PAPER_PARAMS


def quiet() -> Reporter:
    """A reporter that stays silent (the figures' progress lines)."""
    return Reporter("test", interval=math.inf)


def test_the_command_is_registered_and_writes_a_png_and_strict_json_per_figure(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, dask_scheduler: str
) -> None:
    assert "figures" in cli.SUBCOMMANDS  # run by tdslip_ros.commands.figures
    monkeypatch.setattr(figures_command, "DEFAULT", TINY)  # the default resolution takes a minute per figure
    assert (
        cli.main(["figures", "--out", str(tmp_path), "--only", "fig09", "--scheduler", dask_scheduler]) == 0
    )
    assert_png(tmp_path / "fig09.png")
    document = strict_json(tmp_path / "fig09.json")
    assert document["figure"] == "fig09" and document["params"]["kbar"] == pytest.approx(36.0)
    assert document["resolution"] == vars(TINY)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["comparison.md", "fig09.json", "fig09.png"]
    # No claim reads fig09 alone (fig08 holds its fixed points): the table says so, and lists nothing else.
    assert (tmp_path / "comparison.md").read_text().startswith(paper_comparison.NO_ROWS + "\n| figure |")


def test_a_run_of_one_figure_reports_the_claims_of_that_figure_and_nothing_else(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], dask_scheduler: str
) -> None:
    """``--only fig08``: its one claim, filled with the numbers of fig08.json, printed and in comparison.md;
    no row of a figure not drawn, nor of the model alone (the full run's). At TINY's grid sizes, given as
    --resolution: the fixed points are traced over TINY.energies goal energies (the default has 57)."""
    sizes = [f"{name}={value:g}" for name, value in vars(TINY).items()]
    command = ["figures", "--out", str(tmp_path), "--only", "fig08", "--resolution", *sizes]
    assert cli.main([*command, "--scheduler", dask_scheduler]) == 0
    document = json.loads((tmp_path / "fig08.json").read_text())
    assert document["resolution"] == vars(TINY) != vars(figures_command.DEFAULT)
    assert len(document["beta_22"]["fixed_points"]["parameter"]) == TINY.energies
    analytic, exact = figure_claims.fig08_unstable({"fig08": document})
    claim = "figs 8, 9: unstable fixed points beside the stable ones (IV.B)"
    printed = capsys.readouterr().out
    assert printed.startswith(
        f"{claim}\n  paper:    stable and unstable fixed points\n  analytic: {analytic}\n"
    )
    assert printed.count("\n  paper: ") == 1 and f"  exact:    {exact}\n" in printed
    table = (tmp_path / "comparison.md").read_text().split("\n\n")[0].splitlines()
    assert len(table) == 3 and table[2].startswith(
        f"| {claim} | stable and unstable fixed points | {analytic} |"
    )


@pytest.mark.parametrize(
    ("setting", "error"),
    [
        ("energies=0", "energies must be a positive count, got '0'"),
        ("energies=2.5", "energies must be a positive count, got '2.5'"),
        ("speed_step=-1", "speed_step must be a positive number, got '-1'"),
        ("energy=5", "expected NAME=N with NAME one of heights, alphas, "),
        ("energies", "expected NAME=N with NAME one of heights, alphas, "),
    ],
)
def test_a_grid_size_no_figure_can_use_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], setting: str, error: str
) -> None:
    with pytest.raises(SystemExit) as raised:
        cli.main(["figures", "--out", str(tmp_path / "out"), "--resolution", setting])
    assert raised.value.code == 2
    message = capsys.readouterr().err
    assert message.startswith(f"tdslip figures: argument --resolution: {error}") and message.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_a_run_of_every_figure_computes_the_rows_the_model_alone_answers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The full run (here of a catalogue without figures, so that it takes no time) computes the rows that
    read no figure; only the cheapest of them is kept, the others take seconds."""
    speed_row = next(row for row in paper_comparison.ROWS if row[0] == "xdotbar = 1.5 (IV.B)")
    monkeypatch.setattr(paper_comparison, "ROWS", (speed_row,))
    monkeypatch.setattr(figures_command, "FIGURES", {})
    assert cli.main(["figures", "--out", str(tmp_path)]) == 0
    table = (tmp_path / "comparison.md").read_text()
    assert "| xdotbar = 1.5 (IV.B) | about 4.7 m/s | xdotbar 1.5 = 4.70 m/s " in table  # 1.5 sqrt(g r0)


def test_figures_with_the_paper_s_map_draw_that_map(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--map paper`` reaches the figures (the JSON says which map drew them), and fig04's fixed points are
    then those of the map with eq. 7's speed: each maps to itself under that map, not under ours."""
    monkeypatch.setattr(figures_command, "DEFAULT", TINY)
    assert cli.main(["figures", "--only", "fig04", "--map", "paper", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "fig04.json").read_text())
    assert data["analytic_map_speed"] == "liftoff"
    traced = data["c"]
    beta = math.radians(data["beta_deg"])
    y = units.height_from_bar(PARAMS, np.array(traced["ybar"], dtype=float))
    energy = units.energy_from_bar(PARAMS, np.array(traced["Ebar"], dtype=float))
    found = np.isfinite(y)
    assert found.sum() >= 5
    alpha = np.broadcast_to(np.array(traced["parameter"])[:, None], y.shape)[found]
    for speed, maps_to_itself in (("liftoff", True), ("energy", False)):
        y_next, energy_next = analytic_fixed_points.open_loop_energy_map(
            PARAMS, beta, alpha, y[found], energy[found], speed=speed
        )
        closes = np.isclose(y_next, y[found], rtol=1e-7) & np.isclose(energy_next, energy[found], rtol=1e-7)
        assert closes.all() if maps_to_itself else not closes.any()


def test_fig08_holds_the_regulated_maps_and_their_fixed_points() -> None:
    _, data = regulated.fig08(TINY, quiet(), "energy")
    for beta_deg in (22.0, 30.0):
        panel = data[f"beta_{beta_deg:g}"]
        beta = math.radians(beta_deg)
        assert panel["infeasible_below_ybar"] == pytest.approx(math.cos(beta))
        points = panel["fixed_points"]
        energies = units.energy_from_bar(PARAMS, np.array(points["parameter"]))
        y = units.height_from_bar(PARAMS, np.array(points["ybar"], dtype=float)[:, 0])
        found = np.isfinite(y)
        assert found.sum() >= 6
        mapped = analytic_fixed_points.regulated_height_map(PARAMS, beta, energies[found], y[found])
        np.testing.assert_allclose(mapped, y[found], rtol=1e-9)
        radius = np.array(points["spectral_radius"], dtype=float)[found, 0]
        assert list(np.array(points["stable"])[found, 0]) == list(radius < 1.0)
        curve = panel["maps"]["3"]
        assert np.all(np.array(curve["ybar"]) > math.cos(beta))


def _exact_regulated_hop(beta: float, y: float, energy: float) -> float:
    """The next apex height [m] of the exact plant (exact_map's DOP853 stride) from the apex at height ``y``
    [m] with ``energy`` [J], under the command the ideal regulator (energy_exact) answers that apex with."""
    apex = ApexState.from_height_energy(PARAMS, y, energy)
    command = exact_energy_regulation(PARAMS, apex.y, apex.xdot, beta, energy)
    stride = apex_return_map(
        PARAMS, apex, StanceCommand(float(command.touchdown_angle), float(command.tau0), float(command.t_f))
    )
    assert stride.apex is not None, stride.reason
    assert stride.apex.energy(PARAMS) == pytest.approx(energy, rel=1e-10)  # the regulator holds its goal
    return stride.apex.y


def test_fig09_holds_the_eigenvalues_of_fixed_points_the_exact_plant_returns_to() -> None:
    """The paper's fig. 9: eigenvalues of the regulated fixed points, kbar = 36, zeta0 = 0.08, (a) beta = 22
    deg, (b) beta = 30 deg. Truths: the analytic fixed points map to themselves under the analytic map at
    the panel's angle, with the map's slope there (central differences) as eigenvalue; the exact plant's
    fixed points, hopped by the exact map (not the compiled stride the figure's search used) under the
    exact regulator's command, return to themselves, with the slope of those hops as eigenvalue."""
    _, data = regulated.fig09(TINY, quiet(), "energy")
    assert [data[panel]["beta_deg"] for panel in "ab"] == [22.0, 30.0]
    step = 1e-5 * PARAMS.r0
    for panel in "ab":
        figure = data[panel]
        beta = math.radians(figure["beta_deg"])
        energies = units.energy_from_bar(PARAMS, np.array(figure["parameter"]))
        y = units.height_from_bar(PARAMS, np.array(figure["ybar"], dtype=float)[:, 0])
        found = np.isfinite(y)
        assert found.sum() >= 6, panel
        np.testing.assert_allclose(
            analytic_fixed_points.regulated_height_map(PARAMS, beta, energies[found], y[found]),
            y[found],
            rtol=1e-9,
        )
        slope = (
            analytic_fixed_points.regulated_height_map(PARAMS, beta, energies[found], y[found] + step)
            - analytic_fixed_points.regulated_height_map(PARAMS, beta, energies[found], y[found] - step)
        ) / (2.0 * step)
        eigenvalue = np.real(np.array(figure["eigenvalues"])[found, 0, 0])
        np.testing.assert_allclose(eigenvalue, slope, rtol=1e-5, atol=1e-7)
        exact = figure["exact"]
        exact_y = units.height_from_bar(PARAMS, np.array(exact["ybar"], dtype=float)[:, 0])
        assert np.isfinite(exact_y).sum() >= 5, panel
        exact_eigenvalue = np.real(np.array(exact["eigenvalues"])[:, 0, 0])
        for row in np.flatnonzero(np.isfinite(exact_y)):
            y_star, energy = float(exact_y[row]), float(energies[row])
            assert _exact_regulated_hop(beta, y_star, energy) == pytest.approx(y_star, rel=1e-10)
            exact_slope = (
                _exact_regulated_hop(beta, y_star + step, energy)
                - _exact_regulated_hop(beta, y_star - step, energy)
            ) / (2.0 * step)
            assert exact_eigenvalue[row] == pytest.approx(exact_slope, rel=1e-5, abs=1e-6), (panel, row)
            assert exact["stable"][row][0] == (abs(exact_slope) < 1.0)
        # An analytic fixed point is on the exact plant where the exact plant has one of that energy.
        assert [row[0] for row in figure["analytic_exists_on_exact_plant"]] == list(
            found & np.isfinite(exact_y)
        )


def test_fig10_compares_the_exact_plant_s_fixed_points_with_the_analytic_ones() -> None:
    _, data = exact_basins.fig10(TINY, quiet(), "energy")
    lanes = TINY.basin_energies * TINY.basin_heights
    assert sum(data["outcome_counts"].values()) == lanes
    exact = data["exact_fixed_points"]
    analytic = data["analytic"]
    for goal, ybar in zip(exact["Ebar_goal"], exact["ybar"], strict=True):
        if ybar is None or goal < 3.0:
            continue
        nearest = int(np.argmin(np.abs(np.array(analytic["parameter"]) - goal)))
        assert ybar == pytest.approx(analytic["ybar"][nearest][0], rel=0.03)


def test_fig04_traces_the_open_loop_fixed_points_and_their_saddle_nodes() -> None:
    _, data = open_loop.fig04(TINY, quiet(), "energy")
    low, high = data["c"]["saddle_node_alpha"]
    assert 1.1 < low < high < 1.45
    section = data["a"]
    beta = math.radians(data["beta_deg"])
    energies = units.energy_from_bar(PARAMS, np.array(section["Ebar_fixed"]))
    heights = units.height_from_bar(PARAMS, np.array(section["ybar"]))
    _, mapped = analytic_fixed_points.open_loop_energy_map(PARAMS, beta, section["alpha"], heights, energies)
    np.testing.assert_allclose(mapped, energies, rtol=1e-10)


def test_the_comparison_table_reads_our_numbers_from_the_figure_documents() -> None:
    nan = float("nan")
    documents = {
        "ranges": {
            "analytic": {"20": [0.969, 3.316], "22": [0.98, 4.6], "26": [1.1, 8.2], "30": [nan, nan]},
            "energy": {"20": [1.55, 3.341], "22": [1.7, 4.7], "26": [2.5, 9.2], "30": [3.44, 16.85]},
            "energy_exact": {"20": [1.094, 3.344], "22": [1.3, 4.7], "26": [2.1, 9.2], "30": [3.24, 16.9]},
        }
    }
    table = {row.claim: row for row in paper_comparison.rows(documents, PARAMS, model_rows=False)}
    twenty = table["stable Ebar range, beta = 20 deg (IV.C)"]
    assert (twenty.paper, twenty.analytic) == ("[1.1, 3.4]", "[0.97, 3.32]")
    assert twenty.exact == "energy [1.55, 3.34]; energy_exact [1.09, 3.34]"
    assert twenty.command == "tdslip figures --out DIR --only ranges"
    assert table["stable Ebar range, beta = 30 deg (IV.C)"].analytic == "none"
    assert set(table) == {row[0] for row in paper_comparison.ROWS if row[2] == ("ranges",)}  # and no other
    markdown = paper_comparison.markdown(list(table.values()))
    assert markdown.count("\n") == len(table) + 2 and "docs/paper.md#stable-ranges" in markdown


def test_the_sweeps_run_as_tasks_on_the_engine_and_the_figures_draw_from_their_results(
    monkeypatch: pytest.MonkeyPatch, dask_scheduler: str
) -> None:
    figures_command.precompute(["fig10"], TINY, "energy", engine.Where(scheduler=dask_scheduler))

    def computed_here(*args: object, **kwargs: object) -> None:
        raise AssertionError("a figure computed a sweep itself instead of taking the engine's result")

    for module, name in (
        (basins, "basin"),
        (exact_fixed_points, "fixed_points"),
        (analytic_fixed_points, "energy_fixed_point"),
    ):
        monkeypatch.setattr(module, name, computed_here)
    _, fig10 = exact_basins.fig10(TINY, quiet(), "energy")
    assert sum(fig10["outcome_counts"].values()) == TINY.basin_energies * TINY.basin_heights
    assert [name for name, _ in catalogue.shared_work(["fig13", "ranges"], TINY)][:4] == ["stable_range"] * 4


def test_every_sweep_the_figures_need_is_a_registered_shared_computation() -> None:
    """The engine's workers run them by name (catalogue.compute_shared): a name without a computation would
    fail only there."""
    work = catalogue.shared_work(list(catalogue.FIGURES), TINY)
    assert len(work) > len(catalogue.FIGURES) and all(name in SHARED for name, _ in work)
    assert "no_such_sweep" not in SHARED
