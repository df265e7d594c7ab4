"""Message definition texts and type hashes, checked against rosidl's type descriptions, the rosbags
type store, rmw's reported type hashes and rosbag2's documented layout."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mcap_ros2._dynamic import generate_dynamic
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from tdslip_ros.bag.schema import (
    SEPARATOR,
    MessageDefinitionError,
    canonical_type_name,
    message_definition,
    package_share_directory,
    type_description_hash,
)

TYPES = [
    "std_msgs/msg/String",
    "geometry_msgs/msg/WrenchStamped",
    "rosgraph_msgs/msg/Clock",
    "geometry_msgs/msg/PoseWithCovarianceStamped",  # fixed-size array float64[36]
    "geometry_msgs/msg/PolygonStamped",  # unbounded array of a nested type
    "std_msgs/msg/Float64MultiArray",  # nested type inside the same package, arrays
]


def sections(definition: str) -> list[tuple[str | None, str]]:
    """Split a rosbag2 definition into (dependency name or None for the root, text) pairs."""
    parts = definition.split(f"\n{SEPARATOR}\n")
    result: list[tuple[str | None, str]] = [(None, parts[0])]
    for part in parts[1:]:
        header, _, text = part.partition("\n")
        match = re.fullmatch(r"MSG: (\S+)", header)
        assert match is not None, f"section header {header!r} is not 'MSG: pkg/Type'"
        result.append((match[1], text))
    return result


def installed_description(type_name: str) -> dict[str, Any]:
    package, _, name = type_name.split("/")
    return json.loads((package_share_directory(package) / "msg" / f"{name}.json").read_text())


@pytest.mark.parametrize("type_name", TYPES)
def test_sections_are_exactly_the_referenced_types_of_the_rosidl_description(type_name: str) -> None:
    parts = sections(message_definition(type_name))
    names = [canonical_type_name(name) for name, _ in parts[1:]]
    referenced = installed_description(type_name)["type_description_msg"]["referenced_type_descriptions"]
    assert len(names) == len(set(names)), "a dependency was emitted twice"
    assert set(names) == {entry["type_name"] for entry in referenced}


@pytest.mark.parametrize("type_name", TYPES)
def test_every_section_parses_to_the_fields_of_the_rosbags_kilted_store(type_name: str) -> None:
    store = get_typestore(Stores.ROS2_KILTED)
    for name, text in sections(message_definition(type_name)):
        canonical = type_name if name is None else canonical_type_name(name)
        parsed = get_types_from_msg(text, canonical)
        assert parsed[canonical] == store.fielddefs[canonical]


@pytest.mark.parametrize("type_name", TYPES)
def test_mcap_ros2_builds_a_decoder_from_the_definition(type_name: str) -> None:
    decoders = generate_dynamic(type_name, message_definition(type_name))
    assert type_name in decoders


def test_dependency_order_is_rosbag2s_sorted_depth_first_walk() -> None:
    # rosbag2 emits each parent's dependencies in sorted order of their spelled names, recursing
    # into each one before the next: Wrench < Header at the top, Vector3 under Wrench, Time under Header.
    parts = sections(message_definition("geometry_msgs/msg/WrenchStamped"))
    assert [name for name, _ in parts] == [
        None,
        "geometry_msgs/Wrench",
        "geometry_msgs/Vector3",
        "std_msgs/Header",
        "builtin_interfaces/Time",
    ]
    for name, text in parts:
        path_type = "geometry_msgs/msg/WrenchStamped" if name is None else canonical_type_name(name)
        package, _, short = path_type.split("/")
        assert text == (package_share_directory(package) / "msg" / f"{short}.msg").read_text()


@pytest.mark.parametrize("type_name", TYPES)
def test_type_hash_equals_the_rosbags_rihs01_computation(type_name: str) -> None:
    assert type_description_hash(type_name) == get_typestore(Stores.ROS2_KILTED).hash_rihs01(type_name)


@pytest.mark.nodes
def test_type_hash_equals_what_rmw_reports_for_a_live_publisher() -> None:
    rclpy = pytest.importorskip("rclpy")
    from geometry_msgs.msg import WrenchStamped
    from rclpy.context import Context
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import String

    context = Context()
    rclpy.init(context=context, domain_id=91)
    try:
        node = rclpy.create_node("type_hash_probe", context=context)
        for message_type, type_name in (
            (String, "std_msgs/msg/String"),
            (WrenchStamped, "geometry_msgs/msg/WrenchStamped"),
            (Clock, "rosgraph_msgs/msg/Clock"),
        ):
            topic = "/probe_" + type_name.replace("/", "_")
            node.create_publisher(message_type, topic, 10)
            (info,) = node.get_publishers_info_by_topic(topic)
            assert str(info.topic_type_hash) == type_description_hash(type_name)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


@pytest.fixture
def synthetic_package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """An ament prefix holding package ``bagschema_test_msgs``, found through AMENT_PREFIX_PATH."""
    share = tmp_path / "share"
    (share / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (share / "ament_index" / "resource_index" / "packages" / "bagschema_test_msgs").write_text("")
    msg_dir = share / "bagschema_test_msgs" / "msg"
    msg_dir.mkdir(parents=True)
    (msg_dir / "Inner.msg").write_text(
        "# constants, bounded strings and bounded arrays are not dependencies\n"
        "uint8 KIND_A=1\n"
        'string LABEL="x#y"\n'
        "int32[<=4] values\n"
        "string<=8[<=2] labels\n"
        "std_msgs/Header header\n"
    )
    (msg_dir / "Outer.msg").write_text(
        "Inner[] many  # same-package reference, spelled without the package\n"
        "Inner[2] pair\n"
        "Inner[<=3] few\n"
        "bagschema_test_msgs/Inner one\n"
        "wstring wide\n"
        "\n"
        "builtin_interfaces/Duration elapsed\n"
    )
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path))
    yield msg_dir
    # The lookups are cached per process; forget this temporary package (pytest-repeat, reruns).
    for cached in (package_share_directory, message_definition, type_description_hash):
        cached.cache_clear()


def test_nested_same_package_arrays_and_bounds_are_resolved(synthetic_package: Path) -> None:
    definition = message_definition("bagschema_test_msgs/msg/Outer")
    parts = sections(definition)
    assert [name for name, _ in parts] == [
        None,
        "bagschema_test_msgs/Inner",
        "std_msgs/Header",
        "builtin_interfaces/Time",
        "builtin_interfaces/Duration",
    ]
    assert parts[0][1] == (synthetic_package / "Outer.msg").read_text()
    assert parts[1][1] == (synthetic_package / "Inner.msg").read_text()
    # Both independent parsers accept the whole text and see the nested fields.
    decoders = generate_dynamic("bagschema_test_msgs/msg/Outer", definition)
    assert "bagschema_test_msgs/msg/Outer" in decoders
    inner = get_types_from_msg(parts[1][1], "bagschema_test_msgs/msg/Inner")["bagschema_test_msgs/msg/Inner"]
    assert [field for field, _ in inner[1]] == ["values", "labels", "header"]


def test_missing_packages_files_and_bad_names_raise_clear_errors(synthetic_package: Path) -> None:
    with pytest.raises(MessageDefinitionError, match="no_such_pkg"):
        message_definition("no_such_pkg/msg/Thing")
    with pytest.raises(MessageDefinitionError, match="Missing.msg"):
        message_definition("bagschema_test_msgs/msg/Missing")
    with pytest.raises(MessageDefinitionError, match="Inner.json"):
        type_description_hash("bagschema_test_msgs/msg/Inner")
    for bad in ("String", "std_msgs/srv/Empty", "std_msgs/msg/String/x", "1pkg/msg/T"):
        with pytest.raises(MessageDefinitionError, match="not a message type name"):
            canonical_type_name(bad)
