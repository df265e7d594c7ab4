"""Viability Q-maps on Dask: a space's pairs in chunks, each chunk a task written as it arrives, so that a
killed run resumes and a killed worker's chunk runs again elsewhere, bit for bit.

A chunk is the pairs [i c, (i + 1) c) in the Q-map's flat order (:func:`.viability_spaces.transitions`): a
pure function of (space, i), whose lanes do not interact, so the chunking changes nothing in the result.
Each chunk is written to ``DIR/qmap-chunks/<digest>-<i>.npz`` (the digest: the space's fields), renamed into
place once complete; a run with ``resume`` reuses the chunks of the same space found there. When every chunk
is in, the Q-map is assembled and the chunks removed.

Memory: the client holds the whole Q-map at the end, about BYTES_PER_PAIR per pair with the fixed point
(:data:`.viability_spaces.BYTES_PER_PAIR`); :func:`check_memory` refuses a space beyond a limit before any
work starts. A worker holds one chunk at a time (about 300 bytes per lane in the batched engine).
"""

from __future__ import annotations

import hashlib
import os
import pickle
import shutil
from pathlib import Path

import numpy as np
from distributed import Client

from tdslip_ros.model.params import ParameterError
from tdslip_ros.model.stability.viability import QMap
from tdslip_ros.model.stability.viability_spaces import (
    BYTES_PER_PAIR,
    ViabilitySpace,
    assemble,
    pair_count,
    transitions,
)
from tdslip_ros.studies.engine import Progress, for_each
from tdslip_ros.studies.table import StudyDirectoryError

CHUNK_PAIRS = 20_000
"""Pairs per chunk by default: about 1 s of one core (docs/benchmarks.md), few enough tasks for 10^7 pairs."""
CHUNKS_DIRECTORY = "qmap-chunks"


class ViabilityDirectoryError(StudyDirectoryError):
    """The output directory holds another run's chunks, or chunks without --resume; one line."""


def space_digest(space: ViabilitySpace) -> str:
    """16 hex digits of the space's fields (pickled: the grids' bytes included)."""
    return hashlib.sha256(pickle.dumps(space, protocol=5)).hexdigest()[:16]


def memory_limit() -> int:
    """Half the machine's physical memory [bytes], the default limit of :func:`check_memory`."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2


def check_memory(space: ViabilitySpace, limit: int) -> None:
    """ParameterError, before any work, where the Q-map and its fixed point would take more than ``limit``."""
    need = pair_count(space) * BYTES_PER_PAIR
    if need > limit:
        raise ParameterError(
            f"the grid has {pair_count(space):,} pairs, about {need / 1e9:.3g} GB with its viable set, "
            "beyond the "
            f"memory limit of {limit / 1e9:.3g} GB"
        )


def _chunk(space: ViabilitySpace, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
    return transitions(space, start, stop)


def run_q_map(
    space: ViabilitySpace,
    directory: Path,
    client: Client,
    resume: bool = False,
    chunk_pairs: int = CHUNK_PAIRS,
    progress: Progress | None = None,
) -> QMap:
    """The Q-map of ``space``, its chunks computed on ``client``'s cluster and kept in ``directory`` until
    every one is in (ViabilityDirectoryError where chunks of another space are there, or any without
    ``resume``)."""
    if chunk_pairs < 1:
        raise ParameterError(f"chunk_pairs must be at least 1, got {chunk_pairs}")
    digest, total = space_digest(space), pair_count(space)
    chunks = directory / CHUNKS_DIRECTORY
    found = sorted(chunks.glob("*.npz")) if chunks.is_dir() else []
    if found and not resume:
        raise ViabilityDirectoryError(
            f"{chunks} holds the chunks of an interrupted run: --resume completes it"
        )
    if any(not path.name.startswith(digest + "-") for path in found):
        raise ViabilityDirectoryError(f"{chunks} holds chunks of another space: use another --out")
    chunks.mkdir(parents=True, exist_ok=True)
    starts = range(0, total, chunk_pairs)
    path_of = [chunks / f"{digest}-{start // chunk_pairs:06d}.npz" for start in starts]
    todo = [index for index, path in enumerate(path_of) if not path.exists()]
    if progress is not None:
        progress.start(total, total - sum(min(chunk_pairs, total - starts[i]) for i in todo))

    def receive(position: int, result: tuple[np.ndarray, np.ndarray]) -> None:
        index = todo[position]
        partial = path_of[index].with_suffix(".partial.npz")
        np.savez(partial, successor=result[0], failure=result[1])
        partial.replace(path_of[index])
        if progress is not None:
            progress.advance(result[1].size)

    calls = [
        (
            f"qmap-{digest}-{index:06d}",
            _chunk,
            (space, starts[index], min(starts[index] + chunk_pairs, total)),
        )
        for index in todo
    ]
    for_each(client, calls, receive)
    if progress is not None:
        progress.finish()
    successor = np.empty((total, len(space.states)))
    failure = np.empty(total, dtype=np.int64)
    for start, path in zip(starts, path_of, strict=True):
        with np.load(path) as part:
            stop = start + part["failure"].size
            successor[start:stop], failure[start:stop] = part["successor"], part["failure"]
    q = assemble(space, successor, failure)
    shutil.rmtree(chunks)
    return q
