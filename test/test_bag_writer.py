"""RosbagMcapWriter output read back by independent readers: ``mcap`` + ``mcap-ros2-support`` and
``rosbags`` (which also re-derives each type hash from the stored schema text and checks it)."""

from __future__ import annotations

import errno
import io
import os
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import pytest
import yaml
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Vector3, Wrench, WrenchStamped
from mcap.exceptions import EndOfFile, McapError
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.reader import read_ros2_messages
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader, AnyReaderError
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Header, String

from tdslip_ros.bag import (
    BagClosedError,
    BagWriteError,
    OfferedQos,
    RosbagMcapWriter,
    message_definition,
    open_bag,
    type_description_hash,
    writer,
)
from tdslip_ros.bag.recover import recover
from tdslip_ros.bag.writer import reserve_path

QOS_DEFAULT = OfferedQos()
QOS_LATCHED = OfferedQos(history="unknown", depth=0, durability="transient_local", deadline_ns=1_500_000_000)
TOPICS = {
    "/chatter": ("std_msgs/msg/String", (QOS_DEFAULT,)),
    "/tdslip/grf": ("geometry_msgs/msg/WrenchStamped", (QOS_DEFAULT, QOS_LATCHED)),
    "/clock": ("rosgraph_msgs/msg/Clock", ()),
}


@dataclass(frozen=True)
class Written:
    topic: str
    message: Any
    log_time_ns: int
    publish_time_ns: int


def sample_message(topic: str, index: int) -> Any:
    stamp = Time(sec=index // 1000, nanosec=(index % 1000) * 1_000_000)
    if topic == "/chatter":
        return String(data=f"message {index} ünïcode")
    if topic == "/tdslip/grf":
        return WrenchStamped(
            header=Header(stamp=stamp, frame_id="world"),
            wrench=Wrench(
                force=Vector3(x=0.5 * index, y=-1.0 - index, z=1e-9 * index), torque=Vector3(z=-float(index))
            ),
        )
    return Clock(clock=stamp)


def write_sample_bag(
    bag: RosbagMcapWriter, count: int, start_ns: int = 1_700_000_000_000_000_000
) -> list[Written]:
    for topic, (type_name, qos) in TOPICS.items():
        bag.add_topic(topic, type_name, offered_qos=qos)
    written = []
    for index in range(count):
        topic = list(TOPICS)[index % len(TOPICS)]
        log_time = start_ns + 1_000_000 * index
        entry = Written(topic, sample_message(topic, index), log_time, log_time - 250_000)
        bag.write(topic, serialize_message(entry.message), entry.log_time_ns, entry.publish_time_ns)
        written.append(entry)
    return written


def field_values(value: Any, template: Any) -> Any:
    """The field values of a decoded message, walked along the fields of the rclpy ``template``."""
    if hasattr(template, "get_fields_and_field_types"):
        return {
            name: field_values(getattr(value, name), getattr(template, name))
            for name in template.get_fields_and_field_types()
        }
    return value


def per_topic(written: list[Written]) -> dict[str, list[Written]]:
    return {topic: [entry for entry in written if entry.topic == topic] for topic in TOPICS}


@pytest.mark.parametrize(
    ("compression", "chunk_compression"), [("none", ""), ("lz4", "lz4"), ("zstd", "zstd")]
)
def test_bag_directory_reads_back_in_mcap_ros2(
    tmp_path: Path, compression: str, chunk_compression: str
) -> None:
    bag = RosbagMcapWriter(tmp_path / "run", compression=compression, chunk_size=4096)  # type: ignore[arg-type]
    written = write_sample_bag(bag, 900)
    bag.close()
    expected = per_topic(written)
    assert bag.message_counts == {topic: len(entries) for topic, entries in expected.items()}

    with bag.mcap_path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == "ros2"
        assert header.library.startswith("tdslip_ros")
        summary = reader.get_summary()
        assert summary is not None
        assert summary.statistics is not None
        assert {schema.name for schema in summary.schemas.values()} == {t for t, _ in TOPICS.values()}
        for schema in summary.schemas.values():
            assert schema.encoding == "ros2msg"
            assert schema.data.decode() == message_definition(schema.name)
        channels = {channel.topic: channel for channel in summary.channels.values()}
        assert set(channels) == set(TOPICS)
        for topic, channel in channels.items():
            type_name, _ = TOPICS[topic]
            assert channel.message_encoding == "cdr"
            assert set(channel.metadata) == {"offered_qos_profiles", "topic_type_hash"}
            assert channel.metadata["topic_type_hash"] == type_description_hash(type_name)
            assert summary.schemas[channel.schema_id].name == type_name
            assert summary.statistics.channel_message_counts[channel.id] == len(expected[topic])
        assert len(summary.chunk_indexes) > 3
        assert {index.compression for index in summary.chunk_indexes} == {chunk_compression}

        decoded: dict[str, list[tuple[int, int, int, Any]]] = {topic: [] for topic in TOPICS}
        for _, channel, message, ros_message in reader.iter_decoded_messages(log_time_order=False):
            decoded[channel.topic].append(
                (message.log_time, message.publish_time, message.sequence, ros_message)
            )
    for topic, entries in expected.items():
        assert [(log, publish, sequence) for log, publish, sequence, _ in decoded[topic]] == [
            (entry.log_time_ns, entry.publish_time_ns, number)
            for number, entry in enumerate(entries, start=1)
        ]
        for (_, _, _, ros_message), entry in zip(decoded[topic], entries, strict=True):
            assert field_values(ros_message, entry.message) == field_values(entry.message, entry.message)


def test_bag_directory_reads_back_in_rosbags(tmp_path: Path) -> None:
    with RosbagMcapWriter(tmp_path / "run") as bag:
        written = write_sample_bag(bag, 300)
    expected = per_topic(written)
    with AnyReader([tmp_path / "run"]) as reader:
        connections = {connection.topic: connection for connection in reader.connections}
        assert set(connections) == set(TOPICS)
        for topic, connection in connections.items():
            type_name, qos = TOPICS[topic]
            assert connection.msgtype == type_name
            assert connection.msgcount == len(expected[topic])
            assert connection.digest == type_description_hash(type_name)
            offered = connection.ext.offered_qos_profiles  # type: ignore[union-attr]
            assert [(q.history.name.lower(), q.depth, q.durability.name.lower()) for q in offered] == [
                (q.history, q.depth, q.durability) for q in qos
            ]
        seen: dict[str, list[tuple[int, Any]]] = {topic: [] for topic in TOPICS}
        for connection, timestamp, raw in reader.messages():
            seen[connection.topic].append((timestamp, reader.deserialize(raw, connection.msgtype)))
    for topic, entries in expected.items():
        assert [timestamp for timestamp, _ in seen[topic]] == [entry.log_time_ns for entry in entries]
        for (_, message), entry in zip(seen[topic], entries, strict=True):
            assert field_values(message, entry.message) == field_values(entry.message, entry.message)


def test_metadata_yaml_and_rosbag2_record_describe_the_bag(tmp_path: Path) -> None:
    with RosbagMcapWriter(tmp_path / "run", ros_distro="kilted", custom_data={"policy": "energy"}) as bag:
        written = write_sample_bag(bag, 30, start_ns=5_000_000)
    assert bag.metadata_path is not None
    information = yaml.safe_load(bag.metadata_path.read_text())["rosbag2_bagfile_information"]
    log_times = [entry.log_time_ns for entry in written]
    counts = {topic: len(entries) for topic, entries in per_topic(written).items()}
    assert information["version"] == 9
    assert information["storage_identifier"] == "mcap"
    assert information["starting_time"] == {"nanoseconds_since_epoch": min(log_times)}
    assert information["duration"] == {"nanoseconds": max(log_times) - min(log_times)}
    assert information["message_count"] == len(written)
    assert information["compression_format"] == information["compression_mode"] == ""
    assert information["relative_file_paths"] == [bag.mcap_path.name]
    assert (bag.metadata_path.parent / information["relative_file_paths"][0]) == bag.mcap_path
    assert information["files"] == [
        {
            "path": bag.mcap_path.name,
            "starting_time": {"nanoseconds_since_epoch": min(log_times)},
            "duration": {"nanoseconds": max(log_times) - min(log_times)},
            "message_count": len(written),
        }
    ]
    assert information["custom_data"] == {"policy": "energy"}
    assert information["ros_distro"] == "kilted"
    topics = {entry["topic_metadata"]["name"]: entry for entry in information["topics_with_message_count"]}
    for topic, (type_name, qos) in TOPICS.items():
        metadata = topics[topic]["topic_metadata"]
        assert topics[topic]["message_count"] == counts[topic]
        assert metadata["type"] == type_name
        assert metadata["serialization_format"] == "cdr"
        assert metadata["type_description_hash"] == type_description_hash(type_name)
        assert metadata["offered_qos_profiles"] == [q.to_yaml_mapping() for q in qos]

    with bag.mcap_path.open("rb") as stream:
        records = list(make_reader(stream).iter_metadata())
    # As rosbag2 does: one record when the bag is opened (custom_data, no topics yet), one at close.
    assert [(record.name, set(record.metadata)) for record in records] == [
        ("rosbag2", {"serialized_metadata"})
    ] * 2
    opening, closing = (yaml.safe_load(record.metadata["serialized_metadata"]) for record in records)
    assert closing == information
    assert opening["custom_data"] == {"policy": "energy"} and opening["topics_with_message_count"] == []


def test_bare_mcap_file_has_no_metadata_yaml(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RosbagMcapWriter(path, bag_directory=False) as bag:
        written = write_sample_bag(bag, 12)
    assert bag.metadata_path is None
    assert list(tmp_path.iterdir()) == [path]
    decoded = [message.ros_msg for message in read_ros2_messages(str(path))]
    assert [field_values(m, e.message) for m, e in zip(decoded, written, strict=True)] == [
        field_values(e.message, e.message) for e in written
    ]


def test_every_message_of_a_1khz_scale_run_is_kept(tmp_path: Path) -> None:
    total = 60_000
    payloads = {topic: serialize_message(sample_message(topic, 7)) for topic in TOPICS}
    topics = list(TOPICS)
    with RosbagMcapWriter(tmp_path / "run") as bag:
        for topic, (type_name, qos) in TOPICS.items():
            bag.add_topic(topic, type_name, offered_qos=qos)
        for index in range(total):
            topic = topics[index % 3]
            bag.write(topic, payloads[topic], 1_000_000 * index)
    expected = dict.fromkeys(TOPICS, total // 3)
    assert bag.message_counts == expected

    sequences: dict[int, list[int]] = {}
    with bag.mcap_path.open("rb") as stream:
        for _, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            sequences.setdefault(channel.id, []).append(message.sequence)
    assert sorted(len(numbers) for numbers in sequences.values()) == [total // 3] * 3
    assert all(numbers == list(range(1, total // 3 + 1)) for numbers in sequences.values())
    with AnyReader([tmp_path / "run"]) as reader:
        assert {connection.topic: connection.msgcount for connection in reader.connections} == expected
        assert sum(1 for _ in reader.messages()) == total


def read_message_count(path: Path) -> int:
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    assert summary.statistics is not None
    return summary.statistics.message_count


def test_close_from_another_thread_while_writing_keeps_every_accepted_message(tmp_path: Path) -> None:
    bag = RosbagMcapWriter(tmp_path / "run", chunk_size=4096)
    bag.add_topic("/chatter", "std_msgs/msg/String")
    accepted = 0
    started = threading.Event()

    def produce() -> None:
        nonlocal accepted
        while True:
            try:
                bag.write("/chatter", serialize_message(String(data=str(accepted))), accepted)
            except BagClosedError:
                return
            accepted += 1
            started.set()

    producer = threading.Thread(target=produce)
    producer.start()
    assert started.wait(10)
    threading.Event().wait(0.05)
    bag.close()
    producer.join(10)
    assert not producer.is_alive()
    assert accepted > 0
    assert bag.message_counts == {"/chatter": accepted}
    assert read_message_count(bag.mcap_path) == accepted
    with AnyReader([tmp_path / "run"]) as reader:
        assert [reader.deserialize(raw, "std_msgs/msg/String").data for _, _, raw in reader.messages()] == [
            str(number) for number in range(accepted)
        ]


def test_close_requested_inside_a_write_completes_when_that_write_returns(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A signal handler runs on the writing thread between two bytecodes of write(); simulate one that
    # arrives while the tenth message is being added.
    bag = RosbagMcapWriter(tmp_path / "run")
    bag.add_topic("/chatter", "std_msgs/msg/String")
    add_message = bag._mcap.add_message
    calls = 0

    def add_message_interrupted(*args: Any, **kwargs: Any) -> None:
        nonlocal calls
        calls += 1
        if calls == 10:
            bag.close()
            assert not bag.closed, "close must wait for the interrupted write"
        add_message(*args, **kwargs)

    monkeypatch.setattr(bag._mcap, "add_message", add_message_interrupted)
    for number in range(10):
        bag.write("/chatter", serialize_message(String(data=str(number))), number)
    assert bag.closed
    with pytest.raises(BagClosedError):
        bag.write("/chatter", b"", 11)
    assert read_message_count(bag.mcap_path) == 10


def test_usage_errors_are_reported(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="compression"):
        RosbagMcapWriter(tmp_path / "a", compression="gzip")  # type: ignore[arg-type]
    bag = RosbagMcapWriter(tmp_path / "run")
    with pytest.raises(FileExistsError):
        RosbagMcapWriter(tmp_path / "run")
    with pytest.raises(FileExistsError):
        RosbagMcapWriter(bag.mcap_path, bag_directory=False)
    channel = bag.add_topic("/chatter", "std_msgs/String")
    assert bag.add_topic("/chatter", "std_msgs/msg/String") == channel
    with pytest.raises(ValueError, match="already recorded"):
        bag.add_topic("/chatter", "rosgraph_msgs/msg/Clock")
    with pytest.raises(KeyError, match="add_topic"):
        bag.write("/unknown", b"", 0)
    with pytest.raises(ValueError, match="times"):
        bag.write("/chatter", b"", 10, publish_time_ns=-1)
    with pytest.raises(ValueError, match="sequence"):
        bag.write("/chatter", b"", 10, sequence=2**32)
    bag.close()
    bag.close()
    with pytest.raises(BagClosedError):
        bag.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    assert read_message_count(bag.mcap_path) == 0


def scan_messages(stream: IO[bytes]) -> tuple[list[Message], McapError | None]:
    """Every message record of a sequential scan, and the error that ended it, if any."""
    messages = []
    try:
        for record in StreamReader(stream).records:
            if isinstance(record, Message):
                messages.append(record)
    except McapError as error:
        return messages, error
    return messages, None


def test_truncated_file_is_rejected_by_readers_and_complete_chunks_are_recoverable(tmp_path: Path) -> None:
    with RosbagMcapWriter(tmp_path / "run", chunk_size=4096) as bag:
        written = write_sample_bag(bag, 1500)
    with bag.mcap_path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda index: index.chunk_start_offset)
    cut_chunk = chunks[len(chunks) // 2]
    data = bag.mcap_path.read_bytes()[: cut_chunk.chunk_start_offset + cut_chunk.chunk_length // 2]
    bag.mcap_path.write_bytes(data)

    with pytest.raises(McapError):
        list(make_reader(io.BytesIO(data)).iter_messages())
    with pytest.raises(McapError):
        list(read_ros2_messages(str(bag.mcap_path)))
    with pytest.raises(AnyReaderError, match="magic"), AnyReader([tmp_path / "run"]) as reader:
        list(reader.messages())

    recovered, error = scan_messages(io.BytesIO(data))
    assert isinstance(error, EndOfFile)
    last_complete = chunks[len(chunks) // 2 - 1].message_end_time
    assert [message.log_time for message in recovered] == [
        entry.log_time_ns for entry in written if entry.log_time_ns <= last_complete
    ]


def child_environment() -> dict[str, str]:
    """Environment for a child Python that imports this checkout's tdslip_ros."""
    repo = Path(__file__).resolve().parents[1]
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(repo), os.environ.get("PYTHONPATH", "")]))


def test_hard_killed_writer_leaves_every_flushed_chunk_recoverable(tmp_path: Path) -> None:
    script = tmp_path / "killed_writer.py"
    script.write_text(
        "import os, signal, sys\n"
        "from pathlib import Path\n"
        "from tdslip_ros.bag import RosbagMcapWriter\n"
        "bag = RosbagMcapWriter(Path(sys.argv[1]), chunk_size=4096)\n"
        "bag.add_topic('/chatter', 'std_msgs/msg/String')\n"
        "payload = bytes([0, 1, 0, 0, 4, 0, 0, 0]) + b'abc\\0'\n"
        "for number in range(3000):\n"
        "    bag.write('/chatter', payload, number)\n"
        "bag.flush()\n"
        "for number in range(3000, 3050):\n"
        "    bag.write('/chatter', payload, number)\n"
        "os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    run = tmp_path / "run"
    result = subprocess.run(
        [sys.executable, str(script), str(run)], env=child_environment(), timeout=60, check=False
    )
    assert result.returncode == -signal.SIGKILL
    mcap_path = run / "run_0.mcap"
    assert not (run / "metadata.yaml").exists()
    with pytest.raises(McapError), mcap_path.open("rb") as stream:
        list(make_reader(stream).iter_messages())
    with mcap_path.open("rb") as stream:
        recovered, error = scan_messages(stream)
    assert isinstance(error, EndOfFile)
    assert [(message.sequence, message.log_time) for message in recovered] == [
        (number + 1, number) for number in range(3000)
    ]


def test_sigterm_handler_closing_the_writer_leaves_a_finalised_bag(tmp_path: Path) -> None:
    script = tmp_path / "terminated_writer.py"
    script.write_text(
        "import signal, sys\n"
        "from pathlib import Path\n"
        "from rclpy.serialization import serialize_message\n"
        "from std_msgs.msg import String\n"
        "from tdslip_ros.bag import BagClosedError, RosbagMcapWriter\n"
        "bag = RosbagMcapWriter(Path(sys.argv[1]), chunk_size=4096)\n"
        "bag.add_topic('/chatter', 'std_msgs/msg/String')\n"
        "signal.signal(signal.SIGTERM, lambda *_: bag.close())\n"
        "accepted = 0\n"
        "print('ready', flush=True)\n"
        "while True:\n"
        "    try:\n"
        "        bag.write('/chatter', serialize_message(String(data=str(accepted))), accepted)\n"
        "    except BagClosedError:\n"
        "        break\n"
        "    accepted += 1\n"
        "print(accepted, flush=True)\n"
    )
    run = tmp_path / "run"
    child = subprocess.Popen(
        [sys.executable, str(script), str(run)], env=child_environment(), stdout=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "ready"
        threading.Event().wait(0.3)
        child.send_signal(signal.SIGTERM)
        output, _ = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 0
    accepted = int(output.strip())
    assert accepted > 0
    assert read_message_count(run / "run_0.mcap") == accepted
    with AnyReader([run]) as reader:
        assert [reader.deserialize(raw, "std_msgs/msg/String").data for _, _, raw in reader.messages()] == [
            str(number) for number in range(accepted)
        ]


# --- write errors -------------------------------------------------------------------------------


class CappedDisk:
    """Stands in for the writer module's ``os``: ``pwrite`` behaves like a disk of ``capacity`` bytes
    on which the reserve file (while it exists) takes its share, or fails with ``errno`` for good
    from byte ``fail_from`` on; everything else is the real ``os``."""

    def __init__(self, capacity: int, reserve: Path, reserve_size: int, fail_from: int | None = None) -> None:
        self.capacity, self.reserve, self.reserve_size, self.fail_from = (
            capacity,
            reserve,
            reserve_size,
            fail_from,
        )

    def __getattr__(self, name: str) -> Any:
        return getattr(os, name)

    def pwrite(self, fd: int, data: Any, offset: int) -> int:
        if self.fail_from is not None and offset + len(data) > self.fail_from:
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        room = self.capacity - (self.reserve_size if self.reserve.exists() else 0) - offset
        if room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return os.pwrite(fd, data[:room], offset)


def write_until_refused(bag: RosbagMcapWriter, payload: bytes) -> tuple[int, BagWriteError]:
    """Write ``payload`` messages until the writer raises BagWriteError; the messages given (the
    refused one included) and the error."""
    given = 0
    while given < 10_000_000:
        given += 1
        try:
            bag.write("/chatter", payload, given)
        except BagWriteError as error:
            return given, error
    raise AssertionError("the disk never filled up")


STRING_PAYLOAD = bytes([0, 1, 0, 0, 200, 0, 0, 0]) + bytes(range(199)) + b"\0"  # a 199-character String


def check_full_disk_bag(bag: RosbagMcapWriter, given: int, error: BagWriteError) -> None:
    """What a full disk must leave: one clear line, a closed writer, and a finalised bag holding every
    message given to it, read back by mcap and by rosbags."""
    assert error.errno == errno.ENOSPC and error.finalised
    message = str(error)
    assert "\n" not in message and "No space left on device" in message
    assert f"finalised with all {given} messages" in message
    assert bag.closed and bag.message_counts == {"/chatter": given}
    with pytest.raises(BagClosedError):
        bag.write("/chatter", STRING_PAYLOAD, given + 1)
    assert read_message_count(bag.mcap_path) == given
    assert bag.metadata_path is not None and bag.metadata_path.is_file()
    assert not reserve_path(bag.mcap_path).exists()
    with AnyReader([bag.mcap_path.parent]) as reader:
        assert [timestamp for _, timestamp, _ in reader.messages()] == list(range(1, given + 1))


def test_a_full_disk_stops_the_recording_with_a_finalised_bag_of_everything_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Simulated disk of 256 KiB: the writer's reserve is what makes room for the last chunk and the
    summary."""
    reserve = 2 * 4096 + 64 * 1024
    mcap_path = tmp_path / "run" / "run_0.mcap"
    monkeypatch.setattr(writer, "os", CappedDisk(256 * 1024, reserve_path(mcap_path), reserve))
    bag = RosbagMcapWriter(tmp_path / "run", chunk_size=4096, reserve=reserve)
    bag.add_topic("/chatter", "std_msgs/msg/String")
    given, error = write_until_refused(bag, STRING_PAYLOAD)
    monkeypatch.undo()
    assert bag.mcap_path.stat().st_size > 256 * 1024 - reserve  # it got to the reserve
    check_full_disk_bag(bag, given, error)


def test_a_full_tmpfs_leaves_a_finalised_bag(tiny_disk: Path) -> None:
    bag = RosbagMcapWriter(tiny_disk / "run", chunk_size=16 * 1024, custom_data={"policy": "energy"})
    bag.add_topic("/chatter", "std_msgs/msg/String")
    given, error = write_until_refused(bag, STRING_PAYLOAD)
    check_full_disk_bag(bag, given, error)
    assert open_bag(tiny_disk / "run").custom_data == {"policy": "energy"}


def random_strings(count: int) -> list[bytes]:
    """Serialized std_msgs/String messages of 199 random letters: chunks of them hardly compress, as
    the 1 kHz state does not, so a small disk fills after thousands of messages, not millions."""
    letters = np.random.default_rng(7).integers(ord("a"), ord("z") + 1, size=(count, 199), dtype=np.uint8)
    return [STRING_PAYLOAD[:8] + row.tobytes() + b"\0" for row in letters]


def test_a_nearly_full_disk_keeps_the_first_messages_with_the_default_reserve(tiny_disk: Path) -> None:
    """The 2 MiB tmpfs of issue 35 at the default chunk size: the reserve (two chunks and the summary's
    room, 2 MiB) once took the whole disk, and the bag held 0 messages. Sized to half of what is free,
    it leaves the first megabyte to the messages."""
    bag = RosbagMcapWriter(tiny_disk / "run")
    bag.add_topic("/chatter", "std_msgs/msg/String")
    payloads = random_strings(20_000)
    given = 0
    with pytest.raises(BagWriteError) as refused:
        for given, payload in enumerate(payloads, start=1):
            bag.write("/chatter", payload, given)
    error = refused.value
    assert error.errno == errno.ENOSPC and "\n" not in str(error)
    assert f"finalised with all {given} messages" in str(error)
    assert not reserve_path(bag.mcap_path).exists() and (tiny_disk / "run" / "metadata.yaml").is_file()
    check_bag_holds(tiny_disk / "run", payloads[:given])
    assert given > 4_000  # 1 MiB of 209-byte messages, at least


def check_bag_holds(bag: Path, payloads: list[bytes]) -> None:
    """The bag directory holds exactly ``payloads``, in order, at log times 1, 2, ... (rosbags reads it)."""
    with AnyReader([bag]) as reader:
        read = [(timestamp, raw) for _, timestamp, raw in reader.messages()]
    assert [timestamp for timestamp, _ in read] == list(range(1, len(payloads) + 1))
    assert [raw for _, raw in read] == payloads


RLIMIT_WRITER = """
import resource, sys
from pathlib import Path
sys.path[:0] = [sys.argv[3], sys.argv[4]]
from test_bag_writer import random_strings
from tdslip_ros.bag import BagWriteError, RosbagMcapWriter
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[2]), resource.RLIM_INFINITY))
bag = RosbagMcapWriter(Path(sys.argv[1]))
bag.add_topic("/chatter", "std_msgs/msg/String")
for given, payload in enumerate(random_strings(20_000), start=1):
    try:
        bag.write("/chatter", payload, given)
    except BagWriteError as error:
        print(given)
        print(error)
        break
"""


def test_a_file_size_limit_finalises_the_bag_with_every_message_given(tmp_path: Path) -> None:
    """RLIMIT_FSIZE (what ``ulimit -f`` sets, no privileges needed) on the writing process: the write
    that reaches the last reserve below the limit is the last, and the bag holds everything given."""
    limit = 1536 * 1024
    test_dir, repo = Path(__file__).parent, Path(__file__).parents[1]
    result = subprocess.run(
        [sys.executable, "-c", RLIMIT_WRITER, str(tmp_path / "run"), str(limit), str(test_dir), str(repo)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    given_line, message = result.stdout.splitlines()
    assert (tmp_path / "run" / "run_0.mcap").stat().st_size <= limit
    given = int(given_line)
    assert "RLIMIT_FSIZE" in message and f"finalised with all {given} messages" in message
    assert (tmp_path / "run" / "metadata.yaml").is_file()
    check_bag_holds(tmp_path / "run", random_strings(given))
    assert given > 2_000  # 768 KiB below the limit hold at least that many 209-byte messages


def test_no_room_for_the_reserve_is_one_clear_error(tiny_disk: Path) -> None:
    with pytest.raises(
        BagWriteError, match="no room for the bag's 4194304 B reserve: No space left on device"
    ):
        RosbagMcapWriter(tiny_disk / "run", reserve=4 * 1024 * 1024)
    assert list((tiny_disk / "run").iterdir()) == []


def test_a_lasting_io_error_leaves_a_file_that_recover_makes_readable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    mcap_path = tmp_path / "run" / "run_0.mcap"
    monkeypatch.setattr(writer, "os", CappedDisk(2**40, reserve_path(mcap_path), 0, fail_from=100_000))
    bag = RosbagMcapWriter(tmp_path / "run", chunk_size=4096, custom_data={"policy": "energy"})
    bag.add_topic("/chatter", "std_msgs/msg/String")
    given, error = write_until_refused(bag, STRING_PAYLOAD)
    monkeypatch.undo()
    assert error.errno == errno.EIO and not error.finalised and "\n" not in str(error)
    assert f"not finalised: tdslip recover {mcap_path}" in str(error)
    assert bag.closed and not reserve_path(mcap_path).exists()
    assert mcap_path.stat().st_size <= 100_000  # the failed chunk was cut off
    recovery = recover(tmp_path / "run")
    kept = recovery.recovered["/chatter"]
    with AnyReader([tmp_path / "run"]) as reader:
        assert [timestamp for _, timestamp, _ in reader.messages()] == list(range(1, kept + 1))
    messages_per_chunk = 4096 // len(STRING_PAYLOAD) + 1
    assert given - messages_per_chunk <= kept <= given  # at most the chunk being written is lost
    assert recovery.scan.discarded_bytes == 0 and open_bag(tmp_path / "run").custom_data == {
        "policy": "energy"
    }
