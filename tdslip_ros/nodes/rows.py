"""Rows of numbers kept in typed columns: what a run keeps of each stride, at 4-8 bytes a field.

A run keeps a little of every stride for its summary (the apexes, the latency of each command). Kept as
rclpy messages or tuples of Python numbers, that is about 1.4 KB a stride, a Python object per field; a
realtime run of ten minutes grew by 3.6 MiB (issue 35). :class:`Rows` keeps the same numbers in
:mod:`array` columns and gives each row back as a named tuple, so a reader sees the same attribute names.
"""

from __future__ import annotations

from array import array
from collections import namedtuple
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, overload

TYPECODES = {
    "boolean": "B",
    "uint8": "B",
    "int32": "i",
    "uint32": "I",
    "int64": "q",
    "uint64": "Q",
    "float": "f",
    "double": "d",
}
"""array typecode of each ROS field type :meth:`Rows.of_message` keeps."""


class Rows(Sequence[Any]):
    """Rows of the named ``fields`` (name -> :mod:`array` typecode), appended one at a time, read as
    named tuples (``rows[i].name``); a slice is a list of them."""

    def __init__(self, name: str, fields: Mapping[str, str]) -> None:
        self._row = namedtuple(name, list(fields))  # type: ignore[misc]
        self._columns = [array(code) for code in fields.values()]

    @classmethod
    def of_message(cls, message_class: type, leave_out: Sequence[str] = ("header",)) -> Rows:
        """Rows of the numeric fields of ``message_class`` (a ROS message type), ``leave_out`` left out."""
        fields = message_class.get_fields_and_field_types()  # type: ignore[attr-defined]
        kept = {name: TYPECODES[kind] for name, kind in fields.items() if name not in leave_out}
        return cls(f"{message_class.__name__}Row", kept)

    def append(self, *values: Any) -> None:
        """A row of the fields' values, in the fields' order."""
        for column, value in zip(self._columns, values, strict=True):
            column.append(value)

    def append_message(self, message: Any) -> None:
        """A row of the fields of ``message``, read by name."""
        for column, name in zip(self._columns, self._row._fields, strict=True):
            column.append(getattr(message, name))

    def __len__(self) -> int:
        return len(self._columns[0])

    @overload
    def __getitem__(self, index: int) -> Any: ...

    @overload
    def __getitem__(self, index: slice) -> list[Any]: ...

    def __getitem__(self, index: int | slice) -> Any:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return self._row(*(column[index] for column in self._columns))

    def __iter__(self) -> Iterator[Any]:
        return map(self._row, *self._columns)

    def __reduce__(self) -> tuple[Any, ...]:
        # The row type is made at run time, which pickle cannot look up: a report is pickled by its columns.
        fields = {
            name: column.typecode for name, column in zip(self._row._fields, self._columns, strict=True)
        }
        return (_unpickled, (self._row.__name__, fields, self._columns))


def _unpickled(name: str, fields: Mapping[str, str], columns: list[array[Any]]) -> Rows:
    rows = Rows(name, fields)
    rows._columns = columns
    return rows
