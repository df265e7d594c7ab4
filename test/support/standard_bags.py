"""Recordings in standard ROS messages, for the topic map and the strides found in data (issue 33).

:func:`plant_run` runs the suite's own 1 kHz plant (the plant node's engine,
:class:`~tdslip_ros.model.plant.stepper.FixedStepStepper`) in-process, a few strides in a few hundred
milliseconds, with a hopper unlike the default (KNOWN_HOPPER) and a ramp per stride that changes from stride
to stride. :func:`write_suite_bag` records it as the suite does (``tdslip/state`` HopperState and
``tdslip/grf`` WrenchStamped at 1 kHz); :func:`write_gazebo_bag` re-expresses the same samples as a
Gazebo-style robot would publish them (REP 103, z up): ``/odom`` nav_msgs/Odometry at 250 Hz, a force plate's
``/force_plate`` WrenchStamped at 1 kHz (the force on the plate: minus the ground's force on the hopper)
and ``/joint_states`` JointState at 1 kHz (a hip revolute about +y, whose angle and effort are minus the
model's theta and tau, and a prismatic leg). :data:`GAZEBO_MAP` is its topic map.

nav_msgs is not installed here: its schema text is written below from the ROS message definition (the
dependencies read from the installed geometry_msgs and std_msgs), and every message is serialised from
that text by mcap-ros2-support's dynamic encoder, as a foreign recorder would have done.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Schema
from mcap_ros2._dynamic import serialize_dynamic

from tdslip_ros.bag import RosbagMcapWriter
from tdslip_ros.bag.cdr import FixedLayoutEncoder
from tdslip_ros.bag.schema import SEPARATOR, message_definition, msg_dependencies, package_share_directory
from tdslip_ros.interfaces import GRF_FIELDS, STAMP_FIELDS, STATE_FIELDS
from tdslip_ros.model.events import EventKind, Phase
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, StanceCommand
from tdslip_ros.model.plant.stepper import FixedStepStepper

KNOWN_HOPPER = HopperParams(
    m=65.4, k=PAPER_PARAMS.k * 1.15, r0=PAPER_PARAMS.r0, c=PAPER_PARAMS.c * 0.7, g=9.81
)
"""The hopper of issue 33's tests: the paper's stiffness +15 %, damping -30 %, m = 65.4 kg (Fig. 12's)."""

ODOMETRY_MSG = """\
# This represents an estimate of a position and velocity in free space.
std_msgs/Header header
string child_frame_id
geometry_msgs/PoseWithCovariance pose
geometry_msgs/TwistWithCovariance twist
"""
"""nav_msgs/msg/Odometry.msg, as ROS 2 defines it (comments shortened)."""

GAZEBO_MAP = {
    "format": "tdslip_topic_map/1",
    "quantities": {
        "body_forward": {
            "topic": "/odom",
            "type": "nav_msgs/msg/Odometry",
            "field": "pose.pose.position",
            "axis": "x",
            "unit": "m",
        },
        "body_vertical": {
            "topic": "/odom",
            "type": "nav_msgs/msg/Odometry",
            "field": "pose.pose.position",
            "axis": "z",
            "unit": "m",
        },
        "body_forward_velocity": {
            "topic": "/odom",
            "type": "nav_msgs/msg/Odometry",
            "field": "twist.twist.linear",
            "axis": "x",
            "unit": "m/s",
        },
        "body_vertical_velocity": {
            "topic": "/odom",
            "type": "nav_msgs/msg/Odometry",
            "field": "twist.twist.linear",
            "axis": "z",
            "unit": "m/s",
        },
        "leg_length": {
            "topic": "/joint_states",
            "type": "sensor_msgs/msg/JointState",
            "field": "position",
            "joint": "leg_slider",
            "unit": "m",
        },
        "leg_angle": {
            "topic": "/joint_states",
            "type": "sensor_msgs/msg/JointState",
            "field": "position",
            "joint": "hip_pitch",
            "sign": -1,
            "unit": "rad",
        },
        "hip_torque": {
            "topic": "/joint_states",
            "type": "sensor_msgs/msg/JointState",
            "field": "effort",
            "joint": "hip_pitch",
            "sign": -1,
            "unit": "N m",
        },
        "ground_force_forward": {
            "topic": "/force_plate",
            "type": "geometry_msgs/msg/WrenchStamped",
            "field": "wrench.force",
            "axis": "x",
            "sign": -1,
            "unit": "N",
        },
        "ground_force_vertical": {
            "topic": "/force_plate",
            "type": "geometry_msgs/msg/WrenchStamped",
            "field": "wrench.force",
            "axis": "z",
            "sign": -1,
            "unit": "N",
        },
    },
}
"""The topic map of :func:`write_gazebo_bag` (docs/identify.md's second example)."""

FOOT_SWITCH = {False: b"\x00\x01\x00\x00\x00\x00\x00\x00", True: b"\x00\x01\x00\x00\x01\x00\x00\x00"}
"""A std_msgs/Bool, serialised (CDR little-endian: the header, the byte, padding to 4)."""
ODOMETRY_EVERY = 4
"""Plant ticks per Odometry message: 250 Hz."""


@dataclass(frozen=True)
class PlantRun:
    """Every 1 kHz tick of a run of the plant: the HopperState's fields by name (arrays) and the hopper."""

    params: HopperParams
    columns: dict[str, np.ndarray]
    commands: tuple[StanceCommand, ...]


def stride_command(params: HopperParams, xdot: float, stride: int) -> StanceCommand:
    """A hop in place of a controller: the neutral angle for the speed, nudged towards 3.8 m/s, and a ramp
    torque that changes from stride to stride (-80, -100, -120 N m over 0.12 s)."""
    stance_time = math.pi * math.sqrt(params.m / params.k)
    angle = math.asin(xdot * stance_time / (2.0 * params.r0)) + 0.08 * (xdot - 4.0)
    return StanceCommand(angle, -80.0 - 20.0 * (stride % 3), 0.12)


def plant_run(params: HopperParams = KNOWN_HOPPER, ticks: int = 2801) -> PlantRun:
    """``ticks`` ticks of the plant from the apex (1 m, 4 m/s), commanded by :func:`stride_command`."""
    commands = [stride_command(params, 4.0, 0)]
    stepper = FixedStepStepper(params, ApexState(1.0, 4.0), commands[0])
    names = ("t", "x", "y", "xdot", "ydot", "toe_x", "toe_y", "r", "theta", "hip_torque", "grf_x", "grf_y")
    rows = []
    for _ in range(ticks):
        for event in stepper.step():
            if event.kind is EventKind.APEX:
                commands.append(stride_command(params, event.state.xdot, len(commands)))
                stepper.set_command(commands[-1])
        state = stepper.state
        rows.append([getattr(state, name) for name in names] + [state.phase is Phase.STANCE])
    table = np.array(rows, dtype=float)
    columns = {name: table[:, i] for i, name in enumerate(names)}
    columns["stance"] = table[:, -1]
    return PlantRun(params, columns, tuple(commands))


def odometry_definition() -> str:
    """The schema text of nav_msgs/msg/Odometry in rosbag2's format (bag.schema.message_definition's)."""
    emitted: set[str] = set()

    def append(text: str, package: str) -> str:
        for dependency in sorted(msg_dependencies(text, package)):
            if dependency not in emitted:
                emitted.add(dependency)
                dep_package, name = dependency.split("/")
                own = (package_share_directory(dep_package) / "msg" / f"{name}.msg").read_text()
                text += f"\n{SEPARATOR}\nMSG: {dependency}\n" + append(own, dep_package)
        return text

    return append(ODOMETRY_MSG, "nav_msgs")


class Topics:
    """A bag being written: each topic's messages serialised from a dict once (mcap-ros2-support's dynamic
    encoder, from the schema text), then from the values of the fields that change (bag.cdr's
    FixedLayoutEncoder, the suite's own 1 kHz path: ten times faster)."""

    def __init__(self, writer: RosbagMcapWriter) -> None:
        self.writer = writer
        self.encoders: dict[str, FixedLayoutEncoder] = {}

    def add(
        self, topic: str, type_name: str, sample: dict[str, Any], fields: list[str], text: str | None = None
    ) -> None:
        text = message_definition(type_name) if text is None else text
        schema = Schema(id=0, name=type_name, encoding="ros2msg", data=text.encode())
        self.writer.add_topic(
            topic, type_name, schema=schema, type_hash="" if "nav_msgs" in type_name else None
        )
        encoded = serialize_dynamic(type_name, text)[type_name](sample)
        self.encoders[topic] = FixedLayoutEncoder(schema, encoded, list(STAMP_FIELDS) + fields)

    def write(self, topic: str, t: float, values: list[float]) -> None:
        ns = round(t * 1e9)
        stamp = [ns // 1_000_000_000, ns % 1_000_000_000]
        data = self.encoders[topic].encode(stamp + values)
        self.writer.write(topic, data, log_time_ns=ns + 200_000, publish_time_ns=ns)


def header(t: float, frame: str = "world") -> dict[str, Any]:
    ns = round(t * 1e9)
    return {"stamp": {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}, "frame_id": frame}


VECTOR = ("x", "y", "z")
ZERO = dict.fromkeys(VECTOR, 0.0)
WRENCH = {"force": ZERO, "torque": ZERO}


def write_suite_bag(path: Path, run: PlantRun) -> Path:
    """``run`` as the suite records it: tdslip/state and tdslip/grf at 1 kHz."""
    c = run.columns
    # The HopperState fields the plant run holds, in the message's order, and the run's column of each.
    column_of = {"phase": "stance", "leg_length": "r", "leg_angle": "theta"}
    state_fields = [name for name in STATE_FIELDS if column_of.get(name, name) in c]
    columns = [column_of.get(name, name) for name in state_fields]
    state = dict.fromkeys(STATE_FIELDS, 0.0) | {"header": header(0.0), "stride": 0, "phase": 0}
    with RosbagMcapWriter(path) as writer:
        topics = Topics(writer)
        topics.add("/tdslip/state", "tdslip_msgs/msg/HopperState", state, state_fields)
        topics.add(
            "/tdslip/grf",
            "geometry_msgs/msg/WrenchStamped",
            {"header": header(0.0), "wrench": WRENCH},
            list(GRF_FIELDS),
        )
        rows = np.stack([c[name] for name in columns], axis=-1).tolist()
        for t, row, fx, fy in zip(
            c["t"].tolist(), rows, c["grf_x"].tolist(), c["grf_y"].tolist(), strict=True
        ):
            topics.write("/tdslip/state", t, [int(row[0])] + row[1:])
            topics.write("/tdslip/grf", t, [fx, fy])
    return path


def write_gazebo_bag(path: Path, run: PlantRun) -> Path:
    """``run`` re-expressed in standard messages, REP 103 (module docstring); its map is GAZEBO_MAP."""
    c = run.columns
    covariance = [0.0] * 36
    pose = {"position": ZERO, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
    odometry = {
        "header": header(0.0, "odom"),
        "child_frame_id": "base_link",
        "pose": {"pose": pose, "covariance": covariance},
        "twist": {"twist": {"linear": ZERO, "angular": ZERO}, "covariance": covariance},
    }
    joints = {
        "header": header(0.0, ""),
        "name": ["hip_pitch", "leg_slider"],
        "position": [0.0, 0.0],
        "velocity": [0.0, 0.0],
        "effort": [0.0, 0.0],
    }
    with RosbagMcapWriter(path) as writer:
        topics = Topics(writer)
        odometry_fields = [
            "pose.pose.position.x",
            "pose.pose.position.z",
            "twist.twist.linear.x",
            "twist.twist.linear.z",
        ]
        topics.add("/odom", "nav_msgs/msg/Odometry", odometry, odometry_fields, odometry_definition())
        topics.add(
            "/force_plate",
            "geometry_msgs/msg/WrenchStamped",
            {"header": header(0.0, "plate"), "wrench": WRENCH},
            ["wrench.force.x", "wrench.force.z"],
        )
        topics.add(
            "/joint_states", "sensor_msgs/msg/JointState", joints, ["position[0]", "position[1]", "effort[0]"]
        )
        # A foot switch without a header, which the map does not use (a recorder keeps more than a map reads).
        writer.add_topic("/foot_contact", "std_msgs/msg/Bool")
        columns = ["t", "x", "y", "xdot", "ydot", "grf_x", "grf_y", "theta", "r", "hip_torque", "stance"]
        for i, (t, x, y, xdot, ydot, fx, fy, theta, r, tau, stance) in enumerate(
            np.stack([c[n] for n in columns], axis=-1).tolist()
        ):
            if i % ODOMETRY_EVERY == 0:
                topics.write("/odom", t, [x, y, xdot, ydot])
            topics.write("/force_plate", t, [-fx, -fy])  # the force on the plate
            topics.write("/joint_states", t, [-theta, r, -tau])  # a hip about +y turns the leg backwards
            ns = round(t * 1e9)
            writer.write(
                "/foot_contact", FOOT_SWITCH[stance > 0.5], log_time_ns=ns + 200_000, publish_time_ns=ns
            )
    return path
