"""Names, types and QoS of the node suite's topics and service: the one place they are spelled.

Every topic is reliable. The plant's topics are KEEP_ALL and volatile: a publisher whose subscriber
lags keeps the messages until they are acknowledged (and blocks briefly if its history fills)
instead of overwriting them, and late joiners get nothing old. Before the plant starts, ``tdslip
run`` waits until every subscriber has matched the plant's publishers, so nothing of a run is missed.

/tdslip/command is the exception (:data:`COMMAND_QOS`): its publisher is the controller, and whether
the recorder has matched the controller cannot be seen from the plant's process; the controller
answers the first apex at once. So its publisher is transient-local and keeps the last
:data:`COMMAND_HISTORY` answers for subscribers that match late; the recorder asks for them. The
plant subscribes volatile: an old answer is of no use to a plant that starts later.
"""

from __future__ import annotations

from geometry_msgs.msg import WrenchStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from tdslip_msgs.msg import ApexEvent, ContactEvent, HopperState, StanceCommand, Status

from tdslip_ros.bag import OfferedQos

# Re-exported: the nodes spell every topic topics.NAME.
from tdslip_ros.interfaces import APEX, CLOCK, COMMAND, CONTACT, GRF, RESET_SERVICE, STATE, STATUS  # noqa: F401

FRAME_ID = "world"

QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    depth=0,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
COMMAND_HISTORY = 1000  # answers kept: minutes of hopping at a few strides a second
COMMAND_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=COMMAND_HISTORY,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


def qos(topic: str) -> QoSProfile:
    """The QoS the suite publishes ``topic`` with (and records it with)."""
    return COMMAND_QOS if topic == COMMAND else QOS


def offered_qos(topic: str) -> OfferedQos:
    """qos(topic) as rosbag2 writes it into a recording's topic metadata."""
    if topic == COMMAND:
        return OfferedQos(
            history="keep_last", depth=COMMAND_HISTORY, reliability="reliable", durability="transient_local"
        )
    return OfferedQos(history="keep_all", depth=0, reliability="reliable", durability="volatile")


MESSAGE_TYPES: dict[str, type] = {
    STATE: HopperState,
    GRF: WrenchStamped,
    APEX: ApexEvent,
    CONTACT: ContactEvent,
    STATUS: Status,
    COMMAND: StanceCommand,
    CLOCK: Clock,
}
"""Every topic of the suite and its message class; the plant publishes all but COMMAND."""

TDSLIP_TOPICS = tuple(topic for topic in MESSAGE_TYPES if topic.startswith("/tdslip/"))


def type_name(message_class: type) -> str:
    """``pkg/msg/Type`` of a generated message class, the name rosbag2 records."""
    package = message_class.__module__.split(".", 1)[0]
    return f"{package}/msg/{message_class.__name__}"
