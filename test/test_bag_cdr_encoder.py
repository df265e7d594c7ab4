"""The encoders the plant publishes its 1 kHz messages with give what rclpy's serialize_message gives for
the same message: the rosidl type support (the independent truth) reads it back as that very message, from
bytes of the same length. So do the batches of samples (HopperSamples), and a batch's rows written back as
messages are the plant's live messages, byte for byte."""

from __future__ import annotations

import math
import random
from dataclasses import replace

import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import WrenchStamped
from mcap.records import Schema
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from tdslip_msgs.msg import ApexEvent, ContactEvent, HipTorque, HopperSamples, HopperState, StanceCommand
from visualization_msgs.msg import Marker, MarkerArray

from tdslip_ros.bag.cdr import FixedLayoutEncoder, SequenceColumns
from tdslip_ros.bag.schema import message_definition
from tdslip_ros.interfaces import GRF_FIELDS
from tdslip_ros.model.events import HopperState as ModelState
from tdslip_ros.model.events import Phase
from tdslip_ros.nodes.markers import GRF_SCALE, GROUND_HALF_WINDOW, HopperMarkers
from tdslip_ros.nodes.plant_output import APEX_FIELDS, CONTACT_FIELDS
from tdslip_ros.nodes.wire import (
    SAMPLE_COLUMNS,
    SAMPLE_FIELDS,
    command_encoder,
    fixed_layout_encoder,
    grf_encoder,
    sample_batch,
    sample_rows,
    serialized,
    state_encoder,
    state_values,
)

NUMBERS = (
    "x y xdot ydot toe_x toe_y r theta rdot thetadot hip_torque energy grf_x grf_y ground_height".split()
)


def random_state(rng: random.Random) -> ModelState:
    numbers = {name: rng.uniform(-1e3, 1e3) for name in NUMBERS}
    t = rng.uniform(0.0, 1e5)
    return ModelState(t=t, stride=rng.randrange(2**32), phase=rng.choice(list(Phase)), **numbers)


def fill_state(msg: HopperState, state: ModelState, t: float) -> None:
    """A model state copied into a HopperState message stamped t [s], field by field: the message the
    encoders must give the bytes of."""
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(round(t * 1e9), 1_000_000_000)
    msg.stride = state.stride
    msg.phase = HopperState.PHASE_STANCE if state.phase is Phase.STANCE else HopperState.PHASE_FLIGHT
    msg.x, msg.y, msg.xdot, msg.ydot = state.x, state.y, state.xdot, state.ydot
    msg.toe_x, msg.toe_y = state.toe_x, state.toe_y
    msg.leg_length, msg.leg_angle = state.r, state.theta
    msg.leg_length_rate, msg.leg_angle_rate = state.rdot, state.thetadot
    msg.hip_torque, msg.energy, msg.ground_height = state.hip_torque, state.energy, state.ground_height


def test_hopper_states_encode_to_the_bytes_of_serialize_message() -> None:
    rng = random.Random(7)
    encoder = fixed_layout_encoder(HopperState, SAMPLE_FIELDS)
    for _ in range(500):
        state = random_state(rng)
        msg = HopperState()
        msg.header.frame_id = "world"
        fill_state(msg, state, state.t)
        data = encoder.encode(state_values(state, state.t))
        # rosidl's own type support reads back exactly the message that fill_state builds. (The bytes
        # may differ in CDR padding, which serialize_message leaves as it finds it in its buffer.)
        assert deserialize_message(data, HopperState) == msg
        assert len(data) == len(serialize_message(msg))
        assert deserialize_message(data, HopperState).energy == state.energy


@pytest.mark.parametrize(
    ("message_class", "fields", "values"),
    [
        (
            WrenchStamped,
            ("header.stamp.sec", "header.stamp.nanosec", "wrench.force.x", "wrench.force.y"),
            None,
        ),
        (Clock, ("clock.sec", "clock.nanosec"), None),
    ],
)
def test_grf_and_clock_encode_to_the_bytes_of_serialize_message(
    message_class: type, fields: tuple[str, ...], values: None
) -> None:
    rng = random.Random(11)
    encoder = fixed_layout_encoder(message_class, fields)
    for _ in range(200):
        sec, nanosec = rng.randrange(2**31), rng.randrange(10**9)
        msg = message_class()
        stamp: Time = msg.clock if message_class is Clock else msg.header.stamp
        stamp.sec, stamp.nanosec = sec, nanosec
        numbers: tuple[float, ...] = ()
        if message_class is WrenchStamped:
            msg.header.frame_id = "world"
            numbers = (rng.uniform(-1e4, 1e4), math.ldexp(rng.random(), -1000))
            msg.wrench.force.x, msg.wrench.force.y = numbers
        data = encoder.encode((sec, nanosec, *numbers))
        assert deserialize_message(data, message_class) == msg
        assert len(data) == len(serialize_message(msg))


def test_hip_torques_encode_their_64_bit_tick_to_the_bytes_of_serialize_message() -> None:
    encoder = fixed_layout_encoder(
        HipTorque, ("header.stamp.sec", "header.stamp.nanosec", "epoch", "stride", "tick", "torque")
    )
    rng = random.Random(5)
    for _ in range(200):
        values = (rng.randrange(2**31), rng.randrange(10**9), rng.randrange(2**32), rng.randrange(2**32))
        tick, torque = rng.randrange(2**64), rng.uniform(-1e3, 1e3)
        msg = HipTorque(epoch=values[2], stride=values[3], tick=tick, torque=torque)
        msg.header.frame_id = "world"
        msg.header.stamp.sec, msg.header.stamp.nanosec = values[:2]
        data = encoder.encode((*values, tick, torque))
        assert deserialize_message(data, HipTorque) == msg and data == serialized(msg)


def schema_of(type_name: str) -> Schema:
    return Schema(id=0, name=type_name, encoding="ros2msg", data=message_definition(type_name).encode())


def test_what_it_cannot_encode_is_refused_when_it_is_made() -> None:
    state = serialize_message(HopperState())
    with pytest.raises(ValueError, match="no fixed CDR layout"):  # bytes of another message
        FixedLayoutEncoder(schema_of("visualization_msgs/msg/MarkerArray"), state, ())
    with pytest.raises(ValueError, match="no primitive field markers.0.id"):  # arrays are indexed: [0]
        FixedLayoutEncoder(
            schema_of("visualization_msgs/msg/MarkerArray"),
            serialize_message(MarkerArray()),
            ("markers.0.id",),
        )
    with pytest.raises(ValueError, match="no primitive field height"):
        FixedLayoutEncoder(schema_of("tdslip_msgs/msg/HopperState"), state, ("height",))
    with pytest.raises(ValueError, match="in the message's order"):
        FixedLayoutEncoder(schema_of("tdslip_msgs/msg/HopperState"), state, ("y", "x"))


def test_the_batch_declares_one_column_per_field_of_the_live_messages() -> None:
    assert tuple(HopperSamples.get_fields_and_field_types()) == SAMPLE_COLUMNS
    assert len(SAMPLE_COLUMNS) == len(SAMPLE_FIELDS) + len(GRF_FIELDS)


@pytest.mark.parametrize("rows", [0, 1, 2, 3, 50])
def test_sample_batches_serialise_as_rclpy_does_and_give_back_the_live_messages(rows: int) -> None:
    rng = random.Random(rows)
    states = [random_state(rng) for _ in range(rows)]
    times = [rng.uniform(0.0, 1e5) for _ in range(rows)]
    values = [(*state_values(s, t), s.grf_x, s.grf_y) for s, t in zip(states, times, strict=True)]
    batch = sample_batch()
    for row in values:
        batch.append(row)
    data = batch.take()
    assert len(batch) == 0
    reference = HopperSamples(**{name: [row[i] for row in values] for i, name in enumerate(SAMPLE_COLUMNS)})
    assert data == serialized(reference)  # padding zero, as the plant's other messages
    assert deserialize_message(data, HopperSamples) == reference
    written = list(sample_rows(data))
    assert len(written) == rows
    for row, state, t in zip(written, states, times, strict=True):
        live = HopperState()
        live.header.frame_id = "world"
        fill_state(live, state, t)
        assert state_encoder().encode(row[:-2]) == serialized(live)
        force = WrenchStamped()
        force.header.frame_id = "world"
        force.header.stamp.sec, force.header.stamp.nanosec = row[:2]
        force.wrench.force.x, force.wrench.force.y = state.grf_x, state.grf_y
        assert grf_encoder().encode((*row[:2], *row[-2:])) == serialized(force)


def test_sequence_columns_refuse_a_message_with_other_fields() -> None:
    with pytest.raises(ValueError, match="not sequences of primitives: header, stride, phase, x,"):
        SequenceColumns(schema_of("tdslip_msgs/msg/HopperState"))


def test_markers_encode_in_place_to_the_bytes_of_serialize_message() -> None:
    """Arrays keep the lengths of the template (two points a line): the drawing's stamps and coordinates
    land where rclpy puts them, every other byte as rclpy serialises the template."""
    rng = random.Random(13)
    for index in range(100):
        rigid = index % 2 == 1  # a rigid body's trunk drawn, the fixed body's deleted
        drawing = HopperMarkers("world", rigid)
        state, t, ground = random_state(rng), rng.uniform(0.0, 1e4), rng.uniform(-1.0, 1.0)
        if rng.random() < 0.3:
            state = replace(state, grf_x=0.0, grf_y=0.0)  # flight: the arrow deleted
        data = drawing.encoded(state, t, ground)
        message = deserialize_message(data, MarkerArray)
        assert serialized(message) == data
        body, leg, toe, ground_line, grf, trunk = message.markers
        sec, nanosec = divmod(round(t * 1e9), 1_000_000_000)
        assert {(m.header.stamp.sec, m.header.stamp.nanosec) for m in message.markers} == {(sec, nanosec)}
        assert (body.pose.position.x, body.pose.position.z) == (state.x, state.y)
        assert (toe.pose.position.x, toe.pose.position.z) == (state.toe_x, state.toe_y)
        if not rigid:
            assert [(p.x, p.z) for p in leg.points] == [(state.x, state.y), (state.toe_x, state.toe_y)]
        assert trunk.action == (Marker.ADD if rigid else Marker.DELETE)
        assert [p.z for p in ground_line.points] == [ground, ground]
        assert ground_line.points[1].x - ground_line.points[0].x == pytest.approx(2 * GROUND_HALF_WINDOW)
        assert grf.action == (Marker.DELETE if state.grf_x == state.grf_y == 0.0 else Marker.ADD)
        assert (grf.points[1].x - state.toe_x) * GRF_SCALE == pytest.approx(state.grf_x, abs=1e-9)
        assert [m.id for m in message.markers] == list(range(6)) and body.color.b == pytest.approx(0.9)


def test_apex_and_contact_events_encode_to_the_bytes_of_serialize_message() -> None:
    rng = random.Random(17)
    apex_encoder = fixed_layout_encoder(ApexEvent, APEX_FIELDS)
    template = ContactEvent()
    template.header.frame_id = template.state.header.frame_id = "world"
    contact_encoder = fixed_layout_encoder(ContactEvent, CONTACT_FIELDS, template)
    for _ in range(200):
        state, t = random_state(rng), rng.uniform(0.0, 1e5)
        sec, nanosec = divmod(round(t * 1e9), 1_000_000_000)
        epoch, stride = rng.randrange(2**32), rng.randrange(2**32)
        numbers = [rng.uniform(-1e3, 1e3) for _ in range(12)]
        apex = ApexEvent(epoch=epoch, stride=stride)
        apex.header.frame_id = "world"
        apex.header.stamp.sec, apex.header.stamp.nanosec = sec, nanosec
        names = APEX_FIELDS[4:]
        for name, value in zip(names, [t, *numbers[: len(names) - 1]], strict=True):
            setattr(apex, name, value)
        assert apex_encoder.encode(
            (sec, nanosec, epoch, stride, t, *numbers[: len(names) - 1])
        ) == serialized(apex)
        kind = rng.choice([ContactEvent.TOUCHDOWN, ContactEvent.BOTTOM, ContactEvent.LIFTOFF])
        contact = ContactEvent(kind=kind, epoch=epoch, stride=stride, sim_time=t, ground_height=numbers[0])
        contact.header.frame_id = contact.state.header.frame_id = "world"
        contact.header.stamp.sec, contact.header.stamp.nanosec = sec, nanosec
        fill_state(contact.state, state, t)
        encoded = contact_encoder.encode(
            (sec, nanosec, kind, epoch, stride, t, numbers[0], *state_values(state, t))
        )
        assert encoded == serialized(contact)


@pytest.mark.parametrize("frame_id", ["world", "", "odom_of_a_longer_frame"])
@pytest.mark.parametrize("policy", ["energy", "deadbeat", "apex_foot_placement", "x"])
def test_stance_commands_encode_to_the_bytes_of_serialize_message(policy: str, frame_id: str) -> None:
    """The controller's answers: the frame's length moves the fields after it, the policy's the byte after
    its name; both are the encoder's key."""
    rng = random.Random(23)
    encoder = command_encoder(policy, frame_id)
    for _ in range(50):
        sec, nanosec = rng.randrange(2**31), rng.randrange(10**9)
        epoch, stride = rng.randrange(2**32), rng.randrange(2**32)
        angle, tau0, t_f = (rng.uniform(-1e3, 1e3) for _ in range(3))
        msg = StanceCommand(
            epoch=epoch, stride=stride, touchdown_angle=angle, tau0=tau0, t_f=t_f, policy=policy
        )
        msg.header.frame_id = frame_id
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        assert encoder.encode((sec, nanosec, epoch, stride, angle, tau0, t_f)) == serialized(msg)
