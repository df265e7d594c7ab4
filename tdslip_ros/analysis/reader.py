"""Load a recorded run (a bare ``.mcap`` or a rosbag2 bag directory) without rclpy.

The recording is opened and checked by :mod:`tdslip_ros.bag.reader` (magic, footer, summary CRC,
chunk CRCs, message counts) and its messages decoded by :mod:`tdslip_ros.bag.cdr` from the schemas
stored in it; the two 1 kHz topics (state and ground reaction force) take the vectorised path to
numpy columns.

What comes out (:class:`Run`) is tidy: one :class:`StrideRecord` per recorded apex (its state, the
command applied in the stance that follows, that stance's energy flows, the failure that ended the
run in it), the contact events, every command and status message, and the 1 kHz samples as
arrays. Heights are in the world frame, as recorded; each record carries its ground height.

A stride under stance feedback (a command with ``stance`` STANCE_FEEDBACK) has no ramp: its record holds
the stance feedback as applied instead (:attr:`StrideRecord.stance_feedback`), the touchdown angle and the
torques the plant held, from ``tdslip/applied_torque``, replayable by the model's engines
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
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from mcap.records import Schema

from tdslip_ros.bag.cdr import decoded_columns, decoder
from tdslip_ros.bag.reader import Bag, BagReadError, iter_messages, open_bag
from tdslip_ros.interfaces import (
    APEX,
    APPLIED_TORQUE,
    COMMAND,
    CONTACT,
    GRF,
    GRF_FIELDS,
    HOPPER_PARAMETERS,
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
from tdslip_ros.model import dynamics
from tdslip_ros.model.params import HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.perturbations import Perturbations, placed_angle
from tdslip_ros.model.plant.stance_laws import DEFAULT_SAMPLE_PERIOD, RecordedTorques, StanceFeedback

FloatArray = npt.NDArray[np.float64]


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
DAMPING_CONSISTENCY = 1e-6
"""Largest mismatch of the damping ratio zeta0 = c / (2 sqrt(m k)) with the recorded liftoffs."""
STANCE_FEEDBACK = 1
"""StanceCommand.stance of a command answering with stance feedback (0: the ramp)."""
REQUIRED_TOPICS = (APEX,)
"""The suite topics a run cannot be analysed without; the others may be missing (no messages)."""

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


# --- the file -----------------------------------------------------------------------------------


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


# --- records ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ApexRecord:
    """An ApexEvent: apex ``stride`` at sim time t [s]; energy flows of the stance before it [J]; ground
    height of that stance [m] and the apex the controller's sensor reported (world frame)."""

    stride: int
    t: float
    x: float
    y: float
    xdot: float
    energy: float
    hip_work: float
    damping_loss: float
    spring_loss: float
    ground: float = 0.0
    measured_y: float = math.nan
    measured_xdot: float = math.nan


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
    ground_height: float = 0.0


@dataclass(frozen=True)
class ContactRecord:
    """A touchdown, bottom or liftoff of the stance after apex ``stride``, on ground [m] (the toe's)."""

    kind: str
    stride: int
    t: float
    state: StateRecord
    ground: float = 0.0


@dataclass(frozen=True)
class CommandRecord:
    """A StanceCommand message as received by the recorder (log_time_ns: reception time)."""

    stride: int
    touchdown_angle: float
    tau0: float
    t_f: float
    policy: str
    log_time_ns: int
    stance: int = 0
    """0: the ramp tau0, t_f; STANCE_FEEDBACK: torques streamed per tick (recordings before it: 0)."""


@dataclass(frozen=True)
class TorqueRecord:
    """A hip torque the plant applied (tdslip/applied_torque): held from plant tick ``tick`` on in the
    stance of ``stride``."""

    stride: int
    tick: int
    torque: float


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

    Perturbations: y is the apex height in the world frame, ``ground`` that of the stance before the apex
    (y - ground the height the maps and policies use), ``stance_ground`` that of this stride's stance (NaN
    without a touchdown); measured_y, measured_xdot: the apex as the controller's sensor reported it;
    angle_error [rad]: the placement error drawn for the stride; placed_angle [rad]: where the leg landed
    (the command's angle plus the placement error, NaN without a command); push [m/s]:
    applied right after the apex; saturated: |tau0| exceeded tau_max.

    Stance feedback: ``command`` is None and ``stance_feedback`` the stance as applied, its touchdown angle
    and the torques held (sample times on the plant's clock, :class:`RecordedTorques`); saturated: one of
    them is at tau_max.
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
    ground: float = 0.0
    stance_ground: float = math.nan
    measured_y: float = math.nan
    measured_xdot: float = math.nan
    angle_error: float = 0.0
    placed_angle: float = math.nan
    push: float = 0.0
    saturated: bool = False
    stance_feedback: StanceFeedback | None = None

    @property
    def height(self) -> float:
        """The apex height above the ground of the last stance [m]."""
        return self.y - self.ground


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
    ground_height: FloatArray
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
    perturbations: Perturbations = field(default_factory=Perturbations)
    controller_params: HopperParams | None = None
    """The hopper the controller planned with (None: the plant's, ``params``)."""

    @property
    def planner(self) -> HopperParams:
        """The hopper the controller planned with: controller_params, else the plant's."""
        return self.params if self.controller_params is None else self.controller_params

    @property
    def saturated_strides(self) -> int:
        return sum(s.saturated for s in self.strides)

    @property
    def policies(self) -> tuple[str, ...]:
        """Names of the policies whose commands were applied, in order of first use."""
        applied = (s for s in self.strides if s.command is not None or s.stance_feedback is not None)
        return tuple(dict.fromkeys(s.policy for s in applied))

    def apex_array(self) -> FloatArray:
        """(n, 2) apex heights above the ground of the last stance [m] and speeds [m/s] of the recorded
        strides (on flat ground the recorded heights)."""
        return np.array([(s.height, s.xdot) for s in self.strides], dtype=float).reshape(-1, 2)


def read_run(path: Path, params: HopperParams | None = None, namespace: str | None = None) -> Run:
    """Load a run (see the module docstring); ``params`` overrides the inferred hopper parameters,
    ``namespace`` chooses the hopper in a recording of several (see :func:`suite_namespace`)."""
    recording = open_recording(path, namespace=namespace)
    bag = recording.bag
    suite_topics = {recording.name(topic): topic for topic in TOPIC_TYPES}
    events: dict[str, list[bytes]] = {topic: [] for topic in (APEX, CONTACT, STATUS, COMMAND, APPLIED_TORQUE)}
    log_times: list[int] = []
    stream_batches: dict[str, list[bytes]] = {STATE: [], GRF: []}
    columns: dict[str, list[dict[str, np.ndarray]]] = {STATE: [], GRF: []}
    fields = {STATE: (*STAMP_FIELDS, *STATE_FIELDS), GRF: (*STAMP_FIELDS, *GRF_FIELDS)}

    def flush(topic: str) -> None:
        batch, schema = stream_batches[topic], recording.schema(topic)
        columns[topic].append(
            _checked(
                recording.name(topic),
                lambda: (
                    decoded_columns(_stored(recording, topic, schema), batch, fields[topic])
                    if batch
                    else {path: np.empty(0) for path in fields[topic]}
                ),
            )
        )
        stream_batches[topic] = []

    with _as_run_error():
        for channel, message in iter_messages(bag, topics=suite_topics):
            topic = suite_topics[channel.topic]
            if topic in stream_batches:
                stream_batches[topic].append(message.data)
                if len(stream_batches[topic]) >= _BATCH:
                    flush(topic)
            else:
                events[topic].append(message.data)
                if topic == COMMAND:
                    log_times.append(message.log_time)
    for topic in stream_batches:
        flush(topic)

    decoded = {topic: _decode_all(recording, topic, datas) for topic, datas in events.items()}
    apexes = sorted((_apex(m) for m in decoded[APEX]), key=lambda a: a.t)
    contacts = sorted((_contact(m) for m in decoded[CONTACT]), key=lambda c: c.t)
    commands = [_command(m, log_time) for m, log_time in zip(decoded[COMMAND], log_times, strict=True)]
    statuses = sorted((_status(m) for m in decoded[STATUS]), key=lambda s: s.t)
    torques = sorted(
        (TorqueRecord(int(m.stride), int(m.tick), float(m.torque)) for m in decoded[APPLIED_TORQUE]),
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
    samples = _samples(columns)
    source = "given"
    if params is None:
        params, source = _stored_params(recording), "stored in the recording"
    if params is None:
        params, source = infer_params(apexes, contacts, bag.mcap_path), "inferred from the recording"
    _check_params(params, apexes, contacts, f"{bag.mcap_path}: the hopper parameters {source}")
    outcome = next((s for s in statuses if s.fatal), None)
    perturbations = _stored_perturbations(recording)
    return Run(
        path=Path(path),
        params=params,
        params_source=source,
        strides=_strides(apexes, contacts, commands, outcome, perturbations, torques),
        apexes=tuple(apexes),
        contacts=tuple(contacts),
        commands=tuple(commands),
        statuses=tuple(statuses),
        samples=samples,
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


def _decode_all(recording: Recording, topic: str, datas: list[bytes]) -> list[Any]:
    if not datas:
        return []
    with _as_run_error():
        decode = decoder(_stored(recording, topic, recording.schema(topic)))
    return [_checked(recording.name(topic), partial(decode, data)) for data in datas]


def _stamp_seconds(sec: np.ndarray, nanosec: np.ndarray) -> FloatArray:
    return np.asarray(sec, dtype=np.float64) + np.asarray(nanosec, dtype=np.float64) * 1e-9


def _samples(columns: dict[str, list[dict[str, np.ndarray]]]) -> Samples:
    def joined(topic: str, path: str) -> np.ndarray:
        return np.concatenate([batch[path] for batch in columns[topic]])

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
        ground_height=float(msg.ground_height),
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


# --- from messages to strides -------------------------------------------------------------------


def applied_commands(
    contacts: Sequence[ContactRecord],
    commands: Sequence[CommandRecord],
    perturbations: Perturbations | None = None,
) -> dict[int, CommandRecord]:
    """The command applied at each recorded touchdown, by stride.

    The plant applies the latest valid command answering the stride, or keeps the one in force. At
    touchdown the leg is at the commanded angle (plus the stride's placement error, reproduced from the
    ``perturbations``) and the hip torque equals tau0 (saturated at tau_max), both copied exactly into
    the touchdown state, so the applied command is the last command answering the stride that matches
    them bit for bit, else the command applied before it if that one matches. A touchdown that no
    recorded command matches (the plant's initial command) gets none.
    """
    perturbations = perturbations or Perturbations()
    by_stride: dict[int, list[CommandRecord]] = {}
    for command in sorted(commands, key=lambda c: c.log_time_ns):
        by_stride.setdefault(command.stride, []).append(command)
    applied: dict[int, CommandRecord] = {}
    in_force: CommandRecord | None = None
    touchdowns = [c for c in contacts if c.kind == "touchdown"]
    errors = _angle_errors(perturbations, max((c.stride for c in touchdowns), default=-1) + 1)
    for touchdown in touchdowns:

        def matches(command: CommandRecord | None, touchdown: ContactRecord = touchdown) -> bool:
            return command is not None and _applied_at(command, touchdown, perturbations, errors)

        candidates = [c for c in by_stride.get(touchdown.stride, []) if matches(c)]
        chosen = candidates[-1] if candidates else in_force if matches(in_force) else None
        if chosen is not None:
            applied[touchdown.stride] = chosen
        in_force = chosen
    return applied


def _angle_errors(perturbations: Perturbations, strides: int) -> FloatArray:
    """The placement errors of the first ``strides`` strides of the run (trajectory 0: epoch 0)."""
    return perturbations.draws([0], 0, strides).angle_error[:, 0]


def _applied_at(
    command: CommandRecord, touchdown: ContactRecord, perturbations: Perturbations, errors: FloatArray
) -> bool:
    placed = placed_angle(command.touchdown_angle, float(errors[touchdown.stride]))
    torque = command.tau0  # stance feedback: 0, the hold from touchdown to the first sample instant
    if perturbations.saturates and command.stance != STANCE_FEEDBACK:
        torque = float(dynamics.hip_torque(command.tau0, command.t_f, 0.0, float(perturbations.tau_max)))
    return bool(placed == touchdown.state.theta and torque == touchdown.state.hip_torque)


def _strides(
    apexes: Sequence[ApexRecord],
    contacts: Sequence[ContactRecord],
    commands: Sequence[CommandRecord],
    outcome: StatusRecord | None,
    perturbations: Perturbations,
    torques: Sequence[TorqueRecord] = (),
) -> tuple[StrideRecord, ...]:
    applied = applied_commands(contacts, commands, perturbations)
    held: dict[int, list[TorqueRecord]] = {}
    for torque in torques:
        held.setdefault(torque.stride, []).append(torque)
    event_times = {(c.kind, c.stride): c.t for c in contacts}
    stance_grounds = {c.stride: c.ground for c in contacts if c.kind == "touchdown"}
    next_apex = {a.stride - 1: a for a in apexes}
    draws = perturbations.draws([0], 0, max((a.stride for a in apexes), default=-1) + 1)
    tau_max = float(perturbations.tau_max) if perturbations.saturates else math.inf
    records = []
    for apex in apexes:
        record = applied.get(apex.stride)
        feedback, command, saturated = None, None, False
        if record is not None and record.stance == STANCE_FEEDBACK:
            stance_torques = held.get(apex.stride, [])
            feedback = _feedback(record, stance_torques)
            saturated = any(abs(r.torque) >= tau_max for r in stance_torques)
        elif record is not None:
            command = StanceCommand(record.touchdown_angle, record.tau0, record.t_f)
            saturated = abs(command.tau0) > tau_max
        after = next_apex.get(apex.stride)
        failed = outcome is not None and outcome.kind in FAILURE_KINDS and outcome.stride == apex.stride
        error = float(draws.angle_error[apex.stride, 0])
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
                ground=apex.ground,
                stance_ground=stance_grounds.get(apex.stride, math.nan),
                measured_y=apex.measured_y,
                measured_xdot=apex.measured_xdot,
                angle_error=error,
                placed_angle=math.nan if record is None else placed_angle(record.touchdown_angle, error),
                push=float(draws.push[apex.stride, 0]),
                saturated=saturated,
                stance_feedback=feedback,
            )
        )
    return tuple(records)


def _feedback(command: CommandRecord, torques: Sequence[TorqueRecord]) -> StanceFeedback:
    """The stance feedback of a stride as applied: the command's touchdown angle, and each torque held from
    its tick's instant on the plant's clock (tick * the sample period, the stepper's own arithmetic)."""
    times = np.array([r.tick for r in torques], dtype=float) * DEFAULT_SAMPLE_PERIOD
    law = RecordedTorques(times, np.array([r.torque for r in torques], dtype=float))
    return StanceFeedback(command.touchdown_angle, law)


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
