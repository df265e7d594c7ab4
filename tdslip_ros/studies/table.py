"""The study table: one row per trajectory, Parquet, one file per chunk, in the study's directory.

    DIR/study.json                the design (Study.document()) and its digest
    DIR/table/part-000000.parquet the rows of chunk 0, ...

A part is written to a temporary name and renamed, so a part on disk is always whole; its schema metadata
names the study's digest and the chunk, which :func:`complete_parts` checks on ``--resume``. A part of the
study written before a text setting of the policies had its column (``analytic_map``) gets it there, at the
setting's default (:func:`_fill_settings`), so that the table's parts share one schema. The directory
``DIR/table`` is the table (``pyarrow.parquet.read_table(DIR / "table")``, or :func:`read`, which sorts by
trajectory). Columns, SI (units in each field's metadata):

* ``trajectory`` (int64), ``policy`` and ``analytic_map`` (string: the design's CHOICES), and the design's
  numeric parameters (float64, see :mod:`.design`), the initial apex y0, xdot0, energy0 among them (NaN
  xdot0: no such apex);
* ``outcome`` (string, one of basins.OUTCOMES), ``failure_stride`` (-1 for none), ``strides_survived``,
  ``convergence_stride`` (-1 where not converged) (int32);
* ``y_end``, ``xdot_end``: the last apex reached; ``y_fixed``, ``xdot_fixed``, ``energy_fixed``: the fixed
  point reached (NaN where not converged); ``y_std``, ``xdot_std``: the spread (standard deviation) of the
  apexes over the strides survived (float64).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from tdslip_ros.model.arrays import Array
from tdslip_ros.model.stability import basins
from tdslip_ros.studies.design import (
    CHOICE_SETTINGS,
    CHOICES,
    DEFAULTS,
    NUMERIC_PARAMETERS,
    UNITS,
    Lanes,
    Study,
)

MANIFEST = "study.json"
PARTS = "table"
OUTCOME_COLUMNS: dict[str, tuple[pa.DataType, str]] = {
    "outcome": (pa.string(), ""),
    "failure_stride": (pa.int32(), ""),
    "strides_survived": (pa.int32(), ""),
    "convergence_stride": (pa.int32(), ""),
    "y_end": (pa.float64(), "m"),
    "xdot_end": (pa.float64(), "m/s"),
    "y_fixed": (pa.float64(), "m"),
    "xdot_fixed": (pa.float64(), "m/s"),
    "energy_fixed": (pa.float64(), "J"),
    "y_std": (pa.float64(), "m"),
    "xdot_std": (pa.float64(), "m/s"),
    "x_end": (pa.float64(), "m"),
    "strides_held": (pa.int32(), ""),
    "strides_saturated": (pa.int32(), ""),
}
SCHEMA = pa.schema(
    [
        pa.field("trajectory", pa.int64()),
        *(pa.field(name, pa.string()) for name in CHOICES),
        *(pa.field(name, pa.float64(), metadata={"unit": UNITS[name]}) for name in NUMERIC_PARAMETERS),
        *(
            pa.field(name, kind, metadata={"unit": unit} if unit else None)
            for name, (kind, unit) in OUTCOME_COLUMNS.items()
        ),
    ]
)


class StudyDirectoryError(Exception):
    """The output directory cannot take this study (holds another, or a finished one without --resume)."""


def empty_outcomes(count: int) -> dict[str, Array]:
    """Outcome columns for ``count`` lanes, to be filled."""
    return {
        name: np.full(count, -1 if pa.types.is_integer(kind) else np.nan, dtype=kind.to_pandas_dtype())
        for name, (kind, _) in OUTCOME_COLUMNS.items()
        if name != "outcome"
    } | {"outcome": np.full(count, basins.IMPOSSIBLE)}


def of(lanes: Lanes, outcomes: dict[str, Array], digest: str) -> pa.Table:
    """The rows of a chunk (lanes in trajectory order) with the study's digest in the metadata."""
    columns: dict[str, Any] = {name: lanes[name] for name in ("trajectory", *CHOICES, *NUMERIC_PARAMETERS)}
    columns |= {name: outcomes[name] for name in OUTCOME_COLUMNS if name != "outcome"}
    columns["outcome"] = np.asarray(basins.OUTCOMES, dtype=object)[outcomes["outcome"]]
    arrays = [pa.array(columns[field.name], type=field.type) for field in SCHEMA]
    metadata = {
        b"tdslip.study": digest.encode(),
        b"tdslip.first_trajectory": str(int(lanes["trajectory"][0])).encode(),
    }
    return pa.Table.from_arrays(arrays, schema=SCHEMA.with_metadata(metadata))


def part_path(directory: Path, index: int) -> Path:
    return directory / PARTS / f"part-{index:06d}.parquet"


def write_part(directory: Path, index: int, rows: pa.Table) -> None:
    """Write chunk ``index``'s rows whole: to a temporary file, then renamed."""
    path = part_path(directory, index)
    temporary = path.with_name(path.name + ".tmp")
    pq.write_table(rows, temporary)
    os.replace(temporary, path)


def complete_parts(directory: Path, study: Study) -> set[int]:
    """The chunks whose parts are on disk, readable, of this study, with all their rows; the columns of a
    text setting they lack filled in (:func:`_fill_settings`)."""
    done = set()
    for index in range(study.chunks):
        path = part_path(directory, index)
        if not path.exists():
            continue
        try:
            metadata = pq.read_metadata(path)
        except (OSError, pa.ArrowException):
            continue
        start, stop = study.chunk_range(index)
        stored = metadata.metadata or {}
        if (
            metadata.num_rows == stop - start
            and stored.get(b"tdslip.study") == study.digest.encode()
            and stored.get(b"tdslip.first_trajectory") == str(start).encode()
        ):
            _fill_settings(directory, index, metadata.schema.names)
            done.add(index)
    return done


def _fill_settings(directory: Path, index: int, names: list[str]) -> None:
    """Rewrite part ``index`` (its columns ``names``) with the columns of the policies' text settings
    (CHOICE_SETTINGS) it lacks, at their defaults. A part without such a column was written before the
    setting existed, so it ran what is now the default; and it is this study's (the digest), whose design
    therefore names no such setting (one that does has another digest) and runs the default too.
    StudyDirectoryError where it lacks any other column."""
    missing = [name for name in SCHEMA.names if name not in names]
    if not missing:
        return
    unknown = [name for name in missing if name not in CHOICE_SETTINGS]
    if unknown:
        raise StudyDirectoryError(
            f"{directory}: {part_path(directory, index).name} has no column {', '.join(unknown)} (written by "
            "another version of tdslip_ros); choose another --out"
        )
    rows = pq.read_table(part_path(directory, index))
    arrays = [
        rows[field.name]
        if field.name in names
        else pa.array([DEFAULTS[field.name]] * rows.num_rows, field.type)
        for field in SCHEMA
    ]
    write_part(
        directory, index, pa.Table.from_arrays(arrays, schema=SCHEMA.with_metadata(rows.schema.metadata))
    )


def prepare(directory: Path, study: Study, resume: bool) -> None:
    """Make ``directory`` ready for ``study``: new, or (with resume) holding the same study.

    StudyDirectoryError where it holds another study, or any study while resume is off."""
    manifest = directory / MANIFEST
    if manifest.exists():
        try:
            stored = json.loads(manifest.read_text()).get("digest")
        except (OSError, ValueError, AttributeError):
            stored = None
        if stored != study.digest:
            raise StudyDirectoryError(
                f"{directory} holds another study (its {MANIFEST} differs); choose another --out"
            )
        if not resume:
            raise StudyDirectoryError(
                f"{directory} already holds this study; add --resume to complete it, or choose another --out"
            )
    elif resume and (directory / PARTS).exists():
        raise StudyDirectoryError(f"{directory} has no {MANIFEST}: nothing to resume")
    (directory / PARTS).mkdir(parents=True, exist_ok=True)
    for leftover in (directory / PARTS).glob("*.tmp"):  # a write cut short by an interruption
        leftover.unlink()
    if not manifest.exists():
        document = {
            "digest": study.digest,
            "size": study.size,
            "chunks": study.chunks,
            "study": study.document(),
        }
        manifest.write_text(json.dumps(document, indent=1, allow_nan=True) + "\n")


def column(rows: pa.Table, name: str) -> np.ndarray:
    """One column of a table as a numpy array."""
    return np.asarray(rows[name].to_numpy(zero_copy_only=False))


def read(directory: Path, columns: list[str] | None = None) -> pa.Table:
    """The whole table (or some columns), sorted by trajectory."""
    rows = pq.read_table(
        directory / PARTS, columns=None if columns is None else sorted({*columns, "trajectory"})
    )
    return rows.sort_by("trajectory")
