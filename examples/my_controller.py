"""A controller of your own for the tdslip_ros plant, as a ROS 2 user would write it.

It answers every apex with a fixed touchdown angle and a torque ramp that pushes harder when the
hopper is slower than 5 m/s (it settles near 5.5 m/s). Default QoS on both topics; the command
copies the apex's epoch and stride, which is how the plant knows what it answers.

    tdslip run --controller none --out runs/mine   # the plant and the recorder; they wait for you
    python3 examples/my_controller.py              # in another terminal (same ROS_DOMAIN_ID)
    tdslip analyze runs/mine                       # each stride against the maps

(On a ROS 2 install without tdslip on the PATH: `ros2 run tdslip_ros recorder_node --ros-args -p
output:=runs/mine`, then `ros2 run tdslip_ros plant_node --ros-args -p wait_for_recorder:=true -p
command_timeout:=60.0`, then this script.)
"""

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.task import Future
from tdslip_msgs.msg import ApexEvent, StanceCommand, Status


class MyController(Node):
    def __init__(self) -> None:
        super().__init__("my_controller")
        self.commands = self.create_publisher(StanceCommand, "tdslip/command", 10)
        self.create_subscription(ApexEvent, "tdslip/apex", self.on_apex, 10)
        self.run_ended = Future()  # done at the plant's fatal Status: its run is over, and so is ours
        self.create_subscription(Status, "tdslip/status", self.on_status, 10)

    def on_status(self, status: Status) -> None:
        if status.fatal and not self.run_ended.done():
            self.run_ended.set_result(status.kind)

    def on_apex(self, apex: ApexEvent) -> None:
        command = StanceCommand(epoch=apex.epoch, stride=apex.stride, policy="my_controller")
        command.touchdown_angle = 0.35  # rad, about 20 degrees
        command.tau0 = -273.0 + 200.0 * (apex.measured_forward_speed - 5.0)  # N m, < 0: forward thrust
        command.t_f = 0.13  # s
        self.commands.publish(command)


def main() -> None:
    # It ends with the plant's run. As ros2/demos' demo_nodes_py: Ctrl-C (KeyboardInterrupt) and SIGTERM
    # (rclpy shuts the context down: ExternalShutdownException) both end it earlier, quietly.
    try:
        with rclpy.init():
            controller = MyController()
            rclpy.spin_until_future_complete(controller, controller.run_ended)
            # Its last answers reach the recorder before it goes: a reliable writer that is destroyed drops
            # what it has not yet delivered.
            controller.commands.wait_for_all_acked(Duration(seconds=2))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


if __name__ == "__main__":
    main()
