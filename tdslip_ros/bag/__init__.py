"""rosbag2-compatible MCAP recording of raw CDR messages, without rclpy.

:class:`RosbagMcapWriter` writes what rosbag2's MCAP storage plugin writes, so ``ros2 bag``,
Foxglove, ``rosbags`` and ``mcap`` + ``mcap-ros2-support`` read the result; :mod:`.schema` builds
the message definition texts and type hashes from the installed interface files.
"""

from tdslip_ros.bag.qos import OfferedQos
from tdslip_ros.bag.schema import MessageDefinitionError, message_definition, type_description_hash
from tdslip_ros.bag.writer import DEFAULT_CHUNK_SIZE, BagClosedError, Compression, RosbagMcapWriter

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "BagClosedError",
    "Compression",
    "MessageDefinitionError",
    "OfferedQos",
    "RosbagMcapWriter",
    "message_definition",
    "type_description_hash",
]
