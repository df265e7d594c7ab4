"""The lifecycle manager: brings managed nodes up, one after the other, through their lifecycle services.

    ros2 run tdslip_ros lifecycle_manager --ros-args -p managed_nodes:=recorder,controller,plant

Each node of ``managed_nodes`` (names relative to the manager's namespace) is configured and then
activated by its ``change_state`` service before the next one is taken on, so the recorder records before
the controller answers and the controller answers before the plant steps (nav2's lifecycle_manager, in
small). The manager then exits 0; a transition refused, or a node whose services do not appear within
``service_timeout``, ends it at once with one line and status 1.

Why services and not launch_ros' ``OnStateTransition``: that event handler hears the node's
``transition_event`` topic, which is volatile, so an event published before launch's subscription has
matched is lost and the launch waits forever (ros2/rcl#1166; seen once in CI on the 2-core VM). A service
call is answered, whenever the node is found.
"""

from __future__ import annotations

import sys

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from tdslip_ros.nodes import parameters
from tdslip_ros.nodes.entry import spin_until
from tdslip_ros.nodes.parameters import ParameterSpec

MANAGED_NODES = ParameterSpec(
    "managed_nodes",
    "recorder,controller,plant",
    "the nodes to configure and activate, comma-separated, in this order",
    read_only=True,
)
SERVICE_TIMEOUT = ParameterSpec(
    "service_timeout",
    60.0,
    "s to wait for a node's lifecycle services to appear",
    0.1,
    3600.0,
    read_only=True,
)
TRANSITION_TIMEOUT = ParameterSpec(
    "transition_timeout",
    300.0,
    "s to wait for a transition's answer (a plant's configure compiles kernels on a first run)",
    0.1,
    3600.0,
    read_only=True,
)
SPECS = (MANAGED_NODES, SERVICE_TIMEOUT, TRANSITION_TIMEOUT)
TRANSITIONS = (("configure", Transition.TRANSITION_CONFIGURE), ("activate", Transition.TRANSITION_ACTIVATE))


def bring_up(node: Node, executor: SingleThreadedExecutor) -> str | None:
    """Configure and activate each managed node in order; None when all are active, else why not."""
    values = parameters.declare(node, SPECS)
    names = [name.strip() for name in str(values["managed_nodes"]).split(",") if name.strip()]
    for name in names:
        client = node.create_client(ChangeState, f"{name}/change_state")
        if not spin_until(executor, client.service_is_ready, float(values["service_timeout"])):
            return f"{client.service_name} did not appear within {values['service_timeout']} s"
        for label, transition_id in TRANSITIONS:
            future = client.call_async(ChangeState.Request(transition=Transition(id=transition_id)))
            if not spin_until(executor, future.done, float(values["transition_timeout"])):
                return f"{label} of {name} was not answered within {values['transition_timeout']} s"
            if not future.result().success:
                return f"{label} of {name} failed (its log says why)"
        node.get_logger().info(f"{name} is active")
    return None


def main(argv: list[str] | None = None) -> int:
    rclpy.init(args=sys.argv if argv is None else argv)
    node = Node("lifecycle_manager")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        failure = bring_up(node, executor)
        if failure is not None:
            node.get_logger().error(failure)
        return 0 if failure is None else 1
    except (KeyboardInterrupt, ExternalShutdownException):  # Ctrl-C, or launch's SIGINT at its shutdown
        return 130
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
