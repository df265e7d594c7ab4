"""``tdslip robustness``: the operating point, the studies it builds, and the command end to end.

Truth used: the exact map (the operating point is a fixed point of energy regulation on the exact plant,
and open loop applies the very same command there), the tables the command wrote, counted by hand.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from support.helpers import assert_png, strict_json

from tdslip_ros.commands import cli
from tdslip_ros.commands.robustness import DEFAULT_ENERGY_BAR
from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.policies import controllers
from tdslip_ros.model.policies.registry import PolicySpec
from tdslip_ros.studies import robustness
from tdslip_ros.studies.design import DEFAULTS

PARAMS = PAPER_PARAMS
BETA = math.radians(26.0)


@pytest.fixture(scope="module")
def point() -> robustness.OperatingPoint:
    return robustness.operating_point(PARAMS, BETA, units.energy_from_bar(PARAMS, 3.5))


def _spec(name: str, point: robustness.OperatingPoint) -> PolicySpec:
    values = {key: DEFAULTS[key] for key in PolicySpec.settings() if key in DEFAULTS}
    return PolicySpec(name=name, corrections=1, **values | point.settings)


def test_every_policy_holds_the_operating_point_on_flat_ground(point: robustness.OperatingPoint) -> None:
    apex = ApexState(point.y, point.xdot)
    # Planned on the analytic map, energy regulation holds the exact plant within 1 % of its goal.
    assert apex.energy(PARAMS) == pytest.approx(units.energy_from_bar(PARAMS, 3.5), rel=1e-2)
    energy = _spec("energy", point).commands(PARAMS, apex.y, apex.xdot, apex.xdot)
    after = apex_return_map(PARAMS, apex, energy.command(), rtol=1e-12, atol=1e-12).apex
    assert after is not None
    assert units.height_to_bar(PARAMS, abs(after.y - apex.y)) < 1e-4  # the basins' convergence tolerance
    assert units.speed_to_bar(PARAMS, abs(after.xdot - apex.xdot)) < 1e-4
    # Open loop applies energy regulation's hip power at touchdown: the same command there.
    open_loop = _spec("open_loop", point).commands(PARAMS, apex.y, apex.xdot, apex.xdot)
    np.testing.assert_allclose(list(open_loop), list(energy), rtol=1e-9)
    # deadbeat and apex_foot_placement aim at the operating point itself.
    assert (point.settings["target_height"], point.settings["target_speed"]) == (point.y, point.xdot)


def test_each_kind_is_a_grid_of_policy_and_size_with_its_own_draws(point: robustness.OperatingPoint) -> None:
    made = robustness.studies(
        robustness.chosen_kinds(["noise", "step"]),
        ["energy", "apex_foot_placement"],
        point,
        PARAMS,
        3,
        20,
        4,
        "stiffness",
    )
    noise, step = made["noise"], made["step"]
    sizes = robustness.KINDS["noise"].sizes
    assert noise.size == 2 * len(sizes) * 3 and noise.hold_commands and noise.seed == 4
    lanes = noise.lanes(0, noise.size)
    np.testing.assert_allclose(lanes["noise_height"][::3][: len(sizes)], np.array(sizes) * PARAMS.r0)
    speed = lanes["noise_speed"][::3][: len(sizes)]
    np.testing.assert_allclose(speed, np.array(sizes) * math.sqrt(PARAMS.g * PARAMS.r0))
    lanes = step.lanes(0, step.size)
    np.testing.assert_array_equal(
        lanes["step_height"][::3][: len(robustness.KINDS["step"].sizes)],
        -np.array(robustness.KINDS["step"].sizes),
    )
    assert len(set(lanes["step_x"])) == step.size and np.all(
        (lanes["step_x"] >= 1.0) & (lanes["step_x"] <= 4.0)
    )
    assert set(lanes["y0"]) == {point.y} and set(lanes["xdot0"]) == {point.xdot}


def test_the_command_writes_survival_figures_and_tables(tmp_path: Path, dask_scheduler: str) -> None:
    out = tmp_path / "robustness"
    command = [
        "robustness",
        "--out",
        str(out),
        "--samples",
        "2",
        "--strides",
        "10",
        "--scheduler",
        dask_scheduler,
    ]
    assert (
        cli.main([*command, "--kinds", "terrain", "mismatch", "--policies", "energy", "apex_foot_placement"])
        == 0
    )
    for name in ("robustness", "strides", "spread", "failures"):
        assert_png(out / f"{name}.png")
    with (out / "summary.csv").open() as stream:
        summary = list(csv.DictReader(stream))
    sizes = {kind: robustness.KINDS[kind].sizes for kind in ("terrain", "mismatch")}
    assert len(summary) == 2 * (len(sizes["terrain"]) + len(sizes["mismatch"]))
    # Every summary row from the trajectories' table, counted here.
    for kind, axis, scale in (("terrain", "terrain_sigma", 1.0), ("mismatch", "mismatch_stiffness", 1.0)):
        rows = pq.read_table(out / kind / "table").to_pylist()
        assert len(rows) == 2 * len(sizes[kind]) * 2
        for entry in (r for r in summary if r["kind"] == kind):
            cell = [
                r
                for r in rows
                if r["policy"] == entry["policy"] and r[axis] * scale == pytest.approx(float(entry["size"]))
            ]
            assert len(cell) == 2
            assert float(entry["surviving"]) == np.mean([r["strides_survived"] == 10 for r in cell])
            failures = [r["outcome"] for r in cell if r["strides_survived"] < 10]
            counted = {name: int(entry[name]) for name in robustness.FAILURES if int(entry[name])}
            assert counted == {name: failures.count(name) for name in set(failures)}
    document = strict_json(out / "summary.json")
    assert document["sizes_survived"]["terrain"]["apex_foot_placement"]["all"][0] == 0.0
    assert document["operating_point"]["touchdown_angle"] == pytest.approx(math.radians(20.0))  # the default
    table = (out / "robustness.md").read_text()
    assert table.count("\n| terrain |") == 2 and "| mismatch | energy |" in table


def test_map_paper_plans_deadbeat_on_the_paper_s_map(tmp_path: Path, dask_scheduler: str) -> None:
    """--map paper is the design's analytic_map. Energy regulation plans alike on both maps (E_tau = E_loss
    does not involve the next speed), so the operating point is ours; deadbeat aims by the next speed, so
    its first stride on flat ground is the exact map's under the command it plans on the paper's map."""
    out = tmp_path / "robustness"
    command = ["robustness", "--out", str(out), "--samples", "1", "--strides", "1", "--kinds", "step"]
    command += ["--policies", "deadbeat", "--map", "paper", "--scheduler", dask_scheduler]
    assert cli.main(command) == 0
    rows = pq.read_table(out / "step" / "table").sort_by("trajectory")
    assert set(rows["analytic_map"].to_pylist()) == {"paper"}
    assert "Analytic map the policies plan on: paper." in (out / "robustness.md").read_text()
    document = strict_json(out / "summary.json")["operating_point"]
    assert document["analytic_map"] == "paper"
    energy = units.energy_from_bar(PARAMS, DEFAULT_ENERGY_BAR)  # the command's default operating point
    ours = robustness.operating_point(PARAMS, math.radians(20.0), energy)
    assert (document["y"], document["xdot"]) == (ours.y, ours.xdot)
    apex = ApexState(ours.y, ours.xdot)
    ends = {}
    for speed in ("liftoff", "energy"):
        planned = controllers.deadbeat(PARAMS, apex.y, apex.xdot, apex.y, apex.xdot, speed=speed)
        after = apex_return_map(PARAMS, apex, planned.command(), rtol=1e-12, atol=1e-12).apex
        assert after is not None
        ends[speed] = np.array([after.y, after.xdot])
    assert rows["step_height"][0].as_py() == 0.0  # the first size: flat ground
    reached = np.array([rows["y_end"][0].as_py(), rows["xdot_end"][0].as_py()])
    np.testing.assert_allclose(reached, ends["liftoff"], rtol=1e-9)
    assert np.abs(reached - ends["energy"]).max() > 0.01  # m, m/s: ours would have gone elsewhere


def test_a_bad_operating_point_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["robustness", "--out", str(tmp_path / "a"), "--touchdown-angle-deg", "95"]) == 2
    assert (
        capsys.readouterr().err == "tdslip robustness: --touchdown-angle-deg must be in (0, 90) deg, got 95\n"
    )
    assert cli.main(["robustness", "--out", str(tmp_path / "b"), "--energy-bar", "0.5"]) == 2
    error = capsys.readouterr().err
    assert error.startswith("tdslip robustness: energy regulation at 20 deg does not settle at Ebar = 0.5")
    assert len(error.splitlines()) == 1
    # the hopper is an input here too (commands/options.py), refused as the others before anything runs
    absent = tmp_path / "absent.yaml"
    assert cli.main(["robustness", "--out", str(tmp_path / "c"), "--hopper", str(absent)]) == 2
    assert (
        capsys.readouterr().err
        == f"tdslip robustness: hopper file {absent}: cannot be read (No such file or directory)\n"
    )
    assert not (tmp_path / "c").exists()


def test_the_sizes_of_a_kind_are_an_option(tmp_path: Path, dask_scheduler: str) -> None:
    """--step-sizes replaces the step's default grid (0-8 m): the study hops those steps down, the summary and
    the table list those sizes."""
    out = tmp_path / "robustness"
    command = ["robustness", "--out", str(out), "--samples", "1", "--strides", "2", "--kinds", "step"]
    command += ["--step-sizes", "0", "0.05", "0.5", "--policies", "energy", "--scheduler", dask_scheduler]
    assert cli.main(command) == 0
    rows = pq.read_table(out / "step" / "table").sort_by("trajectory")
    assert rows["step_height"].to_pylist() == [0.0, -0.05, -0.5]
    document = json.loads((out / "summary.json").read_text(), parse_constant=pytest.fail)
    assert document["sizes"] == {"step": {"label": "step down [m]", "sizes": [0.0, 0.05, 0.5]}}
    assert [row["size"] for row in document["rows"]] == [0.0, 0.05, 0.5]


@pytest.mark.parametrize(
    ("option", "values", "error"),
    [
        ("--step-sizes", ["8", "4", "0"], "step sizes 8 4 0: they must increase"),
        ("--step-sizes", ["0", "2", "2"], "step sizes 0 2 2: they must increase"),
        (
            "--terrain-sizes",
            ["0.01", "0.02"],
            "terrain sizes 0.01 0.02: they must include 0, the unperturbed size",
        ),
        ("--mismatch-sizes", ["0", "1"], "mismatch sizes 0 1: they must be finite and > 0"),
        ("--noise-sizes", ["-0.1", "0"], "noise sizes -0.1 0: they must be finite and >= 0"),
        ("--step-sizes", [], "argument --step-sizes: expected at least one argument"),
    ],
)
def test_sizes_no_study_can_use_are_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], option: str, values: list[str], error: str
) -> None:
    """Refused before the operating point is computed or anything is written."""
    out = tmp_path / "robustness"
    try:
        status = cli.main(["robustness", "--out", str(out), option, *values])
    except SystemExit as exit:  # argparse's own refusal
        status = exit.code
    assert status == 2
    assert capsys.readouterr().err.startswith(f"tdslip robustness: {error}")
    assert not out.exists()
