"""Offered QoS profiles in rosbag2's metadata version 9 form, without importing rclpy.

rosbag2 (Jazzy and later, metadata version 9) stores each topic's offered QoS profiles as a list of
mappings whose policies are the lower-case rmw names (``keep_last``, ``reliable``, ``volatile``,
``automatic``, ``unknown`` ...) and whose durations are ``{sec, nsec}``. The same list appears as a
YAML *string* in the MCAP channel metadata key ``offered_qos_profiles`` and as a YAML *list* under
``topic_metadata.offered_qos_profiles`` in ``metadata.yaml``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs

# rmw's RMW_DURATION_INFINITE, which rmw reports for "no deadline/lifespan/lease".
DURATION_INFINITE_NS = 2**63 - 1
_NS_PER_S = 1_000_000_000

HISTORY_POLICIES = frozenset(("system_default", "keep_last", "keep_all", "unknown"))
RELIABILITY_POLICIES = frozenset(("system_default", "reliable", "best_effort", "best_available", "unknown"))
DURABILITY_POLICIES = frozenset(
    ("system_default", "transient_local", "volatile", "best_available", "unknown")
)
LIVELINESS_POLICIES = frozenset(
    ("system_default", "automatic", "manual_by_topic", "best_available", "unknown")
)


class _NamedPolicy(Protocol):
    @property
    def name(self) -> str: ...


class _Duration(Protocol):
    @property
    def nanoseconds(self) -> int: ...


class RclpyQosProfile(Protocol):
    """The attributes of ``rclpy.qos.QoSProfile`` that a recorder sees on a publisher's endpoint."""

    @property
    def history(self) -> _NamedPolicy: ...
    @property
    def depth(self) -> int: ...
    @property
    def reliability(self) -> _NamedPolicy: ...
    @property
    def durability(self) -> _NamedPolicy: ...
    @property
    def deadline(self) -> _Duration: ...
    @property
    def lifespan(self) -> _Duration: ...
    @property
    def liveliness(self) -> _NamedPolicy: ...
    @property
    def liveliness_lease_duration(self) -> _Duration: ...
    @property
    def avoid_ros_namespace_conventions(self) -> bool: ...


def _duration_yaml(nanoseconds: int) -> dict[str, int]:
    return {"sec": nanoseconds // _NS_PER_S, "nsec": nanoseconds % _NS_PER_S}


def _duration_ns(value: Any) -> int:
    return int(value["sec"]) * _NS_PER_S + int(value["nsec"])


@dataclass(frozen=True)
class OfferedQos:
    """One publisher's offered QoS. Defaults: rclpy's default publisher profile as rmw reports it."""

    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    deadline_ns: int = DURATION_INFINITE_NS
    lifespan_ns: int = DURATION_INFINITE_NS
    liveliness: str = "automatic"
    liveliness_lease_duration_ns: int = DURATION_INFINITE_NS
    avoid_ros_namespace_conventions: bool = False

    def __post_init__(self) -> None:
        for value, allowed in (
            (self.history, HISTORY_POLICIES),
            (self.reliability, RELIABILITY_POLICIES),
            (self.durability, DURABILITY_POLICIES),
            (self.liveliness, LIVELINESS_POLICIES),
        ):
            if value not in allowed:
                raise ValueError(f"QoS policy {value!r} is not one of {sorted(allowed)}")
        durations = (self.deadline_ns, self.lifespan_ns, self.liveliness_lease_duration_ns)
        if self.depth < 0 or min(durations) < 0:
            raise ValueError(f"QoS depth and durations must be >= 0: {self}")

    @classmethod
    def from_rclpy(cls, profile: RclpyQosProfile) -> OfferedQos:
        """Convert an ``rclpy.qos.QoSProfile`` (e.g. ``TopicEndpointInfo.qos_profile``)."""
        return cls(
            history=profile.history.name.lower(),
            depth=int(profile.depth),
            reliability=profile.reliability.name.lower(),
            durability=profile.durability.name.lower(),
            deadline_ns=int(profile.deadline.nanoseconds),
            lifespan_ns=int(profile.lifespan.nanoseconds),
            liveliness=profile.liveliness.name.lower(),
            liveliness_lease_duration_ns=int(profile.liveliness_lease_duration.nanoseconds),
            avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
        )

    @classmethod
    def from_yaml_mapping(cls, mapping: Any) -> OfferedQos:
        """The inverse of :meth:`to_yaml_mapping` (ValueError if ``mapping`` is not one)."""
        try:
            return cls(
                history=str(mapping["history"]),
                depth=int(mapping["depth"]),
                reliability=str(mapping["reliability"]),
                durability=str(mapping["durability"]),
                deadline_ns=_duration_ns(mapping["deadline"]),
                lifespan_ns=_duration_ns(mapping["lifespan"]),
                liveliness=str(mapping["liveliness"]),
                liveliness_lease_duration_ns=_duration_ns(mapping["liveliness_lease_duration"]),
                avoid_ros_namespace_conventions=bool(mapping["avoid_ros_namespace_conventions"]),
            )
        except (KeyError, TypeError) as error:
            raise ValueError(f"not an offered QoS profile: {mapping!r} ({error!r})") from None

    def to_yaml_mapping(self) -> dict[str, Any]:
        """The mapping rosbag2 writes for one profile (keys in rosbag2's order)."""
        return {
            "history": self.history,
            "depth": self.depth,
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": _duration_yaml(self.deadline_ns),
            "lifespan": _duration_yaml(self.lifespan_ns),
            "liveliness": self.liveliness,
            "liveliness_lease_duration": _duration_yaml(self.liveliness_lease_duration_ns),
            "avoid_ros_namespace_conventions": self.avoid_ros_namespace_conventions,
        }


class _BlockDumper(yaml.SafeDumper):  # type: ignore[misc]  # PyYAML ships no type stubs
    """Block-style YAML with sequences indented under their key, as yaml-cpp (rosbag2) writes it."""

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> None:
        super().increase_indent(flow, False)


def dump_yaml(data: object) -> str:
    """YAML text in rosbag2's layout: block style, keys in insertion order, no trailing newline."""
    text: str = yaml.dump(data, Dumper=_BlockDumper, default_flow_style=False, sort_keys=False)
    return text.rstrip("\n")


def qos_profiles_yaml(profiles: tuple[OfferedQos, ...]) -> str:
    """The channel-metadata string ``offered_qos_profiles`` for these profiles (``[]`` for none)."""
    return dump_yaml([profile.to_yaml_mapping() for profile in profiles])


def parse_qos_profiles(text: str) -> tuple[OfferedQos, ...]:
    """The profiles of a channel-metadata string ``offered_qos_profiles`` (ValueError if it is not one)."""
    try:
        profiles = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ValueError(f"offered_qos_profiles is not YAML ({error})") from None
    if not isinstance(profiles, list):
        raise ValueError(f"offered_qos_profiles is not a list: {text!r}")
    return tuple(OfferedQos.from_yaml_mapping(profile) for profile in profiles)
