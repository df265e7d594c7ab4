"""One recorded hop with managed nodes: the recorder, the controller and the plant start unconfigured
(``autostart`` false), and this launch drives each through configure and activate, in that order, each
node's next transition on the event of its last (launch_ros ``OnStateTransition``): the recorder records
before the controller answers, and the controller answers before the plant steps. The launch ends when the
plant's run ends: the controller and the recorder end with it (``end_with_run``, the recorder finalising
its bag), and the plant's exit shuts down whatever is left.

    ros2 launch tdslip_ros hop_managed.launch.py strides:=20 output:=runs/managed

Arguments: ``strides`` and ``mode`` (lockstep or realtime), defaulting to config/plant.yaml's
``max_strides`` and ``clock_mode``, and ``output``, the bag directory (default: the recorder's own name,
rosbag2_<date>-<time>). The nodes' other parameters are the installed config/*.yaml defaults.
"""

from pathlib import Path

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler, Shutdown
from launch.event_handlers import OnProcessExit
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from lifecycle_msgs.msg import Transition


def plant_default(name: str) -> str:
    """A parameter's value in the installed config/plant.yaml, as a launch argument's default."""
    config = Path(get_package_share_directory("tdslip_ros")) / "config" / "plant.yaml"
    return str(yaml.safe_load(config.read_text())["/**"]["ros__parameters"][name])


def transition(node: LifecycleNode, transition_id: int) -> EmitEvent:
    return EmitEvent(
        event=ChangeState(lifecycle_node_matcher=matches_action(node), transition_id=transition_id)
    )


def generate_launch_description() -> LaunchDescription:
    managed = {"autostart": False}
    recorder = LifecycleNode(
        package="tdslip_ros",
        executable="recorder_node",
        name="recorder",
        namespace="",
        output="screen",
        parameters=[{**managed, "end_with_run": True, "output": LaunchConfiguration("output")}],
    )
    controller = LifecycleNode(
        package="tdslip_ros",
        executable="controller_node",
        name="controller",
        namespace="",
        output="screen",
        parameters=[{**managed, "end_with_run": True}],
    )
    plant = LifecycleNode(
        package="tdslip_ros",
        executable="plant_node",
        name="plant",
        namespace="",
        output="screen",
        parameters=[
            {
                **managed,
                "wait_for_recorder": True,
                "max_strides": LaunchConfiguration("strides"),
                "clock_mode": LaunchConfiguration("mode"),
            }
        ],
    )
    # Each node is configured once the one before is active, and activated once it is configured.
    order = [recorder, controller, plant]
    chain = []
    for node, after in zip(order, [None, *order[:-1]], strict=True):
        configure = transition(node, Transition.TRANSITION_CONFIGURE)
        if after is None:
            chain.append(configure)
        else:
            chain.append(
                RegisterEventHandler(
                    OnStateTransition(target_lifecycle_node=after, goal_state="active", entities=[configure])
                )
            )
        chain.append(
            RegisterEventHandler(
                OnStateTransition(
                    target_lifecycle_node=node,
                    goal_state="inactive",
                    start_state="configuring",
                    entities=[transition(node, Transition.TRANSITION_ACTIVATE)],
                )
            )
        )
    return LaunchDescription(
        [
            DeclareLaunchArgument("strides", default_value=plant_default("max_strides")),
            DeclareLaunchArgument("mode", default_value=plant_default("clock_mode")),
            DeclareLaunchArgument("output", default_value=""),
            recorder,
            controller,
            plant,
            *chain,
            RegisterEventHandler(
                OnProcessExit(target_action=plant, on_exit=[Shutdown(reason="the run ended")])
            ),
        ]
    )
