"""Viability Q-maps on Dask (studies/viability.py) and ``tdslip viability`` end to end.

Truth used: the same Q-map computed in this process without Dask (viability_spaces.q_map), bit for bit; the
files the command wrote; one-line errors that leave nothing behind. Every test shares the session's local
cluster of 2 workers (conftest.dask_scheduler). About 20 s in all once the cluster is up.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from distributed import Client
from support.cluster import KillAWorker
from support.helpers import deadline

from tdslip_ros.commands import cli
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.stability.viability import QMap, viable_set
from tdslip_ros.model.stability.viability_spaces import EnergySpace, q_map
from tdslip_ros.studies import engine, viability

SLIP = HopperParams(m=80.0, k=8200.0, r0=1.0, c=0.0, g=9.81)
SPACE = EnergySpace(
    SLIP,
    SLIP.m * (SLIP.g * 0.85 + 0.5 * 5.5**2),
    np.linspace(0.1, 0.995, 20),
    np.radians(np.linspace(-10, 70, 15)),
)
CHUNK = 25  # 300 pairs in 12 chunks


@pytest.fixture(scope="module")
def local(dask_scheduler: str):
    with engine.connect(engine.Where(scheduler=dask_scheduler)) as client:
        yield client


@pytest.fixture(scope="module")
def one_process() -> QMap:
    return q_map(SPACE)


def assert_same(qmap: QMap, reference: QMap) -> None:
    np.testing.assert_array_equal(qmap.successor, reference.successor)  # NaN equal to NaN, floats to the bit
    np.testing.assert_array_equal(qmap.failure, reference.failure)
    np.testing.assert_array_equal(viable_set(qmap).viable, viable_set(reference).viable)


def test_a_worker_killed_mid_run_gives_the_same_q_map_and_viable_set_bit_for_bit(
    tmp_path: Path, one_process: QMap, local: Client
) -> None:
    with deadline(180):
        progress = KillAWorker(local)
        qmap = viability.run_q_map(SPACE, tmp_path, local, chunk_pairs=CHUNK, progress=progress)
    assert progress.killed is not None
    assert_same(qmap, one_process)
    assert not (tmp_path / viability.CHUNKS_DIRECTORY).exists()


def test_an_interrupted_run_resumes_from_its_chunks(tmp_path: Path, one_process: QMap, local: Client) -> None:
    chunks = tmp_path / viability.CHUNKS_DIRECTORY
    chunks.mkdir()
    digest = viability.space_digest(SPACE)
    for index in (0, 3, 11):  # what a killed run left, each chunk as it wrote it
        successor, failure = viability.transitions(SPACE, index * CHUNK, min((index + 1) * CHUNK, 300))
        np.savez(chunks / f"{digest}-{index:06d}.npz", successor=successor, failure=failure)
    with pytest.raises(viability.ViabilityDirectoryError, match="--resume completes it"):
        viability.run_q_map(SPACE, tmp_path, local, chunk_pairs=CHUNK)
    progress = engine.Progress("test", "strides", stream=open("/dev/null", "w"))
    with deadline(120):
        qmap = viability.run_q_map(SPACE, tmp_path, local, resume=True, chunk_pairs=CHUNK, progress=progress)
    assert progress.skipped == 3 * CHUNK
    assert_same(qmap, one_process)


def test_the_command_writes_the_q_map_viable_set_summary_and_figures(
    tmp_path: Path, one_process: QMap, dask_scheduler: str
) -> None:
    out = tmp_path / "out"
    arguments = ["viability", "energy", "--out", str(out), "--scheduler", dask_scheduler]
    arguments += ["--stiffness", "8200", "--mass", "80", "--r0", "1", "--gravity", "9.81", "--zeta0", "0"]
    arguments += ["--energy-of-apex", "0.85", "5.5", "--fractions", "0.1", "0.995", "20"]
    arguments += ["--angles-deg", "-10", "70", "15", "--chunk-size", "40"]
    with deadline(180):
        assert cli.main(arguments) == 0
    stored = np.load(out / "qmap.npz")
    np.testing.assert_array_equal(stored["successor"], one_process.successor)
    reference = viable_set(one_process)
    np.testing.assert_array_equal(np.load(out / "viability.npz")["kernel"], reference.kernel)
    summary = json.loads((out / "viability.json").read_text())
    assert summary["kernel_states"] == reference.kernel.sum() and summary["pairs"] == 300
    for name in ("qmap.png", "kernel.png", "measure.png"):
        assert (out / name).read_bytes().startswith(b"\x89PNG")


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["energy", "--fractions", "0.2", "0.9", "0"], "--fractions is empty: N = 0"),
        (
            ["apex", "--heights", "1.5", "1.0", "10"],
            "--heights is inverted or empty: HI 1 is not above LO 1.5",
        ),
        (["apex", "--torques", "0", "-100", "x"], "--torques must be LO HI N"),
        (["apex", "--memory-limit-gb", "0.001"], "pairs, about 0.0"),
        (["apex", "--terrain", "step:height=-0.05,x=1"], "only flat ground"),
        (["energy"], "a damped leg with an idle hip"),
        (["regulation", "--push", "0.3"], "a push changes the energy"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], arguments: list[str], message: str
) -> None:
    out = tmp_path / "out"
    assert cli.main(["viability", *arguments, "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert len(error.splitlines()) == 1 and error.startswith("tdslip viability: ") and message in error, error
    assert not out.exists()
