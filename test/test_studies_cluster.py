"""Studies on real Dask clusters: a LocalCluster of 2 worker processes, and a ``dask scheduler`` with two
``dask worker`` processes on 127.0.0.1; a worker killed mid-study; an interrupted study resumed.

Truth used: the same study run chunk by chunk in this process, without Dask. Every test is bounded by
DEADLINE (SIGALRM), so a cluster that stops answering fails the test instead of hanging the suite.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from distributed import Client
from support.cluster import KillAWorker
from support.helpers import deadline

from tdslip_ros.studies import chunk, engine, table
from tdslip_ros.studies.design import Study, Uniform

DEADLINE = 180  # s per test
DASK = Path(sys.executable).with_name("dask")
# 3 policies x 3 energies x 4 draws of y0 = 36 trajectories of 12 strides, in 8 chunks.
STUDY = Study.of(
    grid={"policy": ["energy", "deadbeat", "open_loop"], "energy0": [2400.0, 3000.0, 3600.0]},
    draws={"y0": Uniform(0.95, 1.7)},
    samples=4,
    fixed={"touchdown_power": 1300.0, "target_speed": 4.0},
    strides=12,
    chunk_size=5,
    seed=11,
)


@pytest.fixture(autouse=True)
def within_deadline() -> Iterator[None]:
    with deadline(DEADLINE):
        yield


@pytest.fixture(scope="module")
def local(dask_scheduler: str) -> Iterator[Client]:
    """A client of the session's local cluster of 2 worker processes (conftest.dask_scheduler), which the
    study engine started as it starts its own (a cluster takes seconds to start)."""
    with engine.connect(engine.Where(scheduler=dask_scheduler)) as client:
        yield client


@pytest.fixture(scope="module")
def one_process() -> pa.Table:
    """The study, chunk by chunk in this process: the reference every cluster must match."""
    return pa.concat_tables([chunk.run_chunk(STUDY, index) for index in range(STUDY.chunks)])


def assert_same_rows(rows: pa.Table, reference: pa.Table) -> None:
    assert rows.num_rows == reference.num_rows == STUDY.size
    assert rows.schema.remove_metadata() == reference.schema.remove_metadata()
    for name in reference.column_names:  # NaN equal to NaN; floats to the bit
        np.testing.assert_array_equal(
            rows[name].to_numpy(zero_copy_only=False), reference[name].to_numpy(zero_copy_only=False)
        )


def test_the_reference_has_converged_failed_and_sustained_rows(one_process: pa.Table) -> None:
    outcomes = set(one_process["outcome"].to_pylist())
    assert "converged" in outcomes and len(outcomes) >= 3
    assert one_process["trajectory"].to_pylist() == list(range(STUDY.size))


def test_a_local_cluster_of_two_workers_gives_the_rows_of_one_process(
    tmp_path: Path, one_process: pa.Table, local: Client
) -> None:
    assert len(local.scheduler_info()["workers"]) == 2
    pids = set(local.run(os.getpid).values())
    assert len(pids) == 2 and os.getpid() not in pids  # two worker processes, not threads of this one
    summary = engine.run_study(STUDY, tmp_path, local)
    assert (summary.chunks, summary.computed, summary.reused) == (8, 8, 0)
    assert sorted(path.name for path in (tmp_path / table.PARTS).iterdir()) == [
        f"part-{index:06d}.parquet" for index in range(8)
    ]
    assert_same_rows(table.read(tmp_path), one_process)
    assert json.loads((tmp_path / table.MANIFEST).read_text())["digest"] == STUDY.digest


def test_a_dask_scheduler_and_two_dask_workers_give_the_rows_of_one_process(
    tmp_path: Path, one_process: pa.Table
) -> None:
    scheduler_file = tmp_path / "scheduler.json"
    common = ["--no-dashboard"]
    processes = [
        subprocess.Popen(
            [
                str(DASK),
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--scheduler-file",
                str(scheduler_file),
                *common,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    try:
        for _ in range(600):
            if scheduler_file.exists() and scheduler_file.stat().st_size:
                break
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for name in ("a", "b"):
            processes.append(
                subprocess.Popen(
                    [
                        str(DASK),
                        "worker",
                        address,
                        "--nthreads",
                        "1",
                        "--name",
                        name,
                        "--host",
                        "127.0.0.1",
                        *common,
                    ],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
        with engine.connect(engine.Where(scheduler=address)) as client:
            client.wait_for_workers(2, timeout=60)
            summary = engine.run_study(STUDY, tmp_path / "study", client)
            ran_on = {worker["name"] for worker in client.scheduler_info()["workers"].values()}
        assert ran_on == {"a", "b"} and summary.computed == STUDY.chunks
        assert_same_rows(table.read(tmp_path / "study"), one_process)
    finally:
        for process in reversed(processes):
            process.terminate()
        for process in processes:
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=20)


class InterruptAfter(engine.Progress):
    """Ctrl-C (KeyboardInterrupt) once ``chunks`` chunks have been written."""

    def __init__(self, chunks: int) -> None:
        super().__init__("test", "trajectories", stream=open(os.devnull, "w"))
        self.chunks, self.arrived = chunks, 0

    def advance(self, count: int) -> None:
        super().advance(count)
        self.arrived += 1
        if self.arrived == self.chunks:
            raise KeyboardInterrupt


def test_an_interrupted_study_resumes_computing_only_its_missing_chunks(
    tmp_path: Path, one_process: pa.Table, local: Client
) -> None:
    with pytest.raises(KeyboardInterrupt):
        engine.run_study(STUDY, tmp_path, local, progress=InterruptAfter(3))
    written = {path: path.stat().st_mtime_ns for path in (tmp_path / table.PARTS).glob("*.parquet")}
    assert len(written) == 3
    with pytest.raises(table.StudyDirectoryError, match="--resume"):
        engine.run_study(STUDY, tmp_path, local)
    summary = engine.run_study(STUDY, tmp_path, local, resume=True)
    assert (summary.reused, summary.computed) == (3, STUDY.chunks - 3)
    # The parts written before the interruption were not written again.
    assert {path: path.stat().st_mtime_ns for path in written} == written
    assert_same_rows(table.read(tmp_path), one_process)


def test_a_torn_or_missing_part_is_recomputed_on_resume(
    tmp_path: Path, one_process: pa.Table, local: Client
) -> None:
    engine.run_study(STUDY, tmp_path, local)
    table.part_path(tmp_path, 4).write_bytes(b"PAR1 cut short")
    table.part_path(tmp_path, 6).unlink()
    summary = engine.run_study(STUDY, tmp_path, local, resume=True)
    assert (summary.reused, summary.computed) == (STUDY.chunks - 2, 2)
    assert_same_rows(table.read(tmp_path), one_process)


def test_an_unreachable_scheduler_is_one_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(engine, "CONNECT_TIMEOUT", 2.0)
    with pytest.raises(engine.EngineError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:9"):
        with engine.connect(engine.Where(scheduler="tcp://127.0.0.1:9")):
            pass


def test_a_worker_killed_mid_study_is_replaced_and_the_table_is_the_undisturbed_one(
    tmp_path: Path, one_process: pa.Table, local: Client
) -> None:
    progress = KillAWorker(local)
    summary = engine.run_study(STUDY, tmp_path, local, progress=progress)
    pids_after = set(local.run(os.getpid).values())
    assert progress.killed is not None and progress.killed not in pids_after
    assert summary.computed == STUDY.chunks
    assert_same_rows(table.read(tmp_path), one_process)
