"""Where a CDR message holds bytes that carry no value: alignment padding, found from the schema.

A serialised ROS 2 message (plain little- or big-endian CDR, as the ROS 2 RMWs write it) is a 4-byte
encapsulation header (kind, then two option bytes) and a payload in which every primitive is aligned
to its own size (8 at most), counted from the start of the payload. The bytes skipped to reach that
alignment, the header's option bytes and anything after the last field (an RMW pads a message to a
multiple of 4 bytes, :func:`padded_to_4`) carry no value. rclpy's ``serialize_message`` leaves them
as it finds them in its buffer, which is how heap contents can end up in a recording.

:func:`padding_positions` finds them from the ``ros2msg`` schema text stored with every channel, for
any message (nested types, strings, fixed arrays, bounded and unbounded sequences);
:class:`PaddingZeroer` and :func:`zero_padding` return a message with all of them zero, which is
what every message this package writes holds.
"""

from __future__ import annotations

from dataclasses import dataclass

from tdslip_ros.bag.schema import MessageDefinitionError, message_fields

PRIMITIVE_SIZES: dict[str, int] = {
    "bool": 1,
    "byte": 1,
    "char": 1,
    "int8": 1,
    "uint8": 1,
    "int16": 2,
    "uint16": 2,
    "int32": 4,
    "uint32": 4,
    "int64": 8,
    "uint64": 8,
    "float32": 4,
    "float64": 8,
}
HEADER_SIZE = 4
"""Bytes of the CDR encapsulation header (kind, options) before the payload."""
_ENDIANNESS = {b"\x00\x00": "big", b"\x00\x01": "little"}


class PaddingError(ValueError):
    """The message does not match its schema (too short, an unknown type, an unsupported encoding)."""


@dataclass(frozen=True)
class Layout:
    """Where one message's bytes carry no value, and the length fields that fixed its layout."""

    size: int
    padding: tuple[int, ...]
    """Offsets from the message's first byte."""
    length_fields: tuple[int, ...]
    """Offsets of the 4-byte lengths of its strings and sequences: any message of the schema of the same
    size whose length fields hold the same bytes there has the same layout."""


def layout(schema_name: str, schema_text: str, data: bytes) -> Layout:
    """The :class:`Layout` of ``data``, a message of the schema (PaddingError if it is not one)."""
    kind = bytes(data[:2])
    if len(data) < HEADER_SIZE or kind not in _ENDIANNESS:
        raise PaddingError(f"{schema_name}: not plain CDR (encapsulation {kind.hex() or 'missing'})")
    byteorder = _ENDIANNESS[kind]
    try:
        type_name, definitions = message_fields(schema_name, schema_text)
    except MessageDefinitionError as error:
        raise PaddingError(str(error)) from None
    payload = memoryview(data)[HEADER_SIZE:]
    padding: list[int] = [2, 3]
    length_fields: list[int] = []
    offset = 0

    def align(size: int) -> None:
        nonlocal offset
        skip = -offset % min(size, 8)
        padding.extend(range(HEADER_SIZE + offset, HEADER_SIZE + offset + skip))
        offset += skip

    def take(size: int) -> int:
        nonlocal offset
        if offset + size > len(payload):
            raise PaddingError(f"{schema_name}: the message ends inside a field ({len(data)} bytes)")
        start = offset
        offset += size
        return start

    def length() -> int:
        align(4)
        start = take(4)
        length_fields.append(HEADER_SIZE + start)
        return int.from_bytes(payload[start : start + 4], byteorder)

    def values(base: str, count: int) -> None:
        if base in PRIMITIVE_SIZES:
            if count:
                align(PRIMITIVE_SIZES[base])
                take(PRIMITIVE_SIZES[base] * count)
        elif base == "string":
            for _ in range(count):
                take(length())
        elif base in definitions:
            for _ in range(count):
                for field in definitions[base]:
                    if field.sequence:
                        values(field.base, length())
                    else:
                        values(field.base, 1 if field.count is None else field.count)
        else:
            raise PaddingError(f"{schema_name}: no definition of {base} in the schema")

    values(type_name, 1)
    padding.extend(range(HEADER_SIZE + offset, len(data)))
    return Layout(len(data), tuple(padding), tuple(length_fields))


def padding_positions(schema_name: str, schema_text: str, data: bytes) -> tuple[int, ...]:
    """Offsets in ``data`` (from its first byte) of every byte that carries no value: the header's
    option bytes, alignment padding and anything after the last field."""
    return layout(schema_name, schema_text, data).padding


class PaddingZeroer:
    """Zeroes the padding of messages of one schema. A publisher's messages mostly share one layout
    (the same strings and sequence lengths): the last layout is kept and reused for a message whose
    size and length fields match it, which spares walking the schema (dear for a MarkerArray;
    docs/benchmarks.md)."""

    def __init__(self, schema_name: str, schema_text: str) -> None:
        self._schema = (schema_name, schema_text)
        self._layout: Layout | None = None
        self._lengths = b""

    def __call__(self, data: bytes) -> bytes:
        """``data`` with every padding byte zero."""
        known = self._layout
        if known is None or known.size != len(data) or self._length_bytes(known, data) != self._lengths:
            known = self._layout = layout(*self._schema, data)
            self._lengths = self._length_bytes(known, data)
        buffer = bytearray(data)
        for position in known.padding:
            buffer[position] = 0
        return bytes(buffer)

    @staticmethod
    def _length_bytes(known: Layout, data: bytes) -> bytes:
        return b"".join(data[position : position + 4] for position in known.length_fields)


def padded_to_4(data: bytes) -> bytes:
    """``data`` with zero bytes appended up to a multiple of 4: the form in which the RMW publishes a
    message object (RTPS aligns what it sends), and rosbags serialises one; ``serialize_message``
    stops at the last field."""
    return bytes(data) + bytes(-len(data) % 4)


def zero_padding(schema_name: str, schema_text: str, data: bytes) -> bytes:
    """``data`` with every byte :func:`padding_positions` names set to zero."""
    return PaddingZeroer(schema_name, schema_text)(data)
