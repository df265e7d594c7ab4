"""ROS parameters of the nodes: one spec per parameter, declared with a description and a range.

rclpy enforces the numeric ranges itself (for YAML overrides at start-up and for runtime
``set_parameters``); string choices are checked by :func:`validate`, which every node installs
as its on-set-parameters callback, so a bad value is refused with a reason and never taken.

The hopper's physical parameters (:data:`HOPPER`) are SI and shared by the plant and the
controller, which needs the same values to plan; both YAML files carry them under the same keys. Either
node may instead read them from a hopper file (``hopper_file``,
:func:`tdslip_ros.interfaces.read_hopper_file`).
Their defaults are the paper's figures 8-10: kbar = 36, zeta0 = 0.08, m = 80 kg, r0 = 1 m.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from tdslip_ros.interfaces import (
    BODY_KINDS,
    BODY_PARAMETER,
    FIXED_BODY,
    HOPPER_FILE_PARAMETER,
    RIGID_BODY_PARAMETERS,
)
from tdslip_ros.model.paper import PAPER_PARAMS, UPRIGHT_TRUNK
from tdslip_ros.model.params import ParameterError
from tdslip_ros.model.plant.terrain import TERRAIN_FORMS

ParameterValue = bool | int | float | str


@dataclass(frozen=True)
class ParameterSpec:
    """A node parameter: name, default (its type is the parameter's type), description, limits.

    low/high bound numbers (inclusive, rclpy's ranges); choices restrict strings.
    """

    name: str
    default: ParameterValue
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False

    def descriptor(self) -> ParameterDescriptor:
        descriptor = ParameterDescriptor(
            name=self.name, description=self.description, read_only=self.read_only
        )
        if self.choices:
            descriptor.additional_constraints = "one of: " + ", ".join(self.choices)
        if self.low is not None and self.high is not None:
            if isinstance(self.default, bool):
                raise TypeError(f"{self.name}: a bool parameter has no range")
            if isinstance(self.default, int):
                descriptor.integer_range = [
                    IntegerRange(from_value=int(self.low), to_value=int(self.high), step=1)
                ]
            else:
                descriptor.floating_point_range = [
                    FloatingPointRange(from_value=float(self.low), to_value=float(self.high), step=0.0)
                ]
        return descriptor


def _hopper(name: str, default: float, description: str, low: float, high: float) -> ParameterSpec:
    return ParameterSpec(name, default, description, low, high, read_only=True)


HOPPER: tuple[ParameterSpec, ...] = (
    _hopper("mass", PAPER_PARAMS.m, "body mass m [kg]", 1e-3, 1e5),
    _hopper("stiffness", PAPER_PARAMS.k, "leg spring stiffness k [N/m]", 1e-3, 1e9),
    _hopper("rest_length", PAPER_PARAMS.r0, "leg rest length r0 [m]", 1e-3, 1e2),
    _hopper("damping", PAPER_PARAMS.c, "leg damping c [N s/m] (zeta0 = c / (2 sqrt(m k)) < 1)", 0.0, 1e7),
    _hopper("gravity", PAPER_PARAMS.g, "gravitational acceleration g [m/s^2]", 1e-3, 1e3),
    ParameterSpec(
        BODY_PARAMETER,
        FIXED_BODY,
        "fixed: the paper's body, held level; rigid: a body that rotates freely in pitch, of the four below "
        "(docs/rotating_body.md)",
        choices=BODY_KINDS,
        read_only=True,
    ),
    _hopper(
        RIGID_BODY_PARAMETERS["inertia"],
        UPRIGHT_TRUNK.inertia,
        "rigid body: pitch inertia J about the centre of mass [kg m^2]",
        1e-6,
        1e6,
    ),
    _hopper(
        RIGID_BODY_PARAMETERS["hip_x"],
        UPRIGHT_TRUNK.hip_x,
        "rigid body: the hip's offset from the centre of mass along x at pitch 0 [m]",
        -10.0,
        10.0,
    ),
    _hopper(
        RIGID_BODY_PARAMETERS["hip_y"],
        UPRIGHT_TRUNK.hip_y,
        "rigid body: the hip's offset along y at pitch 0 [m] (< 0: below)",
        -10.0,
        10.0,
    ),
    _hopper(
        RIGID_BODY_PARAMETERS["tip_limit"],
        UPRIGHT_TRUNK.tip_limit,
        "rigid body: |pitch| beyond which it has tipped, a failure [rad]",
        1e-3,
        math.pi,
    ),
    ParameterSpec(
        HOPPER_FILE_PARAMETER,
        "",
        "a hopper file (YAML, SI; tdslip identify writes one) whose hopper replaces mass to gravity "
        "(empty: none)",
        read_only=True,
    ),
)


SEED_RANGE = (0, 2**31 - 1)
PERTURBATIONS: tuple[ParameterSpec, ...] = (
    ParameterSpec(
        "terrain",
        "flat",
        f"ground under the hopper [m]: {TERRAIN_FORMS}",
        read_only=True,
    ),
    ParameterSpec(
        "apex_height_noise",
        0.0,
        "sensor noise: standard deviation of the measured apex height [m]",
        0.0,
        10.0,
        read_only=True,
    ),
    ParameterSpec(
        "apex_speed_noise",
        0.0,
        "sensor noise: standard deviation of the measured apex speed [m/s]",
        0.0,
        100.0,
        read_only=True,
    ),
    ParameterSpec("apex_noise_seed", 0, "seed of the sensor noise", *SEED_RANGE, read_only=True),
    ParameterSpec(
        "angle_noise",
        0.0,
        "standard deviation of the leg's touchdown angle error [rad]",
        0.0,
        1.0,
        read_only=True,
    ),
    ParameterSpec("angle_noise_seed", 0, "seed of the touchdown angle error", *SEED_RANGE, read_only=True),
    ParameterSpec(
        "tau_max",
        0.0,
        "the hip torque saturates at +-tau_max [N m] (0: no saturation)",
        0.0,
        1e9,
        read_only=True,
    ),
    ParameterSpec(
        "pushes",
        "",
        "horizontal velocity changes [m/s] right after the apex, ';'-separated: STRIDE:DV (at that stride) "
        "and random:size=DV,rate=P,seed=N (+-DV with probability P per stride); '': none",
        read_only=True,
    ),
)
"""The plant's perturbation parameters (tdslip_ros.interfaces.PERTURBATION_PARAMETERS)."""


def declare(node: Node, specs: Iterable[ParameterSpec]) -> dict[str, ParameterValue]:
    """Declare every spec on ``node`` (overrides from YAML/CLI apply) and return the values by name."""
    specs = tuple(specs)
    parameters = node.declare_parameters("", [(spec.name, spec.default, spec.descriptor()) for spec in specs])
    return {parameter.name: parameter.value for parameter in parameters}


def validate(specs: Sequence[ParameterSpec], parameters: Sequence[Parameter[Any]]) -> SetParametersResult:
    """On-set-parameters check beyond rclpy's own (types and ranges): string choices."""
    by_name = {spec.name: spec for spec in specs}
    for parameter in parameters:
        spec = by_name.get(parameter.name)
        if spec is None:
            continue
        if spec.choices and parameter.value not in spec.choices:
            return SetParametersResult(
                successful=False, reason=f"{spec.name} must be one of {', '.join(spec.choices)}"
            )
    return SetParametersResult(successful=True)


_TYPE_NAMES = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}
_RCL_TRUE = {"y", "Y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON"}
_RCL_FALSE = {"n", "N", "no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF"}
_RCL_FLOAT_WORDS = {".nan", ".NaN", ".NAN", ".inf", ".Inf", ".INF", "-.inf", "-.Inf", "-.INF"}


def check_values(specs: Sequence[ParameterSpec], values: Mapping[str, object]) -> None:
    """ParameterError, in one line, for the first of ``values`` (None: not set) outside its spec's range or
    choices: what the node would refuse at start-up, said before it is started."""
    by_name = {spec.name: spec for spec in specs}
    for name, value in values.items():
        spec = by_name[name]
        if value is None:
            continue
        if spec.choices and value not in spec.choices:
            raise ParameterError(f"{name} must be one of {', '.join(spec.choices)}, got {value!r}")
        bounded = spec.low is not None and spec.high is not None and isinstance(value, int | float)
        if bounded and not spec.low <= value <= spec.high:  # type: ignore[operator]
            raise ParameterError(f"{name} must lie in [{spec.low:g}, {spec.high:g}], got {value!r}")


def rcl_value_type(text: str) -> type:
    """The type rcl's parameter parser gives a ``-p name:=text`` value: a quoted text is a string,
    then it tries bool words, an integer, a floating-point number, in that order; else a string."""
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return str
    if text in _RCL_TRUE or text in _RCL_FALSE:
        return bool
    try:
        int(text, 10)
        return int
    except ValueError:
        pass
    if text in _RCL_FLOAT_WORDS:
        return float
    try:
        float(text)
        return float
    except ValueError:
        return str


def _ros_arguments(argv: Sequence[str]) -> list[tuple[int, str, str]]:
    """(index, flag, value) of the flags with a value inside the ``--ros-args`` sections of argv."""
    found = []
    inside = False
    index = 0
    while index < len(argv):
        token = argv[index]
        if token == "--ros-args":
            inside = True
        elif token == "--":
            inside = False
        elif inside and token in ("-p", "--param", "--params-file") and index + 1 < len(argv):
            found.append((index + 1, token, argv[index + 1]))
            index += 1
        index += 1
    return found


RCLPY_PARAMETERS = ("use_sim_time", "start_type_description_service")
"""Parameters every rclpy node declares itself (besides ``qos_overrides.*``)."""


def _is_rclpy_parameter(name: str) -> bool:
    return name in RCLPY_PARAMETERS or name.startswith("qos_overrides.")


def check_command_line(argv: list[str], specs: Sequence[ParameterSpec]) -> list[str]:
    """argv checked against ``specs`` before rcl reads it, which would let a default params file
    silently win over a ``-p`` value of the wrong type: a value of another type, an unparsable one
    or a missing params file raise ParameterError naming it, and so does a name the node does not have
    (rcl would ignore ``-p max_strids:=5`` silently). An integer given for a float parameter
    (``-p mass:=80``) is what the user means: the returned argv spells it as a float."""
    by_name = {spec.name: spec for spec in specs}
    checked = list(argv)
    for index, flag, value in _ros_arguments(argv):
        if flag == "--params-file":
            if not Path(value).is_file():
                raise ParameterError(f"--params-file {value}: no such file")
            continue
        name, assign, text = value.partition(":=")
        spec = by_name.get(name.rsplit(":", 1)[-1])
        if assign and spec is None and ":" not in name and not _is_rclpy_parameter(name):
            # Unprefixed: meant for this node (``-p other_node:name:=...`` is another node's business).
            close = difflib.get_close_matches(name, by_name, n=1)
            hint = f"did you mean {close[0]}? " if close else ""
            raise ParameterError(
                f"parameter {name}: this node has no such parameter ({hint}{flag} {value}; see the node's "
                "params file for its parameters)"
            )
        if not assign or spec is None:
            continue
        given = rcl_value_type(text)
        expected = type(spec.default)
        if expected is float and given is int:
            checked[index] = f"{name}:={float(text)!r}"
        elif given is not expected:
            raise ParameterError(
                f"parameter {spec.name}: {text} is not {_TYPE_NAMES[expected]} "
                f"({flag} {value}; default {spec.default!r})"
            )
    return checked
