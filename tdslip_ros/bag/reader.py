"""Read a rosbag2 MCAP recording without rclpy: find its file, check it, list its topics, iterate
and decode its messages.

A recording is a bag directory (rosbag2's layout: ``metadata.yaml`` and one ``.mcap`` file; without
``metadata.yaml`` the one ``.mcap`` file in it) or a bare ``.mcap`` file. :func:`open_bag` checks it
before anything is read from it: the MCAP magic at both ends (a file without the closing magic was
not finalised: :mod:`tdslip_ros.bag.recover` makes it readable), the footer, the summary section's
CRC and its statistics; it returns the topics (type, stored schema, channel metadata such as the
offered QoS and type hash, message count), the time span and the rosbag2 metadata record's
``custom_data`` and ``ros_distro``. rosbag2 writes that record when it opens a bag and again when it
closes it; like rosbag2's reader, the last one wins.

:func:`iter_messages` checks every chunk's CRC as it decompresses it and, in a full pass, that the
data section holds as many messages as the summary counts; :func:`verify` is that pass alone.

Every problem with the input raises :class:`BagReadError` with a one-line message that names what
is missing or wrong.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader, get_chunk_data_stream

MCAP_MAGIC = b"\x89MCAP0\r\n"
_FOOTER = struct.Struct("<BQQQI")  # opcode, record length, summary start, summary offset start, CRC
_RECORD = struct.Struct("<BQ")  # opcode, record length
_MESSAGE = struct.Struct("<HIQ")  # channel id, sequence, log time (publish time follows)
_MESSAGE_HEADER = 2 + 4 + 8 + 8
_UNCHUNKED_BATCH = 65536  # messages of a file without chunks handed on at once
ROSBAG2_RECORD = "rosbag2"
"""Name of the MCAP metadata record in which rosbag2 stores the bag information (key
``serialized_metadata``: the YAML of metadata.yaml's ``rosbag2_bagfile_information``)."""


class BagReadError(Exception):
    """The recording cannot be read; the message says what is missing or wrong."""


# The mcap reader, zstandard, lz4 and the CDR decoder raise many unrelated exception types on damaged
# input (McapError, struct.error, ValueError, ZstdError, IndexError, ...); the handlers marked
# "see _damaged" catch Exception and turn it into a BagReadError that says where the damage is.


@dataclass(frozen=True)
class TopicInfo:
    """One recorded topic: its message type, stored definition, channel metadata and message count."""

    topic: str
    type_name: str
    schema: Schema | None
    metadata: dict[str, str]
    """The channel metadata: ``offered_qos_profiles`` (YAML text) and ``topic_type_hash`` in rosbag2."""
    message_count: int


@dataclass(frozen=True)
class Bag:
    """A checked recording: its MCAP file, its topics by name, message count and log-time span [ns]
    (0, 0 without messages), and the ``custom_data`` and ``ros_distro`` of its rosbag2 metadata
    (empty if it has none)."""

    mcap_path: Path
    topics: dict[str, TopicInfo]
    message_count: int
    start_ns: int
    end_ns: int
    custom_data: dict[str, str]
    ros_distro: str


def mcap_file(path: Path) -> Path:
    """The MCAP file of a recording: ``path`` itself, or the one file of a bag directory."""
    path = Path(path)
    if not path.exists():
        raise BagReadError(f"{path}: no such file or directory")
    if path.is_file():
        return path
    names: list[str] = []
    metadata = path / "metadata.yaml"
    if metadata.is_file():
        try:
            information = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
            names = [str(name) for name in information["relative_file_paths"]]
        except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError) as error:
            raise BagReadError(f"{metadata}: not a rosbag2 metadata file ({error!r})") from None
    else:
        names = sorted(candidate.name for candidate in path.glob("*.mcap"))
    if not names:
        raise BagReadError(f"{path}: bag directory without an .mcap file")
    if len(names) > 1:
        raise BagReadError(f"{path}: split bags ({len(names)} files: {', '.join(names)}) are not supported")
    mcap_path = path / names[0]
    if not mcap_path.is_file():
        raise BagReadError(f"{path}: {names[0]} (listed in metadata.yaml) is missing")
    return mcap_path


def open_bag(path: Path) -> Bag:
    """Check the recording at ``path`` (module docstring) and return what its summary says."""
    mcap_path = mcap_file(path)
    try:
        stream = open(mcap_path, "rb")  # closed below; open errors are reported
    except OSError as error:
        raise BagReadError(f"{mcap_path}: cannot be read ({error.strerror})") from None
    with stream:
        check_magic(mcap_path, stream)
        _check_summary_crc(mcap_path, stream)
        try:
            reader = SeekingReader(stream)
            summary = reader.get_summary()
            rosbag2 = [record.metadata for record in reader.iter_metadata() if record.name == ROSBAG2_RECORD]
        except Exception as error:  # see _damaged
            raise BagReadError(f"{mcap_path}: the summary section is unreadable ({error!r})") from None
    if summary is None or summary.statistics is None:
        raise BagReadError(f"{mcap_path}: no summary statistics (the file was not finalised)")
    statistics = summary.statistics
    topics = {
        channel.topic: TopicInfo(
            topic=channel.topic,
            type_name=summary.schemas[channel.schema_id].name if channel.schema_id in summary.schemas else "",
            schema=summary.schemas.get(channel.schema_id),
            metadata=dict(channel.metadata),
            message_count=statistics.channel_message_counts.get(channel_id, 0),
        )
        for channel_id, channel in summary.channels.items()
    }
    information = bag_information(mcap_path, rosbag2[-1]) if rosbag2 else {}
    return Bag(
        mcap_path=mcap_path,
        topics=topics,
        message_count=statistics.message_count,
        start_ns=statistics.message_start_time,
        end_ns=statistics.message_end_time,
        custom_data=custom_data(information),
        ros_distro=str(information.get("ros_distro") or ""),
    )


def bag_information(mcap_path: Path, record: dict[str, str]) -> dict[str, Any]:
    """The bag information (metadata.yaml's ``rosbag2_bagfile_information``) of a rosbag2 record."""
    try:
        information = yaml.safe_load(record["serialized_metadata"])
    except (yaml.YAMLError, KeyError) as error:
        raise BagReadError(f"{mcap_path}: the rosbag2 metadata record is unreadable ({error!r})") from None
    if not isinstance(information, dict):
        raise BagReadError(f"{mcap_path}: the rosbag2 metadata record is not a mapping")
    return information


def custom_data(information: dict[str, Any]) -> dict[str, str]:
    """The ``custom_data`` mapping of bag information, as text (empty if it has none)."""
    mapping = information.get("custom_data") or {}
    if not isinstance(mapping, dict):
        return {}
    return {str(key): str(value) for key, value in mapping.items()}


def check_magic(path: Path, stream: BinaryIO) -> None:
    """BagReadError unless the stream starts and ends with the MCAP magic; leaves it at the start."""
    head = stream.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise BagReadError(f"{path}: not an MCAP file (it starts with {head!r}, not the MCAP magic)")
    stream.seek(0, 2)
    size = stream.tell()
    stream.seek(max(len(MCAP_MAGIC), size - len(MCAP_MAGIC)))
    tail = stream.read(len(MCAP_MAGIC))
    stream.seek(0)
    if tail != MCAP_MAGIC:
        raise BagReadError(
            f"{path}: truncated or not finalised: the MCAP footer and closing magic are missing "
            f"(the file ends after {size} bytes; tdslip recover makes it readable)"
        )


def _check_summary_crc(path: Path, stream: BinaryIO) -> None:
    """The footer's CRC over the summary section (and the footer's own fields), when it has one."""
    size = stream.seek(0, 2)
    footer_start = size - len(MCAP_MAGIC) - _FOOTER.size
    if footer_start < len(MCAP_MAGIC):
        raise BagReadError(f"{path}: too short for an MCAP file ({size} bytes)")
    stream.seek(footer_start)
    footer = stream.read(_FOOTER.size)
    opcode, _, summary_start, _, expected = _FOOTER.unpack(footer)
    in_file = summary_start == 0 or len(MCAP_MAGIC) <= summary_start <= footer_start
    if opcode != Opcode.FOOTER or not in_file:
        raise BagReadError(f"{path}: the MCAP footer is damaged")
    if expected != 0:
        stream.seek(summary_start or footer_start)
        summary = stream.read(footer_start - summary_start if summary_start else 0)
        if zlib.crc32(footer[:-4], zlib.crc32(summary)) != expected:
            raise BagReadError(f"{path}: the summary section is corrupt (its CRC does not match)")
    stream.seek(0)


@contextmanager
def _damage_reported(bag: Bag, count: list[int], stream: BinaryIO) -> Iterator[None]:
    try:
        yield
    except Exception as error:  # see _damaged
        raise BagReadError(
            f"{bag.mcap_path}: corrupt data after {count[0]} messages, near byte {stream.tell()}: "
            f"{type(error).__name__}: {error}"
        ) from None


def iter_messages(
    bag: Bag, topics: Collection[str] | None = None, log_time_order: bool = False
) -> Iterator[tuple[Channel, Message]]:
    """The messages of ``bag`` (of ``topics`` only, if given) with their channels, in file order or in
    log-time order; every chunk's CRC is checked. A full pass in file order also checks that the data
    section holds the messages the summary counts."""
    count = [0]
    with open(bag.mcap_path, "rb") as stream:
        if log_time_order:
            with _damage_reported(bag, count, stream):
                reader = SeekingReader(stream, validate_crcs=True)
                for _, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
                    count[0] += 1
                    yield channel, message
            return
        channels: dict[int, Channel] = {}
        records = StreamReader(stream, validate_crcs=True).records
        while True:
            with _damage_reported(bag, count, stream):
                record = next(records, None)
            if record is None:
                break
            if isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                defined = channels.get(record.channel_id)
                if defined is None:
                    raise BagReadError(
                        f"{bag.mcap_path}: message {count[0]} refers to channel {record.channel_id}, "
                        "which is not defined before it"
                    )
                count[0] += 1
                if topics is None or defined.topic in topics:
                    yield defined, record
    if count[0] != bag.message_count:
        raise BagReadError(
            f"{bag.mcap_path}: the data section holds {count[0]} messages, the summary counts "
            f"{bag.message_count}"
        )


def verify(bag: Bag) -> None:
    """Read every record of ``bag`` once with all checks (see iter_messages); BagReadError if one fails."""
    for _ in iter_messages(bag):
        pass


def topic_messages(bag: Bag, topics: Collection[str]) -> dict[str, tuple[list[bytes], list[int]]]:
    """The serialised messages of ``topics`` and their log times [ns], in file order, by topic: the
    batches of :func:`iter_topic_batches` joined."""
    found: dict[str, tuple[list[bytes], list[int]]] = {topic: ([], []) for topic in topics}
    for batch in iter_topic_batches(bag, topics):
        for topic, (datas, log_times) in batch.items():
            found[topic][0].extend(datas)
            found[topic][1].extend(log_times)
    return found


def iter_topic_batches(
    bag: Bag, topics: Collection[str]
) -> Iterator[dict[str, tuple[list[bytes], list[int]]]]:
    """The serialised messages of ``topics`` and their log times [ns], in file order, one chunk at a time
    (by topic): the fast path of a full read of a few topics, whose working set is one chunk. Each chunk of
    the summary's index that holds one of them is read, decompressed and its CRC checked (as
    :func:`iter_messages` does), then its records are walked with ``struct`` alone; at the end the message
    counts are checked against the summary's. Without a chunk index (an unchunked file) this is
    :func:`iter_messages`, in batches. Timed by bench/bench_measured.py: about 20 times faster than
    iter_messages."""
    with open(bag.mcap_path, "rb") as stream:
        try:
            summary = SeekingReader(stream).get_summary()
        except Exception as error:  # see _damaged
            raise BagReadError(f"{bag.mcap_path}: the summary section is unreadable ({error!r})") from None
        if summary is None or not summary.chunk_indexes:
            yield from _unchunked_batches(bag, topics)
            return
        names = {cid: c.topic for cid, c in summary.channels.items() if c.topic in topics}
        counts = dict.fromkeys(names, 0)
        for index in sorted(summary.chunk_indexes, key=lambda chunk: chunk.chunk_start_offset):
            if not names.keys() & index.message_index_offsets.keys():
                continue
            stream.seek(index.chunk_start_offset)
            record = stream.read(index.chunk_length)
            try:
                opcode, length = _RECORD.unpack_from(record)
                if opcode != Opcode.CHUNK:
                    raise ValueError(f"opcode {opcode:#x} where the index places a chunk")
                chunk = Chunk.read(ReadDataStream(io.BytesIO(record[_RECORD.size : _RECORD.size + length])))
                data = get_chunk_data_stream(chunk, validate_crc=True)[0].read(chunk.uncompressed_size)
            except Exception as error:  # see _damaged
                raise BagReadError(
                    f"{bag.mcap_path}: the chunk at byte {index.chunk_start_offset} is corrupt: "
                    f"{type(error).__name__}: {error}"
                ) from None
            wanted: dict[int, tuple[list[bytes], list[int]]] = {cid: ([], []) for cid in names}
            _collect(data, wanted, bag.mcap_path, index.chunk_start_offset)
            for cid, (datas, _) in wanted.items():
                counts[cid] += len(datas)
            yield {names[cid]: found for cid, found in wanted.items() if found[0]}
    for cid, count in counts.items():
        expected = summary.statistics.channel_message_counts.get(cid, 0) if summary.statistics else count
        if count != expected:
            raise BagReadError(
                f"{bag.mcap_path}: {names[cid]}: the chunks hold {count} messages, "
                f"the summary counts {expected}"
            )


def _unchunked_batches(
    bag: Bag, topics: Collection[str]
) -> Iterator[dict[str, tuple[list[bytes], list[int]]]]:
    """:func:`iter_messages` of ``topics``, in batches of at most _UNCHUNKED_BATCH messages by topic."""
    batch: dict[str, tuple[list[bytes], list[int]]] = {}
    held = 0
    for channel, message in iter_messages(bag, topics):
        datas, log_times = batch.setdefault(channel.topic, ([], []))
        datas.append(message.data)
        log_times.append(message.log_time)
        held += 1
        if held == _UNCHUNKED_BATCH:
            yield batch
            batch, held = {}, 0
    if batch:
        yield batch


def _collect(data: bytes, wanted: dict[int, tuple[list[bytes], list[int]]], path: Path, where: int) -> None:
    """Append the messages of ``wanted`` channels among the records of a decompressed chunk."""
    offset, end, message = 0, len(data), int(Opcode.MESSAGE)
    while offset < end:
        if offset + _RECORD.size > end:
            raise BagReadError(f"{path}: the chunk at byte {where} ends inside a record")
        opcode, length = _RECORD.unpack_from(data, offset)
        body = offset + _RECORD.size
        offset = body + length
        if opcode != message:
            continue
        channel, _, log_time = _MESSAGE.unpack_from(data, body)
        into = wanted.get(channel)
        if into is not None:
            into[0].append(data[body + _MESSAGE_HEADER : offset])
            into[1].append(log_time)
    if offset != end:
        raise BagReadError(f"{path}: the chunk at byte {where} ends inside a record")
