"""Command-line input errors of the offline commands: one line on stderr and exit status 2 (a usage error,
as argparse's), never a traceback or a hang; a closed output pipe ends every command quietly."""

from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tdslip_ros.commands import cli
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.nodes.run_options import (
    RunOptionError,
    RunOptions,
    check_options,
    check_placement,
    controller_overrides,
    run_custom_data,
)
from tdslip_ros.nodes.runner import RunReport

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def a_file(tmp_path: Path) -> Path:
    path = tmp_path / "afile"
    path.write_text("not a directory\n")
    return path


def one_line_error(capsys: pytest.CaptureFixture[str], command: str) -> str:
    captured = capsys.readouterr()
    assert captured.err.startswith(f"tdslip {command}: ") and captured.err.count("\n") == 1, captured.err
    assert "Traceback" not in captured.err + captured.out
    return captured.err


@pytest.mark.parametrize("command", ["analyze", "compare", "figures"])
@pytest.mark.parametrize("where", ["/proc/x", "the file", "below the file"])
def test_an_unusable_output_directory_is_one_line(
    tmp_path: Path, a_file: Path, capsys: pytest.CaptureFixture[str], command: str, where: str
) -> None:
    out = {"/proc/x": Path("/proc/x"), "the file": a_file, "below the file": a_file / "sub"}[where]
    arguments = {
        "analyze": [str(tmp_path / "run"), "--out", str(out)],
        "compare": ["--out", str(out), "--speeds-bar", "1.0", "--strides", "2"],  # refused before any run
        "figures": ["--out", str(out), "--only", "fig04"],
    }[command]
    assert cli.main([command, *arguments]) == 2
    error = one_line_error(capsys, command)
    assert f"--out {out}: " in error
    assert ("is not a directory" in error) if where != "/proc/x" else ("cannot create the directory" in error)
    assert a_file.read_text() == "not a directory\n"


@pytest.mark.parametrize(
    ("option", "value", "needle"),
    [
        ("--touchdown-angle-deg", "nan", "--touchdown-angle-deg must be in (0, 90) deg, not nan"),
        ("--touchdown-angle-deg", "90", "--touchdown-angle-deg must be in (0, 90) deg"),
        ("--target-energy", "-1", "--target-energy must be a finite energy > 0 J, not -1.0"),
        ("--target-height", "inf", "--target-height must be a finite height > 0 m"),
        ("--foot-placement-kd", "-0.1", "--foot-placement-kd must be a finite gain >= 0"),
        ("--corrections", "-1", "--corrections must be a count >= 0"),
    ],
)
def test_policy_settings_without_meaning_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], option: str, value: str, needle: str
) -> None:
    """Before: exit 0 with NaN commands and an empty fixed point."""
    assert cli.main(["analyze", str(tmp_path / "run"), "--out", str(tmp_path / "out"), option, value]) == 2
    assert needle in one_line_error(capsys, "analyze")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("arguments", "needle"),
    [
        (["--strides", "0"], "--strides must be at least 1, not 0"),
        (["--strides", "-3"], "--strides must be at least 1, not -3"),
        (["--target-height", "nan"], "--target-height must be a finite height > 0 m"),
        (["--speeds-bar", "1.0", "-2.0"], "--speeds-bar must be finite speeds >= 0, not -2.0"),
    ],
)
def test_a_sweep_no_run_can_make_is_refused_at_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], arguments: list[str], needle: str
) -> None:
    """Before: ``compare --strides 0`` never ended."""
    assert cli.main(["compare", "--out", str(tmp_path / "sweep"), *arguments]) == 2
    assert needle in one_line_error(capsys, "compare")


def test_robustness_refuses_a_learned_policy_file_before_its_workers_start(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: a missing file started the Dask cluster, then failed in a worker with a traceback."""
    out = tmp_path / "robustness"
    arguments = ["robustness", "--out", str(out), "--policies", "learned", "--workers", "1"]
    assert cli.main([*arguments, "--policy-file", str(tmp_path / "missing.json")]) == 2
    assert "missing.json: [Errno 2] No such file" in one_line_error(capsys, "robustness")
    assert not out.exists()


def run_with_closed_output(arguments: list[str]) -> subprocess.CompletedProcess[str]:
    """``tdslip ARGUMENTS`` writing into a pipe whose reader is already gone (``| head`` finished)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        return subprocess.run(
            [sys.executable, "-m", "tdslip_ros.commands.cli", *arguments],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
            timeout=300,
            check=False,
        )
    finally:
        os.close(write_end)


def test_a_closed_pipe_ends_simulate_quietly() -> None:
    result = run_with_closed_output(["simulate", "--strides", "3"])
    assert (result.returncode, result.stderr) == (cli.BROKEN_PIPE, "")


def test_a_closed_pipe_ends_analyze_quietly(energy: RunReport, tmp_path: Path) -> None:
    result = run_with_closed_output(["analyze", str(energy.bag), "--out", str(tmp_path / "report")])
    assert (result.returncode, result.stderr) == (cli.BROKEN_PIPE, "")
    assert (tmp_path / "report" / "summary.json").is_file()  # the work was done before the output


def _tree(root: Path) -> dict[str, bytes | None]:
    """Every path below root, with the contents of the files."""
    return {
        str(path.relative_to(root)): path.read_bytes() if path.is_file() else None for path in root.rglob("*")
    }


@pytest.mark.parametrize(
    ("arguments", "status"),
    [
        (["analyze", "{tmp}/no/such/run"], 2),
        (["analyze", "{tmp}/not_a_bag"], 1),
        (["analyze", "{tmp}/not_a_bag", "--out", "{tmp}/new/report"], 1),
        (["figures", "--out", "/proc/x/y", "--only", "fig04"], 2),
        (["run", "--height", "0.2", "--out", "{tmp}/new/run"], 2),
        (["run", "--out", "/proc/x"], 2),
        (["run", "--touchdown-angle-deg", "95", "--out", "{tmp}/new/run"], 2),
        (["run", "--terrain", "blocks:sigma=abc", "--out", "{tmp}/new/run"], 2),
    ],
)
def test_a_failing_command_leaves_the_file_system_as_it_found_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], arguments: list[str], status: int
) -> None:
    (tmp_path / "not_a_bag").mkdir()
    (tmp_path / "not_a_bag" / "notes.txt").write_text("not a recording\n")
    before = _tree(tmp_path)
    assert cli.main([argument.format(tmp=tmp_path) for argument in arguments]) == status
    one_line_error(capsys, arguments[0])
    assert _tree(tmp_path) == before
    assert not Path("/proc/x").exists()


def test_run_hands_its_analytic_map_to_the_controller_and_stores_it(tmp_path: Path) -> None:
    options = RunOptions(out=tmp_path / "run", analytic_map="paper")
    check_options(options)
    assert controller_overrides(options, PAPER_PARAMS)["analytic_map"] == "paper"
    assert "tdslip_ros.controller.analytic_map=paper" in run_custom_data(options, PAPER_PARAMS).split()
    # Not given: the installed controller parameters' (ours, as declared).
    assert controller_overrides(RunOptions(out=tmp_path / "run"), PAPER_PARAMS)["analytic_map"] is None
    with pytest.raises(RunOptionError, match="analytic map must be one of ours, paper, not 'papr'"):
        check_options(RunOptions(out=tmp_path / "run", analytic_map="papr"))


def test_run_hands_the_stance_touchdown_angle_to_the_stance_controller_and_places_the_leg_at_it(
    tmp_path: Path,
) -> None:
    options = RunOptions(out=tmp_path / "run", policy="stance_pd_speed_energy", stance_touchdown_angle=0.3)
    check_options(options)
    assert controller_overrides(options, PAPER_PARAMS)["stance_touchdown_angle"] == 0.3
    assert (
        "tdslip_ros.controller.stance_touchdown_angle=0.3" in run_custom_data(options, PAPER_PARAMS).split()
    )
    # From 0.95 m the leg lands at the installed 22 deg, not at 10 deg (r0 cos(10 deg) is above 0.98 m).
    low = RunOptions(out=tmp_path / "run", policy="stance_pd_speed_energy", height=0.95)
    check_placement(low, PAPER_PARAMS)
    with pytest.raises(RunOptionError, match="at the touchdown angle 10 deg"):
        check_placement(dataclasses.replace(low, stance_touchdown_angle=math.radians(10.0)), PAPER_PARAMS)


def test_a_misspelt_subcommand_gets_the_closest_name(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["anaylze", "RUN"]) == 2
    assert (
        capsys.readouterr().err
        == "tdslip: unknown command 'anaylze'; did you mean 'analyze'? try 'tdslip --help'\n"
    )
