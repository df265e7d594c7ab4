"""A rosbag2-compatible MCAP writer for already-serialized (CDR) ROS 2 messages.

The file follows what rosbag2's MCAP storage plugin (``rosbag2_storage_mcap``, Kilted) writes:

* header profile ``ros2``;
* one schema per message type: name ``pkg/msg/Type``, encoding ``ros2msg``, data = the full
  definition text (:func:`tdslip_ros.bag.schema.message_definition`);
* one channel per topic: message encoding ``cdr``, metadata ``offered_qos_profiles`` (YAML string,
  metadata version 9 policy names) and ``topic_type_hash`` (RIHS01);
* messages with ``log_time`` (receive time) and ``publish_time`` in ns and a sequence number;
* chunked, compressed (``zstd`` by default, ``lz4`` or none) and fully indexed;
* at close, a metadata record named ``rosbag2`` with the single key ``serialized_metadata`` (the
  bag information as YAML, ``ros_distro`` inside, as rosbag2 >= Jazzy writes it), and, for a bag
  directory, ``metadata.yaml`` beside ``<dir>_0.mcap``.

Durability. The file is written through without a user-space buffer: every chunk reaches the
kernel the moment it is complete, so a hard kill (SIGKILL, crash) loses only the open chunk
(at most ``chunk_size`` bytes; call :meth:`RosbagMcapWriter.flush` to bound that in time). Such an
unfinalised file has no summary or footer: ``mcap.reader.make_reader`` and ``rosbags`` reject it,
while a sequential scan (``mcap.stream_reader.StreamReader``, or ``mcap recover`` from the mcap
CLI) returns every record up to the cut, i.e. every message of every complete chunk.

Threads and signals. All methods are serialized by one re-entrant lock. :meth:`close` may be called
from another thread (it waits for a write in progress) or from a signal handler: if the handler
interrupted a write on the same thread, the close is completed as soon as that write returns, so
the handler itself must not raise. Writing after close raises :class:`BagClosedError`.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Literal, cast

from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from tdslip_ros.bag.qos import OfferedQos, dump_yaml, qos_profiles_yaml
from tdslip_ros.bag.schema import canonical_type_name, message_definition, type_description_hash

Compression = Literal["none", "lz4", "zstd"]

# The mcap C++ library's default chunk size, which rosbag2's MCAP plugin uses unless configured.
DEFAULT_CHUNK_SIZE = 768 * 1024
METADATA_VERSION = 9
STORAGE_IDENTIFIER = "mcap"
DEFAULT_ROS_DISTRO = "kilted"
LIBRARY = f"tdslip_ros.bag; {LIBRARY_IDENTIFIER}"
MCAP_COMPRESSION = {"none": CompressionType.NONE, "lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD}
_UINT64_MAX = 2**64 - 1
_UINT32_MAX = 2**32 - 1


class BagClosedError(RuntimeError):
    """A message or topic was given to a writer that is already closed."""


class _WriteThroughFile:
    """Minimal binary sink for ``mcap.writer.Writer`` that hands every write straight to the kernel.

    The mcap writer only writes whole records (a finished chunk, its message indexes, the summary),
    so unbuffered writes cost a few system calls per chunk and nothing per message.
    """

    def __init__(self, path: Path) -> None:
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self._position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        while view:
            written = os.write(self._fd, view)
            view = view[written:]
        self._position += len(data)
        return len(data)

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        """Nothing is buffered here."""

    def close(self) -> None:
        os.fsync(self._fd)
        os.close(self._fd)


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
    goes into the bag metadata's ``custom_data`` mapping.
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
    ) -> None:
        if compression not in MCAP_COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(MCAP_COMPRESSION)}, not {compression!r}")
        if chunk_size <= 0:
            raise ValueError(f"chunk_size must be positive, not {chunk_size}")
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
        self._lock = threading.RLock()
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[str, int] = {}
        self._start_ns: int | None = None
        self._end_ns = 0
        self._busy = False
        self._close_requested = False
        self._closed = False
        self._file = _WriteThroughFile(self.mcap_path)
        self._mcap = Writer(
            cast(IO[Any], self._file), chunk_size=chunk_size, compression=MCAP_COMPRESSION[compression]
        )
        self._mcap.start(profile="ros2", library=LIBRARY)

    # -- topics and messages -------------------------------------------------------------------

    def add_topic(
        self,
        topic: str,
        type_name: str,
        *,
        offered_qos: Iterable[OfferedQos] = (),
        type_hash: str | None = None,
    ) -> int:
        """Register ``topic`` of message type ``type_name`` and return its MCAP channel id.

        The schema text and, unless ``type_hash`` is given (e.g. the ``topic_type_hash`` that rclpy's
        graph API reports), the RIHS01 hash are read from the installed interface files. Adding the
        same topic again with the same type returns the existing channel id.
        """
        canonical = canonical_type_name(type_name)
        # Look everything up first, so that a missing interface file registers nothing.
        definition = message_definition(canonical).encode("utf-8")
        resolved_hash = type_hash if type_hash is not None else type_description_hash(canonical)
        profiles = tuple(offered_qos)
        with self._exclusive():
            existing = self._topics.get(topic)
            if existing is not None:
                if existing.type_name != canonical:
                    raise ValueError(f"topic {topic!r} is already recorded as {existing.type_name}")
                return existing.channel_id
            schema_id = self._schema_ids.get(canonical)
            if schema_id is None:
                schema_id = self._mcap.register_schema(canonical, "ros2msg", definition)
                self._schema_ids[canonical] = schema_id
            channel_id = self._mcap.register_channel(
                topic,
                "cdr",
                schema_id,
                {"offered_qos_profiles": qos_profiles_yaml(profiles), "topic_type_hash": resolved_hash},
            )
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
        ``sequence`` to the topic's running message number (1, 2, ...)."""
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
            self._mcap.add_message(entry.channel_id, log_time_ns, data, publish_time, number)
            entry.message_count = count
            if self._start_ns is None or log_time_ns < self._start_ns:
                self._start_ns = log_time_ns
            if log_time_ns > self._end_ns:
                self._end_ns = log_time_ns

    def flush(self) -> None:
        """Write out the chunk in progress now, so that a hard kill cannot lose it."""
        with self._exclusive():
            self._mcap.flush()  # type: ignore[no-untyped-call]

    @contextmanager
    def _exclusive(self) -> Iterator[None]:
        """Hold the lock for one operation on the open file; run a close requested meanwhile."""
        with self._lock:
            # Busy before the closed check: a signal handler's close() landing in between then
            # either finalises first (and we raise) or is deferred (and we finish first).
            self._busy = True
            try:
                if self._closed:
                    raise BagClosedError(f"{self.mcap_path} is closed")
                yield
            finally:
                self._busy = False
                if self._close_requested:
                    self._finalize()

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

    # -- closing -------------------------------------------------------------------------------

    def close(self) -> None:
        """Finalise the file (summary, indexes, ``rosbag2`` record, ``metadata.yaml``). Idempotent."""
        with self._lock:
            if self._busy:
                # Re-entered from a signal handler that interrupted an operation on this thread:
                # let it finish; it finalises on its way out (see _exclusive).
                self._close_requested = True
                return
            self._finalize()

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
            self._mcap.add_metadata("rosbag2", {"serialized_metadata": dump_yaml(information)})
            self._mcap.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()
        if self.metadata_path is not None:
            staging = self.metadata_path.with_suffix(".yaml.tmp")
            staging.write_text(dump_yaml({"rosbag2_bagfile_information": information}) + "\n")
            os.replace(staging, self.metadata_path)
