"""Where studies run: a ``dask.distributed`` client, chunks as tasks, rows written as they arrive.

* :func:`connect`: a local cluster that the command starts itself (one worker process per core, one thread
  each: numpy work holds the GIL between calls), or an existing cluster at ``tcp://HOST:PORT`` (started with
  ``dask scheduler`` and ``dask worker``, whose Python must have tdslip_ros installed).
* :func:`run_study`: every chunk missing from the study directory becomes a task (key: the study's digest
  and the chunk), at most IN_FLIGHT_PER_THREAD per worker thread at a time so that neither the scheduler
  nor the client holds the whole study; each chunk's rows are written as soon as they arrive
  (:mod:`.table`), so an interrupted study resumes where it stopped. A chunk is a pure function of its
  inputs: if its worker dies, the scheduler runs it again on another (up to Dask's
  ``distributed.scheduler.allowed-failures``, 3), and an exception in it is retried RETRIES times.
* :func:`compute`: other pure calls (the figures' sweeps) as tasks, results in order.

Memory per worker is that of one chunk at a time: about 3.5 kB per trajectory of 50 strides at the chunk's
peak (its apex histories, 16 bytes x (strides + 1), and the batched engine's and the policies' work arrays),
on top of the worker process with numpy, scipy, pyarrow and Dask (about 170 MB).
"""

from __future__ import annotations

import hashlib
import itertools
import logging
import math
import os
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import dask
import pyarrow as pa
from distributed import Client, Future, LocalCluster, as_completed

from tdslip_ros.studies import chunk, table
from tdslip_ros.studies.design import Study

RETRIES = 2
"""Retries of a task that raised (a worker that dies is Dask's allowed-failures)."""
IN_FLIGHT_PER_THREAD = 2
"""Chunks submitted per worker thread at a time: one running, one queued behind it."""
CONNECT_TIMEOUT = 10.0
"""s to reach an existing scheduler."""
WORKER_TIMEOUT = 60.0
"""s to wait for the first worker of an existing scheduler."""


class EngineError(Exception):
    """The cluster cannot be reached, or a task failed for good; the message is one line."""


@dataclass(frozen=True)
class Where:
    """Where to run: an existing scheduler's address, or a local cluster of ``workers`` processes (default:
    one per core)."""

    scheduler: str | None = None
    workers: int | None = None

    def describe(self) -> str:
        if self.scheduler:
            return f"the cluster at {self.scheduler}"
        return f"a local cluster of {self.local_workers} worker processes"

    @property
    def local_workers(self) -> int:
        return self.workers or os.cpu_count() or 1


@contextmanager
def connect(where: Where) -> Iterator[Client]:
    """A client of the cluster ``where`` says; a local cluster is started here and shut down after."""
    if where.workers is not None and where.workers < 1:
        raise EngineError(f"--workers must be at least 1, got {where.workers}")
    # The cluster's own chatter (a worker restarted, a task rescheduled) would bury the progress line.
    logging.getLogger("distributed").setLevel(logging.ERROR)
    if where.scheduler:
        try:
            client = Client(where.scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError, ValueError) as error:
            raise EngineError(f"cannot reach the Dask scheduler at {where.scheduler}: {error}") from None
        with client:
            try:
                client.wait_for_workers(1, timeout=WORKER_TIMEOUT)
            except TimeoutError:
                raise EngineError(
                    f"no worker joined the Dask scheduler at {where.scheduler} within {WORKER_TIMEOUT:g} s "
                    "(start some with: dask worker " + where.scheduler + ")"
                ) from None
            yield client
        return
    # For the workers started here (a cluster of one's own is its owner's to configure): no statistical
    # profiler sampling the task's thread every 10 ms for a dashboard these commands do not show, and
    # no MALLOC_TRIM_THRESHOLD_ (Dask's default of 64 kB hands freed memory back to the system at once,
    # so that the batched engine's arrays fault their pages in again (the cost: docs/benchmarks.md); a
    # chunk's memory is bounded anyway).
    environ = dask.config.get("distributed.nanny.pre-spawn-environ")
    with (
        dask.config.set(
            {
                "distributed.worker.profile.enabled": False,
                "distributed.nanny.pre-spawn-environ": {
                    name: value for name, value in environ.items() if name != "MALLOC_TRIM_THRESHOLD_"
                },
            }
        ),
        LocalCluster(
            n_workers=where.local_workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # a free port (the HTTP routes; the dashboard only with bokeh)
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


class Progress:
    """A progress line on ``stream``: items done of the total, rate, time left. Redrawn in place on a
    terminal (at most every ``redraw`` s), else one line every ``interval`` s and at the end."""

    def __init__(self, label: str, unit: str, stream: IO[str] | None = None, interval: float = 10.0) -> None:
        self.label, self.unit, self.stream = label, unit, stream or sys.stderr
        self.terminal = self.stream.isatty()
        self.interval = 0.2 if self.terminal else interval
        self.total = self.done = self.skipped = 0
        self.started = self.shown = time.monotonic()

    def start(self, total: int, done: int = 0) -> None:
        """``done`` of ``total`` are done already (on disk): they count as done, not in the rate."""
        self.total, self.done, self.skipped = total, done, done
        self.started = time.monotonic()
        self.shown = -math.inf
        self._show()

    def advance(self, count: int) -> None:
        self.done += count
        if time.monotonic() - self.shown >= self.interval or self.done >= self.total:
            self._show()

    def finish(self) -> None:
        if self.terminal:
            print(file=self.stream, flush=True)

    def line(self) -> str:
        elapsed = time.monotonic() - self.started
        rate = (self.done - self.skipped) / elapsed if elapsed > 0 else 0.0
        share = 100.0 * self.done / self.total if self.total else 100.0
        text = f"{self.label}: {self.done:,}/{self.total:,} {self.unit} ({share:.0f} %)"
        if self.done >= self.total:
            return text + f", done in {_duration(elapsed)}"
        if rate > 0:
            text += f", {rate:,.3g}/s, about {_duration((self.total - self.done) / rate)} left"
        return text

    def _show(self) -> None:
        self.shown = time.monotonic()
        if self.terminal:
            bar = int(30 * self.done / self.total) if self.total else 30
            print(
                f"\r[{'#' * bar}{'.' * (30 - bar)}] {self.line()}\x1b[K", end="", file=self.stream, flush=True
            )
        else:
            print(self.line(), file=self.stream, flush=True)


def _duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{seconds // 60:.0f} min {seconds % 60:.0f} s"
    return f"{seconds // 3600:.0f} h {seconds % 3600 // 60:.0f} min"


@dataclass(frozen=True)
class Summary:
    """What a run of a study did: chunks in all, found complete on disk (reused), computed now."""

    trajectories: int
    chunks: int
    reused: int
    computed: int


def run_study(
    study: Study, directory: Path, client: Client, resume: bool = False, progress: Progress | None = None
) -> Summary:
    """Compute every chunk of ``study`` missing from ``directory`` on ``client``'s cluster, writing each one's
    rows as they arrive. table.StudyDirectoryError where the directory cannot take the study, EngineError
    where a chunk fails for good (the chunks written so far stay: --resume goes on from them)."""
    return run_many({directory: study}, client, resume, progress)


def run_many(
    studies: Mapping[Path, Study], client: Client, resume: bool = False, progress: Progress | None = None
) -> Summary:
    """:func:`run_study` for several studies (directory: study) at once: their missing chunks go through one
    stream, so the cluster stays busy from the first study's chunks to the last one's."""
    todo: dict[str, list[tuple[Path, Study, int]]] = {}  # by task key (the same chunk twice: computed once)
    reused = chunks = size = on_disk = 0
    for directory, study in studies.items():
        table.prepare(directory, study, resume)
        done = table.complete_parts(directory, study)
        for index in range(study.chunks):
            if index not in done:
                todo.setdefault(f"tdslip-chunk-{study.digest}-{index:06d}", []).append(
                    (directory, study, index)
                )
        reused, chunks, size = reused + len(done), chunks + study.chunks, size + study.size
        on_disk += sum(_chunk_size(study, index) for index in done)
    if progress is not None:
        progress.start(size, on_disk)

    def submit(key: str) -> Future[Any]:
        _, study, index = todo[key][0]
        return client.submit(chunk.run_chunk, study, index, key=key, retries=RETRIES)

    def write(future: Future[Any]) -> None:
        rows = future.result()
        for directory, _, index in todo[future.key]:
            table.write_part(directory, index, rows)
            if progress is not None:
                progress.advance(rows.num_rows)

    _stream(client, list(todo), submit, write, lambda future: f"chunk {future.key.rsplit('-', 1)[1]}")
    if progress is not None:
        progress.finish()
    return Summary(size, chunks, reused, chunks - reused)


def _chunk_size(study: Study, index: int) -> int:
    start, stop = study.chunk_range(index)
    return stop - start


def _stream(
    client: Client,
    items: Sequence[Any],
    submit: Callable[[Any], Future[Any]],
    receive: Callable[[Future[Any]], None],
    name: Callable[[Future[Any]], str],
) -> None:
    """Submit ``items`` at most IN_FLIGHT_PER_THREAD per worker thread at a time, hand each finished
    future to ``receive``; EngineError on the first task that failed for good (the others are cancelled)."""
    threads = sum(client.nthreads().values()) or 1
    waiting = iter(items)
    running = as_completed(
        [submit(item) for item in itertools.islice(waiting, IN_FLIGHT_PER_THREAD * threads)]
    )
    try:
        for future in running:
            if future.status == "error":
                error = future.exception()
                raise EngineError(f"{name(future)} failed: {type(error).__name__}: {error}")
            receive(future)
            future.release()
            following = next(waiting, None)
            if following is not None:
                running.add(submit(following))
    finally:
        running.clear()


Call = tuple[str, Callable[..., Any], tuple[Any, ...]]
"""(name, function, args): a pure call function(*args); the name labels its task and its errors."""


def compute(client: Client, calls: Sequence[Call], progress: Progress | None = None) -> list[Any]:
    """The results of pure calls, in order, computed as tasks on the cluster (at most IN_FLIGHT_PER_THREAD
    per thread at a time, in the order given); EngineError where one fails for good."""
    results: list[Any] = [None] * len(calls)
    for_each(client, calls, results.__setitem__, progress)
    return results


def for_each(
    client: Client,
    calls: Sequence[Call],
    receive: Callable[[int, Any], None],
    progress: Progress | None = None,
) -> None:
    """:func:`compute`'s calls, each result handed to ``receive(position, result)`` as it arrives (in any
    order) and not kept, so that a caller can write it and let it go."""
    positions: dict[str, list[int]] = {}  # a call made twice is computed once
    for position, (name, _, args) in enumerate(calls):
        positions.setdefault(_call_key(name, args), []).append(position)
    if progress is not None:
        progress.start(len(positions))

    def submit(key: str) -> Future[Any]:
        _, function, args = calls[positions[key][0]]
        return client.submit(function, *args, key=key, retries=RETRIES)

    def received(future: Future[Any]) -> None:
        result = future.result()
        for position in positions[future.key]:
            receive(position, result)
        if progress is not None:
            progress.advance(1)

    _stream(client, list(positions), submit, received, lambda future: calls[positions[future.key][0]][0])
    if progress is not None:
        progress.finish()


def _call_key(name: str, args: tuple[Any, ...]) -> str:
    digest = hashlib.sha256(repr(args).encode()).hexdigest()[:16]
    return f"tdslip-{name}-{digest}"


def run_studies(
    studies: dict[str, Study], directory: Path, where: Where, resume: bool, label: str
) -> dict[str, pa.Table]:
    """Run the studies into directory/name on one cluster, with one progress line on stderr, and read their
    tables."""
    with connect(where) as client:
        summary = run_many(
            {directory / name: study for name, study in studies.items()},
            client,
            resume,
            Progress(label, "trajectories"),
        )
    if summary.reused:
        print(
            f"{label}: {summary.reused} of {summary.chunks} chunks were on disk, {summary.computed} computed",
            file=sys.stderr,
        )
    return {name: table.read(directory / name) for name in studies}
