"""``tdslip run`` end to end, as a user runs it: three processes, a bag, a table, an exit status."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml  # type: ignore[import-untyped]
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from tdslip_ros.analysis.reader import read_run
from tdslip_ros.interfaces import resolve
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.parameters import PAPER_PARAMS

pytestmark = pytest.mark.slow


def tdslip_run(*arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tdslip_ros.cli", "run", *arguments],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )


def table_rows(stdout: str) -> list[list[float]]:
    """The apex table: stride, t, y, xdot, E, ybar, xdotbar, Ebar per row."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.lstrip().startswith("stride")) + 2
    rows = []
    for line in lines[start:]:
        if not line.strip():
            break
        rows.append([float(field) for field in line.replace("|", " ").split()])
    return rows


def bag_apexes(bag: Path) -> list[tuple[int, float, float]]:
    with (bag / f"{bag.name}_0.mcap").open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [
            (message.stride, message.height, message.forward_speed)
            for _, _, _, message in reader.iter_decoded_messages(topics=[resolve(topics.APEX)])
        ]


def bag_counts(bag: Path) -> dict[str, int]:
    information = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {
        entry["topic_metadata"]["name"]: entry["message_count"]
        for entry in information["topics_with_message_count"]
    }


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_run_prints_its_apexes_and_leaves_a_complete_bag(tmp_path: Path, mode: str) -> None:
    bag = tmp_path / "runs" / "hop"
    result = tdslip_run("--strides", "3", "--policy", "energy", "--mode", mode, "--out", str(bag))
    assert result.returncode == 0, result.stdout + result.stderr
    rows = table_rows(result.stdout)
    assert [int(row[0]) for row in rows] == [0, 1, 2, 3]
    # The table is the bag's apex sequence, in SI and in the paper's units (r0 = 1 m, sqrt(g r0)).
    for row, (stride, height, speed) in zip(rows, bag_apexes(bag), strict=True):
        assert row[0] == stride
        assert row[2:4] == pytest.approx([height, speed], abs=1e-5)
        assert row[5:7] == pytest.approx(
            [height / PAPER_PARAMS.r0, speed / (PAPER_PARAMS.g * PAPER_PARAMS.r0) ** 0.5], abs=1e-5
        )
    counts = bag_counts(bag)
    # (A realtime run on a loaded machine may also report a command that came after its touchdown.)
    assert counts[resolve(topics.APEX)] == 4 and counts[resolve(topics.STATUS)] >= 1
    assert counts[resolve(topics.STATE)] > 700
    printed = {
        line.split()[0]: line.split()[1:] for line in result.stdout.splitlines() if line.startswith("/")
    }
    for topic, count in counts.items():  # the run's own check, printed per topic
        assert printed[topic] == [str(count), str(count)], topic
    assert "LOST" not in result.stdout and f"{mode} run, policy energy: 3 strides" in result.stdout


@pytest.mark.parametrize(
    ("mode", "failure"),
    [
        # In realtime the plant hops on the command in force; the 20 degree leg cannot be placed.
        ("realtime", "toe_stubbing"),
        # In lockstep it waits for the controller, which has no command for such an apex.
        ("lockstep", "command_timeout"),
    ],
)
def test_a_failed_run_names_the_failure_and_exits_non_zero(tmp_path: Path, mode: str, failure: str) -> None:
    bag = tmp_path / "low"
    # From a 0.9 m apex a leg at 20 degrees (r0 cos = 0.94 m) cannot be placed.
    result = tdslip_run(
        "--strides", "3", "--height", "0.9", "--mode", mode, "--timeout", "0.5", "--out", str(bag)
    )
    assert result.returncode == 1
    assert f"run FAILED at stride 0, t = 0.000000 s: {failure}" in result.stderr
    if mode == "lockstep":  # (in realtime the stubbing comes at the first tick, before any answer)
        assert "no command for apex 0" in result.stderr  # the controller's reason is shown
    assert bag_counts(bag)[resolve(topics.STATUS)] == 1  # the failure is recorded too, nothing lost
    assert "LOST" not in result.stdout


def test_an_existing_output_is_refused(tmp_path: Path) -> None:
    result = tdslip_run("--strides", "1", "--out", str(tmp_path))
    assert result.returncode == 1 and "exists already" in result.stderr


def test_a_2000_stride_lockstep_run_with_both_cores_busy_records_every_message(tmp_path: Path) -> None:
    """The plant paces itself on the recorder (flow control) instead of failing when the recorder
    falls behind on a loaded machine: the run completes and nothing is lost."""
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        bag = tmp_path / "long"
        result = subprocess.run(
            [sys.executable, "-m", "tdslip_ros.cli", "run", "--strides", "2000", "--out", str(bag)],
            capture_output=True,
            text=True,
            timeout=1200,
            check=False,
        )
    finally:
        for process in busy:
            process.kill()
            process.wait()
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert "lockstep run, policy energy: 2000 strides" in result.stdout
    counts = bag_counts(bag)
    assert counts[resolve(topics.APEX)] == 2001 and counts[resolve(topics.STATE)] > 500_000
    printed = {
        line.split()[0]: line.split()[1:] for line in result.stdout.splitlines() if line.startswith("/")
    }
    assert {topic: int(values[1]) for topic, values in printed.items()} == counts
    assert all(values[0] == values[1] for values in printed.values())  # published = recorded, per topic


def test_a_run_in_a_namespace_records_and_analyses_its_topics_there(tmp_path: Path) -> None:
    bag = tmp_path / "ns"
    result = tdslip_run("--strides", "3", "--namespace", "/h1", "--out", str(bag))
    assert result.returncode == 0, result.stdout + result.stderr
    counts = bag_counts(bag)
    assert counts["/h1/tdslip/apex"] == 4 and not any(topic.startswith("/tdslip/") for topic in counts)
    run = read_run(bag)
    assert len(run.strides) == 4 and run.params_source == "stored in the recording"
