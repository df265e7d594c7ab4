"""Load a recorded run (a bare ``.mcap`` or a rosbag2 bag directory) without rclpy.

The file is read with ``mcap`` (one sequential pass, chunk CRCs checked) and the CDR messages are
decoded with ``mcap-ros2-support`` from the schemas stored in the file. The two 1 kHz topics
(state and ground reaction force) take a vectorised path instead: their messages have a fixed CDR
layout, computed here from the same stored schema text, so a batch of them becomes numpy columns
in one ``frombuffer`` call (``test_analysis_reader.py`` checks it against ``mcap-ros2-support``).

What comes out (:class:`Run`) is tidy: one :class:`StrideRecord` per recorded apex (its state, the
command applied in the stance that follows, that stance's energy flows, the failure that ended the
run in it), the contact events, every command and status message, and the 1 kHz samples as
arrays. The hopper parameters are the given ones, else those ``tdslip run`` stored in the bag's
custom_data, else :func:`infer_params` recovers them from the physics of the recorded events
(exact to rounding); either way they are checked against the recorded events.

Every problem with the input -- no such path, not an MCAP file, a truncated or unfinalised file, a
corrupt chunk, a missing topic, a topic of the wrong type, an undecodable message -- raises
:class:`RunReadError` with a message that names what is missing or wrong.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import numpy.typing as npt
import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory

from tdslip_ros.interfaces import (
    APEX,
    COMMAND,
    CONTACT,
    GRF,
    HOPPER_PARAMETERS,
    STATE,
    STATUS,
    TOPIC_TYPES,
    hopper_from_parameters,
    resolve,
    stored_parameters,
)
from tdslip_ros.model.params import HopperParams, ParameterError, StanceCommand

FloatArray = npt.NDArray[np.float64]


MCAP_MAGIC = b"\x89MCAP0\r\n"
FAILURE_KINDS = (
    "toe_stubbing",
    "no_liftoff",
    "fall",
    "reversal",
    "state_limit",
    "command_timeout",
    "publish_failed",
)
"""Status kinds that end a run as a failure (the model's FailureKind values and the plant's own)."""
CONTACT_KINDS = {0: "touchdown", 1: "bottom", 2: "liftoff"}
PARAMETER_CONSISTENCY = 1e-9
"""Largest relative energy mismatch of the recorded events accepted for one set of hopper parameters."""

_STATE_FIELDS = (
    "stride",
    "phase",
    "x",
    "y",
    "xdot",
    "ydot",
    "toe_x",
    "toe_y",
    "leg_length",
    "leg_angle",
    "leg_length_rate",
    "leg_angle_rate",
    "hip_torque",
    "energy",
)
_STAMP_FIELDS = ("header.stamp.sec", "header.stamp.nanosec")
_GRF_FIELDS = ("wrench.force.x", "wrench.force.y")
_BATCH = 65536  # 1 kHz messages collected before they are converted to columns (bounds memory)


class RunReadError(Exception):
    """The recording cannot be analysed; the message says what is missing or wrong."""


# _corrupt: the mcap reader, zstandard, lz4 and the CDR decoder raise many unrelated exception types on
# damaged input (McapError, struct.error, ValueError, ZstdError, IndexError, ...); the handlers marked
# "see _corrupt" catch Exception and turn it into a RunReadError that says where the damage is.


# --- the file -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicInfo:
    """One recorded topic: its message type, stored definition text, channel metadata and count."""

    topic: str
    type_name: str
    schema: Schema | None
    metadata: dict[str, str]
    message_count: int


@dataclass(frozen=True)
class Recording:
    """A validated MCAP file: where it is, its topics (by recorded name), its message count, the
    ``custom_data`` of its rosbag2 metadata (``tdslip run`` stores the nodes' parameters there; empty
    if none) and the namespace the suite's topics were recorded in."""

    mcap_path: Path
    topics: dict[str, TopicInfo]
    message_count: int
    custom_data: dict[str, str]
    namespace: str = "/"

    def name(self, topic: str) -> str:
        """The recorded name of a suite topic given by its relative name (interfaces.STATE, ...)."""
        return resolve(topic, self.namespace)


def mcap_file(path: Path) -> Path:
    """The MCAP file of a run: ``path`` itself, or the one file of a bag directory."""
    path = Path(path)
    if not path.exists():
        raise RunReadError(f"{path}: no such file or directory")
    if path.is_file():
        return path
    names: list[str] = []
    metadata = path / "metadata.yaml"
    if metadata.is_file():
        try:
            information = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
            names = [str(name) for name in information["relative_file_paths"]]
        except (yaml.YAMLError, KeyError, TypeError) as error:
            raise RunReadError(f"{metadata}: not a rosbag2 metadata file ({error!r})") from None
    else:
        names = sorted(candidate.name for candidate in path.glob("*.mcap"))
    if not names:
        raise RunReadError(f"{path}: bag directory without an .mcap file")
    if len(names) > 1:
        raise RunReadError(f"{path}: split bags ({len(names)} files: {', '.join(names)}) are not supported")
    mcap_path = path / names[0]
    if not mcap_path.is_file():
        raise RunReadError(f"{path}: {names[0]} (listed in metadata.yaml) is missing")
    return mcap_path


def suite_namespace(topics: Iterable[str], namespace: str | None = None) -> str:
    """The namespace of the suite's topics among recorded topic names: ``namespace`` if given, else
    the one namespace holding an apex topic ("/" if none does); RunReadError if several do."""
    if namespace is not None:
        return resolve("", namespace).rstrip("/") or "/"
    suffix = "/" + APEX
    found = sorted({name[: -len(suffix)] or "/" for name in topics if name.endswith(suffix)})
    if len(found) > 1:
        raise RunReadError(
            f"the recording holds the hopper topics of several namespaces ({', '.join(found)}); "
            "choose one (--namespace)"
        )
    return found[0] if found else "/"


def open_recording(
    path: Path, required: dict[str, str] | None = None, namespace: str | None = None
) -> Recording:
    """Check that ``path`` is a complete MCAP recording holding the ``required`` suite topics (relative
    names with their types; default :data:`TOPIC_TYPES`) in ``namespace`` (default: found by
    :func:`suite_namespace`) and return its layout; RunReadError otherwise."""
    required = TOPIC_TYPES if required is None else required
    mcap_path = mcap_file(path)
    with open(mcap_path, "rb") as stream:
        _check_magic(mcap_path, stream)
        try:
            reader = make_reader(stream)
            summary = reader.get_summary()
            rosbag2 = [record.metadata for record in reader.iter_metadata() if record.name == "rosbag2"]
        except Exception as error:  # see _corrupt
            raise RunReadError(f"{mcap_path}: the summary section is unreadable ({error!r})") from None
    if summary is None or summary.statistics is None:
        raise RunReadError(f"{mcap_path}: no summary statistics (the file was not finalised)")
    counts = summary.statistics.channel_message_counts
    topics = {
        channel.topic: TopicInfo(
            topic=channel.topic,
            type_name=summary.schemas[channel.schema_id].name if channel.schema_id in summary.schemas else "",
            schema=summary.schemas.get(channel.schema_id),
            metadata=dict(channel.metadata),
            message_count=counts.get(channel_id, 0),
        )
        for channel_id, channel in summary.channels.items()
    }
    namespace = suite_namespace(topics, namespace)
    missing = [resolve(topic, namespace) for topic in required if resolve(topic, namespace) not in topics]
    if missing:
        raise RunReadError(
            f"{mcap_path}: missing topic{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
            f"(recorded: {', '.join(sorted(topics)) or 'none'})"
        )
    for topic, type_name in required.items():
        recorded = topics[resolve(topic, namespace)]
        if recorded.type_name != type_name:
            raise RunReadError(
                f"{mcap_path}: topic {recorded.topic} has type {recorded.type_name or 'unknown'}, "
                f"expected {type_name}"
            )
    custom_data = _custom_data(mcap_path, rosbag2)
    return Recording(mcap_path, topics, summary.statistics.message_count, custom_data, namespace)


def _custom_data(mcap_path: Path, rosbag2: list[dict[str, str]]) -> dict[str, str]:
    """The custom_data mapping of the rosbag2 metadata record."""
    if not rosbag2:
        return {}
    try:
        information = yaml.safe_load(rosbag2[0]["serialized_metadata"])  # metadata.yaml's inner mapping
        return {str(key): str(value) for key, value in (information.get("custom_data") or {}).items()}
    except (yaml.YAMLError, KeyError, TypeError, AttributeError) as error:
        raise RunReadError(f"{mcap_path}: the rosbag2 metadata record is unreadable ({error!r})") from None


def _check_magic(path: Path, stream: BinaryIO) -> None:
    head = stream.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise RunReadError(f"{path}: not an MCAP file (it starts with {head!r}, not the MCAP magic)")
    stream.seek(-len(MCAP_MAGIC), 2)
    tail = stream.read(len(MCAP_MAGIC))
    stream.seek(0)
    if tail != MCAP_MAGIC:
        raise RunReadError(
            f"{path}: truncated or not finalised: the MCAP footer and closing magic are missing "
            f"(the file ends after {path.stat().st_size} bytes)"
        )


def iter_messages(recording: Recording) -> Iterator[tuple[Channel, Message]]:
    """Every message of the file in file order, with its channel; chunk CRCs are checked."""
    channels: dict[int, Channel] = {}
    count = 0
    with open(recording.mcap_path, "rb") as stream:
        records = StreamReader(stream, validate_crcs=True).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception as error:  # see _corrupt
                raise RunReadError(
                    f"{recording.mcap_path}: corrupt data after {count} messages, near byte "
                    f"{stream.tell()}: {type(error).__name__}: {error}"
                ) from None
            if isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    raise RunReadError(
                        f"{recording.mcap_path}: message {count} refers to channel {record.channel_id}, "
                        "which is not defined before it"
                    )
                count += 1
                yield channel, record
    if count != recording.message_count:
        raise RunReadError(
            f"{recording.mcap_path}: the data section holds {count} messages, the summary counts "
            f"{recording.message_count}"
        )


# --- CDR decoding -------------------------------------------------------------------------------

_PRIMITIVES: dict[str, str] = {
    "bool": "?",
    "byte": "u1",
    "char": "u1",
    "int8": "i1",
    "uint8": "u1",
    "int16": "<i2",
    "uint16": "<u2",
    "int32": "<i4",
    "uint32": "<u4",
    "int64": "<i8",
    "uint64": "<u8",
    "float32": "<f4",
    "float64": "<f8",
}
_SEPARATOR = "\n" + "=" * 80 + "\n"
_CDR_LITTLE_ENDIAN = b"\x00\x01"


def _message_fields(schema: Schema) -> dict[str, list[tuple[str, str]]]:
    """(type, name) of the fields of the schema's message and of each nested definition, by type name
    (``pkg/Type``); constants and comments dropped, same-package types qualified."""
    definitions: dict[str, list[tuple[str, str]]] = {}
    for index, section in enumerate(schema.data.decode().split(_SEPARATOR)):
        if index == 0:
            package, _, name = schema.name.partition("/msg/")
            type_name, body = f"{package}/{name}", section
        else:
            header, _, body = section.partition("\n")
            type_name = header.removeprefix("MSG: ").strip()
        package = type_name.split("/")[0]
        fields = []
        for line in body.splitlines():
            tokens = line.split("#", 1)[0].split()
            if len(tokens) < 2 or "=" in tokens[1]:
                continue
            field_type = tokens[0]
            if field_type not in _PRIMITIVES and field_type != "string" and "/" not in field_type:
                field_type = f"{package}/{field_type}"
            fields.append((field_type, tokens[1]))
        definitions[type_name] = fields
    return definitions


def _fixed_layout(schema: Schema, sample: bytes) -> dict[str, tuple[int, str]] | None:
    """Byte offset (after the 4-byte encapsulation header) and numpy type of every primitive field,
    by dotted path, for messages laid out like ``sample``; None if the layout is not fixed
    (arrays, wide strings) or ``sample`` is not little-endian CDR. Strings take the length that
    ``sample`` holds; callers check that every message of a batch holds the same lengths."""
    if sample[:2] != _CDR_LITTLE_ENDIAN:
        return None
    definitions = _message_fields(schema)
    package, _, name = schema.name.partition("/msg/")
    layout: dict[str, tuple[int, str]] = {}
    payload = memoryview(sample)[4:]
    offset = 0

    def walk(type_name: str, prefix: str) -> bool:
        nonlocal offset
        for field_type, field_name in definitions.get(type_name, []):
            path = prefix + field_name
            if field_type in _PRIMITIVES:
                dtype = np.dtype(_PRIMITIVES[field_type])
                offset += -offset % dtype.itemsize
                layout[path] = (offset, _PRIMITIVES[field_type])
                offset += dtype.itemsize
            elif field_type == "string":
                offset += -offset % 4
                layout[path + ".__length__"] = (offset, "<u4")
                if offset + 4 > len(payload):
                    return False
                offset += 4 + int.from_bytes(payload[offset : offset + 4], "little")
            elif field_type in definitions and "[" not in field_type:
                if not walk(field_type, path + "."):
                    return False
            else:
                return False
        return True

    if not walk(f"{package}/{name}", "") or offset != len(payload):
        return None
    return layout


def _decoded_columns(schema: Schema, datas: Sequence[bytes], paths: Sequence[str]) -> dict[str, np.ndarray]:
    """Columns of the fields ``paths`` (dotted) of CDR messages of one schema, one entry per message."""
    if not datas:
        return {path: np.empty(0) for path in paths}
    layout = _fixed_layout(schema, datas[0])
    if layout is not None and all(len(data) == len(datas[0]) for data in datas):
        dtype = np.dtype(
            {
                "names": list(layout),
                "formats": [fmt for _, fmt in layout.values()],
                "offsets": [offset + 4 for offset, _ in layout.values()],
                "itemsize": len(datas[0]),
            }
        )
        table = np.frombuffer(b"".join(datas), dtype=dtype)
        lengths = [name for name in layout if name.endswith(".__length__")]
        if all(np.all(table[name] == table[name][0]) for name in lengths):
            return {path: np.array(table[path]) for path in paths}
    decode = _decoder(schema)
    messages = [decode(data) for data in datas]
    return {path: np.array([_attribute(message, path) for message in messages]) for path in paths}


def _decoder(schema: Schema) -> Callable[[bytes], Any]:
    decoder = DecoderFactory().decoder_for("cdr", schema)
    if decoder is None:
        raise RunReadError(f"no CDR decoder for schema {schema.name} (encoding {schema.encoding})")
    return decoder


def _attribute(message: object, path: str) -> Any:
    for name in path.split("."):
        message = getattr(message, name)
    return message


# --- records ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ApexRecord:
    """An ApexEvent: apex ``stride`` at sim time t [s]; energy flows of the stance before it [J]."""

    stride: int
    t: float
    x: float
    y: float
    xdot: float
    energy: float
    hip_work: float
    damping_loss: float
    spring_loss: float


@dataclass(frozen=True)
class StateRecord:
    """A HopperState at one instant (an event's state), SI."""

    t: float
    stride: int
    phase: int
    x: float
    y: float
    xdot: float
    ydot: float
    toe_x: float
    toe_y: float
    r: float
    theta: float
    rdot: float
    thetadot: float
    hip_torque: float
    energy: float


@dataclass(frozen=True)
class ContactRecord:
    """A touchdown, bottom or liftoff of the stance after apex ``stride``."""

    kind: str
    stride: int
    t: float
    state: StateRecord


@dataclass(frozen=True)
class CommandRecord:
    """A StanceCommand message as received by the recorder (log_time_ns: reception time)."""

    stride: int
    touchdown_angle: float
    tau0: float
    t_f: float
    policy: str
    log_time_ns: int


@dataclass(frozen=True)
class StatusRecord:
    stride: int
    t: float
    kind: str
    reason: str
    fatal: bool


@dataclass(frozen=True)
class StrideRecord:
    """Stride k: from apex k through the stance after it (to apex k + 1, if recorded).

    ``command`` is the command the plant applied at that stance's touchdown (None if the stance
    was not reached, or if no recorded command matches the touchdown, see :func:`applied_commands`).
    Energy flows [J] are those of the stance after apex k (NaN if apex k + 1 was not recorded).
    ``failure`` is the status kind that ended the run during this stride, with its reason.
    """

    stride: int
    t: float
    x: float
    y: float
    xdot: float
    energy: float
    command: StanceCommand | None
    policy: str
    touchdown_time: float
    liftoff_time: float
    hip_work: float
    damping_loss: float
    spring_loss: float
    failure: str | None
    failure_reason: str


@dataclass(frozen=True)
class Samples:
    """1 kHz state and ground reaction force, as arrays over the samples (SI; phase 1 = stance)."""

    t: FloatArray
    stride: npt.NDArray[np.int64]
    phase: npt.NDArray[np.int64]
    x: FloatArray
    y: FloatArray
    xdot: FloatArray
    ydot: FloatArray
    toe_x: FloatArray
    toe_y: FloatArray
    r: FloatArray
    theta: FloatArray
    rdot: FloatArray
    thetadot: FloatArray
    hip_torque: FloatArray
    energy: FloatArray
    grf_t: FloatArray
    grf_x: FloatArray
    grf_y: FloatArray

    def __len__(self) -> int:
        return len(self.t)


@dataclass(frozen=True)
class Run:
    """A recorded run, tidy. ``params`` are the hopper parameters (given, stored or inferred, see
    ``params_source``); ``outcome`` the fatal status that ended the run (None if the recording
    ends before the run did)."""

    path: Path
    params: HopperParams
    params_source: str
    strides: tuple[StrideRecord, ...]
    apexes: tuple[ApexRecord, ...]
    contacts: tuple[ContactRecord, ...]
    commands: tuple[CommandRecord, ...]
    statuses: tuple[StatusRecord, ...]
    samples: Samples
    outcome: StatusRecord | None
    message_counts: dict[str, int]
    custom_data: dict[str, str]

    @property
    def policies(self) -> tuple[str, ...]:
        """Names of the policies whose commands were applied, in order of first use."""
        return tuple(dict.fromkeys(s.policy for s in self.strides if s.command is not None))

    def apex_array(self) -> FloatArray:
        """(n, 2) apex heights [m] and speeds [m/s] of the recorded strides."""
        return np.array([(s.y, s.xdot) for s in self.strides], dtype=float).reshape(-1, 2)


def read_run(path: Path, params: HopperParams | None = None, namespace: str | None = None) -> Run:
    """Load a run (see the module docstring); ``params`` overrides the inferred hopper parameters,
    ``namespace`` chooses the hopper in a recording of several (see :func:`suite_namespace`)."""
    recording = open_recording(path, namespace=namespace)
    suite_topics = {recording.name(topic): topic for topic in TOPIC_TYPES}
    schemas = {topic: recording.topics[name].schema for name, topic in suite_topics.items()}
    events: dict[str, list[bytes]] = {topic: [] for topic in (APEX, CONTACT, STATUS, COMMAND)}
    log_times: list[int] = []
    stream_batches: dict[str, list[bytes]] = {STATE: [], GRF: []}
    columns: dict[str, list[dict[str, np.ndarray]]] = {STATE: [], GRF: []}
    fields = {STATE: (*_STAMP_FIELDS, *_STATE_FIELDS), GRF: (*_STAMP_FIELDS, *_GRF_FIELDS)}

    def flush(topic: str) -> None:
        schema = schemas[topic]
        assert schema is not None
        columns[topic].append(
            _checked(
                recording.name(topic),
                lambda: _decoded_columns(schema, stream_batches[topic], fields[topic]),
            )
        )
        stream_batches[topic] = []

    for channel, message in iter_messages(recording):
        topic = suite_topics.get(channel.topic, "")
        if topic in stream_batches:
            stream_batches[topic].append(message.data)
            if len(stream_batches[topic]) >= _BATCH:
                flush(topic)
        elif topic in events:
            events[topic].append(message.data)
            if topic == COMMAND:
                log_times.append(message.log_time)
    for topic in stream_batches:
        flush(topic)

    decoded = {
        topic: _decode_all(recording.name(topic), schemas[topic], datas) for topic, datas in events.items()
    }
    apexes = sorted((_apex(m) for m in decoded[APEX]), key=lambda a: a.t)
    contacts = sorted((_contact(m) for m in decoded[CONTACT]), key=lambda c: c.t)
    commands = [_command(m, log_time) for m, log_time in zip(decoded[COMMAND], log_times, strict=True)]
    statuses = sorted((_status(m) for m in decoded[STATUS]), key=lambda s: s.t)
    resets = [s for s in statuses if s.kind == "reset"]
    if resets:
        raise RunReadError(
            f"{recording.mcap_path}: the plant was reset {len(resets)} time(s) (first at t = "
            f"{resets[0].t:.3f} s); analysing a recording of several runs is not supported"
        )
    if not apexes:
        raise RunReadError(
            f"{recording.mcap_path}: topic {recording.name(APEX)} has no messages (not even the initial apex)"
        )
    samples = _samples(columns)
    source = "given"
    if params is None:
        params, source = _stored_params(recording), "stored in the recording"
    if params is None:
        params, source = infer_params(apexes, contacts, recording.mcap_path), "inferred from the recording"
    _check_params(params, apexes, contacts, recording.mcap_path)
    outcome = next((s for s in statuses if s.fatal), None)
    return Run(
        path=Path(path),
        params=params,
        params_source=source,
        strides=_strides(apexes, contacts, commands, outcome),
        apexes=tuple(apexes),
        contacts=tuple(contacts),
        commands=tuple(commands),
        statuses=tuple(statuses),
        samples=samples,
        outcome=outcome,
        message_counts={topic: info.message_count for topic, info in recording.topics.items()},
        custom_data=recording.custom_data,
    )


def _stored_params(recording: Recording) -> HopperParams | None:
    """The plant's hopper parameters from the custom_data ``tdslip run`` writes (None if absent)."""
    values = stored_parameters(recording.custom_data, "plant")
    if not all(name in values for name in HOPPER_PARAMETERS.values()):
        return None
    try:
        return hopper_from_parameters(values)
    except (ValueError, ParameterError) as error:
        raise RunReadError(f"{recording.mcap_path}: stored hopper parameters are invalid ({error})") from None


def _checked(topic: str, decode: Callable[[], Any]) -> Any:
    try:
        return decode()
    except RunReadError:
        raise
    except Exception as error:  # see _corrupt
        raise RunReadError(f"topic {topic}: undecodable message ({error!r})") from None


def _decode_all(topic: str, schema: Schema | None, datas: list[bytes]) -> list[Any]:
    if schema is None:
        raise RunReadError(f"topic {topic}: no schema stored for its channel")
    decode = _decoder(schema)
    return [_checked(topic, partial(decode, data)) for data in datas]


def _stamp_seconds(sec: np.ndarray, nanosec: np.ndarray) -> FloatArray:
    return np.asarray(sec, dtype=np.float64) + np.asarray(nanosec, dtype=np.float64) * 1e-9


def _samples(columns: dict[str, list[dict[str, np.ndarray]]]) -> Samples:
    def joined(topic: str, path: str) -> np.ndarray:
        return np.concatenate([batch[path] for batch in columns[topic]])

    t = _stamp_seconds(joined(STATE, "header.stamp.sec"), joined(STATE, "header.stamp.nanosec"))
    grf_t = _stamp_seconds(joined(GRF, "header.stamp.sec"), joined(GRF, "header.stamp.nanosec"))
    order, grf_order = np.argsort(t, kind="stable"), np.argsort(grf_t, kind="stable")
    state = {name: joined(STATE, name)[order] for name in _STATE_FIELDS}
    return Samples(
        t=t[order],
        stride=state["stride"].astype(np.int64),
        phase=state["phase"].astype(np.int64),
        x=state["x"],
        y=state["y"],
        xdot=state["xdot"],
        ydot=state["ydot"],
        toe_x=state["toe_x"],
        toe_y=state["toe_y"],
        r=state["leg_length"],
        theta=state["leg_angle"],
        rdot=state["leg_length_rate"],
        thetadot=state["leg_angle_rate"],
        hip_torque=state["hip_torque"],
        energy=state["energy"],
        grf_t=grf_t[grf_order],
        grf_x=joined(GRF, "wrench.force.x")[grf_order],
        grf_y=joined(GRF, "wrench.force.y")[grf_order],
    )


def _apex(msg: Any) -> ApexRecord:
    return ApexRecord(
        int(msg.stride),
        float(msg.sim_time),
        float(msg.x),
        float(msg.height),
        float(msg.forward_speed),
        float(msg.energy),
        float(msg.hip_work),
        float(msg.damping_loss),
        float(msg.spring_loss),
    )


def _state(msg: Any) -> StateRecord:
    return StateRecord(
        t=float(msg.header.stamp.sec) + float(msg.header.stamp.nanosec) * 1e-9,
        stride=int(msg.stride),
        phase=int(msg.phase),
        x=float(msg.x),
        y=float(msg.y),
        xdot=float(msg.xdot),
        ydot=float(msg.ydot),
        toe_x=float(msg.toe_x),
        toe_y=float(msg.toe_y),
        r=float(msg.leg_length),
        theta=float(msg.leg_angle),
        rdot=float(msg.leg_length_rate),
        thetadot=float(msg.leg_angle_rate),
        hip_torque=float(msg.hip_torque),
        energy=float(msg.energy),
    )


def _contact(msg: Any) -> ContactRecord:
    kind = CONTACT_KINDS.get(int(msg.kind))
    if kind is None:
        raise RunReadError(f"topic {CONTACT}: unknown contact kind {msg.kind}")
    return ContactRecord(kind, int(msg.stride), float(msg.sim_time), _state(msg.state))


def _command(msg: Any, log_time_ns: int) -> CommandRecord:
    return CommandRecord(
        int(msg.stride),
        float(msg.touchdown_angle),
        float(msg.tau0),
        float(msg.t_f),
        str(msg.policy),
        log_time_ns,
    )


def _status(msg: Any) -> StatusRecord:
    return StatusRecord(int(msg.stride), float(msg.sim_time), str(msg.kind), str(msg.reason), bool(msg.fatal))


# --- from messages to strides -------------------------------------------------------------------


def applied_commands(
    contacts: Sequence[ContactRecord], commands: Sequence[CommandRecord]
) -> dict[int, CommandRecord]:
    """The command applied at each recorded touchdown, by stride.

    The plant applies the latest valid command answering the stride, or keeps the one in force. At
    touchdown the leg is at the commanded angle and the hip torque equals tau0, both copied exactly
    into the touchdown state, so the applied command is the last command answering the stride that
    matches them bit for bit, else the command applied before it if that one matches. A touchdown
    that no recorded command matches (the plant's initial command) gets none.
    """
    by_stride: dict[int, list[CommandRecord]] = {}
    for command in sorted(commands, key=lambda c: c.log_time_ns):
        by_stride.setdefault(command.stride, []).append(command)
    applied: dict[int, CommandRecord] = {}
    in_force: CommandRecord | None = None
    for touchdown in (c for c in contacts if c.kind == "touchdown"):
        candidates = [c for c in by_stride.get(touchdown.stride, []) if _applied_at(c, touchdown)]
        chosen = candidates[-1] if candidates else in_force if _applied_at(in_force, touchdown) else None
        if chosen is not None:
            applied[touchdown.stride] = chosen
        in_force = chosen
    return applied


def _applied_at(command: CommandRecord | None, touchdown: ContactRecord) -> bool:
    return (
        command is not None
        and command.touchdown_angle == touchdown.state.theta
        and command.tau0 == touchdown.state.hip_torque
    )


def _strides(
    apexes: Sequence[ApexRecord],
    contacts: Sequence[ContactRecord],
    commands: Sequence[CommandRecord],
    outcome: StatusRecord | None,
) -> tuple[StrideRecord, ...]:
    applied = applied_commands(contacts, commands)
    event_times = {(c.kind, c.stride): c.t for c in contacts}
    next_apex = {a.stride - 1: a for a in apexes}
    records = []
    for apex in apexes:
        record = applied.get(apex.stride)
        command = None if record is None else StanceCommand(record.touchdown_angle, record.tau0, record.t_f)
        after = next_apex.get(apex.stride)
        failed = outcome is not None and outcome.kind in FAILURE_KINDS and outcome.stride == apex.stride
        records.append(
            StrideRecord(
                stride=apex.stride,
                t=apex.t,
                x=apex.x,
                y=apex.y,
                xdot=apex.xdot,
                energy=apex.energy,
                command=command,
                policy="" if record is None else record.policy,
                touchdown_time=event_times.get(("touchdown", apex.stride), math.nan),
                liftoff_time=event_times.get(("liftoff", apex.stride), math.nan),
                hip_work=math.nan if after is None else after.hip_work,
                damping_loss=math.nan if after is None else after.damping_loss,
                spring_loss=math.nan if after is None else after.spring_loss,
                failure=outcome.kind if failed and outcome is not None else None,
                failure_reason=outcome.reason if failed and outcome is not None else "",
            )
        )
    return tuple(records)


# --- hopper parameters --------------------------------------------------------------------------


def infer_params(
    apexes: Sequence[ApexRecord], contacts: Sequence[ContactRecord], source: Path
) -> HopperParams:
    """The hopper parameters from the physics of one recorded stride (exact up to rounding).

    From apex k to its touchdown the fall is ballistic from rest: g = -ydot_td / (t_td - t_apex);
    the leg touches down at rest length r0; the apex energy m (g y + xdot^2 / 2) gives m; the
    energy at maximum compression, kinetic + m g y + k (r - r0)^2 / 2, gives k; at liftoff the leg
    force k (r0 - r) - c rdot is zero, which gives c.
    """
    by_key = {(c.kind, c.stride): c for c in contacts}
    apex_by_stride = {a.stride: a for a in apexes}
    for stride, apex in apex_by_stride.items():
        touchdown, bottom, liftoff = (
            by_key.get((kind, stride)) for kind in ("touchdown", "bottom", "liftoff")
        )
        if touchdown is None or bottom is None or liftoff is None or touchdown.t <= apex.t:
            continue
        g = -touchdown.state.ydot / (touchdown.t - apex.t)
        r0 = touchdown.state.r
        m = apex.energy / (g * apex.y + 0.5 * apex.xdot**2)
        b = bottom.state
        kinetic = 0.5 * m * (b.rdot**2 + (b.r * b.thetadot) ** 2)
        k = 2.0 * (b.energy - kinetic - m * g * b.y) / (b.r - r0) ** 2
        lo = liftoff.state
        # c = 0 puts liftoff at r = r0 up to the event tolerance; a rounding-size negative is 0.
        c = max(0.0, k * (r0 - lo.r) / lo.rdot)
        try:
            return HopperParams(m=m, k=k, r0=r0, c=c, g=g)
        except ParameterError as error:
            raise RunReadError(
                f"{source}: the recorded events give impossible hopper parameters: {error}"
            ) from None
    raise RunReadError(
        f"{source}: cannot infer the hopper parameters: no apex is followed by a recorded touchdown, bottom "
        "and liftoff; give the parameters explicitly (tdslip analyze --params FILE)"
    )


def _check_params(
    params: HopperParams, apexes: Sequence[ApexRecord], contacts: Sequence[ContactRecord], source: Path
) -> None:
    """The recorded energies of apexes and stance events must follow from ``params``."""
    worst, where = 0.0, ""
    for apex in apexes:
        expected = params.m * (params.g * apex.y + 0.5 * apex.xdot**2)
        error = abs(expected - apex.energy) / abs(apex.energy)
        if error > worst:
            worst, where = error, f"apex {apex.stride}"
    for contact in contacts:
        s = contact.state
        expected = (
            0.5 * params.m * (s.rdot**2 + (s.r * s.thetadot) ** 2)
            + params.m * params.g * s.y
            + 0.5 * params.k * (s.r - params.r0) ** 2
        )
        error = abs(expected - s.energy) / abs(s.energy)
        if error > worst:
            worst, where = error, f"{contact.kind} of stride {contact.stride}"
    if worst > PARAMETER_CONSISTENCY:
        raise RunReadError(
            f"{source}: the recorded energies do not follow from the hopper parameters {params} "
            f"(relative mismatch {worst:.2e} at the {where})"
        )
