"""``tdslip sweep``: the studies it builds, and the command end to end on a small grid.

Truth used: the figures' own grids and fixed points (fig. 7's E*(y0) start, fig. 10's goal regulator),
the table the command wrote, and the resume rules of the study directory.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from support.helpers import assert_png, strict_json

from tdslip_ros.commands import cli
from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.stability import analytic_fixed_points, basins
from tdslip_ros.reporting.paper_grids import FIG11_STUDIES
from tdslip_ros.studies import engine, sweep, table

PARAMS = PAPER_PARAMS


def test_the_sweeps_are_the_figures_grids_at_any_resolution() -> None:
    fig10 = sweep.fig10_studies((1000, 1000), 50, None)[""]
    assert (fig10.size, fig10.chunk_size, fig10.chunks) == (1_000_000, 1000, 1000)
    lanes = fig10.lanes(999_999, 1_000_000)
    assert lanes["energy0"][0] == pytest.approx(units.energy_from_bar(PARAMS, 6.0))
    assert lanes["y0"][0] == pytest.approx(2.4) and lanes["target_energy"][0] == lanes["energy0"][0]
    fig07 = sweep.fig07_studies((3, 2), 150, None)[""]
    lanes = fig07.lanes(0, fig07.size)
    assert list(lanes["policy"]) == ["open_loop"] * 6
    alpha = units.power_to_alpha(PARAMS, lanes["touchdown_power"])
    np.testing.assert_allclose(alpha, [0.5, 0.5, 1.5, 1.5, 2.5, 2.5])
    energy = analytic_fixed_points.energy_fixed_point(PARAMS, math.radians(26.0), alpha, lanes["y0"])
    np.testing.assert_array_equal(lanes["energy0"], energy)
    fig11 = sweep.fig11_studies((4, 2), 50, None)
    assert sorted(fig11) == ["beta_deg", "kbar", "zeta0"]
    assert fig11["kbar"].hoppers() == [(k, 0.08) for k in FIG11_STUDIES["kbar"]]
    assert fig11["beta_deg"].size == 6 * 4 * 2


def test_the_command_writes_the_table_figure_and_summary_and_resumes(
    tmp_path: Path, dask_scheduler: str
) -> None:
    out = tmp_path / "fig10"
    command = [
        "sweep",
        "fig10",
        "--out",
        str(out),
        "--grid",
        "4x5",
        "--strides",
        "20",
        "--scheduler",
        dask_scheduler,
    ]
    assert cli.main(command) == 0
    rows = pq.read_table(out / "table").sort_by("trajectory")
    assert rows.num_rows == 20 and rows["trajectory"].to_pylist() == list(range(20))
    summary = strict_json(out / "summary.json")
    counts = summary["studies"]["fig10"]["outcome_counts"]
    assert counts == {name: rows["outcome"].to_pylist().count(name) for name in basins.OUTCOMES}
    assert counts["converged"] > 0
    assert_png(out / "fig10.png")
    parts = {path: path.stat().st_mtime_ns for path in (out / "table").iterdir()}
    assert cli.main(command) == 2  # the directory holds this study: --resume, or another --out
    assert cli.main([*command, "--resume"]) == 0  # nothing left to compute: the parts stay as they were
    assert {path: path.stat().st_mtime_ns for path in (out / "table").iterdir()} == parts


def test_map_paper_starts_fig07_on_the_paper_s_energy_fixed_point_and_hops_the_exact_plant_from_there(
    tmp_path: Path, dask_scheduler: str
) -> None:
    """--map is the design's analytic_map: fig. 7's lanes start on E*(y0) of eq. 27 on the paper's map (not
    ours), and their last apexes are the exact plant's open loop from there."""
    out = tmp_path / "fig07"
    command = ["sweep", "fig07", "--out", str(out), "--grid", "2x3", "--strides", "12"]
    assert cli.main([*command, "--map", "paper", "--scheduler", dask_scheduler]) == 0
    rows = pq.read_table(out / "table").sort_by("trajectory")
    assert set(rows["analytic_map"].to_pylist()) == {"paper"}
    assert json.loads((out / "summary.json").read_text())["analytic_map"] == "paper"
    alpha = units.power_to_alpha(PARAMS, rows["touchdown_power"].to_numpy())
    heights = rows["y0"].to_numpy()
    paper, ours = (
        analytic_fixed_points.energy_fixed_point(PARAMS, math.radians(26.0), alpha, heights, speed=speed)
        for speed in ("liftoff", "energy")
    )
    energy0 = rows["energy0"].to_numpy()
    np.testing.assert_allclose(energy0, paper, rtol=1e-12)
    assert np.all(np.abs(energy0 - ours) > 1.0)  # J: the map changed the start
    expected = basins.open_loop_basin(PARAMS, math.radians(26.0), alpha, heights, paper, strides=12)
    np.testing.assert_array_equal(
        rows["outcome"].to_numpy(zero_copy_only=False), np.asarray(basins.OUTCOMES)[expected.outcome]
    )
    survived = rows["strides_survived"].to_numpy()  # the last apex reached, failed lanes among them
    last = expected.history.y[survived, np.arange(survived.size)]
    np.testing.assert_allclose(rows["y_end"].to_numpy(), last, rtol=1e-12)


def test_resuming_a_study_begun_before_the_analytic_map_column_fills_it_with_ours(
    tmp_path: Path, dask_scheduler: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fig10"
    command = ["sweep", "fig10", "--out", str(out), "--grid", "2x3", "--strides", "5", "--chunk-size", "2"]
    command += ["--scheduler", dask_scheduler]
    assert cli.main(command) == 0
    whole = pq.read_table(out / "table")
    # As a version without the column left it: part 0 written without it, part 2 not yet written.
    first = pq.read_table(table.part_path(out, 0))
    pq.write_table(first.drop_columns(["analytic_map"]), table.part_path(out, 0))
    table.part_path(out, 2).unlink()
    capsys.readouterr()
    assert cli.main([*command, "--resume"]) == 0
    assert "2 of 3 chunks were on disk, 1 computed" in capsys.readouterr().err  # part 0 was not recomputed
    resumed = pq.read_table(out / "table")  # one schema: every part has the column, ours where it lacked it
    assert resumed.schema == whole.schema and resumed["analytic_map"].to_pylist() == ["ours"] * 6
    for name in whole.column_names:
        np.testing.assert_array_equal(
            resumed[name].to_numpy(zero_copy_only=False), whole[name].to_numpy(zero_copy_only=False)
        )
    # A part lacking any other column is not this version's: refused in one line naming the folder.
    pq.write_table(first.drop_columns(["y_std"]), table.part_path(out, 0))
    assert cli.main([*command, "--resume"]) == 2
    error = capsys.readouterr().err
    assert error == (
        f"tdslip sweep: {out}: part-000000.parquet has no column y_std (written by another version of "
        "tdslip_ros); choose another --out\n"
    )


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["fig10", "--grid", "10"], "expected two positive counts like 1000x1000, got '10'"),
        (["fig10", "--grid", "0x3"], "expected two positive counts"),
        (["fig12"], "invalid choice: 'fig12'"),
        (["fig10", "--scheduler", "tcp://127.0.0.1:9", "--workers", "2"], "not allowed with argument"),
        (["fig10", "--workers", "0"], "expected a positive integer, got '0'"),
    ],
)
def test_bad_options_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], arguments: list[str], message: str
) -> None:
    with pytest.raises(SystemExit) as raised:
        cli.main(["sweep", *arguments, "--out", str(tmp_path / "out")])
    assert raised.value.code == 2
    assert message in capsys.readouterr().err.strip().splitlines()[-1]


def test_errors_of_the_run_end_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(engine, "CONNECT_TIMEOUT", 2.0)
    command = ["sweep", "fig10", "--grid", "2x2"]
    assert cli.main([*command, "--out", str(tmp_path / "a"), "--scheduler", "tcp://127.0.0.1:9"]) == 1
    error = capsys.readouterr().err
    assert error.startswith("tdslip sweep: cannot reach the Dask scheduler at tcp://127.0.0.1:9")
    assert len(error.splitlines()) == 1
    (tmp_path / "b").write_text("a file where the directory should go")
    assert cli.main([*command, "--out", str(tmp_path / "b")]) == 2
    error = capsys.readouterr().err
    assert error.startswith("tdslip sweep: --out ") and error.endswith("exists and is not a directory\n")
