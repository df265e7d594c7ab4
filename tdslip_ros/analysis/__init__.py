"""Offline analysis of recorded runs against the analytic apex return map (no rclpy)."""
