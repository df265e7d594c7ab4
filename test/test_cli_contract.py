"""The command line as one tool (issue 23): every subcommand's help describes every option with its default,
every description is written for the command line, and an old spelling still works with a one-line warning.

Truth used: the parsers themselves (``tdslip_ros.commands.<name>.parser()``), walked.
"""

from __future__ import annotations

import argparse
import importlib
import re
from pathlib import Path

import pytest

from tdslip_ros.analysis import rough_terrain
from tdslip_ros.commands import cli

SUBCOMMANDS = list(cli.SUBCOMMANDS)


def parser_of(name: str) -> argparse.ArgumentParser:
    return importlib.import_module(f"tdslip_ros.commands.{name}").parser()


def visible_options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [
        action
        for action in parser._actions
        if action.option_strings
        and action.help is not argparse.SUPPRESS
        and not isinstance(action, argparse._HelpAction)
    ]


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_every_option_says_what_it_is_and_its_default(name: str) -> None:
    parser = parser_of(name)
    formatter = parser._get_formatter()
    for action in visible_options(parser):
        text = formatter._expand_help(action)
        assert action.help and text.strip(), f"tdslip {name} {action.option_strings[0]} has no help"
        assert "default" in text or action.required, f"tdslip {name} {action.option_strings[0]}: {text!r}"
    parser.format_help()  # every help text formats


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_every_description_is_written_for_the_command_line(name: str) -> None:
    description = parser_of(name).description or ""
    assert description.strip(), name
    for markup in (":mod:", ":func:", ":class:", "``"):
        assert markup not in description, (name, markup)
    assert len(description.splitlines()) < 12, name


@pytest.mark.parametrize("name", [name for name in SUBCOMMANDS if name != "analyze"])
def test_one_touchdown_angle_default_everywhere(name: str) -> None:
    """The model's 20 deg, but for tdslip terrain, whose defaults draw the README's figure at its angle (a
    toe that clears the blocks; test_docs_figures.py)."""
    angles = [
        action for action in parser_of(name)._actions if "--touchdown-angle-deg" in action.option_strings
    ]
    expected = rough_terrain.TOUCHDOWN_ANGLE_DEG if name == "terrain" else 20.0
    assert [action.default for action in angles] in ([], [expected])


@pytest.mark.parametrize(
    ("name", "old", "new", "value", "dest"),
    [
        ("simulate", "--beta-deg", "--touchdown-angle-deg", "26", "touchdown_angle_deg"),
        ("run", "--angle", "--touchdown-angle-deg", "26", "touchdown_angle_deg"),
        ("terrain", "--angle", "--touchdown-angle-deg", "26", "touchdown_angle_deg"),
        ("analyze", "--angle", "--touchdown-angle-deg", "26", "touchdown_angle_deg"),
        ("analyze", "--pd-kp", "--foot-placement-kp", "0.1", "foot_placement_kp"),
        ("analyze", "--pd-kd", "--foot-placement-kd", "0.1", "foot_placement_kd"),
        ("robustness", "--touchdown-angle", "--touchdown-angle-deg", "26", "touchdown_angle_deg"),
        ("robustness", "--energy", "--energy-bar", "3.5", "energy_bar"),
        ("compare", "--height", "--target-height", "0.9", "target_height"),
    ],
)
def test_an_old_spelling_still_works_and_warns_in_one_line(
    capsys: pytest.CaptureFixture[str], name: str, old: str, new: str, value: str, dest: str
) -> None:
    parser = parser_of(name)
    positional = {"analyze": ["RUN"]}.get(name, [])
    required = ["--out", "x"] if name == "robustness" else []
    old_args = parser.parse_args([*positional, *required, old, value])
    assert capsys.readouterr().err == f"tdslip {name}: {old} is deprecated; use {new}\n"
    new_args = parser.parse_args([*positional, *required, new, value])
    assert capsys.readouterr().err == ""
    assert getattr(old_args, dest) == getattr(new_args, dest) == float(value)
    assert not re.search(rf"{old}(?![\w-])", parser.format_help())  # hidden from --help


def test_compares_old_speeds_spelling_takes_the_same_dimensionless_speeds(
    capsys: pytest.CaptureFixture[str],
) -> None:
    args = parser_of("compare").parse_args(["--speeds", "1.0", "1.5"])
    assert args.speeds_bar == [1.0, 1.5]
    assert capsys.readouterr().err == "tdslip compare: --speeds is deprecated; use --speeds-bar\n"


def test_simulate_speaks_degrees_when_given_degrees(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["simulate", "--touchdown-angle-deg", "95"]) == 2
    assert (
        capsys.readouterr().err == "tdslip simulate: --touchdown-angle-deg must be in (0, 90) deg, got 95\n"
    )
    assert cli.main(["simulate", "--touchdown-angle-deg", "89", "--strides", "1"]) == 2
    error = capsys.readouterr().err
    assert "89 deg" in error and " rad" not in error and error.count("\n") == 1


def _misspelt(option: str, options: list[str]) -> str:
    """``option`` without one of its letters (``--policy``: ``--plicy``), the first such that is not an option
    itself (``--speed``: not ``--seed``); a short one with its last letter doubled (``--r0``: ``--r00``)."""
    if len(option) < 6:
        return option + option[-1]
    return next(typo for i in range(3, len(option)) if (typo := option[:i] + option[i + 1 :]) not in options)


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_a_misspelt_option_gets_the_closest_one_in_one_line(
    capsys: pytest.CaptureFixture[str], name: str
) -> None:
    """Every long option of every subcommand, misspelt, is refused in one line naming it; before the other
    checks (a required --out, a missing positional RUN), which would otherwise hide it."""
    parser = parser_of(name)
    options = [spelling for action in parser._actions for spelling in action.option_strings]
    for action in visible_options(parser):
        option = next(spelling for spelling in action.option_strings if spelling.startswith("--"))
        typo = _misspelt(option, options)
        with pytest.raises(SystemExit) as raised:
            parser.parse_args([typo, "1"])
        assert raised.value.code == 2
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and error.startswith(f"tdslip {name}: unrecognized option {typo}; ")
        assert f"did you mean {option}?" in error, (name, typo, error)


def test_values_abbreviations_and_words_after_double_dash_are_not_taken_for_misspelt_options() -> None:
    args = parser_of("simulate").parse_args(["--touchdown-angle", "-20", "--speed", "-0.5", "--str", "3"])
    assert (args.touchdown_angle_deg, args.speed, args.strides) == (-20.0, -0.5, 3)
    assert parser_of("analyze").parse_args(["--", "--polcy"]).run == Path("--polcy")


def test_the_run_example_of_the_issue(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as raised:
        cli.main(["run", "--polcy", "energy"])
    assert raised.value.code == 2
    assert capsys.readouterr().err == (
        "tdslip run: unrecognized option --polcy; did you mean --policy? (see tdslip run --help)\n"
    )
