"""rosbag2-compatible MCAP recordings of raw CDR messages, in and out, without rclpy.

:class:`RosbagMcapWriter` writes what rosbag2's MCAP storage plugin writes, so ``ros2 bag``,
Foxglove, ``rosbags`` and ``mcap`` + ``mcap-ros2-support`` read the result; :mod:`.schema` builds
the message definition texts and type hashes from the installed interface files. :mod:`.reader`
opens, checks and iterates a recording, :mod:`.cdr` decodes its messages, and :mod:`.recover`
makes a truncated or unfinalised one readable again.
"""

from tdslip_ros.bag.qos import OfferedQos
from tdslip_ros.bag.reader import Bag, BagReadError, open_bag
from tdslip_ros.bag.schema import MessageDefinitionError, message_definition, type_description_hash
from tdslip_ros.bag.writer import (
    DEFAULT_CHUNK_SIZE,
    BagClosedError,
    BagWriteError,
    Compression,
    RosbagMcapWriter,
)

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "Bag",
    "BagClosedError",
    "BagReadError",
    "BagWriteError",
    "Compression",
    "MessageDefinitionError",
    "OfferedQos",
    "RosbagMcapWriter",
    "message_definition",
    "open_bag",
    "type_description_hash",
]
