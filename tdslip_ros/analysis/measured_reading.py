"""Read any recording through a topic map into a :class:`~.measured.MeasuredRun`: the samples of each
mapped quantity, in SI and the model's plane, on one uniform time base.

The bag is read through the schemas stored in it (:mod:`tdslip_ros.bag.schema`, :mod:`tdslip_ros.bag.cdr`),
so no message package needs to be installed. Each quantity is converted once, here, by its source's
factor (:class:`~.topic_map.Source`: sign, scale, unit; REP 103's z up is the map's choice of axis).

The time base: from the latest first sample to the earliest last sample of all sources, at the shortest
median sample period among them. Times are seconds from the whole second of the earliest stamp (a run of
the suite, in sim time, keeps its own clock). Positions are resampled by cubic Hermite interpolation with
the velocity (recorded, else the source's own central differences): exact for a ballistic flight, whose
position is a parabola, so that a 250 Hz pose gives the apex of a 1 kHz one to rounding. Everything
else is interpolated linearly; the contact flag is held from its last sample. A source whose samples are
more than :data:`GAP_PERIODS` median periods apart has a gap there: the time-base samples inside it are
flagged (``MeasuredRun.in_gap``), for the stride detection to set aside what they touch.

Errors, one line each: :class:`MapMismatchError` (the map names a topic, type, field or joint the bag does
not hold: a usage mistake) and :class:`MeasuredDataError` (stamps that do not increase, values that are not
finite, sources that do not overlap in time: data that cannot serve). Reading plus stride detection of a
long recording is timed by bench/bench_measured.py (docs/benchmarks.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.records import Schema

from tdslip_ros.analysis.measured import FloatArray, MeasuredRun
from tdslip_ros.analysis.topic_map import Source, TopicMap, TopicMapError
from tdslip_ros.bag.cdr import decoded_columns, decoder
from tdslip_ros.bag.reader import Bag, open_bag, topic_messages
from tdslip_ros.bag.schema import MessageDefinitionError, message_fields

GAP_PERIODS = 3.0
"""A source's samples further apart than this many of its median periods leave a gap."""
HEADER_STAMP = ("header.stamp.sec", "header.stamp.nanosec")
_NUMERIC = frozenset(
    ("bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64")
    + ("float32", "float64")
)


class MapMismatchError(TopicMapError):
    """The map names a topic, message type, field or joint that the recording does not hold."""


class MeasuredDataError(ValueError):
    """The recording's data cannot serve: stamps that do not increase, values that are not finite, sources
    that never overlap in time, no stance."""


@dataclass(frozen=True)
class Samples:
    """One source's samples as recorded: times [s from the origin] and values in SI, the model's plane."""

    source: Source
    times: FloatArray
    values: FloatArray

    @property
    def period(self) -> float:
        return float(np.median(np.diff(self.times)))

    def gaps(self) -> list[tuple[float, float]]:
        """The (start, end) of each interval between samples longer than GAP_PERIODS median periods."""
        steps = np.diff(self.times)
        where = np.flatnonzero(steps > GAP_PERIODS * self.period)
        return [(float(self.times[i]), float(self.times[i + 1])) for i in where]


def _field_base(definitions: dict[str, tuple], type_name: str, path: str) -> str | None:
    """The primitive type at a dotted ``path`` of ``type_name`` (``name[]`` for a sequence), or None."""
    current = type_name
    for depth, name in enumerate(path.split(".")):
        field = next((f for f in definitions.get(current, ()) if f.name == name), None)
        if field is None:
            return None
        if depth == len(path.split(".")) - 1:
            return field.base + ("[]" if field.sequence or field.count is not None else "")
        current = field.base
    return None


def _checked_path(bag: Bag, source: Source, first_message: Callable[[], object]) -> str:
    """The field path of ``source`` in the recording (a joint's array element by its index), checked."""
    info = bag.topics.get(source.topic)
    what = f"quantities.{source.quantity}"
    if info is None:
        held = ", ".join(sorted(bag.topics)) or "none"
        raise MapMismatchError(f"{what}: the recording has no topic {source.topic} (it has: {held})")
    if info.type_name != source.type_name:
        raise MapMismatchError(
            f"{what}: {source.topic} is {info.type_name} in the recording, not {source.type_name}"
        )
    if info.schema is None or info.schema.encoding != "ros2msg":
        raise MapMismatchError(f"{what}: {source.topic} has no ros2msg schema stored to read it by")
    try:
        type_name, definitions = message_fields(info.schema.name, info.schema.data.decode())
    except (MessageDefinitionError, UnicodeDecodeError) as error:
        raise MapMismatchError(
            f"{what}: the stored schema of {source.topic} is unreadable ({error})"
        ) from None
    if source.stamp == "header" and _field_base(definitions, type_name, HEADER_STAMP[0]) != "int32":
        raise MapMismatchError(f"{what}: {source.type_name} has no header to stamp by (stamp: log)")
    base = _field_base(definitions, type_name, source.path)
    if source.joint is not None:
        if base != "float64[]":
            raise MapMismatchError(f"{what}: {source.type_name} has no joint array {source.field!r}")
        names = list(first_message().name)
        if source.joint not in names:
            raise MapMismatchError(
                f"{what}: {source.topic} has no joint {source.joint!r} (its joints: {', '.join(names)})"
            )
        return f"{source.field}[{names.index(source.joint)}]"
    if base not in _NUMERIC:
        kind = "has no field" if base is None else f"is not a number ({base}) at"
        raise MapMismatchError(f"{what}: {source.type_name} {kind} {source.path!r}")
    return source.path


def _stamps_ns(source: Source, columns: dict[str, np.ndarray], log_ns: np.ndarray) -> np.ndarray:
    if source.stamp == "log":
        return log_ns
    return columns[HEADER_STAMP[0]].astype(np.int64) * 1_000_000_000 + columns[HEADER_STAMP[1]].astype(
        np.int64
    )


def _read_sources(bag: Bag, topic_map: TopicMap) -> list[tuple[Source, np.ndarray, np.ndarray]]:
    """Each source's stamps [ns] and raw values, in the order of the map."""
    messages = topic_messages(bag, set(topic_map.topics()))
    read = []
    for source in topic_map.sources.values():
        datas, log_times = messages[source.topic]
        schema = bag.topics[source.topic].schema if source.topic in bag.topics else None

        def first_message(
            schema: Schema | None = schema, datas: list[bytes] = datas, topic: str = source.topic
        ) -> object:
            assert schema is not None  # _checked_path looks for the joint after the schema
            if not datas:
                raise MeasuredDataError(f"{topic} holds no messages")
            return decoder(schema)(datas[0])

        path = _checked_path(bag, source, first_message)
        assert schema is not None
        if not datas:
            raise MeasuredDataError(f"{source.topic} holds no messages")
        wanted = [path] + (list(HEADER_STAMP) if source.stamp == "header" else [])
        columns = decoded_columns(schema, datas, wanted)
        stamps = _stamps_ns(source, columns, np.asarray(log_times, dtype=np.int64))
        read.append((source, stamps, columns[path].astype(float)))
    return read


def _checked_samples(source: Source, stamps_ns: np.ndarray, raw: np.ndarray, origin_ns: int) -> Samples:
    times = (stamps_ns - origin_ns) * 1e-9
    values = raw * source.factor
    steps = np.diff(stamps_ns)
    if np.any(steps <= 0):
        i = int(np.flatnonzero(steps <= 0)[0])
        how = "go backwards" if steps[i] < 0 else "repeat"
        raise MeasuredDataError(
            f"{source.topic}: the {source.stamp} stamps {how} at message {i + 1} "
            f"({times[i + 1]:.9f} s after {times[i]:.9f} s)"
        )
    bad = ~np.isfinite(values)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise MeasuredDataError(
            f"{source.topic} {source.path}: {int(bad.sum())} values are not finite "
            f"(the first at {times[i]:.6f} s)"
        )
    if len(times) < 2:
        raise MeasuredDataError(f"{source.topic}: one message, too few to resample")
    return Samples(source, times, values)


def hermite(times: FloatArray, values: FloatArray, slopes: FloatArray, at: FloatArray) -> FloatArray:
    """The cubic Hermite interpolant of (times, values) with derivatives ``slopes``, at ``at``."""
    i = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    h = times[i + 1] - times[i]
    s = (at - times[i]) / h
    s2, s3 = s * s, s * s * s
    return (
        (2 * s3 - 3 * s2 + 1) * values[i]
        + (s3 - 2 * s2 + s) * h * slopes[i]
        + (-2 * s3 + 3 * s2) * values[i + 1]
        + (s3 - s2) * h * slopes[i + 1]
    )


def measured_run_from_bag(bag: Path, topic_map: TopicMap) -> MeasuredRun:
    """The recording at ``bag`` (a bag directory or an .mcap file) read through ``topic_map`` (module
    docstring). MapMismatchError, MeasuredDataError or BagReadError with one line on bad input."""
    checked = open_bag(bag)
    read = _read_sources(checked, topic_map)
    origin_ns = min(int(stamps[0]) for _, stamps, _ in read) // 1_000_000_000 * 1_000_000_000
    samples = {
        source.quantity: _checked_samples(source, stamps, raw, origin_ns) for source, stamps, raw in read
    }
    start = max(float(s.times[0]) for s in samples.values())
    end = min(float(s.times[-1]) for s in samples.values())
    period = min(s.period for s in samples.values())
    if end <= start:
        raise MeasuredDataError("the mapped topics do not overlap in time: no common time base")
    time = start + period * np.arange(int(np.floor((end - start) / period + 1e-9)) + 1)
    in_gap = np.zeros(len(time), dtype=bool)
    for s in samples.values():
        for gap_start, gap_end in s.gaps():
            edge = 1e-6 * period  # a time-base sample on a recorded one (to rounding) is not in the gap
            in_gap |= (time > gap_start + edge) & (time < gap_end - edge)
    sources: list[tuple[str, str]] = []

    def linear(quantity: str) -> FloatArray:
        s = samples[quantity]
        return np.interp(time, s.times, s.values)

    def recorded_slopes(position: str, velocity: str) -> FloatArray:
        s = samples[position]
        if velocity in samples:
            v = samples[velocity]
            return np.interp(s.times, v.times, v.values)
        return np.gradient(s.values, s.times)

    velocity_measured = "body_forward_velocity" in samples
    position = np.empty((len(time), 2))
    velocity = np.empty((len(time), 2))
    for column, axis in enumerate(("forward", "vertical")):
        slopes = recorded_slopes(f"body_{axis}", f"body_{axis}_velocity")
        s = samples[f"body_{axis}"]
        position[:, column] = hermite(s.times, s.values, slopes, time)
        if velocity_measured:
            velocity[:, column] = linear(f"body_{axis}_velocity")
        else:
            velocity[:, column] = np.interp(time, s.times, slopes)
    sources.append(("body_position", samples["body_vertical"].source.topic))
    sources.append(
        ("body_velocity", samples["body_vertical_velocity"].source.topic)
        if velocity_measured
        else ("body_velocity", "inferred: central differences of the body position")
    )
    leg_length = leg_angle = ground_force = hip_torque = contact = None
    if "leg_length" in samples:
        leg_length, leg_angle = linear("leg_length"), linear("leg_angle")
        sources += [
            ("leg_length", samples["leg_length"].source.topic),
            ("leg_angle", samples["leg_angle"].source.topic),
        ]
    elif "toe_forward" in samples:
        ahead = linear("toe_forward") - position[:, 0]
        above = position[:, 1] - linear("toe_vertical")
        leg_length, leg_angle = np.hypot(ahead, above), np.arctan2(ahead, above)
        how = f"inferred: from the body and the toe position ({samples['toe_forward'].source.topic})"
        sources += [("leg_length", how), ("leg_angle", how)]
    if "ground_force_vertical" in samples:
        ground_force = np.stack([linear("ground_force_forward"), linear("ground_force_vertical")], axis=-1)
        sources.append(("ground_force", samples["ground_force_vertical"].source.topic))
    if "hip_torque" in samples:
        hip_torque = linear("hip_torque")
        sources.append(("hip_torque", samples["hip_torque"].source.topic))
    if "contact" in samples:
        s = samples["contact"]
        held = np.clip(np.searchsorted(s.times, time, side="right") - 1, 0, len(s.times) - 1)
        contact = s.values[held] > 0.5
        sources.append(("contact", s.source.topic))
    return MeasuredRun(
        time=time,
        body_position=position,
        body_velocity=velocity,
        velocity_measured=velocity_measured,
        leg_length=leg_length,
        leg_angle=leg_angle,
        ground_force=ground_force,
        hip_torque=hip_torque,
        contact=contact,
        sources=tuple(sources),
        in_gap=in_gap,
    )
