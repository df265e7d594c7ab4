"""Decode CDR messages with the schema stored in a recording, without rclpy.

:func:`decoder` decodes one message into an object tree (``mcap-ros2-support``).
:func:`decoded_columns` turns a batch of messages of one type into numpy columns, one per field:
messages of a fixed CDR layout (primitives and nested messages, strings of one length throughout
the batch) take a vectorised path: the byte offset of every field is computed from the stored
schema text and the batch becomes a structured array in one ``frombuffer`` call, which is what
makes 1 kHz topics cheap to read (``test_analysis_decoding.py`` checks it against
``mcap-ros2-support``). Any other batch is decoded message by message.

Two encoders write messages without building message objects, every padding byte zero:
:class:`FixedLayoutEncoder` (a fixed layout, from field values) and :class:`SequenceColumns` (a
message of sequences of primitives only, filled a row at a time).
"""

from __future__ import annotations

import struct
import sys
from array import array
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

from tdslip_ros.bag.padding import padded_to_4, zero_padding
from tdslip_ros.bag.reader import BagReadError
from tdslip_ros.bag.schema import message_fields

_PRIMITIVES: dict[str, str] = {
    "bool": "?",
    "byte": "u1",
    "char": "u1",
    "int8": "i1",
    "uint8": "u1",
    "int16": "<i2",
    "uint16": "<u2",
    "int32": "<i4",
    "uint32": "<u4",
    "int64": "<i8",
    "uint64": "<u8",
    "float32": "<f4",
    "float64": "<f8",
}
_STRUCT_CODES = {
    "?": "?",
    "u1": "B",
    "i1": "b",
    "i2": "h",
    "u2": "H",
    "i4": "i",
    "u4": "I",
    "i8": "q",
    "u8": "Q",
    "f4": "f",
    "f8": "d",
}
"""struct's code of each primitive's numpy type (without byte order): numpy's own ``dtype.char`` is the C
type's (``L`` for uint64 on Linux), which struct's standard sizes read as 4 bytes."""
_CDR_LITTLE_ENDIAN = b"\x00\x01"


def _fixed_layout(schema: Schema, sample: bytes) -> dict[str, tuple[int, str]] | None:
    """Byte offset (after the 4-byte encapsulation header) and numpy type of every primitive field,
    by dotted path (``points[1].x`` in arrays), for messages laid out like ``sample``; None if ``sample``
    is not little-endian CDR of that layout, or holds a wide string. Strings and sequences take the
    lengths that ``sample`` holds (their ``.__length__`` entries); callers check that every message of a
    batch holds the same lengths."""
    if sample[:2] != _CDR_LITTLE_ENDIAN:
        return None
    type_name, definitions = message_fields(schema.name, schema.data.decode())
    layout: dict[str, tuple[int, str]] = {}
    payload = memoryview(sample)[4:]
    offset = 0

    def length(path: str) -> int | None:
        """The uint32 length of a string or sequence at the offset, read from ``sample``."""
        nonlocal offset
        offset += -offset % 4
        if offset + 4 > len(payload):
            return None
        layout[path + ".__length__"] = (offset, "<u4")
        offset += 4
        return int.from_bytes(payload[offset - 4 : offset], "little")

    def value(base: str, path: str) -> bool:
        nonlocal offset
        if base in _PRIMITIVES:
            size = np.dtype(_PRIMITIVES[base]).itemsize
            offset += -offset % size
            layout[path] = (offset, _PRIMITIVES[base])
            offset += size
        elif base == "string":
            characters = length(path)
            if characters is None:
                return False
            offset += characters
        elif base in definitions:
            return walk(base, path + ".")
        else:
            return False
        return True

    def walk(type_name: str, prefix: str) -> bool:
        nonlocal offset
        for field in definitions.get(type_name, ()):
            path = prefix + field.name
            if not field.sequence and field.count is None:
                if not value(field.base, path):
                    return False
                continue
            count = length(path) if field.sequence else field.count
            if count is None:
                return False
            if field.sequence and field.base in _PRIMITIVES:  # aligned for its elements even when empty
                offset += -offset % np.dtype(_PRIMITIVES[field.base]).itemsize
            for index in range(count):
                if not value(field.base, f"{path}[{index}]"):
                    return False
        return True

    # An RMW pads what it sends to a multiple of 4 bytes: up to 3 bytes may follow the last field.
    if not walk(type_name, "") or not 0 <= len(payload) - offset < 4:
        return None
    return layout


def decoded_columns(schema: Schema, datas: Sequence[bytes], paths: Sequence[str]) -> dict[str, np.ndarray]:
    """Columns of the fields ``paths`` (dotted) of CDR messages of one schema, one entry per message
    (see the module docstring)."""
    if not datas:
        return {path: np.empty(0) for path in paths}
    layout = _fixed_layout(schema, datas[0])
    if (
        layout is not None
        and all(path in layout for path in paths)
        and all(len(data) == len(datas[0]) for data in datas)
    ):
        dtype = np.dtype(
            {
                "names": list(layout),
                "formats": [fmt for _, fmt in layout.values()],
                "offsets": [offset + 4 for offset, _ in layout.values()],
                "itemsize": len(datas[0]),
            }
        )
        table = np.frombuffer(b"".join(datas), dtype=dtype)
        lengths = [name for name in layout if name.endswith(".__length__")]
        if all(np.all(table[name] == table[name][0]) for name in lengths):
            return {path: np.array(table[path]) for path in paths}
    decode = decoder(schema)
    messages = [decode(data) for data in datas]
    return {path: np.array([_attribute(message, path) for message in messages]) for path in paths}


def decoder(schema: Schema) -> Callable[[bytes], Any]:
    """A function decoding one CDR message of ``schema`` (BagReadError if there is none for it)."""
    decoder = DecoderFactory().decoder_for("cdr", schema)
    if decoder is None:
        raise BagReadError(f"no CDR decoder for schema {schema.name} (encoding {schema.encoding})")
    return decoder


def _attribute(message: object, path: str) -> Any:
    """The value at a dotted path; ``name[i]`` takes element i of an array, as the fixed layout names it."""
    for part in path.split("."):
        name, _, index = part.partition("[")
        message = getattr(message, name)
        if index:
            message = message[int(index.rstrip("]"))]
    return message


class FixedLayoutEncoder:
    """Serialises messages of one fixed CDR layout straight from the values of chosen fields, without building
    a message object: the publisher's cost at 1 kHz. ``sample`` is one message serialised the usual way
    (rclpy's ``serialize_message``); every field not in ``fields`` keeps its value there (the frame_id,
    constants, the lengths of its arrays), and every padding byte is zero whatever ``sample`` held there,
    up to a length that is a multiple of 4 (:mod:`tdslip_ros.bag.padding`). ``fields`` are dotted paths in
    the order of the message (their byte order); runs of them that only CDR padding separates are packed
    by one ``struct`` call."""

    def __init__(self, schema: Schema, sample: bytes, fields: Sequence[str]) -> None:
        layout = _fixed_layout(schema, sample)
        if layout is None:
            raise ValueError(f"{schema.name} has no fixed CDR layout")
        missing = [path for path in fields if path not in layout]
        if missing:
            raise ValueError(f"{schema.name} has no primitive field {', '.join(missing)}")
        offsets = [layout[path][0] for path in fields]
        if offsets != sorted(offsets):
            raise ValueError("fields must be given in the message's order")
        sample = zero_padding(schema.name, schema.data.decode(), sample)
        self._template = padded_to_4(sample)
        self._runs: list[tuple[struct.Struct, int, int, int]] = []  # (packer, byte offset, first, end)
        first = 0
        for index, path in enumerate(fields):
            offset, kind = layout[path]
            end = offset + np.dtype(kind).itemsize
            last = index + 1 == len(fields)
            if not last:
                gap = sample[4 + end : 4 + layout[fields[index + 1]][0]]
            if last or any(gap):  # a constant between this field and the next: the run ends here
                run = fields[first : index + 1]
                start = layout[run[0]][0]
                format_ = "<"
                position = start
                for name in run:
                    field_offset, field_kind = layout[name]
                    format_ += "x" * (field_offset - position) + _STRUCT_CODES[field_kind.lstrip("<")]
                    position = field_offset + np.dtype(field_kind).itemsize
                self._runs.append((struct.Struct(format_), 4 + start, first, index + 1))
                first = index + 1

    def encode(self, values: Sequence[Any]) -> bytes:
        """The serialised message with ``values`` in the fields, in the order they were given."""
        buffer = bytearray(self._template)
        for packer, offset, first, end in self._runs:
            packer.pack_into(buffer, offset, *values[first:end])
        return bytes(buffer)


_ARRAY_CODES = {
    "int8": "b",
    "uint8": "B",
    "int16": "h",
    "uint16": "H",
    "int32": "i",
    "uint32": "I",
    "float64": "d",
}
"""array's code of each primitive a :class:`SequenceColumns` can hold (sizes as CDR's on Linux: int32 is C's
int, 4 bytes)."""


class SequenceColumns:
    """The fields of a message whose every field is a sequence of primitives (``float64[] x`` ...), kept
    as arrays and filled a row at a time (one value per field): cheap to append to at 1 kHz, serialised
    in one pass by :meth:`take` (XCDR1 little-endian, as rclpy's ``serialize_message``, padding zero)."""

    def __init__(self, schema: Schema) -> None:
        type_name, definitions = message_fields(schema.name, schema.data.decode())
        fields = definitions[type_name]
        unsupported = [f.name for f in fields if not f.sequence or f.base not in _ARRAY_CODES]
        if unsupported:
            raise ValueError(f"{schema.name}: not sequences of primitives: {', '.join(unsupported)}")
        if sys.byteorder != "little":
            raise ValueError("SequenceColumns writes the machine's arrays as little-endian CDR")
        self.names = tuple(f.name for f in fields)
        self._columns = tuple(array(_ARRAY_CODES[f.base]) for f in fields)

    def __len__(self) -> int:
        return len(self._columns[0])

    def append(self, row: Sequence[Any]) -> None:
        """One value per field, in the message's order."""
        for column, value in zip(self._columns, row, strict=True):
            column.append(value)

    def take(self) -> bytes:
        """The rows appended since the last take, serialised; the columns are empty afterwards."""
        parts = [_CDR_LITTLE_ENDIAN, b"\x00\x00"]
        offset = 0  # CDR aligns relative to the end of the 4-byte encapsulation header
        for column in self._columns:
            padding = -offset % 4
            parts.append(bytes(padding) + struct.pack("<I", len(column)))
            offset += padding + 4
            padding = -offset % column.itemsize  # aligned for the elements even when there are none
            data = column.tobytes()
            parts.append(bytes(padding) + data)
            offset += padding + len(data)
            del column[:]
        parts.append(bytes(-offset % 4))
        return b"".join(parts)
