"""``tdslip analyze`` explains itself: report.md defines every term it uses, every number in summary.json
says its unit, the summary says how the run ended, and figures that would repeat others are not drawn."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import pytest

from tdslip_ros.analysis.compare import compare_run
from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.analysis.report_text import (
    FIGURES,
    RUN_ENDINGS,
    UNITLESS_KEYS,
    glossary,
    glossary_markdown,
)
from tdslip_ros.commands.analyze import main
from tdslip_ros.interfaces import STOP_REQUESTED
from tdslip_ros.nodes.runner import RunReport
from tdslip_ros.reporting.output import DIMENSIONLESS_SUFFIXES, UNIT_SUFFIXES

RUN_NAMES = ("energy", "rough", "fall", "wall")
"""A plain run, one with every perturbation, one that fails on flat ground and one on the terrain."""
REDUNDANT_WITHOUT_PERTURBATIONS = {"terrain_path", "measured_apex"}


pytestmark = pytest.mark.nodes  # the recorded runs of conftest


@pytest.fixture(scope="module")
def reports(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The report directory of each of RUN_NAMES, analysed once."""
    out = {}
    for name in RUN_NAMES:
        report = request.getfixturevalue(name)
        directory = tmp_path_factory.mktemp(f"report_{name}")
        assert main([str(report.bag), "--out", str(directory)]) == 0
        out[name] = directory
    return out


def _summary(directory: Path) -> dict[str, Any]:
    summary = json.loads((directory / "summary.json").read_text())
    assert isinstance(summary, dict)
    return summary


# --- the glossary -------------------------------------------------------------------------------

SYMBOL = re.compile(
    r"\|lambda\||\b(?:\w*bar|[A-Za-z]+_\w+|[a-z]+\d+|[A-Z]{2,}\d*|alpha|beta|lambda|tau\w*|zeta\w*)\b"
)
"""Symbols: the bars, names with an underscore or a digit (tau0, r0, max_strides), abbreviations (GRF,
DOP853), Greek letters."""
ASSIGNED = re.compile(r"\b([A-Za-z]\w*) ?=")
"""Names given a value (m = 80 kg, sigma=0.02, touchdown_angle = ...)."""
PHRASES = (
    "analytic map",
    "exact map",
    "correction",
    "converged",
    "fixed pt",
    "recorded",
    "policy",
    "replaying",
    "max rel. dev.",
    "prediction error",
    "predicted to fail",
    "energy balance",
    "residual",
    "hip work",
    "losses",
    "virtual footfalls",
    "cobweb",
    "toe",
    "saturated",
    "apex noise",
    "angle noise",
    "pushes",
    "mismatch",
    "terrain",
    "eq. 24",
    "fig. 12",
)
"""Terms of the report's text that a newcomer cannot know."""


def _split(markdown: str) -> tuple[str, str]:
    """The report's glossary section and the rest."""
    rest, terms = markdown.split("## Terms\n", 1)
    return terms, rest


def undefined_terms(markdown: str, ignore: tuple[str, ...] = ()) -> set[str]:
    """The symbols and PHRASES the report's text (without the strings ``ignore``: a path, figure names) uses
    that its glossary does not mention."""
    terms, text = _split(markdown)
    for string in ignore:
        text = text.replace(string, " ")
    used = set(SYMBOL.findall(text)) | set(ASSIGNED.findall(text))
    used |= {phrase for phrase in PHRASES if phrase in text}
    return {term for term in used if not re.search(rf"(?<!\w){re.escape(term)}(?!\w)", terms)}


def _ignored(directory: Path) -> tuple[str, ...]:
    summary = _summary(directory)
    return (summary["run"]["path"], "summary.json", *[f"{name}.png" for name in FIGURES], *FIGURES)


@pytest.mark.parametrize("name", RUN_NAMES)
def test_the_glossary_defines_every_term_of_the_report(reports: dict[str, Path], name: str) -> None:
    markdown = (reports[name] / "report.md").read_text()
    assert markdown.index("## Results") < markdown.index("## Terms")  # the results lead, the glossary ends
    assert undefined_terms(markdown, _ignored(reports[name])) == set()


def test_a_term_missing_from_the_glossary_is_found(reports: dict[str, Path]) -> None:
    markdown = (reports["rough"] / "report.md").read_text()
    ignored = _ignored(reports["rough"])
    terms, _ = _split(markdown)
    entry = next(entry for entry in terms.splitlines() if entry.startswith("- **perturbations:"))
    assert {"sigma", "rest_length", "angle noise"} <= undefined_terms(markdown.replace(entry, ""), ignored)
    new = markdown.replace("energy balance per stride", "taubar_max = 0.4, energy balance per stride")
    assert undefined_terms(new, ignored) == {"taubar_max"}


def test_the_glossary_is_the_one_the_report_module_makes(
    reports: dict[str, Path], request: pytest.FixtureRequest
) -> None:
    for name in ("energy", "fall"):
        comparison = compare_run(read_run(request.getfixturevalue(name).bag))
        terms, _ = _split((reports[name] / "report.md").read_text())
        assert terms.strip() == glossary_markdown(glossary(comparison))
    assert "failure kinds" in terms  # the failed run's glossary names the failures


# --- units ----------------------------------------------------------------------------------------

_SUFFIXES = (*UNIT_SUFFIXES.values(), *DIMENSIONLESS_SUFFIXES)


def keys_without_unit(value: object, key: str = "", path: str = "") -> list[str]:
    """The paths of the numbers in ``value`` whose key neither ends in a unit or dimensionless suffix nor is
    one of UNITLESS_KEYS (the numbers of a list, and of a mapping under such a key, take its key)."""
    if isinstance(value, dict):
        return [
            bad
            for child, item in value.items()
            for bad in keys_without_unit(item, key if key in UNITLESS_KEYS else child, f"{path}.{child}")
        ]
    if isinstance(value, list):
        return [bad for i, item in enumerate(value) for bad in keys_without_unit(item, key, f"{path}[{i}]")]
    is_number = isinstance(value, int | float) and not isinstance(value, bool)
    if is_number and not (key.endswith(_SUFFIXES) or key in UNITLESS_KEYS):
        return [path]
    return []


@pytest.mark.parametrize("name", RUN_NAMES)
def test_every_number_in_the_summary_says_its_unit(reports: dict[str, Path], name: str) -> None:
    summary = _summary(reports[name])
    assert keys_without_unit(summary) == []
    assert "touchdown_angle_rad" in summary["comparison"]["policy"]
    assert summary["strides"][0]["command"].keys() == {"touchdown_angle_rad", "tau0_N_m", "t_f_s"}


def test_a_number_without_its_unit_is_found() -> None:
    found = keys_without_unit(
        {"policy": {"touchdown_angle": 0.349, "corrections": 1}, "eigenvalues": [[0.1, 0.0]], "ok": True}
    )
    assert found == [".policy.touchdown_angle"]
    assert keys_without_unit({"pairs": [[1.0, 2.0]], "message_counts": {"/tdslip/apex": 13}}) == [
        ".pairs[0][0]",
        ".pairs[0][1]",
    ]


# --- how the run ended ----------------------------------------------------------------------------


def _fields(value: object) -> set[str]:
    if isinstance(value, dict):
        return set(value) | {key for item in value.values() for key in _fields(item)}
    if isinstance(value, list):
        return {key for item in value for key in _fields(item)}
    return set()


def test_a_completed_run_says_it_completed_and_did_not_fail(reports: dict[str, Path]) -> None:
    summary = _summary(reports["energy"])
    outcome = summary["run"]["outcome"]
    assert outcome["ended"] == "completed" and outcome["failed"] is False
    assert outcome["kind"] == "run_complete" and outcome["reason"] == "reached max_strides = 12"
    assert "fatal" not in _fields(summary)
    assert (
        "completed at stride 12 (reached max_strides = 12)" in (reports["energy"] / "report.md").read_text()
    )
    for name in ("fall", "wall"):
        outcome = _summary(reports[name])["run"]["outcome"]
        assert (
            outcome["ended"] == "failed" and outcome["failed"] is True and outcome["kind"] != "run_complete"
        )


def test_a_stopped_run_and_one_without_its_end_say_so(energy: RunReport) -> None:
    run = read_run(energy.bag)
    assert run.outcome is not None and run.ending == "completed"
    stopped = dataclasses.replace(run, outcome=dataclasses.replace(run.outcome, reason=STOP_REQUESTED))
    assert stopped.ending == "stopped"
    assert dataclasses.replace(run, outcome=None).ending == "unknown"
    assert set(RUN_ENDINGS) == {"completed", "stopped", "failed", "unknown"}


# --- figures --------------------------------------------------------------------------------------


def test_figures_that_would_repeat_others_are_left_out(reports: dict[str, Path]) -> None:
    for name, drawn in (("energy", False), ("fall", False), ("rough", True)):
        directory = reports[name]
        summary = _summary(directory)
        markdown = (directory / "report.md").read_text()
        for figure in REDUNDANT_WITHOUT_PERTURBATIONS:
            assert (directory / f"{figure}.png").is_file() == drawn, (name, figure)
            assert (figure in summary["figures"]) == drawn and (figure in summary["figures_omitted"]) != drawn
            assert (f"({figure}.png)" in markdown) == drawn
        if not drawn:
            assert "Not drawn: " in markdown
    # On the terrain (no sensor noise, no saturation): the path over the ground, not the measured apexes.
    summary = _summary(reports["wall"])
    assert "terrain_path" in summary["figures"] and "measured_apex" in summary["figures_omitted"]
