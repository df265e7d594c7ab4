"""tdslip_ros: ROS 2 node suite around the torque-actuated dissipative spring-mass hopper (TD-SLIP)."""
