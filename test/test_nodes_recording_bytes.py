"""A recording holds only what was published: defined bytes, the same for the same options.

The padding positions come from each channel's stored schema (:mod:`tdslip_ros.bag.padding`, itself
checked against rosidl and rosbags in test_bag_padding.py); rosbags' CDR serialiser, which writes
zero padding, re-encodes every recorded message to the recorded bytes (which the RMW delivers padded
to a multiple of 4 bytes).
"""

from __future__ import annotations

from pathlib import Path

from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from support.analysis_runs import by_topic

from tdslip_ros.bag.padding import padded_to_4, padding_positions
from tdslip_ros.bag.reader import mcap_file
from tdslip_ros.interfaces import resolve
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.runner import RunReport


def _schemas(mcap_path: Path) -> dict[str, tuple[str, str]]:
    """(type name, schema text) of every topic of a recording, as stored in it."""
    with mcap_path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return {
        channel.topic: (
            summary.schemas[channel.schema_id].name,
            summary.schemas[channel.schema_id].data.decode(),
        )
        for channel in summary.channels.values()
    }


STREAMED = {resolve(topics.HIP_TORQUE), resolve(topics.APPLIED_TORQUE)}
"""The topics of stance feedback: a run of ramp commands has no message on them."""


def test_every_padding_byte_of_every_recorded_message_is_zero(energy: RunReport) -> None:
    messages = _check_padding(energy)
    assert set(messages) == {resolve(topic) for topic in topics.RECORDED_TOPICS} - STREAMED


def test_every_byte_of_a_stance_feedback_recording_is_defined_too(stance_pd: RunReport) -> None:
    """The hip torques (the controller's and the applied ones) and the commands of stance feedback."""
    messages = _check_padding(stance_pd)
    assert set(messages) == {resolve(topic) for topic in topics.RECORDED_TOPICS}


def _check_padding(report: RunReport) -> dict[str, list[bytes]]:
    """The recording's messages by topic, each checked: zero padding; rosbags re-encodes it to its bytes."""
    path = mcap_file(report.bag)
    schemas = _schemas(path)
    store = get_typestore(Stores.EMPTY)
    for name, text in set(schemas.values()):
        store.register(get_types_from_msg(text, name))
    messages = by_topic(path)
    assert len(messages[resolve(topics.STATE)]) > 1000  # the 1 kHz topics, with state and GRF
    for topic, datas in messages.items():
        name, text = schemas[topic]
        for index, data in enumerate(datas):
            nonzero = [position for position in padding_positions(name, text, data) if data[position]]
            assert not nonzero, (topic, index, nonzero, data.hex())
            # rosbags stops at the last field; what the RMW delivers is padded to a multiple of 4 bytes.
            assert padded_to_4(store.serialize_cdr(store.deserialize_cdr(data, name), name)) == data, (
                topic,
                index,
            )
    return messages


def test_two_lockstep_runs_with_the_same_options_record_the_same_bytes(
    energy: RunReport, energy_again: RunReport
) -> None:
    again = energy_again  # the same RunOptions (analysis_runs.AGAIN), recorded once
    assert again.recording_complete
    first, second = by_topic(mcap_file(energy.bag)), by_topic(mcap_file(again.bag))
    assert set(first) == set(second) == {resolve(topic) for topic in topics.RECORDED_TOPICS} - STREAMED
    for recording in (first, second):  # the answer to the last apex too, sent as the run ends
        assert len(recording[resolve(topics.COMMAND)]) == len(recording[resolve(topics.APEX)])
    for topic in first:
        assert len(first[topic]) == len(second[topic]), topic
        differing = [i for i, (a, b) in enumerate(zip(first[topic], second[topic], strict=True)) if a != b]
        assert not differing, (topic, differing[:5])
