"""What the nodes and the offline analysis share, without rclpy: the names of the suite's topics
and service, the message types they carry, the installed node parameter files, the node parameters that
hold the hopper and the plant's perturbations (and how they map onto the model's), and the keys under
which ``tdslip run`` stores the nodes' parameters in a bag's ``custom_data``.

tdslip_ros.nodes.topics adds the QoS and message classes; the analysis must not need rclpy.
"""

import dataclasses
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs

from tdslip_ros.bag.schema import package_share_directory
from tdslip_ros.model.params import HopperParams, ParameterError, RigidBody
from tdslip_ros.model.plant.perturbations import Perturbations, PlacementNoise, Pushes, SensingNoise
from tdslip_ros.model.plant.terrain import parse_terrain

# Relative names: the nodes create their topics and service with these, so a node's namespace
# (``--ros-args -r __ns:=/hopper1``) and remapping apply as in any ROS 2 package. /clock is global.
STATE = "tdslip/state"
GRF = "tdslip/grf"
SAMPLES = "tdslip/samples"
APEX = "tdslip/apex"
CONTACT = "tdslip/contact"
STATUS = "tdslip/status"
COMMAND = "tdslip/command"
HIP_TORQUE = "tdslip/hip_torque"
APPLIED_TORQUE = "tdslip/applied_torque"
RECORDER_STATUS = "tdslip/recorder_status"
MARKERS = "tdslip/markers"
CLOCK = "/clock"
RESET_SERVICE = "tdslip/reset"
# The hopper as a robot for RViz and Foxglove (nodes/robot_model.py) and the nodes' health, under the names
# ROS 2's own tools use: robot_state_publisher's (relative) and tf2's and diagnostic_updater's (global).
JOINT_STATES = "joint_states"
ROBOT_DESCRIPTION = "robot_description"
TF = "/tf"
DIAGNOSTICS = "/diagnostics"

TOPIC_TYPES: dict[str, str] = {
    STATE: "tdslip_msgs/msg/HopperState",
    GRF: "geometry_msgs/msg/WrenchStamped",
    APEX: "tdslip_msgs/msg/ApexEvent",
    CONTACT: "tdslip_msgs/msg/ContactEvent",
    STATUS: "tdslip_msgs/msg/Status",
    COMMAND: "tdslip_msgs/msg/StanceCommand",
    APPLIED_TORQUE: "tdslip_msgs/msg/HipTorque",
}
"""The suite's topics that a run's analysis needs, by relative name, with the type name rosbag2
records for them."""

STAMP_FIELDS = ("header.stamp.sec", "header.stamp.nanosec")
"""The header stamp of the 1 kHz messages, as dotted field paths."""
PITCH_FIELDS = ("pitch", "pitch_rate")
"""A rigid body's pitch [rad] and rate [rad/s] in HopperState and ApexEvent, since tdslip_msgs 0.2.0: a bag
recorded before them is read with both 0."""
STATE_FIELDS = (
    "stride",
    "phase",
    "x",
    "y",
    "xdot",
    "ydot",
    "toe_x",
    "toe_y",
    "leg_length",
    "leg_angle",
    "leg_length_rate",
    "leg_angle_rate",
    "hip_torque",
    "energy",
    "ground_height",
    *PITCH_FIELDS,
)
"""The fields of a HopperState after its header, in the message's order."""
GRF_FIELDS = ("wrench.force.x", "wrench.force.y")
"""The fields of the GRF's WrenchStamped that the plant sets (the rest is 0)."""

RUN_COMPLETE = "run_complete"
"""The kind of the Status that ends a run without a failure (the plant's Status.KIND_RUN_COMPLETE); every
other kind of a fatal Status is a failure."""
STOP_REQUESTED = "stopped on request"
"""The reason of the ``run_complete`` Status of a run its caller stopped before its limits (``tdslip run``
on Ctrl-C); a run_complete with any other reason reached a limit it was given (max_strides, a wall time)."""


def qualified_namespace(namespace: str) -> str:
    """``namespace`` fully qualified, as rcl's ``__ns`` remapping needs it: ``h1`` -> ``/h1``."""
    return "/" + namespace.strip("/")


def resolve(name: str, namespace: str = "/") -> str:
    """The fully qualified name of a suite topic or service in ``namespace`` (``/h1`` or ``h1`` ->
    ``/h1/tdslip/state``); absolute names (/clock) stay as they are."""
    if name.startswith("/"):
        return name
    return f"{qualified_namespace(namespace).rstrip('/')}/{name}"


HOPPER_PARAMETERS = {"m": "mass", "k": "stiffness", "r0": "rest_length", "c": "damping", "g": "gravity"}
"""HopperParams fields and the names of the plant's and controller's parameters that hold them (SI)."""
BODY_PARAMETER = "body"
"""The node parameter choosing the body: one of BODY_KINDS."""
FIXED_BODY, RIGID_BODY = "fixed", "rigid"
BODY_KINDS = (FIXED_BODY, RIGID_BODY)
"""``fixed``: the paper's body, held level (HopperParams.body None); ``rigid``: a freely rotating body of the
RIGID_BODY_PARAMETERS (docs/rotating_body.md)."""
RIGID_BODY_PARAMETERS = {
    "inertia": "body_inertia",
    "hip_x": "hip_x",
    "hip_y": "hip_y",
    "tip_limit": "tip_limit",
}
"""RigidBody fields and the names of the node parameters that hold them (SI), read where ``body`` is rigid."""


PERTURBATION_PARAMETERS = {
    "terrain": "terrain",
    "sensing.height": "apex_height_noise",
    "sensing.speed": "apex_speed_noise",
    "sensing.seed": "apex_noise_seed",
    "placement.sigma": "angle_noise",
    "placement.seed": "angle_noise_seed",
    "tau_max": "tau_max",
    "pushes": "pushes",
}
"""Fields of :meth:`Perturbations.scalars` and the names of the plant's parameters that hold them (SI; the
terrain and the pushes as text; tau_max 0: no saturation)."""


def perturbation_parameters(perturbations: Perturbations) -> dict[str, str | float | int]:
    """The plant's parameters of ``perturbations`` by name (ParameterError for per-lane values)."""
    values = perturbations.scalars()
    if values["tau_max"] == math.inf:
        values["tau_max"] = 0.0
    return {name: values[field] for field, name in PERTURBATION_PARAMETERS.items()}


def perturbations_from_parameters(values: Mapping[str, Any]) -> Perturbations:
    """The perturbations of the plant's parameters (values as parameters or text give them; a missing one is
    off; other names are ignored); ParameterError naming a bad one."""
    name = PERTURBATION_PARAMETERS

    def number(field: str, convert: Callable[[Any], Any] = float) -> Any:
        try:
            return convert(values.get(name[field], 0))
        except (TypeError, ValueError):
            raise ParameterError(f"{name[field]} must be a number, got {values[name[field]]!r}") from None

    tau_max = number("tau_max")
    return Perturbations(
        terrain=parse_terrain(str(values.get(name["terrain"], "flat")) or "flat"),
        sensing=SensingNoise(number("sensing.height"), number("sensing.speed"), number("sensing.seed", int)),
        placement=PlacementNoise(number("placement.sigma"), number("placement.seed", int)),
        tau_max=math.inf if tau_max == 0.0 else tau_max,
        pushes=Pushes.parse(str(values.get(name["pushes"], ""))),
    )


def config_file(name: str) -> Path:
    """An installed node parameter file, e.g. ``config_file("plant.yaml")`` (from ``config/``)."""
    path = package_share_directory("tdslip_ros") / "config" / name
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing; install tdslip_ros (./run.sh setup)")
    return path


def installed_parameters(name: str) -> dict[str, Any]:
    """The ``ros__parameters`` of an installed node parameter file, by name."""
    document = yaml.safe_load(config_file(name).read_text())
    return dict(next(iter(document.values()))["ros__parameters"])


HOPPER_FILE_PARAMETER = "hopper_file"
"""The node parameter naming a hopper file that replaces the HOPPER_PARAMETERS' values (empty: none)."""


def hopper_from_parameters(values: Mapping[str, Any]) -> HopperParams:
    """The HopperParams of a node's parameter values by name: the hopper file's where ``hopper_file`` names
    one, else the HOPPER_PARAMETERS', with the body of ``body`` (its RIGID_BODY_PARAMETERS where rigid; fixed
    where the values have no ``body``). ParameterError names a bad one; KeyError a missing one."""
    if values.get(HOPPER_FILE_PARAMETER):
        params = read_hopper_file(Path(str(values[HOPPER_FILE_PARAMETER])))
    else:
        params = HopperParams(**{field: float(values[name]) for field, name in HOPPER_PARAMETERS.items()})
    body = str(values.get(BODY_PARAMETER, FIXED_BODY))  # a bag recorded before the body was one stores none
    if body == FIXED_BODY:
        return params
    if body != RIGID_BODY:
        raise ParameterError(f"{BODY_PARAMETER} must be one of {', '.join(BODY_KINDS)}, got {body!r}")
    rigid = RigidBody(**{field: float(values[name]) for field, name in RIGID_BODY_PARAMETERS.items()})
    return dataclasses.replace(params, body=rigid)


def hopper_parameters(params: HopperParams) -> dict[str, float | str]:
    """The node parameters of ``params`` by name (what :func:`hopper_from_parameters` reads back)."""
    values: dict[str, float | str] = {
        name: getattr(params, field) for field, name in HOPPER_PARAMETERS.items()
    }
    values[BODY_PARAMETER] = FIXED_BODY if params.body is None else RIGID_BODY
    if params.body is not None:
        values.update({name: getattr(params.body, field) for field, name in RIGID_BODY_PARAMETERS.items()})
    return values


HOPPER_FILE_KEY = "hopper"
"""The block of a hopper file that holds the hopper, by the node parameter names of HOPPER_PARAMETERS."""
HOPPER_FILE_PROVENANCE = "provenance"
"""The block of a hopper file that says where the hopper came from (free text and numbers; not read)."""


class HopperFileError(ParameterError):
    """A hopper file cannot serve; the message is one line naming the file and what is wrong."""


def write_hopper_file(path: Path, params: HopperParams, provenance: Mapping[str, Any]) -> None:
    """Write ``params`` as a hopper file (YAML, SI): the block ``hopper`` with a value per node parameter
    of HOPPER_PARAMETERS, and ``provenance`` (what made it: a command, a recording, confidence intervals),
    which :func:`read_hopper_file` ignores. Written whole or not at all (a temporary file, then renamed)."""
    document = {
        HOPPER_FILE_KEY: {name: float(getattr(params, field)) for field, name in HOPPER_PARAMETERS.items()},
        HOPPER_FILE_PROVENANCE: dict(provenance),
    }
    path = Path(path)
    partial = path.with_name(path.name + ".partial")
    partial.write_text(yaml.safe_dump(document, sort_keys=False))
    partial.replace(path)


def read_hopper_file(path: Path) -> HopperParams:
    """The hopper of a hopper file (:func:`write_hopper_file`). Every field but gravity is required (gravity
    defaults to HopperParams'); an unknown name is refused, so that a misspelt one is not silently the
    default. HopperFileError, one line naming the file, for anything else."""
    optional = {f.name for f in dataclasses.fields(HopperParams) if f.default is not dataclasses.MISSING}
    try:
        document = yaml.safe_load(Path(path).read_text())
    except (OSError, UnicodeDecodeError) as error:
        raise HopperFileError(f"hopper file {path}: cannot be read ({error.strerror or error})") from None
    except yaml.YAMLError as error:
        raise HopperFileError(f"hopper file {path}: not YAML ({' '.join(str(error).split())})") from None
    block = document.get(HOPPER_FILE_KEY) if isinstance(document, dict) else None
    if not isinstance(block, dict):
        raise HopperFileError(f"hopper file {path}: no '{HOPPER_FILE_KEY}:' block of name: value lines")
    names = {name: field for field, name in HOPPER_PARAMETERS.items()}
    if unknown := sorted(str(name) for name in block.keys() - names.keys()):
        raise HopperFileError(
            f"hopper file {path}: unknown name(s) {', '.join(unknown)}; known: {', '.join(names)}"
        )
    if missing := [name for name, field in names.items() if name not in block and field not in optional]:
        raise HopperFileError(f"hopper file {path}: missing {', '.join(missing)}")
    values = {}
    for name, value in block.items():
        try:  # PyYAML reads 2e4 (no dot, no sign) as text: take what float() takes
            values[names[name]] = float(value) if not isinstance(value, bool) else math.nan
        except (TypeError, ValueError):
            values[names[name]] = math.nan
        if not math.isfinite(values[names[name]]):
            raise HopperFileError(f"hopper file {path}: {name} must be a finite number (SI), got {value!r}")
    try:
        return HopperParams(**values)
    except ParameterError as error:
        raise HopperFileError(f"hopper file {path}: {error}") from None


def custom_data_key(node: str, parameter: str) -> str:
    """The custom_data key of a node's parameter in a ``tdslip run`` bag (tdslip_ros.controller.policy)."""
    return f"tdslip_ros.{node}.{parameter}"


def stored_parameters(custom_data: Mapping[str, str], node: str) -> dict[str, str]:
    """The parameters of ``node`` that ``tdslip run`` stored in a bag's custom_data, by name, as text."""
    prefix = custom_data_key(node, "")
    return {key[len(prefix) :]: value for key, value in custom_data.items() if key.startswith(prefix)}
