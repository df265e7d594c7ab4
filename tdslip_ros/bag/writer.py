"""A rosbag2-compatible MCAP writer for already-serialized (CDR) ROS 2 messages.

The file follows what rosbag2's MCAP storage plugin (``rosbag2_storage_mcap``, Kilted) writes:

* header profile ``ros2``;
* one schema per message type: name ``pkg/msg/Type``, encoding ``ros2msg``, data = the full
  definition text (:func:`tdslip_ros.bag.schema.message_definition`);
* one channel per topic: message encoding ``cdr``, metadata ``offered_qos_profiles`` (YAML string,
  metadata version 9 policy names) and ``topic_type_hash`` (RIHS01);
* messages with ``log_time`` (receive time) and ``publish_time`` in ns and a sequence number;
* chunked, compressed (``zstd`` by default, ``lz4`` or none) and fully indexed;
* a metadata record named ``rosbag2`` with the single key ``serialized_metadata`` (the bag
  information as YAML, ``ros_distro`` and ``custom_data`` inside, as rosbag2 >= Jazzy writes it),
  written when the bag is opened and again, complete, at close (rosbag2 does the same; its reader
  and :mod:`tdslip_ros.bag.reader` take the last one), and, for a bag directory, ``metadata.yaml``
  beside ``<dir>_0.mcap`` at close.

Durability. The file is written through without a user-space buffer: every chunk reaches the
kernel the moment it is complete, so a hard kill (SIGKILL, crash) loses only the open chunk
(at most ``chunk_size`` bytes, or ``flush_interval`` of log time when one is given; :meth:`flush`
writes it out now). Such an unfinalised file has no summary or footer, and no metadata.yaml:
``mcap.reader.make_reader`` and ``rosbags`` reject it, while a sequential scan returns every record
up to the cut. So that everything but the lost messages survives, schemas and channels are also
written outside the chunks the moment a topic is added, and the opening ``rosbag2`` record carries
the ``custom_data``; ``tdslip recover`` (:mod:`tdslip_ros.bag.recover`) turns such a file into a
finalised bag.

Write errors. A small file is preallocated beside the bag (``<file>.reserve``: two chunks and room
for the summary, or half of what is free where that is less: :func:`reserve_size`). When a write
fails (ENOSPC, EIO), the partial write is cut off, the reserve is released and the write tried once
more; if that works, the bag is finalised at once with everything written so far and
:class:`BagWriteError` (one line) says so; if not, the file is left ending with a whole record, for
``tdslip recover``, and the error says that instead. Either way the bag is closed: later writes
raise :class:`BagClosedError`. A limit on the size of one file (``RLIMIT_FSIZE``, ``ulimit -f``) is
met the same way: the last reserve's worth of bytes below it is kept for finalising, so the write
that reaches into it is the last, and the bag is finalised with everything given to it (EFBIG).

Threads and signals. All methods are serialized by one re-entrant lock. :meth:`close` may be called
from another thread (it waits for a write in progress) or from a signal handler: if the handler
interrupted a write on the same thread, the close is completed as soon as that write returns, so
the handler itself must not raise. Writing after close raises :class:`BagClosedError`.
"""

from __future__ import annotations

import errno
import os
import resource
import threading
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Literal, cast

from mcap.data_stream import RecordBuilder
from mcap.records import Channel, McapRecord, Schema
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from tdslip_ros.bag.qos import OfferedQos, dump_yaml, qos_profiles_yaml
from tdslip_ros.bag.reader import ROSBAG2_RECORD
from tdslip_ros.bag.schema import canonical_type_name, message_definition, type_description_hash

Compression = Literal["none", "lz4", "zstd"]

# The mcap C++ library's default chunk size, which rosbag2's MCAP plugin uses unless configured.
DEFAULT_CHUNK_SIZE = 768 * 1024
METADATA_VERSION = 9
STORAGE_IDENTIFIER = "mcap"
DEFAULT_ROS_DISTRO = "kilted"
LIBRARY = f"tdslip_ros.bag; {LIBRARY_IDENTIFIER}"
MCAP_COMPRESSION = {"none": CompressionType.NONE, "lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD}
SUMMARY_RESERVE = 512 * 1024
"""Bytes of the reserve kept for the summary, the closing rosbag2 record and metadata.yaml (about
3000 chunks' indexes on top of the definitions); the reserve adds two chunks to it."""
RESERVE_SUFFIX = ".reserve"
_UINT64_MAX = 2**64 - 1
_UINT32_MAX = 2**32 - 1


class BagClosedError(RuntimeError):
    """A message or topic was given to a writer that is already closed."""


class BagWriteError(OSError):
    """Writing the bag failed (disk full, I/O error): recording stopped. The message (one line) says
    why, and whether the bag was finalised with everything written before (``finalised``) or is left
    for ``tdslip recover``. ``errno`` is that of the first failed write."""

    def __init__(self, errno: int | None, message: str, finalised: bool) -> None:
        super().__init__(errno, message)
        self.message = message
        self.finalised = finalised

    def __str__(self) -> str:
        return self.message


def reserve_path(mcap_path: Path) -> Path:
    """The reserve file the writer keeps beside ``mcap_path`` while it is open."""
    return mcap_path.with_name(mcap_path.name + RESERVE_SUFFIX)


def file_size_limit() -> int | None:
    """The largest file this process may write (``RLIMIT_FSIZE``, soft), or None if unlimited."""
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return None if limit == resource.RLIM_INFINITY else limit


def reserve_size(directory: Path, chunk_size: int) -> int:
    """The default reserve of a bag written into ``directory``: two chunks and SUMMARY_RESERVE, but
    at most half of the space free there and half of the file-size limit, so that on a nearly full
    disk the first strides are written instead of the reserve taking all the room."""
    free = os.statvfs(directory)
    room = [2 * chunk_size + SUMMARY_RESERVE, free.f_bavail * free.f_frsize // 2]
    limit = file_size_limit()
    if limit is not None:
        room.append(limit // 2)
    return min(room)


class _WriteThroughFile:
    """Minimal binary sink for ``mcap.writer.Writer`` that hands every write straight to the kernel.

    The mcap writer only writes whole records (a finished chunk, its message indexes, the summary),
    so unbuffered writes cost a few system calls per chunk and nothing per message. A failed write
    is cut off (the file keeps ending with a whole record), the reserve released and the write
    tried once more; ``error`` keeps the first failure even when the retry worked. Under a file-size
    limit, the last ``reserve`` bytes below it play the reserve file's part: the write that reaches
    into them succeeds and sets ``error`` (EFBIG), which finalises the bag.
    """

    def __init__(self, path: Path, reserve: int) -> None:
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self._position = 0
        self.error: OSError | None = None
        limit = file_size_limit()
        self._headroom_from = None if limit is None else limit - reserve
        self._reserve: Path | None = reserve_path(path) if reserve > 0 else None
        if self._reserve is not None:
            try:
                _preallocate(self._reserve, reserve)
            except OSError as error:
                self.close()
                path.unlink()
                raise BagWriteError(
                    error.errno, f"{path}: no room for the bag's {reserve} B reserve: {error.strerror}", False
                ) from None

    def write(self, data: bytes | bytearray | memoryview) -> int:
        start = self._position
        if self.error is None and self._headroom_from is not None and start + len(data) > self._headroom_from:
            self.error = OSError(
                errno.EFBIG, "the bag reached the file-size limit (RLIMIT_FSIZE) less its reserve"
            )
        while True:
            try:
                self._write_at(start, data)
                break
            except OSError as error:
                self.error = self.error or error
                os.ftruncate(self._fd, start)  # the file keeps ending with a whole record
                if not self.release_reserve():
                    raise
        self._position = start + len(data)
        return len(data)

    def _write_at(self, offset: int, data: bytes | bytearray | memoryview) -> None:
        view = memoryview(data)
        while view:
            written = os.pwrite(self._fd, view, offset)
            view, offset = view[written:], offset + written

    def release_reserve(self) -> bool:
        """Delete the reserve file (False if there is none left to free)."""
        if self._reserve is None:
            return False
        self._reserve.unlink(missing_ok=True)
        self._reserve = None
        return True

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        """Nothing is buffered here."""

    def close(self) -> None:
        """Sync and close the file and release the reserve (both even if the sync fails). Idempotent."""
        if self._fd < 0:
            return
        try:
            os.fsync(self._fd)
        finally:
            os.close(self._fd)
            self._fd = -1
            self.release_reserve()


def write_metadata_yaml(path: Path, information: Mapping[str, Any]) -> None:
    """Write rosbag2's ``metadata.yaml`` for the bag ``information`` (RosbagMcapWriter.bag_metadata)
    atomically: a reader finds the old file or the new one, never half of one."""
    staging = path.with_suffix(".yaml.tmp")
    try:
        staging.write_text(dump_yaml({"rosbag2_bagfile_information": dict(information)}) + "\n")
    except OSError:
        staging.unlink(missing_ok=True)
        raise
    os.replace(staging, path)


def _preallocate(path: Path, size: int) -> None:
    """Create ``path`` with ``size`` bytes of disk space allocated to it."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        os.posix_fallocate(fd, 0, size)
    except OSError:
        os.close(fd)
        path.unlink(missing_ok=True)
        raise
    os.close(fd)


def _record_bytes(*records: McapRecord) -> bytes:
    builder = RecordBuilder()
    for record in records:
        record.write(builder)
    return bytes(builder.end())  # type: ignore[no-untyped-call]


@dataclass
class _Topic:
    name: str
    type_name: str
    channel_id: int
    offered_qos: tuple[OfferedQos, ...]
    type_hash: str
    message_count: int = 0


class RosbagMcapWriter:
    """Write raw CDR messages into a rosbag2-compatible MCAP file or bag directory.

    ``path`` is the bag directory to create (``bag_directory=True``, rosbag2's layout:
    ``path/metadata.yaml`` and ``path/<path.name>_0.mcap``) or the ``.mcap`` file to create. Neither
    may exist already. ``ros_distro`` defaults to ``$ROS_DISTRO``, else ``kilted``; ``custom_data``
    goes into the bag metadata's ``custom_data`` mapping. ``flush_interval_ns`` (0: none) closes the
    open chunk once its messages span that much log time, which bounds in time what a hard kill
    loses. ``reserve`` is the size of the reserve file (default: :func:`reserve_size`; 0: none);
    BagWriteError if it cannot be allocated.
    """

    def __init__(
        self,
        path: Path,
        *,
        compression: Compression = "zstd",
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        bag_directory: bool = True,
        ros_distro: str | None = None,
        custom_data: Mapping[str, str] | None = None,
        flush_interval_ns: int = 0,
        reserve: int | None = None,
    ) -> None:
        if compression not in MCAP_COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(MCAP_COMPRESSION)}, not {compression!r}")
        if chunk_size <= 0:
            raise ValueError(f"chunk_size must be positive, not {chunk_size}")
        if flush_interval_ns < 0:
            raise ValueError(f"flush_interval_ns must be 0 (none) or positive, not {flush_interval_ns}")
        path = Path(path)
        if bag_directory:
            path.mkdir(parents=True, exist_ok=False)
            self.mcap_path = path / f"{path.name}_0.mcap"
            self.metadata_path: Path | None = path / "metadata.yaml"
        else:
            self.mcap_path = path
            self.metadata_path = None
        self._ros_distro = ros_distro or os.environ.get("ROS_DISTRO") or DEFAULT_ROS_DISTRO
        self._custom_data = dict(custom_data) if custom_data else None
        self._flush_interval_ns = flush_interval_ns
        self._chunk_opened_ns: int | None = None  # log time of the first message of the open chunk
        self._lock = threading.RLock()
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[str, int] = {}
        self._start_ns: int | None = None
        self._end_ns = 0
        self._busy = False
        self._close_requested = False
        self._closed = False
        self._finished = False  # the MCAP file is finalised and closed
        self._metadata_written = False
        self._file = _WriteThroughFile(
            self.mcap_path, reserve_size(self.mcap_path.parent, chunk_size) if reserve is None else reserve
        )
        self._mcap = Writer(
            cast(IO[Any], self._file), chunk_size=chunk_size, compression=MCAP_COMPRESSION[compression]
        )
        with self._exclusive():
            self._mcap.start(profile="ros2", library=LIBRARY)
            # rosbag2 writes its record when it opens a bag, too: the custom_data survives a crash.
            self._mcap.add_metadata(ROSBAG2_RECORD, {"serialized_metadata": dump_yaml(self.bag_metadata())})

    # -- topics and messages -------------------------------------------------------------------

    def add_topic(
        self,
        topic: str,
        type_name: str,
        *,
        offered_qos: Iterable[OfferedQos] = (),
        type_hash: str | None = None,
        schema: Schema | None = None,
    ) -> int:
        """Register ``topic`` of message type ``type_name`` and return its MCAP channel id.

        The schema text and, unless ``type_hash`` is given (e.g. the ``topic_type_hash`` that rclpy's
        graph API reports), the RIHS01 hash are read from the installed interface files, unless
        ``schema`` gives the stored schema to keep (a copied recording). Adding the same topic again
        with the same type returns the existing channel id.
        """
        canonical = canonical_type_name(type_name)
        # Look everything up first, so that a missing interface file registers nothing.
        if schema is None:
            encoding, definition = "ros2msg", message_definition(canonical).encode("utf-8")
        else:
            encoding, definition = schema.encoding, schema.data
        resolved_hash = type_hash if type_hash is not None else type_description_hash(canonical)
        profiles = tuple(offered_qos)
        with self._exclusive():
            existing = self._topics.get(topic)
            if existing is not None:
                if existing.type_name != canonical:
                    raise ValueError(f"topic {topic!r} is already recorded as {existing.type_name}")
                return existing.channel_id
            records: list[McapRecord] = []
            schema_id = self._schema_ids.get(canonical)
            if schema_id is None:
                schema_id = self._mcap.register_schema(canonical, encoding, definition)
                self._schema_ids[canonical] = schema_id
                records.append(Schema(id=schema_id, name=canonical, encoding=encoding, data=definition))
            metadata = {"offered_qos_profiles": qos_profiles_yaml(profiles), "topic_type_hash": resolved_hash}
            channel_id = self._mcap.register_channel(topic, "cdr", schema_id, metadata)
            records.append(
                Channel(
                    id=channel_id, topic=topic, message_encoding="cdr", schema_id=schema_id, metadata=metadata
                )
            )
            # The mcap writer puts these into the open chunk; written now, outside it, they survive a
            # crash that loses that chunk (MCAP allows repeating identical definitions).
            self._file.write(_record_bytes(*records))
            self._topics[topic] = _Topic(topic, canonical, channel_id, profiles, resolved_hash)
            return channel_id

    def write(
        self,
        topic: str,
        data: bytes,
        log_time_ns: int,
        publish_time_ns: int | None = None,
        sequence: int | None = None,
    ) -> None:
        """Append one serialized message. ``publish_time_ns`` defaults to ``log_time_ns`` and
        ``sequence`` to the topic's running message number (1, 2, ...). BagWriteError if the disk
        refuses it (see the module docstring)."""
        with self._exclusive():
            entry = self._topics.get(topic)
            if entry is None:
                raise KeyError(f"topic {topic!r} was not added; call add_topic first")
            count = entry.message_count + 1
            publish_time = log_time_ns if publish_time_ns is None else publish_time_ns
            number = count if sequence is None else sequence
            # Checked here because the mcap writer would fail half-way through packing the record.
            if not (0 <= log_time_ns <= _UINT64_MAX and 0 <= publish_time <= _UINT64_MAX):
                raise ValueError(
                    f"{topic}: times must be in [0, 2**64) ns, got {log_time_ns}, {publish_time}"
                )
            if not 0 <= number <= _UINT32_MAX:
                raise ValueError(f"{topic}: sequence must be in [0, 2**32), got {number}")
            written = self._file.tell()
            self._mcap.add_message(entry.channel_id, log_time_ns, data, publish_time, number)
            entry.message_count = count
            if self._start_ns is None or log_time_ns < self._start_ns:
                self._start_ns = log_time_ns
            if log_time_ns > self._end_ns:
                self._end_ns = log_time_ns
            if self._file.tell() != written:  # this message completed a chunk
                self._chunk_opened_ns = None
            elif self._chunk_opened_ns is None:
                self._chunk_opened_ns = log_time_ns
            elif self._flush_interval_ns and log_time_ns - self._chunk_opened_ns >= self._flush_interval_ns:
                self._mcap.flush()  # type: ignore[no-untyped-call]
                self._chunk_opened_ns = None

    def flush(self) -> None:
        """Write out the chunk in progress now, so that a hard kill cannot lose it."""
        with self._exclusive():
            self._mcap.flush()  # type: ignore[no-untyped-call]
            self._chunk_opened_ns = None

    @contextmanager
    def _exclusive(self) -> Iterator[None]:
        """Hold the lock for one operation on the open file; stop on a write error (see
        _write_failed); run a close requested meanwhile."""
        with self._lock:
            # Busy before the closed check: a signal handler's close() landing in between then
            # either finalises first (and we raise) or is deferred (and we finish first).
            self._busy = True
            try:
                if self._closed:
                    raise BagClosedError(f"{self.mcap_path} is closed")
                try:
                    yield
                except BagWriteError:
                    raise
                except OSError as error:  # a write failed for good, even with the reserve freed
                    raise self._write_failed(error, finalise=False) from None
                if self._file.error is not None:  # a write failed, and worked with the reserve freed
                    raise self._write_failed(self._file.error, finalise=True)
            finally:
                self._busy = False
                if self._close_requested:
                    self._finalize()

    def _write_failed(self, error: OSError, finalise: bool) -> BagWriteError:
        """Close the bag after a write error: finalised with what was written if ``finalise`` and that
        works, else left as it is (ending with a whole record); the error to raise."""
        if finalise:
            try:
                self._finalize()
            except OSError:
                pass  # reported below from the state the bag is left in
        if not self._finished:
            self._abandon()
        count = sum(entry.message_count for entry in self._topics.values())
        if not self._finished:
            state = f"not finalised: tdslip recover {self.mcap_path} makes its complete chunks readable"
        elif self.metadata_path is not None and not self._metadata_written:
            state = f"finalised with {count} messages, but without metadata.yaml (tdslip analyze needs none)"
        else:
            state = f"finalised with all {count} messages given to it"
        first = self._file.error or error
        return BagWriteError(
            first.errno,
            f"{self.mcap_path}: {first.strerror or first}; recording stopped, the bag is {state}",
            self._finished,
        )

    def _abandon(self) -> None:
        """Give up on the file without finalising it (after a write error that the reserve did not
        absorb): release the reserve and close the file, ignoring further errors."""
        self._closed = True
        self._close_requested = False
        try:
            self._file.close()
        except OSError:
            pass  # the file stays as it is; the error that got here is the one reported

    # -- state ---------------------------------------------------------------------------------

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def message_counts(self) -> dict[str, int]:
        """Messages written so far, per topic (every added topic is present)."""
        with self._lock:
            return {name: entry.message_count for name, entry in self._topics.items()}

    def bag_metadata(self) -> dict[str, Any]:
        """The ``rosbag2_bagfile_information`` mapping for what has been written so far."""
        with self._lock:
            start = 0 if self._start_ns is None else self._start_ns
            duration = 0 if self._start_ns is None else self._end_ns - self._start_ns
            count = sum(entry.message_count for entry in self._topics.values())
            file_name = self.mcap_path.name
            return {
                "version": METADATA_VERSION,
                "storage_identifier": STORAGE_IDENTIFIER,
                "duration": {"nanoseconds": duration},
                "starting_time": {"nanoseconds_since_epoch": start},
                "message_count": count,
                "topics_with_message_count": [
                    {
                        "topic_metadata": {
                            "name": entry.name,
                            "type": entry.type_name,
                            "serialization_format": "cdr",
                            "offered_qos_profiles": [qos.to_yaml_mapping() for qos in entry.offered_qos],
                            "type_description_hash": entry.type_hash,
                        },
                        "message_count": entry.message_count,
                    }
                    for entry in self._topics.values()
                ],
                # Chunk compression is internal to the MCAP storage, so rosbag2 leaves these empty.
                "compression_format": "",
                "compression_mode": "",
                "relative_file_paths": [file_name],
                "files": [
                    {
                        "path": file_name,
                        "starting_time": {"nanoseconds_since_epoch": start},
                        "duration": {"nanoseconds": duration},
                        "message_count": count,
                    }
                ],
                "custom_data": self._custom_data,
                "ros_distro": self._ros_distro,
            }

    def update_custom_data(self, items: Mapping[str, str]) -> None:
        """Set ``items`` in the ``custom_data`` that the closing record and ``metadata.yaml`` carry
        (what is known only at the end of a bag, such as the recorder's drops while paused)."""
        with self._lock:
            self._custom_data = (self._custom_data or {}) | dict(items)

    # -- closing -------------------------------------------------------------------------------

    def close(self) -> None:
        """Finalise the file (summary, indexes, ``rosbag2`` record, ``metadata.yaml``). Idempotent.
        BagWriteError if the disk refuses the summary or metadata.yaml."""
        with self._lock:
            if self._busy:
                # Re-entered from a signal handler that interrupted an operation on this thread:
                # let it finish; it finalises on its way out (see _exclusive).
                self._close_requested = True
                return
            try:
                self._finalize()
            except OSError as error:
                raise self._write_failed(error, finalise=False) from None

    def __enter__(self) -> RosbagMcapWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _finalize(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._close_requested = False
        information = self.bag_metadata()
        try:
            self._mcap.add_metadata(ROSBAG2_RECORD, {"serialized_metadata": dump_yaml(information)})
            self._mcap.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()
        self._finished = True
        if self.metadata_path is not None:
            write_metadata_yaml(self.metadata_path, information)
            self._metadata_written = True
