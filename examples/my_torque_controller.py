"""A 1 kHz hip-torque controller of your own for the tdslip_ros plant, as a ROS 2 user would write it.

It answers every apex with stance feedback: a fixed touchdown angle, and `stance = STANCE_FEEDBACK`, which
tells the plant that the hip torques follow on tdslip/hip_torque. Then, at every state sample in stance, it
sends the torque for that sample's tick: a forward push in proportion to how much slower than 5 m/s the
body moves (it settles near 1.01 m and 5.02 m/s). Default QoS on every topic. A torque copies the apex's
epoch, the state's stride and the state's stamp in milliseconds (its tick), which is how the plant knows
what it answers; in lockstep the plant waits for it at every stance tick.

    tdslip run --controller none --domain-id 42 --out runs/mine-torque   # plant and recorder wait for you
    ROS_DOMAIN_ID=42 python3 examples/my_torque_controller.py             # in another terminal
    tdslip analyze runs/mine-torque          # each stance replayed from its recorded torques
"""

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.task import Future
from tdslip_msgs.msg import ApexEvent, HipTorque, HopperState, StanceCommand, Status


class MyTorqueController(Node):
    def __init__(self) -> None:
        super().__init__("my_torque_controller")
        self.epoch = 0
        self.commands = self.create_publisher(StanceCommand, "tdslip/command", 10)
        self.torques = self.create_publisher(HipTorque, "tdslip/hip_torque", 10)
        self.create_subscription(ApexEvent, "tdslip/apex", self.on_apex, 10)
        self.run_ended = Future()  # done at the plant's fatal Status: its run is over, and so is ours
        self.create_subscription(Status, "tdslip/status", self.on_status, 10)
        self.create_subscription(HopperState, "tdslip/state", self.on_state, 10)

    def on_status(self, status: Status) -> None:
        if status.fatal and not self.run_ended.done():
            self.run_ended.set_result(status.kind)

    def on_apex(self, apex: ApexEvent) -> None:
        self.epoch = apex.epoch
        command = StanceCommand(epoch=apex.epoch, stride=apex.stride, policy="my_torque_controller")
        command.touchdown_angle = 0.38  # rad, about 22 degrees
        command.stance = StanceCommand.STANCE_FEEDBACK  # no ramp: the torques come on tdslip/hip_torque
        self.commands.publish(command)

    def on_state(self, state: HopperState) -> None:
        if state.phase != HopperState.PHASE_STANCE:
            return
        torque = HipTorque(header=state.header, epoch=self.epoch, stride=state.stride)
        torque.tick = state.header.stamp.sec * 1000 + round(state.header.stamp.nanosec / 1e6)
        push = -1500.0 * (5.0 - state.xdot)  # N m, < 0: forward thrust
        torque.torque = max(-400.0, min(400.0, push))
        self.torques.publish(torque)


def main() -> None:
    # It ends with the plant's run. As ros2/demos' demo_nodes_py: Ctrl-C (KeyboardInterrupt) and SIGTERM
    # (rclpy shuts the context down: ExternalShutdownException) both end it earlier, quietly as a rule (a
    # Ctrl-C that lands inside rclpy's take of one of the 1 kHz messages can surface as a RuntimeError
    # traceback: an rclpy race).
    try:
        with rclpy.init():
            controller = MyTorqueController()
            rclpy.spin_until_future_complete(controller, controller.run_ended)
            # Its last answers reach the recorder before it goes: a reliable writer that is destroyed drops
            # what it has not yet delivered.
            controller.commands.wait_for_all_acked(Duration(seconds=2))
            controller.torques.wait_for_all_acked(Duration(seconds=2))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


if __name__ == "__main__":
    main()
