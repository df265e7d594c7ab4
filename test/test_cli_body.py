"""``tdslip body`` (issue 36): the rotating body's figures, and the answer to the paper's question they carry.

Independent truth: the exact map's strides (the posture law's gait, run here stride by stride, repeats; the
regulator alone tips the body from the same start), and the balance every periodic gait must keep (its
hip work per metre is the fixed body's, give or take the body's turning).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from support.helpers import assert_png, strict_json

from tdslip_ros.analysis import rotating_body
from tdslip_ros.commands import cli
from tdslip_ros.model.params import ApexState
from tdslip_ros.model.stability.rigid_fixed_points import closed_loop_stride


def test_the_map_answers_the_papers_question_for_an_upright_trunk(tmp_path: Path, capsys) -> None:
    assert (
        cli.main(
            [
                "body",
                "--out",
                str(tmp_path),
                "--only",
                "body_map",
                "--distances",
                "0.05",
                "0.2",
                "--radii",
                "0.3",
            ]
        )
        == 0
    )
    assert_png(tmp_path / "body_map.png")
    document = strict_json(tmp_path / "body_map.json")
    assert document["hip_distances"] == [0.05, 0.2] and document["gyration_radii"] == [0.3]
    standing, hanging = document["cells"]["standing"], document["cells"]["hanging"]
    # 5 cm from the centre of mass no lean can return the thrust's reaction (it needs about 6 cm)
    for cells in (*standing.values(), *hanging.values()):
        assert cells[0][0]["spectral_radius"] is None and "no lean" in cells[0][0]["reason"]
    alone, held = standing["regulation"][0][1], standing["posture"][0][1]
    assert alone["spectral_radius"] > 1.5 and not alone["stable"]
    assert held["spectral_radius"] < 0.8 and held["stable"]
    assert hanging["regulation"][0][1]["stable"]  # hanging from the hip: a pendulum, stable but barely
    fixed_work = document["fixed_body_hip_work_per_metre"]
    for cell in (alone, held):
        assert cell["hip_work_per_metre"] == pytest.approx(fixed_work, rel=0.05)
    # the posture law's gait is one: from its apex, the exact map returns to it
    params = rotating_body.rigid_hopper(-0.2, 0.3)
    apex = ApexState(**held["apex"])
    stride = closed_loop_stride(params, rotating_body.policies()["posture"], apex)
    assert stride.apex is not None
    assert (stride.apex.y, stride.apex.pitch) == pytest.approx((apex.y, apex.pitch), abs=1e-9)
    out = capsys.readouterr().out
    assert "standing, posture (spectral radius):" in out and f"figures: {tmp_path}" in out


def test_the_strides_figure_shows_the_regulator_and_the_pivot_tipping_and_the_posture_law_holding(
    tmp_path: Path,
) -> None:
    assert cli.main(["body", "--out", str(tmp_path), "--only", "body_strides"]) == 0
    assert_png(tmp_path / "body_strides.png")
    runs = strict_json(tmp_path / "body_strides.json")["runs"]
    assert runs["regulation"]["failure"].startswith("tipped")
    assert runs["pivot"]["failure"].startswith("tipped") and len(runs["pivot"]["pitch"]) < 10
    held = runs["posture"]
    assert not held["failure"] and len(held["pitch"]) == rotating_body.STRIDES + 1
    assert max(abs(p) for p in held["pitch"]) < 1.0 < math.pi / 2
    assert abs(held["pitch"][-1] - held["pitch"][-2]) < 1e-6


def test_bad_grids_are_refused_in_one_line(tmp_path: Path, capsys) -> None:
    assert cli.main(["body", "--out", str(tmp_path), "--radii", "0", "0.3"]) == 2
    assert capsys.readouterr().err == "tdslip body: --distances and --radii must be positive\n"
