"""Node parameters: declared with a description and a range, set by config/*.yaml, validated."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml  # type: ignore[import-untyped]
from rcl_interfaces.msg import ParameterType
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from support.ros_harness import RosGraph, overrides

from tdslip_ros.interfaces import hopper_from_parameters
from tdslip_ros.model.params import ParameterError
from tdslip_ros.nodes import (
    controller_node,
    isolation,
    parameters,
    plant_parameters,
    recorder_node,
    stance_controller_node,
)
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.entry import BAD_PARAMETERS, with_default_params_file
from tdslip_ros.nodes.parameters import ParameterSpec
from tdslip_ros.nodes.plant_node import PlantNode
from tdslip_ros.nodes.recorder_node import RecorderNode
from tdslip_ros.nodes.stance_controller_node import StanceControllerNode

CONTROLLERS_SPECS = tuple(
    spec
    for own in controller_node.SPECS
    for spec in ((own, stance_controller_node.STANCE_POLICY) if own.name == "policy" else (own,))
)
"""controller.yaml serves both controller nodes: the ramp controller's parameters, and after its ``policy``
the stance controller's; the stance controller's others are among the ramp controller's."""
NODE_SPECS = {
    "plant.yaml": plant_parameters.SPECS,
    "controller.yaml": CONTROLLERS_SPECS,
    "recorder.yaml": recorder_node.SPECS,
}
HOPPER_KEYS = [spec.name for spec in parameters.HOPPER]


def yaml_parameters(path: Path) -> dict[str, Any]:
    document = yaml.safe_load(path.read_text())
    assert list(document) == ["/**"]
    parameters_: dict[str, Any] = document["/**"]["ros__parameters"]
    return parameters_


@pytest.mark.parametrize("file_name", sorted(NODE_SPECS))
def test_yaml_sets_exactly_the_declared_parameters_to_their_defaults(repo_root: Path, file_name: str) -> None:
    values = yaml_parameters(repo_root / "config" / file_name)
    specs = NODE_SPECS[file_name]
    assert list(values) == [spec.name for spec in specs]  # none missing, none unknown, same order
    for spec in specs:
        value = values[spec.name]
        assert type(value) is type(spec.default), spec.name  # rclpy refuses e.g. an int for a double
        # Bit for bit: a run from the YAML and one from the defaults must be the same run.
        assert value == spec.default, spec.name


def test_controller_yaml_holds_every_parameter_of_the_stance_controller(repo_root: Path) -> None:
    values = yaml_parameters(repo_root / "config" / "controller.yaml")
    for spec in stance_controller_node.SPECS:
        assert values[spec.name] == spec.default, spec.name


def test_plant_and_controller_share_the_paper_hopper(repo_root: Path) -> None:
    plant = yaml_parameters(repo_root / "config" / "plant.yaml")
    controller = yaml_parameters(repo_root / "config" / "controller.yaml")
    assert {key: plant[key] for key in HOPPER_KEYS} == {key: controller[key] for key in HOPPER_KEYS}
    hopper = hopper_from_parameters(plant)
    assert (hopper.kbar, hopper.zeta0, hopper.m, hopper.r0) == pytest.approx(
        (36.0, 0.08, 80.0, 1.0), rel=1e-14
    )


def check_descriptor(node: Node, spec: ParameterSpec) -> None:
    (descriptor,) = node.describe_parameters([spec.name])
    assert descriptor.description, spec.name
    if descriptor.type == ParameterType.PARAMETER_DOUBLE:
        (bounds,) = descriptor.floating_point_range
        assert bounds.from_value <= spec.default <= bounds.to_value
    elif descriptor.type == ParameterType.PARAMETER_INTEGER:
        (bounds,) = descriptor.integer_range
        assert bounds.from_value <= spec.default <= bounds.to_value
    elif descriptor.type == ParameterType.PARAMETER_STRING and spec.choices:
        assert all(choice in descriptor.additional_constraints for choice in spec.choices)
    else:
        assert descriptor.type in (ParameterType.PARAMETER_BOOL, ParameterType.PARAMETER_STRING), spec.name


def test_every_parameter_is_described_with_its_range(ros: RosGraph, tmp_path: Path) -> None:
    nodes = {
        PlantNode(context=ros.context, start_when_ready=False): plant_parameters.SPECS,
        ControllerNode(context=ros.context): controller_node.SPECS,
        StanceControllerNode(context=ros.context): stance_controller_node.SPECS,
        RecorderNode(
            context=ros.context, parameter_overrides=overrides(output=str(tmp_path / "b"))
        ): recorder_node.SPECS,
    }
    for node, specs in nodes.items():
        ros.add(node)
        rclpy_own = ("use_sim_time", "start_type_description_service")
        own = {name for name in node.list_parameters([], 0).names if name not in rclpy_own}
        assert own == {spec.name for spec in specs}
        for spec in specs:
            check_descriptor(node, spec)


def test_a_params_file_configures_the_node_and_bad_values_are_refused(ros: RosGraph, tmp_path: Path) -> None:
    def plant_with(values: dict[str, object]) -> PlantNode:
        path = tmp_path / "plant.yaml"
        path.write_text(yaml.safe_dump({"/**": {"ros__parameters": values}}))
        return ros.add(
            PlantNode(
                context=ros.context,
                start_when_ready=False,
                cli_args=["--ros-args", "--params-file", str(path)],
            )
        )

    plant = plant_with({"mass": 70.0, "clock_mode": "realtime", "max_strides": 7})
    assert (plant.hopper.m, plant.lockstep, plant.get_parameter("max_strides").value) == (70.0, False, 7)
    for bad in ({"damping": -1.0}, {"clock_mode": "fast"}, {"initial_touchdown_angle": 2.0}):
        with pytest.raises(InvalidParameterValueException, match=next(iter(bad))):
            plant_with(bad)
    with pytest.raises(InvalidParameterValueException, match="initial_height"):
        PlantNode(context=ros.context, parameter_overrides=overrides(initial_height=math.inf))


@pytest.mark.nodes
def test_the_recorder_refuses_malformed_custom_data_before_creating_a_bag(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    with isolation.reserved_domain() as domain_id:
        result = subprocess.run(
            [sys.executable, "-m", "tdslip_ros.nodes.recorder_node", "--ros-args"]
            + ["-p", f"output:={bag}", "-p", "custom_data:=run=1 no_value"],
            capture_output=True,
            text=True,
            timeout=60,
            env=isolation.isolated_environment(domain_id),
        )
    assert result.returncode == BAD_PARAMETERS
    assert "custom_data: 'no_value' is not KEY=VALUE" in result.stderr
    assert not bag.exists()


def test_command_line_overrides_win_over_the_default_params_file(ros: RosGraph) -> None:
    argv = ["plant_node", "--ros-args", "-p", "mass:=70.0"]
    arguments = with_default_params_file(argv, "plant.yaml")
    assert arguments[:3] == ["plant_node", "--ros-args", "--params-file"] and arguments[-3:] == argv[1:]
    assert with_default_params_file([*argv, "--params-file", "mine.yaml"], "plant.yaml")[-1] == "mine.yaml"
    plant = ros.add(PlantNode(context=ros.context, start_when_ready=False, cli_args=arguments[1:]))
    assert plant.hopper.m == 70.0
    assert plant.hopper.k == parameters.PAPER_PARAMS.k


def node_executable(module: str, *arguments: str) -> subprocess.CompletedProcess[str]:
    """A node executable started as ``ros2 run`` would, with its own private domain."""
    with isolation.reserved_domain() as domain_id:
        return subprocess.run(
            [sys.executable, "-m", f"tdslip_ros.nodes.{module}", *arguments],
            capture_output=True,
            text=True,
            timeout=60,
            env=isolation.isolated_environment(domain_id),
        )


@pytest.mark.parametrize(
    ("module", "override", "named"),
    [
        ("plant_node", "max_strides:=abc", "max_strides"),
        ("plant_node", "max_strides:=2.5", "max_strides"),
        ("plant_node", "mass:='80'", "mass"),
        ("plant_node", "clock_mode:=1", "clock_mode"),
        ("controller_node", "corrections:=one", "corrections"),
        ("recorder_node", "record_clock:=maybe", "record_clock"),
        ("plant_node", "max_strids:=5", "max_strids"),  # a typo: rcl would ignore it and run 50 strides
        ("controller_node", "polcy:=pd", "polcy"),
    ],
)
@pytest.mark.nodes
def test_a_value_of_the_wrong_type_on_the_command_line_is_an_error_naming_the_parameter(
    module: str, override: str, named: str
) -> None:
    # rcl would let the installed params file win over it and run on the default, silently.
    result = node_executable(module, "--ros-args", "-p", override)
    assert result.returncode == BAD_PARAMETERS, result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"{module}: parameter {named}: ") and "Traceback" not in result.stderr


@pytest.mark.nodes
def test_the_controller_refuses_an_analytic_map_it_does_not_know_in_one_line() -> None:
    result = node_executable("controller_node", "--ros-args", "-p", "analytic_map:=papr")
    assert result.returncode == BAD_PARAMETERS, result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("controller_node: ") and "Traceback" not in result.stderr
    assert "analytic_map must be one of ours, paper" in line and "(papr)" in line


def test_a_misspelt_name_is_named_with_the_closest_parameter_and_rclpy_s_own_pass() -> None:
    with pytest.raises(
        ParameterError, match="max_strids: this node has no such parameter .did you mean max_strides"
    ):
        parameters.check_command_line(
            ["plant_node", "--ros-args", "-p", "max_strids:=5"], plant_parameters.SPECS
        )
    argv = [
        "plant_node",
        "--ros-args",
        "-p",
        "use_sim_time:=true",
        "-p",
        "qos_overrides./clock.publisher.depth:=5",
        "-p",
        "controller:polcy:=pd",  # another node's
    ]
    assert parameters.check_command_line(argv, plant_parameters.SPECS) == argv


def test_an_integer_for_a_float_parameter_is_taken_as_that_float() -> None:
    argv = ["plant_node", "--ros-args", "-p", "mass:=80", "-p", "max_strides:=3", "--", "-p", "mass:=x"]
    checked = parameters.check_command_line(argv, plant_parameters.SPECS)
    assert checked == [
        "plant_node",
        "--ros-args",
        "-p",
        "mass:=80.0",
        "-p",
        "max_strides:=3",
        "--",
        "-p",
        "mass:=x",
    ]


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--params-file", "/nonexistent.yaml"], "--params-file /nonexistent.yaml: no such file"),
        (["-p", "damping:=1e7"], "zeta0"),  # within the parameter's range, but an overdamped leg
        (["-p", "initial_height:=99.0"], "apex height"),  # within the range, beyond the plausibility limits
        (["-p", "initial_tau0:=-900000.0"], "actuator limit"),
        (["-p", "terrain:=hills"], "terrain 'hills' is not one of"),
        (["-p", "pushes:=3:fast"], "neither STRIDE:DV"),
    ],
)
@pytest.mark.nodes
def test_implausible_or_missing_inputs_stop_the_plant_with_one_line(
    arguments: list[str], message: str
) -> None:
    result = node_executable("plant_node", "--ros-args", *arguments)
    assert result.returncode == BAD_PARAMETERS
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("plant_node: ") and message in line
