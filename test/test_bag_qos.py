"""Offered QoS profiles: taken from rclpy, written in rosbag2's version 9 YAML, parsed back by rosbags."""

from __future__ import annotations

import pytest
from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rosbags.interfaces import QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.rosbag2.metadata import parse_qos

from tdslip_ros.bag.qos import DURATION_INFINITE_NS, OfferedQos, qos_profiles_yaml


def test_rclpy_profile_converts_policy_by_policy() -> None:
    profile = QoSProfile(
        history=HistoryPolicy.KEEP_ALL,
        depth=3,
        reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
        deadline=Duration(seconds=2, nanoseconds=5),
        lifespan=Duration(nanoseconds=7),
        liveliness=LivelinessPolicy.MANUAL_BY_TOPIC,
        liveliness_lease_duration=Duration(seconds=1),
        avoid_ros_namespace_conventions=True,
    )
    assert OfferedQos.from_rclpy(profile) == OfferedQos(
        history="keep_all",
        depth=3,
        reliability="best_effort",
        durability="transient_local",
        deadline_ns=2_000_000_005,
        lifespan_ns=7,
        liveliness="manual_by_topic",
        liveliness_lease_duration_ns=1_000_000_000,
        avoid_ros_namespace_conventions=True,
    )


def test_yaml_string_parses_back_in_rosbags() -> None:
    profiles = (
        OfferedQos(),
        OfferedQos(
            "keep_all", 0, "best_effort", "transient_local", 2_000_000_005, 0, "manual_by_topic", 3, True
        ),
    )
    parsed = parse_qos(qos_profiles_yaml(profiles))
    assert [
        (q.history, q.depth, q.reliability, q.durability, q.liveliness, q.avoid_ros_namespace_conventions)
        for q in parsed
    ] == [
        (
            QosHistory.KEEP_LAST,
            10,
            QosReliability.RELIABLE,
            QosDurability.VOLATILE,
            QosLiveliness.AUTOMATIC,
            False,
        ),
        (
            QosHistory.KEEP_ALL,
            0,
            QosReliability.BEST_EFFORT,
            QosDurability.TRANSIENT_LOCAL,
            QosLiveliness.MANUAL_BY_TOPIC,
            True,
        ),
    ]
    # rmw's "infinite" is sec 9223372036, nsec 854775807; others split at 1e9.
    assert [(q.deadline.sec, q.deadline.nsec) for q in parsed] == [(9223372036, 854775807), (2, 5)]
    assert (parsed[1].lifespan.sec, parsed[1].lifespan.nsec) == (0, 0)
    assert (parsed[1].liveliness_lease_duration.sec, parsed[1].liveliness_lease_duration.nsec) == (0, 3)
    assert DURATION_INFINITE_NS == 9223372036 * 10**9 + 854775807
    assert qos_profiles_yaml(()) == "[]"
    assert parse_qos(qos_profiles_yaml(())) == []


@pytest.mark.parametrize(
    "arguments",
    [{"history": "keep_some"}, {"reliability": "RELIABLE"}, {"depth": -1}, {"deadline_ns": -5}],
)
def test_invalid_profiles_are_rejected(arguments: dict[str, object]) -> None:
    with pytest.raises(ValueError, match="QoS"):
        OfferedQos(**arguments)  # type: ignore[arg-type]
