"""rclpy nodes: thin wrappers around tdslip_ros.model."""
