"""``tdslip recover``: a killed writer's bag, truncated and damaged files, made readable again, and
what is reported lost held to what was written."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml  # type: ignore[import-untyped]
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from support.analysis_runs import raw_messages

from tdslip_ros.analysis.decoding import RunReadError, read_run
from tdslip_ros.bag import RosbagMcapWriter, open_bag
from tdslip_ros.bag.reader import BagReadError, iter_messages, mcap_file, verify
from tdslip_ros.bag.recover import RecoverError, recover
from tdslip_ros.bag.writer import reserve_path
from tdslip_ros.commands import cli
from tdslip_ros.interfaces import resolve
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.runner import RunReport

CHUNK_SIZE = 64 * 1024

# Copies a recording into a new bag, as the recorder writes it, and dies by SIGKILL after a number of
# messages: no footer, no summary, no metadata.yaml, an open chunk lost.
KILLED_WRITER = """
import os, signal, sys
from pathlib import Path
from tdslip_ros.bag import RosbagMcapWriter, open_bag
from tdslip_ros.bag.qos import parse_qos_profiles
from tdslip_ros.bag.reader import iter_messages
source = open_bag(Path(sys.argv[1]))
bag = RosbagMcapWriter(Path(sys.argv[2]), chunk_size=int(sys.argv[4]), custom_data=source.custom_data)
for topic, info in source.topics.items():
    qos = parse_qos_profiles(info.metadata["offered_qos_profiles"])
    bag.add_topic(topic, info.type_name, offered_qos=qos, type_hash=info.metadata["topic_type_hash"])
for number, (channel, message) in enumerate(iter_messages(source), start=1):
    bag.write(channel.topic, message.data, message.log_time, message.publish_time, message.sequence)
    if number == int(sys.argv[3]):
        os.kill(os.getpid(), signal.SIGKILL)
"""


def kill_writer_after(source: Path, bag: Path, messages: int) -> None:
    repo = Path(__file__).resolve().parents[1]
    environment = dict(os.environ, PYTHONPATH=os.pathsep.join([str(repo), os.environ.get("PYTHONPATH", "")]))
    result = subprocess.run(
        [sys.executable, "-c", KILLED_WRITER, str(source), str(bag), str(messages), str(CHUNK_SIZE)],
        env=environment,
        timeout=120,
        check=False,
    )
    assert result.returncode == -signal.SIGKILL


def written_counts(source: Path, messages: int) -> dict[str, int]:
    """Messages per topic among the first ``messages`` of ``source`` (what the killed writer wrote)."""
    counts = dict.fromkeys(open_bag(source).topics, 0)
    for number, (channel, _) in enumerate(iter_messages(open_bag(source)), start=1):
        if number > messages:
            break
        counts[channel.topic] += 1
    return counts


def test_a_killed_writer_s_bag_is_recovered_and_analysed(
    energy: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    total = sum(energy.recorded.values())
    messages = total * 2 // 3
    bag = tmp_path / "killed"
    kill_writer_after(energy.bag, bag, messages)
    assert not (bag / "metadata.yaml").exists() and reserve_path(bag / "killed_0.mcap").exists()
    with pytest.raises(RunReadError, match="truncated or not finalised.*tdslip recover"):
        read_run(bag)

    assert cli.main(["recover", str(bag)]) == 0
    output = capsys.readouterr().out
    written = written_counts(energy.bag, messages)
    recovered = open_bag(bag)
    verify(recovered)
    counts = {topic: info.message_count for topic, info in recovered.topics.items()}
    lost = {topic: written[topic] - counts[topic] for topic in written}
    with capsys.disabled():
        print(
            f"\nkill -9 after {messages} of {total} messages: recovered {sum(counts.values())}, lost {lost}"
        )
    # Every topic and its definition survive, and the messages recovered are the first ones written:
    # only the open chunk is lost (its messages, at most CHUNK_SIZE bytes of them).
    assert set(counts) == set(written) == set(energy.recorded)
    assert all(0 <= n for n in lost.values()) and 0 < sum(lost.values())
    in_order = list(raw_messages(mcap_file(energy.bag)))
    assert sum(len(data) for *_, data in in_order[messages - sum(lost.values()) : messages]) <= CHUNK_SIZE
    original = {info.topic: info for info in open_bag(energy.bag).topics.values()}
    for topic, info in recovered.topics.items():
        assert (info.type_name, info.schema, info.metadata) == (
            original[topic].type_name,
            original[topic].schema,
            original[topic].metadata,
        ), topic
    assert f"recovered {bag / 'killed_0.mcap'}: {sum(counts.values())} messages" in output
    assert "the messages lost are not known" in output and "kept as" in output
    assert (bag / "killed_0.mcap.orig").is_file() and not reserve_path(bag / "killed_0.mcap").exists()

    # rosbag2 tools read it (metadata.yaml, custom_data) and so does the analysis, with the stored parameters.
    with AnyReader([bag]) as reader:
        assert sum(1 for _ in reader.messages()) == sum(counts.values())
    information = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert information["custom_data"] == open_bag(energy.bag).custom_data
    run = read_run(bag)
    assert run.params_source == "stored in the recording" and run.params == energy.params
    assert len(run.strides) == counts[resolve(topics.APEX)] and run.outcome is None

    assert cli.main(["recover", str(bag)]) == 0  # intact now: left alone
    assert "nothing to recover" in capsys.readouterr().out


def test_a_writer_killed_before_its_first_chunk_keeps_every_topic_and_the_custom_data(
    energy: RunReport, tmp_path: Path
) -> None:
    bag = tmp_path / "early"
    kill_writer_after(energy.bag, bag, 10)
    recovery = recover(bag)
    assert recovery.recovered == dict.fromkeys(energy.recorded, 0)
    assert open_bag(bag).custom_data == open_bag(energy.bag).custom_data


def cut(source: Path, target: Path, size: int) -> Path:
    target.write_bytes(source.read_bytes()[:size])
    return target


def chunk_offsets(mcap_path: Path) -> list[tuple[int, int]]:
    with mcap_path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return sorted((index.chunk_start_offset, index.chunk_length) for index in summary.chunk_indexes)


@pytest.fixture
def small_chunks(energy: RunReport, tmp_path: Path) -> Path:
    """The energy run as a finalised bag directory of CHUNK_SIZE chunks."""
    source = open_bag(energy.bag)
    with RosbagMcapWriter(tmp_path / "small", chunk_size=CHUNK_SIZE, custom_data=source.custom_data) as bag:
        for topic, info in source.topics.items():
            bag.add_topic(topic, info.type_name)
        for channel, message in iter_messages(source):
            bag.write(channel.topic, message.data, message.log_time, message.publish_time, message.sequence)
    return tmp_path / "small"


def test_a_finalised_bag_cut_mid_chunk_reports_its_losses(small_chunks: Path) -> None:
    mcap_path = mcap_file(small_chunks)
    stated = {topic: info.message_count for topic, info in open_bag(small_chunks).topics.items()}
    start, length = chunk_offsets(mcap_path)[3]
    cut(mcap_path, mcap_path, start + length // 2)
    recovery = recover(small_chunks)
    assert recovery.expected == stated  # from the metadata.yaml of the finalised bag
    assert sum(recovery.lost.values()) == sum(stated.values()) - sum(recovery.recovered.values()) > 0
    assert (
        recovery.scan.discarded_bytes == length // 2
        and "chunk record is cut off" in recovery.scan.stop_reason
    )
    assert (small_chunks / "metadata.yaml.orig").is_file()
    assert read_run(small_chunks).outcome is None


def test_a_damaged_chunk_is_skipped_and_the_rest_kept(small_chunks: Path) -> None:
    mcap_path = mcap_file(small_chunks)
    total = open_bag(small_chunks).message_count
    start, length = chunk_offsets(mcap_path)[2]
    data = bytearray(mcap_path.read_bytes())
    data[start + 200 : start + 210] = bytes(b ^ 0xFF for b in data[start + 200 : start + 210])
    mcap_path.write_bytes(bytes(data))
    with pytest.raises(BagReadError, match="corrupt data"):
        verify(open_bag(small_chunks))
    recovery = recover(small_chunks)
    assert recovery.scan.complete
    assert [(offset, size) for offset, size, _ in recovery.scan.damaged_chunks] == [(start, length)]
    assert recovery.scan.discarded_bytes == length
    assert 0 < total - sum(recovery.recovered.values()) == sum(recovery.lost.values())
    verify(open_bag(small_chunks))


def test_a_bag_cut_while_finalising_loses_nothing(small_chunks: Path, tmp_path: Path) -> None:
    mcap_path = mcap_file(small_chunks)
    with mcap_path.open("rb") as stream:
        summary_start = make_reader(stream).get_summary()
    size = mcap_path.stat().st_size
    bare = cut(mcap_path, tmp_path / "bare.mcap", size - 100)  # inside the summary section
    recovery = recover(bare)
    assert summary_start is not None and recovery.scan.complete and recovery.lost == {}
    assert recovery.recovered == recovery.expected and sum(recovery.expected.values()) > 0
    assert sorted(path.name for path in tmp_path.iterdir()) == ["bare.mcap", "bare.mcap.orig", "small"]


@pytest.mark.parametrize(
    ("content", "needle"),
    [(b"", "not an MCAP file"), (b"stride,y\n0,1.0\n" * 10, "not an MCAP file")],
)
def test_what_is_not_an_mcap_file_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes, needle: str
) -> None:
    path = tmp_path / "run.mcap"
    path.write_bytes(content)
    assert cli.main(["recover", str(path)]) == 2
    error = capsys.readouterr().err
    assert error.startswith("tdslip recover: ") and needle in error and error.count("\n") == 1
    assert [p.name for p in tmp_path.iterdir()] == ["run.mcap"]  # untouched


def test_a_second_recovery_never_overwrites_a_kept_original(small_chunks: Path) -> None:
    mcap_path = mcap_file(small_chunks)
    cut(mcap_path, mcap_path, mcap_path.stat().st_size // 2)
    shutil.copy(mcap_path, mcap_path.with_name(mcap_path.name + ".orig"))
    with pytest.raises(RecoverError, match=r"\.orig exists: the recording was recovered before"):
        recover(small_chunks)
