"""Output files of the commands: a writable ``--out`` directory, strict JSON, one line for a failed write."""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np


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
