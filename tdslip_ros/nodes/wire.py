"""What the nodes put on the wire: every message they publish, serialised with no undefined byte.

rclpy's ``serialize_message`` (and an RMW serialising a message object) leaves CDR alignment padding
as it finds it in memory, so a message object published as it is can carry bytes of the process's
heap into every subscriber and recording. The nodes therefore publish bytes: :func:`serialized` for
the event-rate messages (padding zeroed from the message's schema, :mod:`tdslip_ros.bag.padding`),
:func:`fixed_layout_encoder` for the 1 kHz ones (a zero-padded template whose fields are packed in
place). The same options thus give the same bytes in every process, on every machine.

The 1 kHz samples also travel in batches (``tdslip_msgs/HopperSamples``, :func:`sample_batch`), one
row per tick; a recorder turns each row back into the tick's HopperState and WrenchStamped
(:func:`sample_rows`, :func:`state_encoder`, :func:`grf_encoder`), byte for byte the messages the plant
publishes live.
"""

from __future__ import annotations

from collections.abc import Iterator
from functools import cache, lru_cache

from builtin_interfaces.msg import Time
from geometry_msgs.msg import WrenchStamped
from mcap.records import Schema
from rclpy.serialization import deserialize_message, serialize_message
from tdslip_msgs.msg import HopperSamples, HopperState, StanceCommand

from tdslip_ros.bag.cdr import FixedLayoutEncoder, SequenceColumns
from tdslip_ros.bag.padding import PaddingZeroer, padded_to_4
from tdslip_ros.bag.schema import message_definition
from tdslip_ros.interfaces import GRF_FIELDS, STAMP_FIELDS, STATE_FIELDS
from tdslip_ros.model.events import HopperState as ModelState
from tdslip_ros.model.events import Phase
from tdslip_ros.nodes import topics

_NS_PER_S = 1_000_000_000


@cache
def _definition(message_class: type) -> tuple[str, str]:
    """(``pkg/msg/Type``, schema text) of a message class."""
    name = topics.type_name(message_class)
    return name, message_definition(name)


@cache
def _zeroer(message_class: type) -> PaddingZeroer:
    return PaddingZeroer(*_definition(message_class))


def serialized(msg: object) -> bytes:
    """``msg`` as CDR bytes with every padding byte zero, in the length the RMW would publish it."""
    return padded_to_4(_zeroer(type(msg))(serialize_message(msg)))


def stamp_of(t: float) -> tuple[int, int]:
    """(sec, nanosec) of a time t [s]."""
    sec, nanosec = divmod(round(t * _NS_PER_S), _NS_PER_S)
    return sec, nanosec


def set_stamp(stamp: Time, t: float) -> None:
    stamp.sec, stamp.nanosec = stamp_of(t)


SAMPLE_FIELDS = (*STAMP_FIELDS, *STATE_FIELDS)
"""The fields of a HopperState message that :func:`state_values` gives, in the message's order."""


def state_values(state: ModelState, t: float) -> tuple[int | float, ...]:
    """The values of :data:`SAMPLE_FIELDS` for a model state stamped t [s]."""
    sec, nanosec = stamp_of(t)
    phase = HopperState.PHASE_STANCE if state.phase is Phase.STANCE else HopperState.PHASE_FLIGHT
    return (
        sec,
        nanosec,
        state.stride,
        phase,
        state.x,
        state.y,
        state.xdot,
        state.ydot,
        state.toe_x,
        state.toe_y,
        state.r,
        state.theta,
        state.rdot,
        state.thetadot,
        state.hip_torque,
        state.energy,
        state.ground_height,
        state.pitch,
        state.pitch_rate,
    )


def fixed_layout_encoder(
    message_class: type, fields: tuple[str, ...], template: object | None = None
) -> FixedLayoutEncoder:
    """An encoder of ``message_class`` from ``fields``' values; every other field as in ``template`` (its
    sequences keep their lengths), by default a new message with frame_id ``world`` where it has a header."""
    if template is None:
        template = message_class()
        if hasattr(template, "header"):
            template.header.frame_id = topics.FRAME_ID
    name, text = _definition(message_class)
    schema = Schema(id=0, name=name, encoding="ros2msg", data=text.encode())
    return FixedLayoutEncoder(schema, serialize_message(template), fields)


COMMAND_FIELDS = (*STAMP_FIELDS, "epoch", "stride", "touchdown_angle", "tau0", "t_f")


@lru_cache(maxsize=16)
def command_encoder(policy: str, frame_id: str) -> FixedLayoutEncoder:
    """A ramp StanceCommand of ``policy`` in frame ``frame_id`` from the values of :data:`COMMAND_FIELDS`
    (the frame's length places the fields after it, the policy's the byte after its name)."""
    template = StanceCommand(policy=policy)
    template.header.frame_id = frame_id
    return fixed_layout_encoder(StanceCommand, COMMAND_FIELDS, template)


@cache
def state_encoder() -> FixedLayoutEncoder:
    """The 1 kHz HopperState from the values of :data:`SAMPLE_FIELDS`."""
    return fixed_layout_encoder(HopperState, SAMPLE_FIELDS)


@cache
def grf_encoder() -> FixedLayoutEncoder:
    """The 1 kHz ground reaction force (WrenchStamped) from (sec, nanosec, force x, force y)."""
    return fixed_layout_encoder(WrenchStamped, (*STAMP_FIELDS, *GRF_FIELDS))


SAMPLE_COLUMNS = ("sec", "nanosec", *STATE_FIELDS, "force_x", "force_y")
"""The arrays of a HopperSamples in the order of a sample row: the values of :data:`SAMPLE_FIELDS`, then
the ground reaction force."""


def sample_batch() -> SequenceColumns:
    """An empty batch of sample rows (the values of :data:`SAMPLE_FIELDS`, force x, force y), whose
    ``take()`` is a serialised HopperSamples."""
    name, text = _definition(HopperSamples)
    batch = SequenceColumns(Schema(id=0, name=name, encoding="ros2msg", data=text.encode()))
    assert batch.names == SAMPLE_COLUMNS, batch.names
    return batch


def sample_rows(data: bytes) -> Iterator[tuple[int | float, ...]]:
    """The rows of a serialised HopperSamples, in order."""
    batch = deserialize_message(data, HopperSamples)
    return zip(*(getattr(batch, name) for name in SAMPLE_COLUMNS), strict=True)
