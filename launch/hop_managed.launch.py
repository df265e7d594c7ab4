"""One recorded hop with managed nodes: the recorder, the controller and the plant start unconfigured
(``autostart`` false), and the package's lifecycle manager (``lifecycle_manager``) configures and activates
each through its lifecycle services, in that order: the recorder records before the controller answers,
and the controller answers before the plant steps. The launch ends when the plant's run ends: the
controller and the recorder end with it (``end_with_run``, the recorder finalising its bag), and the
plant's exit shuts down whatever is left. A node that exits with a failure, or a transition the manager
could not make, fails the launch (exit status 1), as in hop.launch.py.

    ros2 launch tdslip_ros hop_managed.launch.py strides:=20 output:=runs/managed

Arguments: ``strides`` and ``mode`` (lockstep or realtime), defaulting to config/plant.yaml's
``max_strides`` and ``clock_mode``, and ``output``, the bag directory (default: the recorder's own name,
rosbag2_<date>-<time>). The nodes' other parameters are the installed config/*.yaml defaults.
"""

import signal
from pathlib import Path

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, RegisterEventHandler, Shutdown
from launch.event_handlers import OnProcessExit
from launch.events.process import ProcessExited
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from tdslip_ros.nodes.answers import ANSWER_SUBSCRIBERS, PLANT_AND_RECORDER


def plant_default(name: str) -> str:
    """A parameter's value in the installed config/plant.yaml, as a launch argument's default."""
    config = Path(get_package_share_directory("tdslip_ros")) / "config" / "plant.yaml"
    return str(yaml.safe_load(config.read_text())["/**"]["ros__parameters"][name])


def generate_launch_description() -> LaunchDescription:
    managed = {"autostart": False}
    recorder = Node(
        package="tdslip_ros",
        executable="recorder_node",
        name="recorder",
        output="screen",
        parameters=[{**managed, "end_with_run": True, "output": LaunchConfiguration("output")}],
    )
    controller = Node(
        package="tdslip_ros",
        executable="controller_node",
        name="controller",
        output="screen",
        # Its answers reach the recorder too before it answers (answers.ANSWER_SUBSCRIBERS).
        parameters=[{**managed, "end_with_run": True, ANSWER_SUBSCRIBERS.name: PLANT_AND_RECORDER}],
    )
    plant = Node(
        package="tdslip_ros",
        executable="plant_node",
        name="plant",
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
    manager = Node(
        package="tdslip_ros",
        executable="lifecycle_manager",
        name="lifecycle_manager",
        output="screen",
        parameters=[{"managed_nodes": "recorder,controller,plant"}],
    )

    def end_of(event: ProcessExited, context: LaunchContext) -> list[Shutdown]:
        # The controller and the recorder end by themselves with the run; launch's SIGINT at its shutdown
        # may land while they exit, when Python has given the signal back to its default: not a failure.
        interrupted = context.is_shutdown and event.returncode == -signal.SIGINT
        if event.returncode != 0 and not interrupted:  # launch's exit status is 1 only when a handler raises
            raise RuntimeError(f"{event.action.name} failed (exit status {event.returncode})")
        return [Shutdown(reason="the run ended")] if event.action is plant else []

    return LaunchDescription(
        [
            DeclareLaunchArgument("strides", default_value=plant_default("max_strides")),
            DeclareLaunchArgument("mode", default_value=plant_default("clock_mode")),
            DeclareLaunchArgument("output", default_value=""),
            recorder,
            controller,
            plant,
            manager,
            RegisterEventHandler(OnProcessExit(on_exit=end_of)),
        ]
    )
