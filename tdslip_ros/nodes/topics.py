"""Names, types and QoS of the node suite's topics and service: the one place they are spelled.

The QoS contract (docs/nodes.md states it for users' own nodes):

* Everything the plant publishes is **reliable, volatile, KEEP_LAST** (:data:`STREAM_QOS`, depth
  :data:`STREAM_DEPTH`). Any subscriber matches it (a default-QoS ``create_subscription(..., 10)``,
  ``ros2 topic echo``, a best-effort one), and none can hold the plant: a subscriber that stalls
  or dies only loses what it did not take, because a KEEP_LAST writer drops its oldest sample
  instead of blocking when its history is full. The plant waits only for a recorder it is told to
  wait for (parameter ``wait_for_recorder``: flow control on :data:`RECORDER_STATUS`).
* Commands: the plant subscribes reliable and volatile, so a controller must publish reliable (ROS's
  default, ``create_publisher(StanceCommand, 'tdslip/command', 10)``); any durability and depth
  work. A command answers one apex: it copies the apex's ``epoch`` and ``stride``. The suite's
  controller publishes volatile with a deep history (:data:`COMMAND_QOS`): a subscriber that
  missed an answer in transport (a recorder starved of CPU) gets it repaired from that history,
  while one that starts late sees the next answer, not an old one (``ros2 topic echo --once``).
* Hip torques (``tdslip/hip_torque``, stance feedback): the plant subscribes as to commands (reliable,
  volatile, KEEP_ALL), so a default-QoS ``create_publisher(HipTorque, 'tdslip/hip_torque', 10)`` drives
  it; the suite's stance controller publishes them with :data:`STREAM_QOS`.
* The recorder adapts its subscriptions to what the publishers offer, as rosbag2 does
  (:func:`adapted_qos`).

Topic names are relative (``tdslip/state``), so ``__ns`` and remapping apply; /clock is global.
"""

from __future__ import annotations

from collections.abc import Iterable

from geometry_msgs.msg import WrenchStamped
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSPresetProfiles,
    QoSProfile,
    ReliabilityPolicy,
)
from rosgraph_msgs.msg import Clock
from tdslip_msgs.msg import (
    ApexEvent,
    ContactEvent,
    HipTorque,
    HopperSamples,
    HopperState,
    StanceCommand,
    Status,
)
from visualization_msgs.msg import MarkerArray

from tdslip_ros.bag import OfferedQos

# Re-exported: the nodes spell every topic topics.NAME.
from tdslip_ros.interfaces import (  # noqa: F401
    APEX,
    APPLIED_TORQUE,
    CLOCK,
    COMMAND,
    CONTACT,
    DIAGNOSTICS,
    GRF,
    HIP_TORQUE,
    JOINT_STATES,
    MARKERS,
    RECORDER_STATUS,
    RESET_SERVICE,
    ROBOT_DESCRIPTION,
    SAMPLES,
    STATE,
    STATUS,
    TF,
)

FRAME_ID = "world"

STREAM_DEPTH = 10_000
"""Samples a plant publisher keeps for a lagging subscriber: 10 s of the 1 kHz state in realtime, so that a
recorder starved of CPU that long loses nothing (at 1 s, a realtime run whose recorder was stopped for 5 s
lost a seventh of its 1 kHz stance torques). A few MB per publisher at most."""
STREAM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=STREAM_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
COMMAND_HISTORY = 1000
"""Answers a controller keeps for reliable repair: minutes of hopping."""
COMMAND_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=COMMAND_HISTORY,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""What the suite's controller publishes commands with (the plant and the recorder accept any
reliable publisher)."""
COMMAND_SUBSCRIPTION_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    depth=0,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""The plant's command subscription: reliable and volatile (an old answer is of no use to a new run),
KEEP_ALL so that no later message can push the valid answer out of its queue."""
RECORDER_STATUS_QOS: QoSProfile = QoSPresetProfiles.DEFAULT.value
DIAGNOSTICS_QOS: QoSProfile = QoSPresetProfiles.DEFAULT.value
"""/diagnostics: reliable, volatile, depth 10, as diagnostic_updater and rqt_robot_monitor use it."""
ROBOT_DESCRIPTION_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""robot_description: transient-local, as robot_state_publisher offers it: a viewer started later gets it."""
TF_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""/tf: tf2_ros's dynamic broadcaster's profile (reliable, volatile, depth 100)."""


def qos(topic: str) -> QoSProfile:
    """The QoS the suite publishes ``topic`` with."""
    return COMMAND_QOS if topic == COMMAND else STREAM_QOS


def offered_qos(profile: QoSProfile) -> OfferedQos:
    """An rclpy profile as rosbag2 writes it into a recording's topic metadata."""
    return OfferedQos.from_rclpy(profile)


def adapted_qos(offered: Iterable[OfferedQos]) -> QoSProfile:
    """The subscription QoS a recorder asks for given the publishers' offered profiles (rosbag2's
    rule): reliable only if every publisher is reliable, transient-local only if every one is;
    KEEP_ALL, so that nothing a reliable publisher sends is dropped on the recorder's side."""
    offered = list(offered)
    reliable = all(profile.reliability == "reliable" for profile in offered)
    transient = bool(offered) and all(profile.durability == "transient_local" for profile in offered)
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL,
        depth=0,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE,
    )


MESSAGE_TYPES: dict[str, type] = {
    STATE: HopperState,
    GRF: WrenchStamped,
    SAMPLES: HopperSamples,
    APEX: ApexEvent,
    CONTACT: ContactEvent,
    STATUS: Status,
    COMMAND: StanceCommand,
    HIP_TORQUE: HipTorque,
    APPLIED_TORQUE: HipTorque,
    MARKERS: MarkerArray,
    CLOCK: Clock,
}
"""Every topic the plant publishes or subscribes, with its message class."""

PLANT_TOPICS = (STATE, GRF, APEX, CONTACT, STATUS, MARKERS, APPLIED_TORQUE)
"""What the plant publishes for anyone (besides /clock and :data:`SAMPLES`)."""
BATCHED_TOPICS = (STATE, GRF)
"""The 1 kHz topics whose samples the plant also publishes in batches on :data:`SAMPLES`: a recorder
records them from there (:func:`~tdslip_ros.nodes.wire.sample_rows`), and the plant publishes them live
only while someone else subscribes."""
RECORDED_TOPICS = (*PLANT_TOPICS, COMMAND, HIP_TORQUE)
"""What the recorder records (and /clock if asked): the topics of the bag. It takes STATE and GRF from
SAMPLES where a plant publishes that, else from the topics themselves (a replay)."""


def type_name(message_class: type) -> str:
    """``pkg/msg/Type`` of a generated message class, the name rosbag2 records."""
    package = message_class.__module__.split(".", 1)[0]
    return f"{package}/msg/{message_class.__name__}"
