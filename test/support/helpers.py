"""Small checks and helpers several test files share: a written PNG, a figure's line, strict JSON, a deadline,
the apex table the commands print, and random ROS messages."""

from __future__ import annotations

import contextlib
import json
import random
import signal
import string
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.lines import Line2D

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
"""The first 8 bytes of every PNG file (the PNG specification, section 5.2)."""


def assert_png(path: Path) -> None:
    """``path`` is a PNG file (by its signature)."""
    assert path.read_bytes()[:8] == PNG_SIGNATURE, f"{path} is not a PNG file"


def drawn_line(axes: Axes, label: str) -> Line2D:
    """The one line of ``axes`` with ``label`` (what a figure draws, read back from its artists)."""
    matches = [line for line in axes.get_lines() if line.get_label() == label]
    assert len(matches) == 1, [line.get_label() for line in axes.get_lines()]
    return matches[0]


def strict_json(path: Path) -> Any:
    """The JSON document at ``path``; AssertionError if it holds NaN or Infinity, which strict JSON (RFC 8259)
    does not allow and other readers refuse."""

    def refuse(constant: str) -> None:
        raise AssertionError(f"{path}: non-standard JSON constant {constant}")

    return json.loads(path.read_text(), parse_constant=refuse)


@contextlib.contextmanager
def deadline(seconds: float) -> Iterator[None]:
    """Fail instead of hanging: SIGALRM raises TimeoutError in the main thread after ``seconds``."""

    def expire(signum: int, frame: FrameType | None) -> None:
        raise TimeoutError(f"still running after its deadline of {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


def apex_table(printed: str) -> list[list[float]]:
    """The rows of the apex table that ``tdslip run`` and ``tdslip simulate`` print: below the header that
    begins with ``stride``, up to the first empty line, each line that begins with a stride number (columns
    apart by spaces or ``|``; the first row's empty cells left out)."""
    lines = printed.splitlines()
    start = next(i for i, line in enumerate(lines) if line.split()[:1] == ["stride"]) + 1
    rows = []
    for line in lines[start:]:
        fields = line.replace("|", " ").split()
        if not fields:
            break
        if fields[0].isdigit():
            rows.append([float(field) for field in fields])
    return rows


# --- random messages ------------------------------------------------------------------------------

_INTEGER_BITS = {"octet": 8, "uint8": 8, "int8": 8, "uint16": 16, "int16": 16, "uint32": 32, "int32": 32}
_INTEGER_BITS |= {"uint64": 64, "int64": 64}


def random_value(rng: random.Random, field_type: str, template: Any, shortest: int = 0) -> Any:
    """A random value of an rclpy field type (primitives, strings, sequences of ``shortest`` to 3
    elements, nested messages: ``template`` or a new one)."""
    if field_type.startswith("sequence<"):
        inner = field_type[len("sequence<") : -1].split(",")[0]
        return [random_value(rng, inner, None, shortest) for _ in range(rng.randrange(shortest, 4))]
    if field_type in ("double", "float"):
        return rng.choice((0.0, -1.5, 3.25)) if field_type == "float" else rng.uniform(-1e3, 1e3)
    if field_type == "boolean":
        return rng.random() < 0.5
    if field_type in _INTEGER_BITS:
        bits = _INTEGER_BITS[field_type]
        low = -(2 ** (bits - 1)) if field_type.startswith("int") else 0
        return rng.randrange(low, low + 2**bits if low == 0 else 2 ** (bits - 1))
    if field_type.startswith("string"):
        return "".join(rng.choice(string.ascii_letters) for _ in range(rng.randrange(12)))
    message = template if template is not None else _message_class(field_type)()
    return fill(rng, message, shortest)


def _message_class(field_type: str) -> type:
    package, name = field_type.split("/")
    module = __import__(f"{package}.msg", fromlist=[name])
    return getattr(module, name)  # type: ignore[no-any-return]


def fill(rng: random.Random, message: Any, shortest: int = 0) -> Any:
    """Random values in every field of ``message``, recursively (sequences of at least ``shortest``
    elements); the message."""
    for name, field_type in message.get_fields_and_field_types().items():
        current = getattr(message, name)
        nested = current if hasattr(current, "get_fields_and_field_types") else None
        setattr(message, name, random_value(rng, field_type, nested, shortest))
    return message
