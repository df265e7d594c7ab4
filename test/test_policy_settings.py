"""The policies' settings are declared once (tdslip_ros.model.policies.POLICY_SETTINGS): the policies use
what it says they use, and the controller node's parameters, config/controller.yaml, the study design's
policy columns and the analysis report's account of a policy agree with it, each checked on the structure
it really uses."""

from __future__ import annotations

import re
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml  # type: ignore[import-untyped]

from tdslip_ros.analysis.report import policy_settings_text
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.policies import (
    DEFAULT_POLICY,
    POLICIES,
    POLICY_SETTINGS,
    PolicySetting,
    PolicySpec,
    settings_of,
)
from tdslip_ros.nodes import controller_node, parameters
from tdslip_ros.studies import design

SETTINGS = {setting.name: setting for setting in POLICY_SETTINGS}
DEFAULT_VALUES = {setting.name: setting.default for setting in POLICY_SETTINGS}


def test_a_declared_setting_is_consistent() -> None:
    with pytest.raises(ValueError, match="default"):
        PolicySetting("x", float, "m", 0.0, 1.0, 2.0, "outside its range", ("pd",))
    with pytest.raises(ValueError, match="default"):
        PolicySetting("x", int, "", 0, 10, 1.0, "of the wrong type", ("pd",))
    with pytest.raises(ValueError, match="unknown policies"):
        PolicySetting("x", float, "m", 0.0, 1.0, 0.5, "of an unknown policy", ("pid",))


def test_policy_spec_holds_a_value_of_each_declared_setting() -> None:
    held = [(field.name, field.type) for field in fields(PolicySpec) if field.name not in ("name", "source")]
    assert held == [(setting.name, setting.kind.__name__) for setting in POLICY_SETTINGS]
    # From text (or parameters), each value is converted to its setting's type.
    spec = PolicySpec.of("pd", {name: str(value) for name, value in DEFAULT_VALUES.items()})
    assert {name: (type(value), value) for name, value in vars(spec).items() if name in SETTINGS} == {
        setting.name: (setting.kind, setting.default) for setting in POLICY_SETTINGS
    }


def _commands(spec: PolicySpec) -> np.ndarray:
    y, xdot, previous_xdot = 1.05, 4.8, 4.6
    return np.array(list(spec.commands(PAPER_PARAMS, y, xdot, previous_xdot)), dtype=float)


def _changed(setting: PolicySetting) -> Any:
    """Another valid value of the setting, close to the default."""
    if setting.kind is int:
        return setting.default + 1
    return setting.default * 1.05 if setting.default else 0.1


@pytest.mark.parametrize("policy", POLICIES)
def test_a_policy_uses_exactly_the_settings_declared_for_it(policy: str) -> None:
    """Changing a setting changes the policy's command where the declaration says the policy uses it, and
    only there."""
    spec = PolicySpec.default(policy)
    before = _commands(spec)
    assert np.all(np.isfinite(before))
    for setting in POLICY_SETTINGS:
        after = _commands(replace(spec, **{setting.name: _changed(setting)}))
        used = policy in setting.policies
        assert (not np.array_equal(after, before)) == used, (
            f"{policy} {'ignores' if used else 'uses'} {setting.name}"
        )


def test_the_controller_node_has_a_parameter_per_setting() -> None:
    assert [spec.name for spec in controller_node.TUNABLE] == ["policy", *SETTINGS]
    by_name = {spec.name: spec for spec in controller_node.SPECS}
    assert (by_name["policy"].default, by_name["policy"].choices) == (DEFAULT_POLICY, POLICIES)
    for setting in POLICY_SETTINGS:
        spec = by_name[setting.name]
        assert type(spec.default) is setting.kind and spec.default == setting.default, setting.name
        descriptor = spec.descriptor()
        assert descriptor.description == setting.text
        (bounds,) = descriptor.integer_range if setting.kind is int else descriptor.floating_point_range
        assert (bounds.from_value, bounds.to_value) == (setting.lower, setting.upper), setting.name
        assert not descriptor.read_only, setting.name  # tunable at runtime


YAML_ENTRY = re.compile(r"^ {4}(?P<key>\w+): \S+ +# (?P<comment>.+)$")


def test_controller_yaml_sets_each_setting_to_its_default_and_describes_it(repo_root: Path) -> None:
    """config/controller.yaml stays a file users edit: its keys, values, units and comments must agree
    with the declaration. A comment is the setting's text, optionally followed by a note in parentheses."""
    text = (repo_root / "config" / "controller.yaml").read_text()
    values = yaml.safe_load(text)["/**"]["ros__parameters"]
    comments = {match["key"]: match["comment"] for match in map(YAML_ENTRY.match, text.splitlines()) if match}
    assert list(values) == [*(spec.name for spec in parameters.HOPPER), "policy", *SETTINGS]
    assert values["policy"] == DEFAULT_POLICY
    assert comments["policy"] == " | ".join(POLICIES)
    for setting in POLICY_SETTINGS:
        value, comment = values[setting.name], comments[setting.name]
        assert type(value) is setting.kind and value == setting.default, setting.name
        assert comment == setting.text or comment.startswith(f"{setting.text} ("), (
            f"{setting.name}: '# {comment}' is not '# {setting.text}' (model.policies)"
        )


STUDY_DEFAULTS = {"touchdown_angle", "touchdown_power", "target_energy"}
"""The settings whose default a study sets itself (design.DEFAULTS: the figures' beta, the goal regulator)."""


def test_the_study_design_has_a_column_per_setting_with_its_unit() -> None:
    per_trajectory = [setting for setting in POLICY_SETTINGS if setting.name != "corrections"]
    assert design.POLICY_PARAMETERS == tuple(setting.name for setting in per_trajectory)
    assert "corrections" in {field.name for field in fields(design.Study)}  # one per study
    for setting in per_trajectory:
        assert design.UNITS[setting.name] == setting.unit, setting.name
        if setting.name not in STUDY_DEFAULTS:
            assert design.DEFAULTS[setting.name] == setting.default, setting.name
    # A trajectory's columns give the policy its settings, as a chunk does.
    study = design.Study.of(fixed={"y0": 1.0, "xdot0": 5.0}, start="speed")
    lanes = study.lanes(0, 1)
    values = {name: float(lanes[name][0]) for name in design.POLICY_PARAMETERS}
    spec = PolicySpec(name=str(lanes["policy"][0]), corrections=study.corrections, **values)
    assert spec.name == DEFAULT_POLICY and spec.target_height == SETTINGS["target_height"].default


@pytest.mark.parametrize("policy", POLICIES)
def test_the_report_gives_the_settings_the_policy_uses(policy: str) -> None:
    text = policy_settings_text(PolicySpec.default(policy), PAPER_PARAMS)
    assert re.findall(r"(\w+) = ", text) == [setting.name for setting in settings_of(policy)]
    for setting in settings_of(policy):
        unit = f" {setting.unit}" if setting.unit else ""
        assert f"{setting.name} = {setting.default:.6g}{unit}" in text
