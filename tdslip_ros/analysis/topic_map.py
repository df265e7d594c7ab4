"""The topic map: where each quantity of a hopper lives in a recording, and how it becomes SI in the
model's plane (docs/identify.md, "The topic map").

A map is a small YAML file, checked against ``config/topic_map.schema.json`` (the one statement of its
rules, read by :mod:`.json_schema`). Each quantity names a topic, its message type, a field path (for
``sensor_msgs/JointState`` the array, ``position``, ``velocity`` or ``effort``, and the joint's name), an
optional axis (the component x, y or z of a vector field), a sign, a scale, a unit and the stamp (the
message's header stamp or the bag's log time). A recorded value v becomes ``sign * scale * v * unit``:
this is where a bag's own conventions (REP 103: z up; a force plate's force on the plate) meet the
model's, in one place. The suite's own topics are the map ``config/topic_map_suite.yaml``
(:func:`suite_topic_map`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs

from tdslip_ros.analysis.json_schema import check_schema, first_error
from tdslip_ros.interfaces import config_file

SCHEMA_FILE = "topic_map.schema.json"
SUITE_MAP_FILE = "topic_map_suite.yaml"
UNITS: dict[str, float] = {
    "m": 1.0,
    "cm": 1e-2,
    "mm": 1e-3,
    "m/s": 1.0,
    "cm/s": 1e-2,
    "mm/s": 1e-3,
    "rad": 1.0,
    "deg": math.pi / 180.0,
    "N": 1.0,
    "kN": 1e3,
    "N m": 1.0,
    "N mm": 1e-3,
    "1": 1.0,
}
"""The SI value of one of each unit the schema allows (which units fit which quantity: the schema)."""
JOINT_STATE = "sensor_msgs/msg/JointState"
JOINT_ARRAYS = ("position", "velocity", "effort")


class TopicMapError(ValueError):
    """The map file is unreadable or breaks the schema; the message says where."""


@dataclass(frozen=True)
class Source:
    """Where one quantity is recorded, and its conversion to SI in the model's plane."""

    quantity: str
    topic: str
    type_name: str
    field: str
    unit: str
    joint: str | None = None
    axis: str | None = None
    sign: int = 1
    scale: float = 1.0
    stamp: str = "header"

    @property
    def factor(self) -> float:
        """What a recorded value is multiplied by: sign * scale * the unit's SI value."""
        return self.sign * self.scale * UNITS[self.unit]

    @property
    def path(self) -> str:
        """The dotted field path of the value, the axis included (a joint's index is added when read)."""
        return f"{self.field}.{self.axis}" if self.axis else self.field


@dataclass(frozen=True)
class TopicMap:
    """A checked topic map: its sources by quantity and where it came from (``origin``)."""

    sources: dict[str, Source]
    origin: str

    def get(self, quantity: str) -> Source | None:
        return self.sources.get(quantity)

    def topics(self) -> dict[str, str]:
        """The map's topics with their message types."""
        return {source.topic: source.type_name for source in self.sources.values()}


@cache
def schema() -> dict[str, Any]:
    """The installed topic-map schema (checked to use only what :mod:`.json_schema` implements)."""
    document: dict[str, Any] = json.loads(config_file(SCHEMA_FILE).read_text())
    check_schema(document)
    return document


def topic_map_from_document(document: Any, origin: str) -> TopicMap:
    """The map of a parsed YAML document; TopicMapError naming the first thing the schema refuses, or a
    joint given for a type that has no joints (or missing for one that has)."""
    error = first_error(schema(), document)
    if error is not None:
        raise TopicMapError(f"{origin}: {error}")
    sources = {}
    for quantity, entry in document["quantities"].items():
        fields = {key: value for key, value in entry.items() if key != "type"}
        source = Source(quantity=quantity, type_name=entry["type"], **fields)
        if (source.type_name == JOINT_STATE) != (source.joint is not None):
            need = "needs a joint" if source.joint is None else "has no joints"
            raise TopicMapError(f"{origin}: quantities.{quantity}: {source.type_name} {need}")
        if source.joint is not None and source.field not in JOINT_ARRAYS:
            raise TopicMapError(
                f"{origin}: quantities.{quantity}.field: a joint's field is one of "
                f"{', '.join(JOINT_ARRAYS)}, not {source.field!r}"
            )
        sources[quantity] = source
    return TopicMap(sources, origin)


def load_topic_map(path: Path) -> TopicMap:
    """The map in the YAML file ``path``; TopicMapError (one line) if it cannot be read or is not valid."""
    try:
        document = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as error:
        raise TopicMapError(f"{path}: cannot be read ({error.strerror})") from None
    except (UnicodeDecodeError, yaml.YAMLError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise TopicMapError(f"{path}: not a YAML file ({reason})") from None
    return topic_map_from_document(document, str(path))


def suite_topic_map() -> TopicMap:
    """The map of the suite's own topics (``config/topic_map_suite.yaml``)."""
    return load_topic_map(config_file(SUITE_MAP_FILE))
