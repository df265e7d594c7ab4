"""Every byte a node publishes is defined: CDR padding is found from the schema and is zero.

Independent truths: rosidl's own type support (rclpy's ``deserialize_message``) for what each byte
means, and rosbags' CDR serialiser, which writes padding as zero, for what the bytes of a message
must be (up to the length: rosbags stops at the last field, an RMW publishes a multiple of 4 bytes).
"""

from __future__ import annotations

import random
from typing import Any

import pytest
from geometry_msgs.msg import WrenchStamped
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosgraph_msgs.msg import Clock
from support.helpers import fill
from tdslip_msgs.msg import ApexEvent, ContactEvent, HopperState, RecorderStatus, StanceCommand, Status
from visualization_msgs.msg import MarkerArray

from tdslip_ros.bag.padding import PaddingError, PaddingZeroer, layout, padded_to_4, padding_positions
from tdslip_ros.bag.schema import message_definition
from tdslip_ros.model.events import HopperState as ModelState
from tdslip_ros.model.events import Phase
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.markers import HopperMarkers
from tdslip_ros.nodes.wire import serialized

FILLED_TYPES = (
    HopperState,
    WrenchStamped,
    Clock,
    ApexEvent,
    ContactEvent,
    Status,
    StanceCommand,
    RecorderStatus,
)


def random_markers(rng: random.Random) -> Any:
    state = ModelState(
        t=rng.uniform(0, 10),
        stride=rng.randrange(100),
        phase=rng.choice(list(Phase)),
        **{
            name: rng.uniform(-2.0, 2.0)
            for name in "x y xdot ydot toe_x toe_y r theta rdot thetadot hip_torque energy grf_x grf_y".split(
                " "
            )
        },
        ground_height=rng.uniform(-0.1, 0.1),
    )
    drawn = HopperMarkers(topics.FRAME_ID).encoded(state, rng.randrange(100), state.ground_height)
    return deserialize_message(drawn, MarkerArray)


def messages(count: int, seed: int = 5) -> list[Any]:
    """Random messages of every type the nodes publish. Their sequences are not empty: Fast-CDR (rclpy, every
    ROS 2 RMW) aligns an empty sequence of 8-byte numbers for its elements, where rosbags does not (an empty
    tdslip_msgs/HopperSamples: 140 bytes against 80)."""
    rng = random.Random(seed)
    out: list[Any] = []
    for _ in range(count):
        for message_class in FILLED_TYPES:
            message = message_class()
            fill(rng, message, shortest=1)
            out.append(message)
        out.append(random_markers(rng))
    return out


def rosbags_typestore(type_names: set[str]) -> Any:
    store = get_typestore(Stores.EMPTY)
    for name in type_names:
        store.register(get_types_from_msg(message_definition(name), name))
    return store


def test_serialized_messages_are_what_rosbags_writes_and_mean_what_rclpy_meant() -> None:
    sample = messages(20)
    names = {topics.type_name(type(message)) for message in sample}
    store = rosbags_typestore(names)
    for message in sample:
        name = topics.type_name(type(message))
        data = serialized(message)
        assert deserialize_message(data, type(message)) == deserialize_message(
            serialize_message(message), type(message)
        )
        # rosbags stops at the last field; the RMW publishes up to a multiple of 4 bytes, and so do we.
        assert padded_to_4(store.serialize_cdr(store.deserialize_cdr(data, name), name)) == data, name


@pytest.mark.parametrize("message_class", [*FILLED_TYPES, "markers"])
def test_padding_positions_are_exactly_the_bytes_that_mean_nothing(message_class: Any) -> None:
    """Setting a padding byte changes no field; changing any other byte changes a field or breaks the
    message (rosidl decodes)."""
    rng = random.Random(3)
    for _ in range(5):
        if message_class == "markers":
            message = random_markers(rng)
        else:
            message = message_class()
            fill(rng, message)
        kind = type(message)
        name = topics.type_name(kind)
        data = serialized(message)
        original = deserialize_message(data, kind)
        found = layout(name, message_definition(name), data)
        positions = set(found.padding)
        # rosidl reads a string length one too large or small alike when the terminator is where it
        # expects one; the lengths are checked by the round trips of the test above instead.
        lengths = {start + index for start in found.length_fields for index in range(4)}
        assert all(data[position] == 0 for position in positions)
        assert data[2:4] == b"\x00\x00" and {2, 3} <= positions  # the options, which Fast-CDR reads
        for position in range(4, len(data)):
            changed = bytearray(data)
            if position in positions:
                changed[position] = 0xA5
                assert deserialize_message(bytes(changed), kind) == original, position
            elif position not in lengths:
                changed[position] ^= 0x01
                assert _decoded_or_none(bytes(changed), kind) != original, position


def _decoded_or_none(data: bytes, kind: type) -> Any:
    """The message rosidl reads from ``data``, None where it refuses it (a broken length or terminator)."""
    try:
        return deserialize_message(data, kind)
    except Exception:  # rosidl raises bare RuntimeErrors and others; any refusal counts as a change
        return None


def test_a_zeroer_reuses_a_layout_only_when_the_lengths_match() -> None:
    name = topics.type_name(Status)
    zeroer = PaddingZeroer(name, message_definition(name))
    rng = random.Random(9)
    for _ in range(200):
        message = Status()
        fill(rng, message)
        message.reason = rng.choice(("", "ab", "abc", "a much longer reason"))  # layouts recur and change
        raw = serialize_message(message)
        assert padded_to_4(zeroer(raw)) == serialized(message)


def test_a_message_shorter_than_its_schema_is_refused() -> None:
    name = topics.type_name(ApexEvent)
    data = serialized(ApexEvent())
    with pytest.raises(PaddingError, match="ends inside a field"):
        padding_positions(name, message_definition(name), data[:-9])
    with pytest.raises(PaddingError, match="not plain CDR"):
        padding_positions(name, message_definition(name), b"\x00\x07" + data[2:])
