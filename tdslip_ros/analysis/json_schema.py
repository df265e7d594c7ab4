"""A small JSON Schema validator: the keywords that ``config/topic_map.schema.json`` uses, read from the
schema itself, so that the rules live in one place (the schema) and the venv needs no ``jsonschema``.

Keywords: ``type`` (object, string, number, integer, boolean, array), ``properties``, ``required``,
``additionalProperties`` (false), ``dependentRequired``, ``const``, ``enum``, ``pattern``,
``exclusiveMinimum`` and ``$ref`` to ``#/$defs/<name>`` (applied beside the keywords next to it, as in draft
2020-12). Any other keyword is refused when the schema is loaded, so a schema never silently checks less
than it says. :func:`first_error` names the first violation with its path (``quantities.body_vertical.unit``).
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from typing import Any

KEYWORDS = frozenset(
    {
        "$schema",
        "$id",
        "$defs",
        "$ref",
        "title",
        "description",
        "type",
        "properties",
        "required",
        "additionalProperties",
        "dependentRequired",
        "const",
        "enum",
        "pattern",
        "exclusiveMinimum",
    }
)
_TYPES: dict[str, tuple[type, ...]] = {
    "object": (dict,),
    "string": (str,),
    "number": (int, float),
    "integer": (int,),
    "boolean": (bool,),
    "array": (list,),
}


class SchemaError(ValueError):
    """The schema uses a keyword this validator does not implement, or a $ref it cannot resolve."""


def check_schema(schema: Mapping[str, Any]) -> None:
    """SchemaError if ``schema`` (or a sub-schema) uses a keyword outside :data:`KEYWORDS`."""

    def walk(node: Mapping[str, Any], where: str) -> None:
        unknown = sorted(set(node) - KEYWORDS)
        if unknown:
            raise SchemaError(f"{where or 'the schema'}: keyword(s) not implemented: {', '.join(unknown)}")
        for key in ("properties", "$defs"):
            for name, child in node.get(key, {}).items():
                walk(child, f"{where}/{key}/{name}")

    walk(schema, "")


def _text(value: Any) -> str:
    return repr(value) if isinstance(value, str) else str(value)


def errors(schema: Mapping[str, Any], instance: Any) -> Iterator[str]:
    """Every violation of ``schema`` by ``instance``, each as ``path: what is wrong``."""
    definitions = schema.get("$defs", {})

    def validate(node: Mapping[str, Any], value: Any, path: str) -> Iterator[str]:
        where = path or "the document"
        if "$ref" in node:
            name = str(node["$ref"]).removeprefix("#/$defs/")
            if name not in definitions:
                raise SchemaError(f"unresolvable $ref {node['$ref']!r}")
            yield from validate(definitions[name], value, path)
        if "const" in node and value != node["const"]:
            yield f"{where}: must be {_text(node['const'])}, not {_text(value)}"
        if "enum" in node and (value not in node["enum"] or isinstance(value, bool)):
            choices = ", ".join(_text(choice) for choice in node["enum"])
            yield f"{where}: {_text(value)} is not one of {choices}"
        kind = node.get("type")
        if kind is not None:
            wrong_bool = isinstance(value, bool) and kind != "boolean"
            if wrong_bool or not isinstance(value, _TYPES[kind]):
                yield f"{where}: must be of type {kind}, not {type(value).__name__}"
                return
        if isinstance(value, str) and "pattern" in node and re.search(node["pattern"], value) is None:
            yield f"{where}: {_text(value)} does not match {node['pattern']}"
        if (
            "exclusiveMinimum" in node
            and isinstance(value, int | float)
            and not value > node["exclusiveMinimum"]
        ):
            yield f"{where}: must be greater than {node['exclusiveMinimum']}, not {value}"
        if not isinstance(value, dict):
            return
        for name in node.get("required", ()):
            if name not in value:
                yield f"{where}: {name} is missing"
        for name, needed in node.get("dependentRequired", {}).items():
            for other in needed:
                if name in value and other not in value:
                    yield f"{where}: {name} needs {other} as well"
        properties = node.get("properties", {})
        for name, item in value.items():
            inner = f"{path}.{name}" if path else str(name)
            if name in properties:
                yield from validate(properties[name], item, inner)
            elif node.get("additionalProperties") is False:
                yield f"{inner}: not allowed here (allowed: {', '.join(properties)})"

    yield from validate(schema, instance, "")


def first_error(schema: Mapping[str, Any], instance: Any) -> str | None:
    """The first violation of ``schema`` by ``instance`` (see :func:`errors`), or None if it is valid."""
    return next(errors(schema, instance), None)
