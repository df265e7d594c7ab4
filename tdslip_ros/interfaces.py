"""Names of the suite's topics and service and the message types they carry, without rclpy.

The nodes (tdslip_ros.nodes.topics adds the QoS and message classes) and the offline analysis, which
must not need rclpy, both take the names from here.
"""

STATE = "/tdslip/state"
GRF = "/tdslip/grf"
APEX = "/tdslip/apex"
CONTACT = "/tdslip/contact"
STATUS = "/tdslip/status"
COMMAND = "/tdslip/command"
CLOCK = "/clock"
RESET_SERVICE = "/tdslip/reset"

TOPIC_TYPES: dict[str, str] = {
    STATE: "tdslip_msgs/msg/HopperState",
    GRF: "geometry_msgs/msg/WrenchStamped",
    APEX: "tdslip_msgs/msg/ApexEvent",
    CONTACT: "tdslip_msgs/msg/ContactEvent",
    STATUS: "tdslip_msgs/msg/Status",
    COMMAND: "tdslip_msgs/msg/StanceCommand",
}
"""Every /tdslip topic with the type name rosbag2 records for it."""
