"""Message definitions and type hashes of installed ROS 2 interfaces, for rosbag2-compatible MCAP.

``message_definition`` builds the schema text exactly the way rosbag2's
``LocalMessageDefinitionSource`` does (rosbag2_cpp): the top-level ``.msg`` file verbatim, then
for every dependency not yet emitted, depth first and in sorted order of the names as they are
written in the parent ``.msg``, a line ``"\\n" + "=" * 80 + "\\n"``, a line ``MSG: <name>`` and that
dependency's ``.msg`` text. A same-package reference ``Foo`` is named ``<pkg>/Foo``, exactly as
rosbag2 names it. ``mcap-ros2-support``, ``rosbags`` and Foxglove all parse this format.

``type_description_hash`` reads the RIHS01 hash that rosidl generated at build time into
``share/<pkg>/msg/<Type>.json`` (key ``type_hashes``); it is the same hash the RMW layer reports as
``topic_type_hash`` in rclpy's graph API.

Share directories come from the ament index (``AMENT_PREFIX_PATH``) and, failing that, from the
running interpreter's prefix, which is where the PyPI ROS wheels install their ``share/`` tree
without setting ``AMENT_PREFIX_PATH``.
"""

from __future__ import annotations

import json
import re
import sys
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

SEPARATOR = "=" * 80
PRIMITIVE_TYPES = frozenset(
    (
        "bool",
        "byte",
        "char",
        "float32",
        "float64",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "string",
        "wstring",
    )
)
_TYPE_NAME = re.compile(r"(?P<package>[a-zA-Z][a-zA-Z0-9_]*)/(?:msg/)?(?P<name>[a-zA-Z][a-zA-Z0-9_]*)")


class MessageDefinitionError(LookupError):
    """A message type, its package, its ``.msg`` file or its type description could not be found."""


def split_type_name(type_name: str) -> tuple[str, str]:
    """``pkg/msg/Type`` or ``pkg/Type`` -> ``(pkg, Type)``; anything else is an error."""
    match = _TYPE_NAME.fullmatch(type_name)
    if match is None:
        raise MessageDefinitionError(f"not a message type name: {type_name!r} (expected 'pkg/msg/Type')")
    return match["package"], match["name"]


def canonical_type_name(type_name: str) -> str:
    """The ``pkg/msg/Type`` spelling used by rosbag2 for schema names and topic types."""
    package, name = split_type_name(type_name)
    return f"{package}/msg/{name}"


@cache
def package_share_directory(package: str) -> Path:
    """The installed ``share/<package>`` directory of an ament package."""
    try:
        return Path(get_package_share_directory(package, print_warning=False))
    except (PackageNotFoundError, OSError):
        # OSError: AMENT_PREFIX_PATH unset, as in a plain venv with the PyPI ROS wheels.
        pass
    marker = Path(sys.prefix) / "share" / "ament_index" / "resource_index" / "packages" / package
    if marker.is_file():
        return Path(sys.prefix) / "share" / package
    raise MessageDefinitionError(
        f"package {package!r} not found in the ament index (AMENT_PREFIX_PATH) nor under {sys.prefix}"
    )


def _interface_file(type_name: str, suffix: str) -> Path:
    package, name = split_type_name(type_name)
    path = package_share_directory(package) / "msg" / f"{name}{suffix}"
    if not path.is_file():
        raise MessageDefinitionError(f"{canonical_type_name(type_name)}: {path} does not exist")
    return path


def msg_dependencies(msg_text: str, package: str) -> set[str]:
    """Names of the non-primitive field types of a ``.msg`` text, spelled as rosbag2 spells them."""
    dependencies = set()
    for line in msg_text.splitlines():
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        # The type is the first token; drop an array suffix ("[]", "[3]", "[<=3]") and a string bound.
        field_type = tokens[0].split("[", 1)[0].split("<=", 1)[0]
        if field_type in PRIMITIVE_TYPES:
            continue
        dependencies.add(field_type if "/" in field_type else f"{package}/{field_type}")
    return dependencies


@cache
def message_definition(type_name: str) -> str:
    """Full ``ros2msg`` definition text of ``type_name`` with all its dependencies, rosbag2's format."""
    emitted: set[str] = set()

    def append(name: str) -> str:
        text = _interface_file(name, ".msg").read_text(encoding="utf-8")
        for dependency in sorted(msg_dependencies(text, split_type_name(name)[0])):
            if dependency not in emitted:
                emitted.add(dependency)
                text += f"\n{SEPARATOR}\nMSG: {dependency}\n" + append(dependency)
        return text

    return append(type_name)


@cache
def type_description_hash(type_name: str) -> str:
    """RIHS01 type hash of ``type_name`` from its generated type description file."""
    canonical = canonical_type_name(type_name)
    path = _interface_file(type_name, ".json")
    try:
        hashes = json.loads(path.read_text(encoding="utf-8"))["type_hashes"]
        return next(str(entry["hash_string"]) for entry in hashes if entry["type_name"] == canonical)
    except (ValueError, KeyError, TypeError, StopIteration) as error:
        raise MessageDefinitionError(f"{canonical}: no type hash in {path}: {error!r}") from None


@dataclass(frozen=True)
class Field:
    """One field of a message definition."""

    name: str
    base: str
    """A primitive (``float64``, ...), ``string``, ``wstring`` or a nested ``pkg/Type``."""
    count: int | None
    """Elements of a fixed array (``float64[3]``); None for a single value or a sequence."""
    sequence: bool
    """A bounded or unbounded sequence (``float64[]``, ``float64[<=5]``)."""


_FIELD_TYPE = re.compile(r"(?P<base>[A-Za-z][\w/]*)(?:<=\d+)?(?:\[(?P<bound><=)?(?P<size>\d*)\])?")
_DEFINITION_SEPARATOR = "\n" + SEPARATOR + "\n"


@cache
def message_fields(schema_name: str, schema_text: str) -> tuple[str, dict[str, tuple[Field, ...]]]:
    """``pkg/Type`` of a schema (``pkg/msg/Type``) and the fields of it and of every definition appended
    to its text (the format of :func:`message_definition`), by ``pkg/Type``: constants and comments
    dropped, same-package types qualified. A message without fields gets rosidl's one ``uint8``.
    MessageDefinitionError for a field type it cannot read."""
    package, _, name = schema_name.partition("/msg/")
    type_name = f"{package}/{name}" if name else schema_name
    definitions: dict[str, tuple[Field, ...]] = {}
    for index, section in enumerate(schema_text.split(_DEFINITION_SEPARATOR)):
        if index == 0:
            current, body = type_name, section
        else:
            header, _, body = section.partition("\n")
            current = header.removeprefix("MSG: ").strip()
        own_package = current.split("/")[0]
        fields = []
        for line in body.splitlines():
            tokens = line.split("#", 1)[0].split()
            if len(tokens) < 2 or "=" in tokens[1] or (len(tokens) > 2 and tokens[2].startswith("=")):
                continue  # blank, comment or constant (NAME=VALUE)
            match = _FIELD_TYPE.fullmatch(tokens[0])
            if match is None:
                raise MessageDefinitionError(f"{current}: cannot read the field type {tokens[0]!r}")
            base = match["base"]
            if base not in PRIMITIVE_TYPES and "/" not in base:
                base = f"{own_package}/{base}"
            is_array = match["size"] is not None
            sequence = is_array and (match["bound"] is not None or match["size"] == "")
            count = int(match["size"]) if is_array and not sequence else None
            fields.append(Field(tokens[1], base.replace("/msg/", "/"), count, sequence))
        definitions[current] = tuple(fields) or (
            Field("structure_needs_at_least_one_member", "uint8", None, False),
        )
    return type_name, definitions
