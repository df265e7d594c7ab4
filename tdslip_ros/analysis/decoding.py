"""Load a recorded run (a bare ``.mcap`` or a rosbag2 bag directory) without rclpy.

The recording is opened and checked by :mod:`tdslip_ros.bag.reader` (magic, footer, summary CRC,
chunk CRCs, message counts) and its messages decoded by :mod:`tdslip_ros.bag.cdr` from the schemas
stored in it; the two 1 kHz topics (state and ground reaction force) take the vectorised path to
numpy columns.

What comes out (:class:`~.records.Run`, of the types in :mod:`.records`) is tidy: one
:class:`~.records.StrideRecord` per recorded apex (its state, the command applied in the stance that
follows, that stance's energy flows, the failure that ended the run in it; rebuilt by :mod:`.strides`),
the contact events, every command and status message, and the 1 kHz samples as arrays. Heights are in the
world frame, as recorded; each record carries its ground height.

A stride under stance feedback (a command with ``stance`` STANCE_FEEDBACK) has no ramp: its record holds
the stance feedback as applied instead (:attr:`~.records.StrideRecord.stance_feedback`), the touchdown
angle and the torques the plant held, from ``tdslip/applied_torque``, replayable by the model's engines
(:class:`~tdslip_ros.model.plant.stance_laws.RecordedTorques`).

The perturbations of the run (:class:`~tdslip_ros.model.plant.perturbations.Perturbations`: terrain, sensing
noise, placement error, torque limit, pushes) come from the plant parameters ``tdslip run`` stores in
custom_data, and the model the controller planned with from its stored hopper parameters (the plant's
when none are stored: no mismatch). The per-stride draws (placement error, push) are reproduced from the
stored seeds and checked against the recorded touchdowns: each stride's applied command is the one whose
placed angle and saturated torque are the touchdown's.

The hopper parameters are the given ones, else those ``tdslip run`` stored in the bag's custom_data, else
:func:`infer_params` recovers them from the physics of the recorded events (exact to rounding); either
way they are checked against the recorded events, the damping included.

Only the apex topic is required: a suite topic that was never written (a recorder stopped before
the first status, a recording salvaged by ``tdslip recover`` or another tool that drops empty
channels) reads as a topic without messages. Every problem with the input -- no such path, not an
MCAP file, a truncated or unfinalised file, a corrupt chunk, no apex topic, a topic of the wrong
type, an undecodable message, parameters that contradict the recording -- raises
:class:`RunReadError` with a message that names what is missing or wrong.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Schema

from tdslip_ros.analysis.records import (
    ApexRecord,
    CommandRecord,
    ContactRecord,
    FloatArray,
    Run,
    Samples,
    StatusRecord,
    TorqueRecord,
)
from tdslip_ros.analysis.sample_keeping import SampleKeeping
from tdslip_ros.analysis.strides import stride_records
from tdslip_ros.bag.cdr import decoded_columns, decoder
from tdslip_ros.bag.reader import Bag, BagReadError, iter_topic_batches, open_bag, topic_messages
from tdslip_ros.bag.schema import message_fields
from tdslip_ros.interfaces import (
    APEX,
    APPLIED_TORQUE,
    COMMAND,
    CONTACT,
    GRF,
    GRF_FIELDS,
    HOPPER_PARAMETERS,
    PITCH_FIELDS,
    STAMP_FIELDS,
    STATE,
    STATE_FIELDS,
    STATUS,
    TOPIC_TYPES,
    hopper_from_parameters,
    perturbations_from_parameters,
    resolve,
    stored_parameters,
)
from tdslip_ros.model.events import HopperState, Phase
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.plant.perturbations import Perturbations

CONTACT_KINDS = {0: "touchdown", 1: "bottom", 2: "liftoff"}
PARAMETER_CONSISTENCY = 1e-9
"""Largest relative energy mismatch of the recorded events accepted for one set of hopper parameters."""
DAMPING_CONSISTENCY = 1e-6
"""Largest mismatch of the damping ratio zeta0 = c / (2 sqrt(m k)) with the recorded liftoffs."""
REQUIRED_TOPICS = (APEX,)
"""The suite topics a run cannot be analysed without; the others may be missing (no messages)."""
EVENT_TOPICS = (APEX, CONTACT, STATUS, COMMAND, APPLIED_TORQUE)
"""The suite's topics read whole in the first pass: the strides are rebuilt from them."""

PHASES = {0: Phase.FLIGHT, 1: Phase.STANCE}
"""HopperState.phase of the message (PHASE_FLIGHT, PHASE_STANCE) as the model's."""

_BATCH = 65536  # 1 kHz messages collected before they are converted to columns (bounds memory)


class RunReadError(Exception):
    """The recording cannot be analysed; the message says what is missing or wrong."""


@contextmanager
def _as_run_error() -> Iterator[None]:
    """The bag reader's errors, as RunReadError."""
    try:
        yield
    except BagReadError as error:
        raise RunReadError(str(error)) from None


@dataclass(frozen=True)
class Recording:
    """A checked recording (:class:`~tdslip_ros.bag.reader.Bag`) and the namespace the suite's
    topics were recorded in."""

    bag: Bag
    namespace: str = "/"

    def name(self, topic: str) -> str:
        """The recorded name of a suite topic given by its relative name (interfaces.STATE, ...)."""
        return resolve(topic, self.namespace)

    def schema(self, topic: str) -> Schema | None:
        """The stored schema of a suite topic (None if it was not recorded)."""
        info = self.bag.topics.get(self.name(topic))
        return None if info is None else info.schema


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


def open_recording(path: Path, namespace: str | None = None) -> Recording:
    """Check that ``path`` is a complete recording holding the REQUIRED_TOPICS in ``namespace``
    (default: found by :func:`suite_namespace`), with each recorded suite topic of its type in
    :data:`TOPIC_TYPES`, and return it; RunReadError otherwise."""
    with _as_run_error():
        bag = open_bag(path)
    recording = Recording(bag, suite_namespace(bag.topics, namespace))
    missing = [recording.name(topic) for topic in REQUIRED_TOPICS if recording.name(topic) not in bag.topics]
    if missing:
        raise RunReadError(
            f"{bag.mcap_path}: missing topic{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
            f"(recorded: {', '.join(sorted(bag.topics)) or 'none'})"
        )
    for topic, type_name in TOPIC_TYPES.items():
        recorded = bag.topics.get(recording.name(topic))
        if recorded is not None and recorded.type_name != type_name:
            raise RunReadError(
                f"{bag.mcap_path}: topic {recorded.topic} has type {recorded.type_name or 'unknown'}, "
                f"expected {type_name}"
            )
    return recording


def read_run(
    path: Path,
    params: HopperParams | None = None,
    namespace: str | None = None,
    full_rate_strides: Collection[int] = (),
) -> Run:
    """Load a run (see the module docstring); ``params`` overrides the inferred hopper parameters,
    ``namespace`` chooses the hopper in a recording of several (see :func:`suite_namespace`). The
    recording is read in two streaming passes, the events first, then the 1 kHz samples that
    :mod:`.sample_keeping` keeps; ``full_rate_strides`` are kept whole in a long recording."""
    recording = open_recording(path, namespace=namespace)
    bag = recording.bag
    names = {recording.name(topic): topic for topic in EVENT_TOPICS}
    with _as_run_error():
        found = topic_messages(bag, names)

    def decoded(topic: str) -> Iterator[Any]:
        return _decoded(recording, topic, found[recording.name(topic)][0])

    # Each apex once: a lockstep plant publishes an unanswered one again, with the same stride and time.
    apexes = sorted({(a.stride, a.t): a for a in map(_apex, decoded(APEX))}.values(), key=lambda a: a.t)
    contacts = sorted((_contact(m) for m in decoded(CONTACT)), key=lambda c: c.t)
    log_times = found[recording.name(COMMAND)][1]
    commands = [_command(m, log_time) for m, log_time in zip(decoded(COMMAND), log_times, strict=True)]
    statuses = sorted((_status(m) for m in decoded(STATUS)), key=lambda s: s.t)
    torques = sorted(
        (TorqueRecord(int(m.stride), int(m.tick), float(m.torque)) for m in decoded(APPLIED_TORQUE)),
        key=lambda r: r.tick,
    )
    resets = [s for s in statuses if s.kind == "reset"]
    if resets:
        raise RunReadError(
            f"{bag.mcap_path}: the plant was reset {len(resets)} time(s) (first at t = "
            f"{resets[0].t:.3f} s); analysing a recording of several runs is not supported"
        )
    if not apexes:
        raise RunReadError(
            f"{bag.mcap_path}: topic {recording.name(APEX)} has no messages (not even the initial apex)"
        )
    outcome = next((s for s in statuses if s.fatal), None)
    perturbations = _stored_perturbations(recording)
    strides = stride_records(apexes, contacts, commands, outcome, perturbations, torques)
    state = bag.topics.get(recording.name(STATE))
    samples_recorded = 0 if state is None else state.message_count
    keeping = SampleKeeping.for_run(samples_recorded, strides, full_rate_strides)
    samples = _samples(recording, keeping)
    source = "given"
    if params is None:
        params, source = _stored_params(recording), "stored in the recording"
    if params is None:
        params, source = infer_params(apexes, contacts, bag.mcap_path), "inferred from the recording"
    _check_params(params, apexes, contacts, f"{bag.mcap_path}: the hopper parameters {source}")
    return Run(
        path=Path(path),
        params=params,
        params_source=source,
        strides=strides,
        apexes=tuple(apexes),
        contacts=tuple(contacts),
        commands=tuple(commands),
        statuses=tuple(statuses),
        samples=samples,
        samples_recorded=samples_recorded,
        sample_bucket=keeping.bucket,
        outcome=outcome,
        message_counts={topic: info.message_count for topic, info in bag.topics.items()},
        custom_data=bag.custom_data,
        perturbations=perturbations,
        controller_params=_stored_params(recording, "controller"),
    )


def _stored_params(recording: Recording, node: str = "plant") -> HopperParams | None:
    """The hopper parameters of ``node`` (the plant's, or the controller's: what it planned with) from the
    custom_data ``tdslip run`` writes (None if absent)."""
    values = stored_parameters(recording.bag.custom_data, node)
    if not all(name in values for name in HOPPER_PARAMETERS.values()):
        return None
    try:
        return hopper_from_parameters(values)
    except (ValueError, ParameterError) as error:
        raise RunReadError(
            f"{recording.bag.mcap_path}: stored {node} hopper parameters are invalid ({error})"
        ) from None


def _stored_perturbations(recording: Recording) -> Perturbations:
    """The plant's perturbations from the custom_data ``tdslip run`` writes (none where absent)."""
    values = stored_parameters(recording.bag.custom_data, "plant")
    try:
        return perturbations_from_parameters(values)
    except ParameterError as error:
        raise RunReadError(f"{recording.bag.mcap_path}: stored perturbations are invalid ({error})") from None


def _checked(topic: str, decode: Callable[[], Any]) -> Any:
    try:
        return decode()
    except RunReadError:
        raise
    except Exception as error:  # see bag.reader's _damaged
        raise RunReadError(f"topic {topic}: undecodable message ({error!r})") from None


def _stored(recording: Recording, topic: str, schema: Schema | None) -> Schema:
    """``schema``, which a topic with messages must have stored."""
    if schema is None:
        raise RunReadError(f"topic {recording.name(topic)}: no schema stored for its channel")
    return schema


def _stored_fields(recording: Recording, topic: str, wanted: tuple[str, ...]) -> tuple[str, ...]:
    """Those of ``wanted`` (a message's top-level fields) that the topic's stored schema has: a bag recorded
    before PITCH_FIELDS came has none of them, and reads as the fixed body's zeros."""
    schema = recording.schema(topic)
    if schema is None:
        return wanted
    with _as_run_error():
        name, definitions = message_fields(schema.name, schema.data.decode())
    stored = {field.name for field in definitions[name]}
    return tuple(field for field in wanted if field in stored or field not in PITCH_FIELDS)


def _decoded(recording: Recording, topic: str, datas: list[bytes]) -> Iterator[Any]:
    """The messages ``datas`` of a suite topic decoded one by one (each is made a record and let go)."""
    if not datas:
        return
    with _as_run_error():
        decode = decoder(_stored(recording, topic, recording.schema(topic)))
    for data in datas:
        yield _checked(recording.name(topic), partial(decode, data))


def _stamp_seconds(sec: np.ndarray, nanosec: np.ndarray) -> FloatArray:
    return np.asarray(sec, dtype=np.float64) + np.asarray(nanosec, dtype=np.float64) * 1e-9


def _samples(recording: Recording, keeping: SampleKeeping) -> Samples:
    """The 1 kHz state and force samples of ``recording`` that ``keeping`` keeps, decoded _BATCH messages
    at a time as the chunks stream past."""
    fields = {
        STATE: (*STAMP_FIELDS, *_stored_fields(recording, STATE, STATE_FIELDS)),
        GRF: (*STAMP_FIELDS, *GRF_FIELDS),
    }
    names = {recording.name(topic): topic for topic in fields}
    pending: dict[str, list[bytes]] = {topic: [] for topic in fields}
    streams = {topic: keeping.stream() for topic in fields}
    columns: dict[str, list[dict[str, np.ndarray]]] = {topic: [] for topic in fields}

    def flush(topic: str) -> None:
        batch, schema = pending[topic], recording.schema(topic)
        decoded = _checked(
            recording.name(topic),
            lambda: decoded_columns(_stored(recording, topic, schema), batch, fields[topic]),
        )
        kept = streams[topic].kept(_stamp_seconds(decoded[STAMP_FIELDS[0]], decoded[STAMP_FIELDS[1]]))
        columns[topic].append({name: column[kept] for name, column in decoded.items()})
        pending[topic] = []

    with _as_run_error():
        for batch in iter_topic_batches(recording.bag, names):
            for name, (datas, _) in batch.items():
                topic = names[name]
                pending[topic].extend(datas)
                if len(pending[topic]) >= _BATCH:
                    flush(topic)
    for topic in fields:
        if pending[topic]:
            flush(topic)

    def joined(topic: str, path: str) -> np.ndarray:
        if path not in fields[topic]:  # a field the bag's schema predates: 0, its value on the fixed body
            return np.zeros(sum(len(batch[STAMP_FIELDS[0]]) for batch in columns[topic]))
        return np.concatenate([batch[path] for batch in columns[topic]]) if columns[topic] else np.empty(0)

    t = _stamp_seconds(joined(STATE, "header.stamp.sec"), joined(STATE, "header.stamp.nanosec"))
    grf_t = _stamp_seconds(joined(GRF, "header.stamp.sec"), joined(GRF, "header.stamp.nanosec"))
    order, grf_order = np.argsort(t, kind="stable"), np.argsort(grf_t, kind="stable")
    state = {name: joined(STATE, name)[order] for name in STATE_FIELDS}
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
        ground_height=state["ground_height"],
        pitch=state["pitch"],
        pitch_rate=state["pitch_rate"],
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
        float(msg.ground_height),
        float(msg.measured_height),
        float(msg.measured_forward_speed),
        *_pitch(msg),
    )


def _pitch(msg: Any) -> tuple[float, float]:
    """A message's (pitch, pitch rate): (0, 0) where its bag predates them (tdslip_msgs 0.1.0)."""
    return float(getattr(msg, "pitch", 0.0)), float(getattr(msg, "pitch_rate", 0.0))


def _state(msg: Any) -> HopperState:
    """The state of a contact event; its message holds no ground reaction force (NaN)."""
    phase = PHASES.get(int(msg.phase))
    if phase is None:
        raise RunReadError(f"topic {CONTACT}: unknown phase {msg.phase} of an event's state")
    pitch, pitch_rate = _pitch(msg)
    return HopperState(
        t=float(msg.header.stamp.sec) + float(msg.header.stamp.nanosec) * 1e-9,
        stride=int(msg.stride),
        phase=phase,
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
        grf_x=math.nan,
        grf_y=math.nan,
        ground_height=float(msg.ground_height),
        pitch=pitch,
        pitch_rate=pitch_rate,
    )


def _contact(msg: Any) -> ContactRecord:
    kind = CONTACT_KINDS.get(int(msg.kind))
    if kind is None:
        raise RunReadError(f"topic {CONTACT}: unknown contact kind {msg.kind}")
    return ContactRecord(
        kind, int(msg.stride), float(msg.sim_time), _state(msg.state), float(msg.ground_height)
    )


def _command(msg: Any, log_time_ns: int) -> CommandRecord:
    return CommandRecord(
        int(msg.stride),
        float(msg.touchdown_angle),
        float(msg.tau0),
        float(msg.t_f),
        str(msg.policy),
        log_time_ns,
        int(getattr(msg, "stance", 0)),
    )


def _status(msg: Any) -> StatusRecord:
    return StatusRecord(int(msg.stride), float(msg.sim_time), str(msg.kind), str(msg.reason), bool(msg.fatal))


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
    params: HopperParams, apexes: Sequence[ApexRecord], contacts: Sequence[ContactRecord], what: str
) -> None:
    """The recorded events must follow from ``params`` (``what`` names them in the error): the energies
    of apexes and stance events (mass, stiffness, rest length, gravity) and, at every liftoff, a leg
    force k (r0 - r) - c rdot of zero (the damping, which no energy shows)."""
    worst, where = 0.0, ""
    inertia = 0.0 if params.body is None else params.body.inertia  # a rigid body's J phidot^2 / 2 counts
    for apex in apexes:
        expected = params.m * (params.g * apex.y + 0.5 * apex.xdot**2) + 0.5 * inertia * apex.pitch_rate**2
        error = abs(expected - apex.energy) / abs(apex.energy)
        if error > worst:
            worst, where = error, f"apex {apex.stride}"
    for contact in contacts:
        s = contact.state  # (x, y) the centre of mass's
        expected = (
            0.5 * params.m * (s.xdot**2 + s.ydot**2)
            + 0.5 * inertia * s.pitch_rate**2
            + params.m * params.g * s.y
            + 0.5 * params.k * (s.r - params.r0) ** 2
        )
        error = abs(expected - s.energy) / abs(s.energy)
        if error > worst:
            worst, where = error, f"{contact.kind} of stride {contact.stride}"
    if worst > PARAMETER_CONSISTENCY:
        raise RunReadError(
            f"{what} contradict the recorded energies (relative mismatch {worst:.2e} at the {where}); "
            f"{_PARAMETERS_ADVICE}"
        )
    critical = 2.0 * math.sqrt(params.m * params.k)
    for liftoff in (c for c in contacts if c.kind == "liftoff" and c.state.rdot > 0.0):
        s = liftoff.state
        shown = params.k * (params.r0 - s.r) / s.rdot
        if abs(shown - params.c) / critical > DAMPING_CONSISTENCY:
            raise RunReadError(
                f"{what} contradict the recorded liftoff of stride {liftoff.stride}: damping c = "
                f"{params.c:.6g} N s/m (zeta0 {params.c / critical:.6f}), the liftoff shows c = "
                f"{shown:.6g} N s/m (zeta0 {shown / critical:.6f}); {_PARAMETERS_ADVICE}"
            )


_PARAMETERS_ADVICE = (
    "give the hopper parameters the run was recorded with (tdslip analyze --params FILE), or none to "
    "use those stored in or inferred from the recording"
)
