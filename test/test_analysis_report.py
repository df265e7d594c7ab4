"""``tdslip analyze``: files, printed headline and clean errors."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import pytest
from support.analysis_runs import as_if_from_ones_own_controller, rewrite
from support.helpers import strict_json

from tdslip_ros.analysis import report_text as report
from tdslip_ros.analysis.compare import compare_run
from tdslip_ros.analysis.decoding import RunReadError, read_run
from tdslip_ros.analysis.report import hopper_params_from_yaml
from tdslip_ros.analysis.report_text import FIGURES
from tdslip_ros.bag.reader import mcap_file
from tdslip_ros.commands import cli
from tdslip_ros.commands.analyze import main
from tdslip_ros.interfaces import config_file, resolve
from tdslip_ros.model.analytic.apex_map import approximate_map
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.runner import RunReport


def test_analyze_writes_summary_figures_and_report(
    energy: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "report"
    assert cli.main(["analyze", str(energy.bag), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    summary = strict_json(out / "summary.json")
    assert isinstance(summary, dict)
    strides = summary["strides"]
    assert [row["stride"] for row in strides] == [apex.stride for apex in energy.apexes]
    assert [row["y_m"] for row in strides] == [apex.height for apex in energy.apexes]
    assert strides[-1]["command"] is None and strides[-1]["hip_work_J"] is None  # NaN became null
    assert summary["run"]["outcome"]["kind"] == "run_complete"
    assert summary["run"]["params"]["kbar"] == pytest.approx(36.0, rel=1e-12)
    comparison = summary["comparison"]
    assert comparison["policy"]["name"] == "energy" and comparison["policy_reproduced"]
    assert comparison["converged_at_stride"] is not None
    # No perturbation: the path over flat ground and the measured (= true) apexes would repeat the others.
    assert set(summary["figures"]) == set(FIGURES) - {"terrain_path", "measured_apex", "body_pitch"}
    assert set(summary["figures_omitted"]) == {"terrain_path", "measured_apex", "body_pitch"}
    for name in summary["figures"].values():
        assert (out / name).stat().st_size > 10_000
    markdown = (out / "report.md").read_text()
    assert all(f"({name})" in markdown for name in summary["figures"].values())
    # The headline carries the numbers of the summary.
    errors = comparison["prediction_errors"]["analytic_1_corrections"]
    assert f"{errors['max_error_ybar']:.2e}" in printed
    assert f"converged (apex change < 1e-4) from stride {comparison['converged_at_stride']}" in printed
    recorded = comparison["recorded_fixed_point"]
    assert f"{recorded['ybar']:.5f}" in printed and f"{recorded['dominant_modulus']:.4f}" in printed
    assert str(out / "report.md") in printed


def test_analyze_takes_the_hopper_from_a_parameter_file(energy: RunReport, tmp_path: Path) -> None:
    plant_yaml = config_file("plant.yaml")
    assert hopper_params_from_yaml(plant_yaml) == energy.params
    assert main([str(energy.bag), "--out", str(tmp_path), "--params", str(plant_yaml)]) == 0
    summary = strict_json(tmp_path / "summary.json")
    assert isinstance(summary, dict) and summary["run"]["params"]["source"] == "given"


def test_a_parameter_file_without_the_hopper_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "recorder.yaml"
    path.write_text(config_file("recorder.yaml").read_text())
    with pytest.raises(RunReadError, match="no hopper parameters"):
        hopper_params_from_yaml(path)


@pytest.mark.parametrize("damage", ["missing_topic", "truncated", "wrong_policy"])
def test_analyze_fails_cleanly(
    energy: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: str
) -> None:
    source = mcap_file(energy.bag)
    arguments = []
    if damage == "missing_topic":
        path = rewrite(source, tmp_path / "run.mcap", keep=lambda topic: topic != resolve(topics.APEX))
        expected = f"missing topic {resolve(topics.APEX)}"
    elif damage == "truncated":
        path = tmp_path / "run.mcap"
        path.write_bytes(source.read_bytes()[:-1000])
        expected = "truncated or not finalised"
    else:
        path, arguments = source, ["--policy", "deadbeat", "--foot-placement-kp", "0.5"]
        expected = ""
    code = main([str(path), "--out", str(tmp_path / "out"), *arguments])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    if damage == "wrong_policy":
        # A policy that is not the run's is analysed, with a loud warning in the headline.
        assert code == 0 and "does NOT reproduce the recorded commands" in captured.out
    else:
        assert code == 1 and captured.err.startswith("tdslip analyze: ") and expected in captured.err


def test_analyze_a_run_of_ones_own_controller_and_name_a_policy_to_compare_with(
    energy: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = as_if_from_ones_own_controller(energy, tmp_path / "own.mcap")
    assert main([str(path), "--out", str(tmp_path / "own")]) == 0
    printed = capsys.readouterr().out
    assert "policy not replayed: the recording shows policy my_controller" in printed
    summary = strict_json(tmp_path / "own" / "summary.json")
    assert isinstance(summary, dict)
    comparison = summary["comparison"]
    assert comparison["policy"] is None and comparison["policy_reproduced"] is None
    assert comparison["command_deviation_ratio"] is None and comparison["analytic_fixed_point"] is None
    assert comparison["prediction_errors"]["exact_map"]["strides"] == len(energy.apexes) - 1
    assert set(summary["figures"]) == set(FIGURES) - {"terrain_path", "measured_apex", "body_pitch"}
    # The policy it was, named, is replayed as for the original recording (settings from the recording).
    assert main([str(path), "--out", str(tmp_path / "named"), "--policy", "energy"]) == 0
    printed = capsys.readouterr().out
    assert "policy energy (" in printed and "replaying it reproduces the recorded commands" in printed


def test_analyze_on_the_papers_map_predicts_and_replays_with_eq_7s_speed(
    deadbeat: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = read_run(deadbeat.bag)
    assert main([str(deadbeat.bag), "--out", str(tmp_path / "ours")]) == 0
    assert main([str(deadbeat.bag), "--out", str(tmp_path / "paper"), "--map", "paper"]) == 0
    printed = capsys.readouterr().out
    summaries = {name: strict_json(tmp_path / name / "summary.json") for name in ("ours", "paper")}
    ours, paper = (summaries[name]["comparison"] for name in ("ours", "paper"))  # type: ignore[index]
    assert (ours["analytic_map"], ours["policy"]["analytic_map"], ours["policy_reproduced"]) == (
        "ours",
        "ours",
        True,
    )
    assert (paper["analytic_map"], paper["policy"]["analytic_map"]) == ("paper", "paper")
    # The controller planned deadbeat on ours: replayed on the paper's map, it aims at another angle.
    assert not paper["policy_reproduced"] and paper["command_deviation_ratio"] > 1e-3
    assert printed.count("analytic map: paper (next apex speed: the liftoff velocity of eq. 7)") == 1
    # Each stride predicted from the recorded apex and applied command, with eq. 7's speed: the height of
    # the next apex as on our map, its speed not.
    compared = 0
    rows = zip(summaries["ours"]["strides"], summaries["paper"]["strides"], run.strides, strict=True)  # type: ignore[index]
    for ours_row, paper_row, stride in rows:
        if "next_apex_predicted" not in paper_row:
            continue
        assert stride.command is not None and stride.ground == 0.0
        for corrections in (0, 1):
            key = f"analytic_{corrections}_corrections"
            expected = approximate_map(
                run.params, stride.y, stride.xdot, stride.command, corrections, speed="liftoff"
            )
            predicted, on_ours = paper_row["next_apex_predicted"][key], ours_row["next_apex_predicted"][key]
            assert (predicted["y_m"], predicted["xdot_m_per_s"]) == pytest.approx(
                (float(expected.y), float(expected.xdot)), rel=1e-12
            )
            assert (
                predicted["y_m"] == on_ours["y_m"]
                and abs(predicted["xdot_m_per_s"] - on_ours["xdot_m_per_s"]) > 1e-3
            )
        compared += 1
    assert compared == len(run.strides) - 1
    # A run whose controller planned on the paper's map (stored by tdslip run --map paper) is analysed on it.
    stored = replace(run, custom_data=run.custom_data | {"tdslip_ros.controller.analytic_map": "paper"})
    comparison = compare_run(stored)
    assert comparison.analytic_map == "paper" and comparison.policy is not None
    assert comparison.policy.analytic_map == "paper" and not comparison.policy_reproduced
    assert comparison.predictions.analytic[1][:, 1] == pytest.approx(
        [
            row["next_apex_predicted"]["analytic_1_corrections"]["xdot_m_per_s"]
            for row in summaries["paper"]["strides"][:-1]
        ],  # type: ignore[index]
        rel=1e-12,
    )


def test_analyze_reports_a_failed_run(
    fall: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([str(fall.bag), "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    outcome = fall.outcome
    assert f"failed at stride {outcome.stride}: {outcome.kind}" in printed
    # The policy commands only strides its map accepts: this failure is the map's error, and says so.
    assert f"predicted a next apex for stride {outcome.stride}" in printed
    assert "not converged: the run failed" in printed
    summary = strict_json(tmp_path / "summary.json")
    assert isinstance(summary, dict)
    last = summary["strides"][-1]
    assert last["failure"] == outcome.kind
    assert last["next_apex_predicted"]["exact_map"] == {"y_m": None, "xdot_m_per_s": None}
    ended = summary["run"]["outcome"]
    assert (ended["ended"], ended["failed"], ended["kind"], ended["stride"]) == (
        "failed",
        True,
        outcome.kind,
        outcome.stride,
    )


def test_a_run_recorded_without_its_1khz_topics_is_analysed(energy: RunReport, tmp_path: Path) -> None:
    """Topics never written are no reason to refuse a run: without state and force samples the
    per-stride analysis and its figures still come out."""
    dropped = (resolve(topics.STATE), resolve(topics.GRF), resolve(topics.STATUS))
    path = rewrite(mcap_file(energy.bag), tmp_path / "run.mcap", keep=lambda topic: topic not in dropped)
    assert main([str(path), "--out", str(tmp_path / "out")]) == 0
    summary = strict_json(tmp_path / "out" / "summary.json")
    assert isinstance(summary, dict) and summary["run"]["samples"] == 0
    assert len(summary["strides"]) == len(energy.apexes)


def test_the_report_leads_with_the_results_and_ends_with_its_glossary(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """report.md's order, on stand-ins for the headline and the glossary (test_analysis_report_terms.py checks
    the glossary of recorded runs)."""
    monkeypatch.setattr(report, "headline", lambda comparison: "HEADLINE")
    monkeypatch.setattr(report, "glossary", lambda comparison: [("ybar", "apex height / r0")])
    comparison = SimpleNamespace(run=SimpleNamespace(path=Path("runs/first")))
    summary = {"figures": {"apex_sequence": "apex_sequence.png"}, "figures_omitted": {}}
    text = report.markdown(comparison, summary)  # type: ignore[arg-type]
    assert re.findall(r"^## (.*)$", text, re.MULTILINE) == ["Results", "Terms"]
    assert text.index("HEADLINE") < text.index("(apex_sequence.png)") < text.index("## Terms")
    assert text.endswith("## Terms\n\n- **ybar**: apex height / r0.\n")
