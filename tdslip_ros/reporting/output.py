"""Output files of the commands: a writable ``--out`` directory, strict JSON whose keys say their units, one
line for a failed write."""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

UNIT_SUFFIXES = {
    "m": "_m",
    "m/s": "_m_per_s",
    "m/s^2": "_m_per_s2",
    "s": "_s",
    "kg": "_kg",
    "kg m^2": "_kg_m2",
    "J": "_J",
    "W": "_W",
    "rad": "_rad",
    "rad/s": "_rad_per_s",
    "N m": "_N_m",
    "N/m": "_N_per_m",
    "N s/m": "_N_s_per_m",
    "rad/(m/s)": "_rad_s_per_m",
    "N m/J": "_N_m_per_J",
    "N s": "_N_s",
    "N s^2": "_N_s2",
}
"""The key suffix of a JSON value in each SI unit: a key says its value's unit (``touchdown_angle_rad``)."""
DIMENSIONLESS_SUFFIXES = {
    "bar": "in the paper's dimensionless units of eq. 24 (ybar, xdotbar, kbar, ...)",
    "_ratio": "a ratio of two quantities of one unit (a relative deviation)",
    "_factor": "a dimensionless multiplier",
}
"""The key suffixes of dimensionless JSON values, and what each means."""


def unit_key(name: str, unit: str) -> str:
    """The JSON key of quantity ``name`` in ``unit`` (one of UNIT_SUFFIXES; "" for a count: ``name``)."""
    return name + UNIT_SUFFIXES[unit] if unit else name


def _json_ready(value: object) -> object:
    """Plain JSON values: NaN and infinities become null (JSON has none), complex numbers [re, im]."""
    if isinstance(value, dict):
        return {str(key): _json_ready(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_json_ready(item) for item in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, complex):
        return [_json_ready(value.real), _json_ready(value.imag)]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def to_json(value: object) -> str:
    """``value`` as indented, strict JSON text (see _json_ready), newline-terminated."""
    return json.dumps(_json_ready(value), indent=1, allow_nan=False) + "\n"


class OutputError(Exception):
    """An output directory cannot be created or written; the message says why."""


def check_output_directory(path: Path) -> None:
    """OutputError naming the obstacle if ``path`` could not be made a writable directory; creates
    nothing (a probe folder in the nearest existing parent is made and removed at once), so that a
    command can refuse a bad ``--out`` before it does anything."""
    existing = next(folder for folder in (path, *path.parents) if folder.exists())
    if not existing.is_dir():
        raise OutputError(f"--out {path}: {existing} exists and is not a directory")
    if existing != path:
        try:
            os.rmdir(tempfile.mkdtemp(prefix=".tdslip-probe-", dir=existing))
        except OSError as error:
            raise OutputError(f"--out {path}: cannot create the directory ({error.strerror})") from None


def output_directory(path: Path) -> Path:
    """``path`` as a writable directory, created if need be (OutputError naming the obstacle)."""
    check_output_directory(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"--out {path}: cannot create the directory ({error.strerror})") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise OutputError(f"--out {path}: the directory is not writable")
    return path


def write_failed(error: OSError) -> str:
    """One line for an output file that could not be written."""
    return f"cannot write {error.filename or 'an output file'}: {error.strerror or error}"
