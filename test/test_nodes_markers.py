"""The hopper as markers (tdslip/markers) for Foxglove and RViz, and the Foxglove layout shipped in
config/: the markers of a recorded run decode in mcap-ros2-support and in rosbags, and each one
draws the recorded state of its tick."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from tdslip_ros.bag.reader import mcap_file
from tdslip_ros.interfaces import resolve
from tdslip_ros.nodes import markers, topics
from tdslip_ros.nodes.runner import RunReport

NS = 1_000_000_000


def stamp(message: Any) -> int:
    return int(message.header.stamp.sec) * NS + int(message.header.stamp.nanosec)


def decoded(bag: Path) -> dict[str, dict[str, list[Any]]]:
    """Markers and states of the bag, per reader."""
    names = [resolve(topics.MARKERS), resolve(topics.STATE), resolve(topics.GRF)]
    by_reader: dict[str, dict[str, list[Any]]] = {"mcap": {}, "rosbags": {}}
    with mcap_file(bag).open("rb") as stream:
        for _, channel, _, message in make_reader(
            stream, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages(topics=names):
            by_reader["mcap"].setdefault(channel.topic, []).append(message)
    with AnyReader([bag]) as bag_reader:
        connections = [c for c in bag_reader.connections if c.topic in names]
        for connection, _, raw in bag_reader.messages(connections=connections):
            by_reader["rosbags"].setdefault(connection.topic, []).append(
                bag_reader.deserialize(raw, connection.msgtype)
            )
    return by_reader


def test_every_marker_array_draws_the_recorded_state_of_its_tick(energy: RunReport) -> None:
    for name, messages in decoded(energy.bag).items():
        arrays = messages[resolve(topics.MARKERS)]
        states = {stamp(s): s for s in messages[resolve(topics.STATE)]}
        forces = {stamp(f): f.wrench.force for f in messages[resolve(topics.GRF)]}
        # 60 Hz of simulated time: one drawing per 17 ticks over the whole run, the initial state's first.
        assert len(arrays) == -(-len(states) // 17), name
        stances = 0
        for array in arrays:
            body, leg, toe, ground, grf, trunk = array.markers
            assert [m.id for m in array.markers] == [
                markers.BODY,
                markers.LEG,
                markers.TOE,
                markers.GROUND,
                markers.GRF,
                markers.TRUNK,
            ]
            assert trunk.action == 2  # Marker.DELETE: the fixed body has no trunk of its own
            state, force = states[stamp(body)], forces[stamp(body)]
            assert all(m.header.frame_id == "world" for m in array.markers), name
            assert (body.pose.position.x, body.pose.position.z) == (state.x, state.y)
            assert (toe.pose.position.x, toe.pose.position.z) == (state.toe_x, state.toe_y)
            hip, foot = leg.points
            assert (hip.x, hip.z, foot.x, foot.z) == (state.x, state.y, state.toe_x, state.toe_y)
            # The leg drawn is the state's leg: length and angle from the vertical.
            assert ((hip.x - foot.x) ** 2 + (hip.z - foot.z) ** 2) ** 0.5 == pytest.approx(
                state.leg_length, rel=1e-12
            )
            assert all(point.z == 0.0 for point in ground.points)  # flat ground
            if state.phase == 1:  # HopperState.PHASE_STANCE
                stances += 1
                tail, head = grf.points
                assert (head.x - tail.x, head.z - tail.z) == pytest.approx(
                    (force.x / markers.GRF_SCALE, force.y / markers.GRF_SCALE), rel=1e-12
                )
                assert grf.action == 0  # Marker.ADD
            else:
                assert grf.action == 2  # Marker.DELETE
        assert stances > 0, name


def test_a_rigid_body_is_drawn_with_its_trunk_along_its_pitch(posture: RunReport) -> None:
    """The posture run's rigid body: the leg from the hip (the toe plus the state's leg, not the centre of
    mass), and the trunk through the centre of mass along the body's axis, turned by the recorded pitch."""
    for name, messages in decoded(posture.bag).items():
        states = {stamp(s): s for s in messages[resolve(topics.STATE)]}
        leaning = 0
        for array in messages[resolve(topics.MARKERS)]:
            body, leg, _, _, _, trunk = array.markers
            state = states[stamp(body)]
            assert (body.pose.position.x, body.pose.position.z) == (state.x, state.y)
            hip, foot = leg.points
            assert (foot.x, foot.z) == (state.toe_x, state.toe_y)
            assert (hip.x - foot.x, hip.z - foot.z) == pytest.approx(
                (-state.leg_length * math.sin(state.leg_angle), state.leg_length * math.cos(state.leg_angle)),
                abs=1e-12,
            )
            # the hip 0.2 m below the centre of mass, along the body's axis
            assert math.dist((hip.x, hip.z), (state.x, state.y)) == pytest.approx(0.2, abs=1e-9), name
            tail, head = trunk.points
            assert trunk.action == 0 and ((tail.x + head.x) / 2, (tail.z + head.z) / 2) == pytest.approx(
                (state.x, state.y), abs=1e-12
            )
            assert math.atan2(-(head.x - tail.x), head.z - tail.z) == pytest.approx(state.pitch, abs=1e-12)
            leaning += abs(state.pitch) > 0.3
        assert leaning > 10, name


def test_the_foxglove_layout_shows_the_suites_topics(repo_root: Path) -> None:
    layout = json.loads((repo_root / "config" / "foxglove_layout.json").read_text())
    panels = layout["configById"]
    assert set(panels["3D!hopper"]["topics"]) == {resolve(topics.MARKERS)}
    plotted = {path["value"].split(".")[0] for panel in panels.values() for path in panel.get("paths", [])}
    assert plotted == {resolve(topics.APEX), resolve(topics.GRF)}

    def leaves(node: Any) -> set[str]:
        return {node} if isinstance(node, str) else leaves(node["first"]) | leaves(node["second"])

    assert leaves(layout["layout"]) == set(panels)  # every panel configured is placed, and only those
