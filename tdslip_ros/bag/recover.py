"""Make a truncated or unfinalised recording readable again, like ``ros2 bag reindex`` (what
``tdslip recover RUN`` does).

A recorder killed hard (SIGKILL, a crash, a full disk) leaves an MCAP file without summary and
footer, maybe with a half-written chunk at its end, and no ``metadata.yaml``: readers refuse it.
The file is scanned record by record from the start. Everything that can be read is kept: every
schema and channel (topic, type, stored definition, offered QoS, type hash; the writer puts them
outside the chunks as soon as a topic is added, so they survive whatever chunk is lost), the
``custom_data`` and ``ros_distro`` of the last readable ``rosbag2`` metadata record (the writer
puts one at the start), and every message of every chunk whose CRC checks out. A chunk that is
damaged (CRC or decompression) is skipped and the scan goes on; it ends at the end of the data
section or at the first record that is cut off or unreadable (nothing after it can be framed).

The result is a finalised bag (:class:`~tdslip_ros.bag.writer.RosbagMcapWriter`: summary, indexes,
closing rosbag2 record; ``metadata.yaml`` for a bag directory) **in place of the original, which is
kept beside it** as ``<file>.mcap.orig`` (and ``metadata.yaml.orig``), so that ``tdslip analyze
RUN`` and ``tdslip replay RUN`` read the recovered bag under its old name. The new file is written
completely (in a hidden directory beside the original) before anything is renamed; a recording
that already has a ``.orig`` is refused, so nothing is ever overwritten. A recording that is
finalised and intact is left alone. The writer's reserve file left behind by a crash is deleted.

The :class:`Recovery` says how much was lost: messages recovered per topic (and, when the original
states how many it held, how many are missing), the bytes discarded and why (:class:`Scan`), and the log
time of the last recovered message.
"""

from __future__ import annotations

import io
import os
import shutil
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from tdslip_ros.bag.qos import parse_qos_profiles
from tdslip_ros.bag.reader import (
    MCAP_MAGIC,
    ROSBAG2_RECORD,
    BagReadError,
    bag_information,
    custom_data,
    mcap_file,
    open_bag,
    verify,
)
from tdslip_ros.bag.schema import MessageDefinitionError
from tdslip_ros.bag.writer import (
    DEFAULT_CHUNK_SIZE,
    Compression,
    RosbagMcapWriter,
    reserve_path,
    write_metadata_yaml,
)

ORIGINAL_SUFFIX = ".orig"
WORK_DIRECTORY = ".tdslip-recover"
"""Hidden directory beside the original in which the recovered file is written before it takes
the original's place."""
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, record length
_COMPRESSIONS: dict[str, Compression] = {"": "none", "lz4": "lz4", "zstd": "zstd"}
_DATA_RECORDS = (Schema, Channel, Message, Metadata)
DataRecord = Schema | Channel | Message | Metadata


class RecoverError(Exception):
    """The recording cannot be recovered; the message says why."""


class RecoverInputError(RecoverError):
    """What was given is no recording to recover (or was recovered before): nothing was touched."""


@dataclass
class Scan:
    """What a record-by-record pass over an MCAP file found (see the module docstring)."""

    path: Path
    size: int
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    information: dict[str, Any] = field(default_factory=dict)
    """The bag information of the last readable rosbag2 metadata record."""
    counts: dict[int, int] = field(default_factory=dict)
    """Messages per channel id."""
    orphans: int = 0
    """Messages of channels that are not defined (lost with a damaged chunk), which cannot be kept."""
    compression: str = ""
    first_log_time: int | None = None
    last_log_time: int | None = None
    damaged_chunks: list[tuple[int, int, str]] = field(default_factory=list)
    """(offset, bytes, reason) of each chunk skipped."""
    end: int = 0
    """Offset at which the scan stopped."""
    complete: bool = False
    """The scan reached the end of the data section (DataEnd or Footer)."""
    stop_reason: str = ""

    @property
    def discarded_bytes(self) -> int:
        """Bytes of messages and definitions not carried over: skipped chunks and the unreadable tail."""
        tail = 0 if self.complete else self.size - self.end
        return tail + sum(length for _, length, _ in self.damaged_chunks)


def scan_records(stream: BinaryIO, scan: Scan) -> Iterator[DataRecord]:
    """The definitions, messages and metadata records of an MCAP file in file order, from every
    readable record (module docstring); ``scan`` is filled in on the way."""
    position = len(MCAP_MAGIC)
    while position < scan.size:
        scan.end = position
        stream.seek(position)
        head = stream.read(_RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size:
            scan.stop_reason = f"a record header is cut off at byte {position}"
            return
        opcode, length = _RECORD_HEAD.unpack(head)
        name = _record_name(opcode)
        if length > scan.size - position - _RECORD_HEAD.size:
            scan.stop_reason = f"a {name} record is cut off at byte {position}"
            return
        try:
            record = _read(opcode, stream.read(length), length)
            records = breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]
        except Exception as error:  # see bag.reader's _damaged
            if opcode != Opcode.CHUNK:
                scan.stop_reason = f"an unreadable {name} record at byte {position} ({error!r})"
                return
            scan.damaged_chunks.append(
                (position, _RECORD_HEAD.size + length, f"{type(error).__name__}: {error}")
            )
            records = []
        if isinstance(record, Chunk) and records:
            scan.compression = record.compression
        for item in records:
            if isinstance(item, _DATA_RECORDS):
                yield _noted(scan, item)
        position += _RECORD_HEAD.size + length
        if opcode in (Opcode.DATA_END, Opcode.FOOTER):
            scan.complete, scan.end = True, position
            return
    scan.end = position
    scan.stop_reason = "the file ends without a data end record"


def _record_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"opcode {opcode:#x}"


def _read(opcode: int, body: bytes, length: int) -> Any:
    """One record from its body; None for the kinds recovery does not need (indexes, summary)."""
    if opcode == 0 or (0x10 <= opcode < 0x80):  # neither an MCAP record nor a user-defined one
        raise ValueError(f"no record has opcode {opcode:#x}")
    stream = ReadDataStream(io.BytesIO(body))
    readers: dict[int, Callable[[], Any]] = {
        Opcode.HEADER: lambda: Header.read(stream),
        Opcode.SCHEMA: lambda: Schema.read(stream),
        Opcode.CHANNEL: lambda: Channel.read(stream),
        Opcode.MESSAGE: lambda: Message.read(stream, length),
        Opcode.CHUNK: lambda: Chunk.read(stream),
        Opcode.METADATA: lambda: Metadata.read(stream),
    }
    reader = readers.get(opcode)
    return None if reader is None else reader()


def _noted(scan: Scan, record: DataRecord) -> DataRecord:
    if isinstance(record, Schema):
        scan.schemas[record.id] = record
    elif isinstance(record, Channel):
        scan.channels[record.id] = record
    elif isinstance(record, Metadata) and record.name == ROSBAG2_RECORD:
        try:
            scan.information = bag_information(scan.path, record.metadata)
        except BagReadError:
            pass  # an unreadable record is skipped; an earlier one stays
    elif isinstance(record, Message):
        if record.channel_id not in scan.channels:
            scan.orphans += 1
        else:
            scan.counts[record.channel_id] = scan.counts.get(record.channel_id, 0) + 1
            first, last = scan.first_log_time, scan.last_log_time
            scan.first_log_time = record.log_time if first is None else min(first, record.log_time)
            scan.last_log_time = record.log_time if last is None else max(last, record.log_time)
    return record


@dataclass(frozen=True)
class Recovery:
    """The result of :func:`recover`."""

    mcap_path: Path
    original: Path | None
    """Where the original file was kept; None if it was intact and left alone."""
    recovered: dict[str, int]
    """Messages per topic in the recovered bag."""
    expected: dict[str, int]
    """Messages per topic the original's closing metadata states (empty if it has none)."""
    scan: Scan
    notes: tuple[str, ...] = ()

    @property
    def lost(self) -> dict[str, int]:
        """Messages missing per topic, where the original states its counts."""
        return {
            topic: count - self.recovered.get(topic, 0)
            for topic, count in self.expected.items()
            if count > self.recovered.get(topic, 0)
        }


def recover(path: Path) -> Recovery:
    """Recover the recording at ``path`` (module docstring); RecoverError if it cannot be."""
    try:
        mcap_path = mcap_file(path)
        if _intact(mcap_path):
            return Recovery(
                mcap_path, None, _intact_counts(mcap_path), {}, Scan(mcap_path, mcap_path.stat().st_size)
            )
    except BagReadError as error:
        raise RecoverInputError(str(error)) from None
    original = mcap_path.with_name(mcap_path.name + ORIGINAL_SUFFIX)
    metadata = (
        mcap_path.parent / "metadata.yaml" if (Path(path).is_dir() or _has_metadata(mcap_path)) else None
    )
    for kept in (original, None if metadata is None else metadata.with_name(metadata.name + ORIGINAL_SUFFIX)):
        if kept is not None and kept.exists():
            raise RecoverInputError(
                f"{kept} exists: the recording was recovered before; move it away to recover again"
            )
    work = mcap_path.parent / WORK_DIRECTORY
    shutil.rmtree(work, ignore_errors=True)  # left by a recovery that was interrupted
    try:
        work.mkdir()
        recovery, information = _copy(mcap_path, work / mcap_path.name)
        os.replace(mcap_path, original)
        try:
            os.replace(work / mcap_path.name, mcap_path)
        except OSError:
            os.replace(original, mcap_path)
            raise
    except OSError as error:
        raise RecoverError(
            f"{mcap_path}: cannot write the recovered bag: {error.strerror or error}"
        ) from None
    finally:
        shutil.rmtree(work, ignore_errors=True)
    reserve_path(mcap_path).unlink(missing_ok=True)
    notes = recovery.notes
    if metadata is not None:
        try:
            if metadata.exists():
                os.replace(metadata, metadata.with_name(metadata.name + ORIGINAL_SUFFIX))
            write_metadata_yaml(metadata, information)
        except OSError as error:
            notes += (f"{metadata} could not be written ({error.strerror}); tdslip analyze needs none",)
    return Recovery(mcap_path, original, recovery.recovered, recovery.expected, recovery.scan, notes)


def recoverable_counts(path: Path) -> dict[str, int]:
    """Messages per topic that :func:`recover` keeps from the recording at ``path`` (a bag directory or
    MCAP file), found by its first pass alone: nothing is written."""
    try:
        scan = _scan(mcap_file(path))
    except BagReadError as error:
        raise RecoverInputError(str(error)) from None
    return {channel.topic: scan.counts.get(channel_id, 0) for channel_id, channel in scan.channels.items()}


def _scan(source: Path) -> Scan:
    """A record-by-record pass over ``source``: definitions, metadata, messages per channel, damage."""
    with open(source, "rb") as stream:
        if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise RecoverInputError(f"{source}: not an MCAP file (no MCAP magic at its start)")
        scan = Scan(source, source.stat().st_size)
        for _ in scan_records(stream, scan):
            pass
    return scan


def _intact(mcap_path: Path) -> bool:
    try:
        verify(open_bag(mcap_path))
    except BagReadError:
        return False
    return True


def _intact_counts(mcap_path: Path) -> dict[str, int]:
    return {topic: info.message_count for topic, info in open_bag(mcap_path).topics.items()}


def _has_metadata(mcap_path: Path) -> bool:
    return (mcap_path.parent / "metadata.yaml").is_file()


def _copy(source: Path, target: Path) -> tuple[Recovery, dict[str, Any]]:
    """Scan ``source`` (first pass: definitions, metadata, damage), then copy what is readable into a
    finalised bag at ``target`` (second pass); the recovery and the bag information written."""
    scan = _scan(source)
    with open(source, "rb") as stream:
        information = scan.information
        notes: list[str] = []
        with RosbagMcapWriter(
            target,
            bag_directory=False,
            compression=_COMPRESSIONS.get(scan.compression, "zstd"),
            chunk_size=DEFAULT_CHUNK_SIZE,
            ros_distro=str(information.get("ros_distro") or "") or None,
            custom_data=custom_data(information),
        ) as bag:
            writable = _add_topics(bag, scan, notes)
            copy = Scan(source, scan.size)
            for record in scan_records(stream, copy):
                if isinstance(record, Message) and record.channel_id in writable:
                    topic = writable[record.channel_id]
                    bag.write(topic, record.data, record.log_time, record.publish_time, record.sequence)
        written = bag.bag_metadata()
    recovered = {
        entry["topic_metadata"]["name"]: entry["message_count"]
        for entry in written["topics_with_message_count"]
    }
    return Recovery(target, None, recovered, _stated_counts(source, information), scan, tuple(notes)), written


def _add_topics(bag: RosbagMcapWriter, scan: Scan, notes: list[str]) -> dict[int, str]:
    """Add every recovered channel with its stored schema, QoS and type hash; the topics by channel id."""
    writable: dict[int, str] = {}
    for channel_id, channel in sorted(scan.channels.items()):
        schema = scan.schemas.get(channel.schema_id)
        if schema is None:
            notes.append(
                f"{channel.topic}: its schema was lost; its {scan.counts.get(channel_id, 0)} messages "
                "are not kept"
            )
            continue
        try:
            profiles = parse_qos_profiles(channel.metadata.get("offered_qos_profiles", "[]"))
        except ValueError as error:
            notes.append(f"{channel.topic}: offered QoS unreadable ({error}); recorded without")
            profiles = ()
        try:
            bag.add_topic(
                channel.topic,
                schema.name,
                offered_qos=profiles,
                type_hash=channel.metadata.get("topic_type_hash", ""),
                schema=schema,
            )
        except (ValueError, MessageDefinitionError) as error:
            notes.append(f"{channel.topic}: not kept ({error})")
            continue
        writable[channel_id] = channel.topic
    return writable


def _stated_counts(source: Path, information: dict[str, Any]) -> dict[str, int]:
    """Messages per topic that the original says it held: its closing rosbag2 record, else the
    metadata.yaml beside it (a bag that was finalised, then damaged); empty if neither says."""
    candidates = [information]
    metadata = source.parent / "metadata.yaml"
    if metadata.is_file():
        try:
            candidates.append(yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"])
        except (OSError, yaml.YAMLError, KeyError, TypeError):
            pass  # no statement from it
    for candidate in candidates:
        try:
            counts = {
                str(entry["topic_metadata"]["name"]): int(entry["message_count"])
                for entry in candidate.get("topics_with_message_count") or []
            }
        except (KeyError, TypeError, ValueError, AttributeError):
            continue
        if sum(counts.values()):
            return counts
    return {}
