"""The tdslip_msgs interfaces match their specification (issue 2) and survive CDR serialisation.

Other engineers code against these names, types, constants and SI units, so each is pinned here.
The units are read from the comments of the installed .msg/.srv files, the text rosbag2 embeds.
"""

from __future__ import annotations

import importlib
import random
import re
from pathlib import Path
from typing import Any

import pytest
from ament_index_python.packages import get_package_share_directory
from rclpy.serialization import deserialize_message, serialize_message
from support.helpers import fill

# (field, rosidl type, SI unit in the comment; None: a nested message, only a comment is required)
HEADER = ("header", "std_msgs/Header", None)
FieldSpec = tuple[str, str, str | None]
MESSAGE_FIELDS: dict[str, list[FieldSpec]] = {
    "HopperState": [
        HEADER,
        ("stride", "uint32", "-"),
        ("phase", "uint8", "-"),
        ("x", "double", "m"),
        ("y", "double", "m"),
        ("xdot", "double", "m/s"),
        ("ydot", "double", "m/s"),
        ("toe_x", "double", "m"),
        ("toe_y", "double", "m"),
        ("leg_length", "double", "m"),
        ("leg_angle", "double", "rad"),
        ("leg_length_rate", "double", "m/s"),
        ("leg_angle_rate", "double", "rad/s"),
        ("hip_torque", "double", "N m"),
        ("energy", "double", "J"),
        ("ground_height", "double", "m"),
        ("pitch", "double", "rad"),
        ("pitch_rate", "double", "rad/s"),
    ],
    "ApexEvent": [
        HEADER,
        ("epoch", "uint32", "-"),
        ("stride", "uint32", "-"),
        ("sim_time", "double", "s"),
        ("x", "double", "m"),
        ("height", "double", "m"),
        ("forward_speed", "double", "m/s"),
        ("energy", "double", "J"),
        ("ground_height", "double", "m"),
        ("measured_height", "double", "m"),
        ("measured_forward_speed", "double", "m/s"),
        ("hip_work", "double", "J"),
        ("damping_loss", "double", "J"),
        ("spring_loss", "double", "J"),
        ("pitch", "double", "rad"),
        ("pitch_rate", "double", "rad/s"),
    ],
    "StanceCommand": [
        HEADER,
        ("epoch", "uint32", "-"),
        ("stride", "uint32", "-"),
        ("touchdown_angle", "double", "rad"),
        ("tau0", "double", "N m"),
        ("t_f", "double", "s"),
        ("policy", "string", "-"),
        ("stance", "uint8", "-"),
    ],
    "HipTorque": [
        HEADER,
        ("epoch", "uint32", "-"),
        ("stride", "uint32", "-"),
        ("tick", "uint64", "-"),
        ("torque", "double", "N m"),
    ],
    "ContactEvent": [
        HEADER,
        ("kind", "uint8", "-"),
        ("epoch", "uint32", "-"),
        ("stride", "uint32", "-"),
        ("sim_time", "double", "s"),
        ("ground_height", "double", "m"),
        ("state", "tdslip_msgs/HopperState", None),
    ],
    "Status": [
        HEADER,
        ("epoch", "uint32", "-"),
        ("stride", "uint32", "-"),
        ("sim_time", "double", "s"),
        ("kind", "string", "-"),
        ("reason", "string", "-"),
        ("fatal", "boolean", "-"),
    ],
}
RESET_REQUEST: list[FieldSpec] = [("height", "double", "m"), ("forward_speed", "double", "m/s")]
RESET_RESPONSE: list[FieldSpec] = [
    ("success", "boolean", "-"),
    ("epoch", "uint32", "-"),
    ("message", "string", "-"),
]

CONSTANTS: dict[str, dict[str, int | str]] = {
    "HopperState": {"PHASE_FLIGHT": 0, "PHASE_STANCE": 1},
    "ContactEvent": {"TOUCHDOWN": 0, "BOTTOM": 1, "LIFTOFF": 2},
    "StanceCommand": {"STANCE_RAMP": 0, "STANCE_FEEDBACK": 1},
    "Status": {
        "KIND_TOE_STUBBING": "toe_stubbing",
        "KIND_NO_LIFTOFF": "no_liftoff",
        "KIND_FALL": "fall",
        "KIND_REVERSAL": "reversal",
        "KIND_STATE_LIMIT": "state_limit",
        "KIND_COMMAND_TIMEOUT": "command_timeout",
        "KIND_COMMAND_REJECTED": "command_rejected",
        "KIND_TORQUE_REJECTED": "torque_rejected",
        "KIND_PUBLISH_FAILED": "publish_failed",
        "KIND_RUN_COMPLETE": "run_complete",
        "KIND_RESET": "reset",
    },
}

# A field line of a .msg/.srv file: type, name, and a comment whose first [...] is the unit.
FIELD_LINE = re.compile(r"^(?P<type>[\w/]+)\s+(?P<name>\w+)\s*(?:#\s*(?P<comment>.*))?$")
UNIT = re.compile(r"^\[(?P<unit>[^\]]+)\]")


def message_class(name: str) -> Any:
    return getattr(importlib.import_module("tdslip_msgs.msg"), name)


def reset_service() -> Any:
    return importlib.import_module("tdslip_msgs.srv").Reset


def declared_fields(message: Any) -> list[tuple[str, str]]:
    return list(message.get_fields_and_field_types().items())


def documented_units(text: str) -> dict[str, str | None]:
    """Field name -> unit from its comment ('' when the comment has no [unit]); constants skipped."""
    units: dict[str, str | None] = {}
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("#") or "=" in line.split("#", 1)[0]:
            continue
        match = FIELD_LINE.match(line)
        assert match, f"unparsed line: {raw!r}"
        comment = match["comment"]
        unit = UNIT.match(comment) if comment else None
        units[match["name"]] = unit["unit"] if unit else ("" if comment else None)
    return units


def check_units(text: str, spec: list[FieldSpec]) -> None:
    units = documented_units(text)
    assert list(units) == [name for name, _, _ in spec]
    for name, _, unit in spec:
        assert units[name] is not None, f"field {name!r} has no comment"
        if unit is not None:
            assert units[name] == unit, f"field {name!r}: unit [{units[name]}], expected [{unit}]"


def interface_text(kind: str, name: str) -> str:
    return (Path(get_package_share_directory("tdslip_msgs")) / kind / f"{name}.{kind}").read_text()


@pytest.mark.parametrize("name", MESSAGE_FIELDS)
def test_message_fields_names_and_types(name: str) -> None:
    spec = MESSAGE_FIELDS[name]
    assert declared_fields(message_class(name)) == [(field, kind) for field, kind, _ in spec]


def test_reset_service_fields() -> None:
    service = reset_service()
    assert declared_fields(service.Request) == [(field, kind) for field, kind, _ in RESET_REQUEST]
    assert declared_fields(service.Response) == [(field, kind) for field, kind, _ in RESET_RESPONSE]


@pytest.mark.parametrize("name", CONSTANTS)
def test_message_constants(name: str) -> None:
    message = message_class(name)
    for constant, value in CONSTANTS[name].items():
        assert getattr(message, constant) == value, constant


@pytest.mark.usefixtures("ament_index")
@pytest.mark.parametrize("name", MESSAGE_FIELDS)
def test_installed_definition_states_si_units(name: str) -> None:
    check_units(interface_text("msg", name), MESSAGE_FIELDS[name])


@pytest.mark.usefixtures("ament_index")
def test_installed_reset_definition_states_si_units() -> None:
    request, response = interface_text("srv", "Reset").split("\n---\n")
    check_units(request, RESET_REQUEST)
    check_units(response, RESET_RESPONSE)


@pytest.mark.parametrize("name", [*MESSAGE_FIELDS, "Reset.Request", "Reset.Response"])
def test_cdr_round_trip_keeps_every_field(name: str) -> None:
    kind = getattr(reset_service(), name.split(".")[1]) if "." in name else message_class(name)
    original = fill(random.Random(name), kind())
    assert original != kind()
    decoded = deserialize_message(serialize_message(original), kind)
    assert decoded == original
