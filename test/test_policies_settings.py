"""The policies' settings are declared once (tdslip_ros.model.policies.registry.POLICY_SETTINGS): the
policies use
what it says they use, and the controller node's parameters, config/controller.yaml, the study design's
policy columns and the analysis report's account of a policy agree with it, each checked on the structure
it really uses."""

from __future__ import annotations

import math
import re
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
import yaml  # type: ignore[import-untyped]
from rclpy.parameter import Parameter
from support.learned_policy import WEIGHTS, learned_file

from tdslip_ros.analysis.report_text import policy_settings_text
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import approximate_map
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.plant.stance_laws import StanceFeedback
from tdslip_ros.model.policies import controllers
from tdslip_ros.model.policies.registry import (
    ANALYTIC_MAP_POLICIES,
    DEFAULT_POLICY,
    LEARNED,
    POLICIES,
    POLICY_SETTINGS,
    STANCE_FEEDBACK_POLICIES,
    STANCE_PD_SPEED_ENERGY,
    PolicyError,
    PolicySetting,
    PolicySpec,
    settings_of,
)
from tdslip_ros.model.policies.stance_pd import StancePDSpeedEnergy
from tdslip_ros.nodes import controller_node, parameters, stance_controller_node
from tdslip_ros.nodes.answers import ANSWER_SUBSCRIBERS
from tdslip_ros.nodes.diagnostics import CONTROLLER_THRESHOLDS, specs_of
from tdslip_ros.nodes.lifecycle import AUTOSTART, END_WITH_RUN
from tdslip_ros.studies import design, table

SETTINGS = {setting.name: setting for setting in POLICY_SETTINGS}
DEFAULT_VALUES = {setting.name: setting.default for setting in POLICY_SETTINGS}


def test_a_declared_setting_is_consistent() -> None:
    with pytest.raises(ValueError, match="default"):
        PolicySetting("x", float, "m", 0.0, 1.0, 2.0, "outside its range", ("apex_foot_placement",))
    with pytest.raises(ValueError, match="default"):
        PolicySetting("x", int, "", 0, 10, 1.0, "of the wrong type", ("apex_foot_placement",))
    with pytest.raises(ValueError, match="unknown policies"):
        PolicySetting("x", float, "m", 0.0, 1.0, 0.5, "of an unknown policy", ("pid",))
    # A setting of text choices: its default is one of them; it has no range, no unit; a number, no choices.
    choice = PolicySetting(
        "x", str, "", None, None, "b", "a choice", ("apex_foot_placement",), choices=("a", "b")
    )
    assert choice.text == "apex_foot_placement: a choice"
    with pytest.raises(ValueError, match="default"):
        PolicySetting(
            "x",
            str,
            "",
            None,
            None,
            "c",
            "not among its choices",
            ("apex_foot_placement",),
            choices=("a", "b"),
        )
    with pytest.raises(ValueError, match="default"):
        PolicySetting(
            "x", str, "", None, None, 1.0, "of the wrong type", ("apex_foot_placement",), choices=("a", "b")
        )
    with pytest.raises(ValueError, match="range"):
        PolicySetting(
            "x", str, "", 0.0, 1.0, "a", "with a range", ("apex_foot_placement",), choices=("a", "b")
        )
    with pytest.raises(ValueError, match="unit"):
        PolicySetting(
            "x", str, "m", None, None, "a", "with a unit", ("apex_foot_placement",), choices=("a", "b")
        )
    with pytest.raises(ValueError, match="choices"):
        PolicySetting(
            "x", float, "m", 0.0, 1.0, 0.5, "a number with choices", ("apex_foot_placement",), choices=("a",)
        )
    with pytest.raises(ValueError, match="range"):
        PolicySetting("x", float, "m", None, None, 0.5, "a number without a range", ("apex_foot_placement",))


def test_policy_spec_holds_a_value_of_each_declared_setting() -> None:
    held = [(field.name, field.type) for field in fields(PolicySpec) if field.name not in ("name", "source")]
    assert held == [(setting.name, setting.kind.__name__) for setting in POLICY_SETTINGS]
    # From text (or parameters), each value is converted to its setting's type.
    spec = PolicySpec.of("apex_foot_placement", {name: str(value) for name, value in DEFAULT_VALUES.items()})
    assert {name: (type(value), value) for name, value in vars(spec).items() if name in SETTINGS} == {
        setting.name: (setting.kind, setting.default) for setting in POLICY_SETTINGS
    }


APEX = (1.05, 4.8, 4.6)
"""y [m], xdot [m/s] and the previous apex's xdot of the apex at which the policies are compared."""


def _commands(spec: PolicySpec, apex: tuple[float, float, float] = APEX) -> np.ndarray:
    return np.array(list(spec.commands(PAPER_PARAMS, *apex)), dtype=float)


@pytest.fixture(scope="module", autouse=True)
def learned_files(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The learned policy's file, and another of other weights (its setting changed)."""
    directory = tmp_path_factory.mktemp("learned")
    LEARNED_FILES.extend(
        (learned_file(directory / "policy.json"), learned_file(directory / "other.json", 0.5 * WEIGHTS))
    )


LEARNED_FILES: list[str] = []


def _default(policy: str) -> PolicySpec:
    """The policy at its defaults; the learned policy with its file."""
    spec = PolicySpec.default(policy)
    return replace(spec, policy_file=LEARNED_FILES[0]) if policy == LEARNED else spec


def _changed(setting: PolicySetting) -> Any:
    """Another valid value of the setting, close to the default (the next choice of a text setting, the other
    learned file)."""
    if setting.name == "policy_file":
        return LEARNED_FILES[1]
    if setting.kind is str:
        return next(choice for choice in setting.choices if choice != setting.default)
    if setting.kind is int:
        return setting.default + 1
    return setting.default * 1.05 if setting.default else 0.1


CHOICE_PROBES: tuple[tuple[tuple[float, float, float], dict[str, float]], ...] = (
    (APEX, {}),
    ((2.4, 4.55, 4.6), {}),
    ((0.95, 2.95, 2.95), {"touchdown_angle": math.radians(40.0)}),
)
"""Apexes (and settings) at which a setting of choices is looked at. The two analytic maps differ in the next
apex speed alone: deadbeat steers by it (its command differs at APEX); open_loop, energy and
apex_foot_placement plan the stance and the energy, alike on both maps, and differ only where one map
foresees a reversal and the other does not (ours: the energy balance leaves the next apex no kinetic energy;
the paper's speed, of eq. 7, is that of liftoff), as at the other two probes."""


def _responds(spec: PolicySpec, setting: PolicySetting) -> bool:
    """Whether changing ``setting`` changes the command of ``spec`` (at APEX, or for a setting of choices
    at one of the CHOICE_PROBES, where a lane without a command is the same as another without)."""
    changed = replace(spec, **{setting.name: _changed(setting)})
    if setting.kind is not str:
        return not np.array_equal(_commands(changed), _commands(spec))
    return any(
        not np.array_equal(
            _commands(replace(changed, **settings), apex),
            _commands(replace(spec, **settings), apex),
            equal_nan=True,
        )
        for apex, settings in CHOICE_PROBES
    )


@pytest.mark.parametrize("policy", POLICIES)
def test_a_policy_uses_exactly_the_settings_declared_for_it(policy: str) -> None:
    """Changing a setting changes the policy's command where the declaration says the policy uses it, and
    only there."""
    spec = _default(policy)
    assert np.all(np.isfinite(_commands(spec)))
    for setting in POLICY_SETTINGS:
        used = policy in setting.policies
        assert _responds(spec, setting) == used, f"{policy} {'ignores' if used else 'uses'} {setting.name}"


@pytest.mark.parametrize("policy", ANALYTIC_MAP_POLICIES)
def test_the_analytic_map_setting_is_the_speed_the_policy_functions_plan_with(policy: str) -> None:
    """PolicySpec with analytic_map ours or paper commands what the policy's function does with speed
    energy or liftoff (the map's next apex speed, model.analytic), called directly."""
    direct = {
        "open_loop": lambda y, xdot, previous, speed, spec: controllers.fixed_power(
            PAPER_PARAMS,
            y,
            xdot,
            spec.touchdown_angle,
            units.power_to_alpha(PAPER_PARAMS, spec.touchdown_power),
            speed=speed,
        ),
        "energy": lambda y, xdot, previous, speed, spec: controllers.energy_regulation(
            PAPER_PARAMS, y, xdot, spec.touchdown_angle, spec.target_energy, speed=speed
        ),
        "deadbeat": lambda y, xdot, previous, speed, spec: controllers.deadbeat(
            PAPER_PARAMS, y, xdot, spec.target_height, spec.target_speed, speed=speed
        ),
        "apex_foot_placement": lambda y, xdot, previous, speed, spec: controllers.apex_foot_placement(
            PAPER_PARAMS, y, xdot, previous, spec.target_height, spec.target_speed, speed=speed
        ),
    }[policy]
    for apex, settings in CHOICE_PROBES:
        spec = replace(PolicySpec.default(policy), **settings)
        ours, paper = (_commands(replace(spec, analytic_map=name), apex) for name in ("ours", "paper"))
        for commands, speed in ((ours, "energy"), (paper, "liftoff")):
            expected = np.array(list(direct(*apex, speed, spec)), dtype=float)
            assert np.array_equal(commands, expected, equal_nan=True), (apex, speed)
        if policy != "deadbeat":  # planned alike on both maps where both foresee a stride
            both = np.isfinite(ours) & np.isfinite(paper)
            assert np.array_equal(ours[both], paper[both])


def test_deadbeat_on_the_papers_map_aims_with_eq_7s_speed() -> None:
    ours, paper = (replace(PolicySpec.default("deadbeat"), analytic_map=name) for name in ("ours", "paper"))
    assert PolicySpec.default("deadbeat").analytic_map == "ours"  # the default
    target = (paper.target_height, paper.target_speed)
    y, xdot, _ = APEX
    command = paper.commands(PAPER_PARAMS, y, xdot, xdot)
    direct = controllers.deadbeat(PAPER_PARAMS, y, xdot, *target, speed="liftoff")
    assert np.array_equal(list(command), list(direct))
    other = ours.commands(PAPER_PARAMS, y, xdot, xdot).touchdown_angle
    assert abs(float(command.touchdown_angle) - float(other)) > 0.05  # rad: another angle for another speed
    # From an apex whence both reach the target speed, each reaches it on its own map, not on the other's.
    y, xdot = 1.1, 5.2
    for spec, speed, wrong in ((paper, "liftoff", "energy"), (ours, "energy", "liftoff")):
        planned = spec.commands(PAPER_PARAMS, y, xdot, xdot)
        mine = approximate_map(PAPER_PARAMS, y, xdot, planned, speed=speed)
        theirs = approximate_map(PAPER_PARAMS, y, xdot, planned, speed=wrong)
        assert float(mine.xdot) == pytest.approx(spec.target_speed, rel=1e-9)
        assert abs(float(theirs.xdot) - spec.target_speed) > 1e-2


def test_an_unknown_analytic_map_is_refused() -> None:
    with pytest.raises(PolicyError, match="analytic_map 'papr'; one of ours, paper"):
        replace(PolicySpec.default("energy"), analytic_map="papr")
    with pytest.raises(PolicyError, match="analytic_map 'papr'"):
        PolicySpec.of("energy", {**DEFAULT_VALUES, "analytic_map": "papr"})


def test_the_controller_node_has_a_parameter_per_setting() -> None:
    assert [spec.name for spec in controller_node.TUNABLE] == ["policy", *SETTINGS]
    by_name = {spec.name: spec for spec in controller_node.SPECS}
    assert (by_name["policy"].default, by_name["policy"].choices) == (DEFAULT_POLICY, POLICIES)
    for setting in POLICY_SETTINGS:
        spec = by_name[setting.name]
        assert type(spec.default) is setting.kind and spec.default == setting.default, setting.name
        descriptor = spec.descriptor()
        assert descriptor.description == setting.text
        assert spec.choices == setting.choices, setting.name
        if setting.kind is str and not setting.choices:  # a free text: any string, no range
            assert not descriptor.additional_constraints and not descriptor.floating_point_range
            assert parameters.validate(controller_node.SPECS, [Parameter(setting.name, value="any/path")])
        elif setting.kind is str:  # its choices, checked by the node's on-set callback, and no range
            assert descriptor.additional_constraints == "one of: " + ", ".join(setting.choices)
            assert not descriptor.integer_range and not descriptor.floating_point_range, setting.name
            refused = parameters.validate(controller_node.SPECS, [Parameter(setting.name, value="papr")])
            assert not refused.successful
            assert refused.reason == f"{setting.name} must be one of {', '.join(setting.choices)}"
            assert parameters.validate(
                controller_node.SPECS, [Parameter(setting.name, value=_changed(setting))]
            )
        else:
            (bounds,) = descriptor.integer_range if setting.kind is int else descriptor.floating_point_range
            assert (bounds.from_value, bounds.to_value) == (setting.lower, setting.upper), setting.name
        assert not descriptor.read_only, setting.name  # tunable at runtime


def test_the_stance_controller_node_has_a_parameter_per_setting_of_its_policies() -> None:
    """The stance-feedback policies run in a node of their own: the lifecycle's, the answers' subscribers, the
    hopper, the policy, the settings of its policies (each once, in the declaration's order), then its
    diagnostics."""
    settings = [s for s in POLICY_SETTINGS if set(s.policies) & set(STANCE_FEEDBACK_POLICIES)]
    lifecycle = (AUTOSTART, END_WITH_RUN, ANSWER_SUBSCRIBERS)
    ahead = (*lifecycle, *parameters.HOPPER, stance_controller_node.STANCE_POLICY)
    assert stance_controller_node.SPECS[: len(ahead)] == ahead
    assert stance_controller_node.STANCE_POLICY.choices == STANCE_FEEDBACK_POLICIES
    tunable = stance_controller_node.SPECS[len(ahead) : len(ahead) + len(settings)]
    assert stance_controller_node.SPECS[len(ahead) + len(settings) :] == specs_of(())
    assert [spec.name for spec in tunable] == [s.name for s in settings]
    for spec, setting in zip(tunable, settings, strict=True):
        assert (spec.default, spec.descriptor().description) == (setting.default, setting.text)


def test_the_stance_feedback_policy_is_its_law_with_its_settings() -> None:
    spec = replace(PolicySpec.default(STANCE_PD_SPEED_ENERGY), stance_speed_gain=1234.0, target_speed=4.5)
    feedback = spec.stance_feedback(PAPER_PARAMS)
    assert isinstance(feedback, StanceFeedback) and feedback.touchdown_angle == math.radians(22.0)
    law = feedback.law
    assert isinstance(law, StancePDSpeedEnergy) and (law.speed_gain, law.target_xdot) == (1234.0, 4.5)
    assert (law.target_y, law.energy_gain) == (DEFAULT_VALUES["target_height"], 3.0)
    with pytest.raises(PolicyError, match="answers with stance feedback, not a ramp"):
        spec.commands(PAPER_PARAMS, *APEX)
    with pytest.raises(PolicyError, match="answers with a ramp, not stance feedback"):
        PolicySpec.default("energy").stance_feedback(PAPER_PARAMS)


YAML_ENTRY = re.compile(r"^ {4}(?P<key>\w+): \S+ +# (?P<comment>.+)$")


def test_controller_yaml_sets_each_setting_to_its_default_and_describes_it(repo_root: Path) -> None:
    """config/controller.yaml stays a file users edit: its keys, values, units and comments must agree
    with the declaration. A comment is the setting's text, optionally followed by a note in parentheses."""
    text = (repo_root / "config" / "controller.yaml").read_text()
    values = yaml.safe_load(text)["/**"]["ros__parameters"]
    comments = {match["key"]: match["comment"] for match in map(YAML_ENTRY.match, text.splitlines()) if match}
    lifecycle = [AUTOSTART.name, END_WITH_RUN.name]
    diagnostics = [spec.name for spec in specs_of(CONTROLLER_THRESHOLDS)]
    assert list(values) == [
        *lifecycle,
        ANSWER_SUBSCRIBERS.name,
        *(spec.name for spec in parameters.HOPPER),
        "policy",
        stance_controller_node.STANCE_POLICY.name,
        *SETTINGS,
        *diagnostics,
    ]
    assert values["policy"] == DEFAULT_POLICY
    assert comments["policy"] == " | ".join(POLICIES)
    assert values["stance_policy"] == STANCE_PD_SPEED_ENERGY
    assert comments["stance_policy"].endswith(": " + " | ".join(STANCE_FEEDBACK_POLICIES) + " (a rigid body)")
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
    # A setting of choices is a text column, like the policy: one value per call of the engine, never drawn.
    choices = [setting for setting in per_trajectory if setting.kind is str]
    assert {name: design.CHOICES[name] for name in design.CHOICE_SETTINGS} == {
        s.name: s.choices for s in choices
    }
    for setting in choices:
        assert setting.name in design.GROUP_PARAMETERS and setting.name not in design.NUMERIC_PARAMETERS
        assert table.SCHEMA.field(setting.name).type == pa.string()
    numeric = [setting.name for setting in per_trajectory if setting.kind is not str]
    assert [name for name in design.NUMERIC_PARAMETERS if name in SETTINGS] == numeric
    # A trajectory's columns give the policy its settings, as a chunk does.
    study = design.Study.of(fixed={"y0": 1.0, "xdot0": 5.0}, start="speed")
    lanes = study.lanes(0, 1)
    values = {name: SETTINGS[name].kind(lanes[name][0]) for name in design.POLICY_PARAMETERS}
    spec = PolicySpec(name=str(lanes["policy"][0]), corrections=study.corrections, **values)
    assert spec.name == DEFAULT_POLICY and spec.target_height == SETTINGS["target_height"].default
    assert all(getattr(spec, setting.name) == setting.default for setting in choices)


@pytest.mark.parametrize("policy", POLICIES)
def test_the_report_gives_the_settings_the_policy_uses(policy: str) -> None:
    text = policy_settings_text(PolicySpec.default(policy), PAPER_PARAMS)  # no file read
    assert re.findall(r"(\w+) = ", text) == [setting.name for setting in settings_of(policy)]
    for setting in settings_of(policy):
        unit = f" {setting.unit}" if setting.unit else ""
        value = setting.default if setting.kind is str else f"{setting.default:.6g}"
        assert f"{setting.name} = {value}{unit}" in text
