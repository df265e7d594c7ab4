"""What the tests share and are not tests themselves: the recorded runs and the background child that makes
them (analysis_runs), a private ROS graph (ros_harness), the README's colcon build (colcon_workspace), the
failure cases of the engines (failure_cases), a learned policy's file (learned_policy), and the small checks
and helpers several test files use (helpers)."""
