"""One recorded hop under ``ros2 launch``: the plant, a controller (or none: yours) and the recorder.

    ros2 launch tdslip_ros hop.launch.py strides:=20 output:=runs/launched
    ros2 launch tdslip_ros hop.launch.py namespace:=h1 controller:=none   # answer /h1/tdslip/apex yourself

The defaults are the installed ``config/plant.yaml``, ``config/controller.yaml`` and
``config/recorder.yaml``, passed to each node as its parameter file; ``params_file`` comes on top of
them, and an argument given here on top of that (an argument left empty sets nothing). So no default
is written twice: ``ros2 launch tdslip_ros hop.launch.py --show-args`` names each argument's default
as read from those files.

The plant waits for the recorder (``wait_for_recorder``), so every message is recorded, and ends at
``strides``. When it exits the launch shuts down: launch sends SIGINT to the controller and the
recorder, which finalises its bag. The exit status is the run's: ``ros2 launch`` returns 0 after a
shutdown whatever its processes returned, and 1 when an event handler raises, so a node that exits
with a failure (a failed run, refused parameters, a recorder that could not write) raises here.
Namespaces are those of ``tdslip run --namespace``: ``h1`` and ``/h1`` are both ``/h1``, so two
launches in two namespaces on one ``ROS_DOMAIN_ID`` are two hoppers.
"""

from __future__ import annotations

from typing import Any

from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler, Shutdown
from launch.event_handlers import OnProcessExit
from launch.events.process import ProcessExited
from launch_ros.actions import Node

from tdslip_ros.interfaces import config_file, installed_parameters, qualified_namespace
from tdslip_ros.model.policies.registry import STANCE_FEEDBACK_POLICIES
from tdslip_ros.nodes.answers import ANSWER_SUBSCRIBERS, PLANT_AND_RECORDER

NO_CONTROLLER = "none"

# launch argument -> (node config file, parameter it sets)
NODE_ARGUMENTS = {
    "policy": ("controller.yaml", "policy"),
    "mode": ("plant.yaml", "clock_mode"),
    "strides": ("plant.yaml", "max_strides"),
    "output": ("recorder.yaml", "output"),
}


def _default(config_name: str, parameter: str) -> Any:
    return installed_parameters(config_name)[parameter]


def _described(config_name: str, parameter: str) -> str:
    return f"{parameter} of config/{config_name} (empty: that file's {_default(config_name, parameter)!r})"


def _arguments() -> list[DeclareLaunchArgument]:
    declared = [
        DeclareLaunchArgument(name, default_value="", description=_described(config_name, parameter))
        for name, (config_name, parameter) in NODE_ARGUMENTS.items()
    ]
    return declared + [
        DeclareLaunchArgument("namespace", default_value="/", description="ROS namespace of the three nodes"),
        DeclareLaunchArgument(
            "use_sim_time",
            default_value="false",
            choices=["true", "false"],
            description="the controller and recorder follow the plant's /clock",
        ),
        DeclareLaunchArgument(
            "params_file",
            default_value="",
            description="a ROS 2 parameter file over config/*.yaml, for every node",
        ),
        DeclareLaunchArgument(
            "controller",
            default_value="tdslip",
            choices=["tdslip", NO_CONTROLLER],
            description=f"tdslip: the suite's controller of the policy; {NO_CONTROLLER}: yours answers",
        ),
    ]


def _set(context: LaunchContext, *arguments: str) -> list[str]:
    """``-p parameter:=value`` for each of ``arguments`` given: the node types and checks it as it does any
    ``-p`` (a wrong type stops it with one line, exit status 2), which it does not for a parameter file."""
    configuration = context.launch_configurations
    given = [argument for argument in arguments if configuration[argument]]
    return [word for a in given for word in ("-p", f"{NODE_ARGUMENTS[a][1]}:={configuration[a]}")]


def _nodes(context: LaunchContext) -> list[Any]:
    configuration = context.launch_configurations
    namespace = qualified_namespace(configuration["namespace"])
    parameter_files = ["--params-file", configuration["params_file"]] if configuration["params_file"] else []
    sim_time = ["-p", f"use_sim_time:={configuration['use_sim_time']}"]

    def node(executable: str, config_name: str, settings: list[str]) -> Node:
        return Node(
            package="tdslip_ros",
            executable=executable,
            namespace=namespace,
            output="screen",
            # In order, since rcl lets later parameter arguments win: launch_ros would put the files of
            # `parameters` after these.
            ros_arguments=["--params-file", str(config_file(config_name)), *parameter_files, *settings],
        )

    plant = node(
        "plant_node", "plant.yaml", [*_set(context, "mode", "strides"), "-p", "wait_for_recorder:=true"]
    )
    recorder = node("recorder_node", "recorder.yaml", [*_set(context, "output"), *sim_time])
    nodes = [recorder, plant]
    if configuration["controller"] != NO_CONTROLLER:
        policy = configuration["policy"] or _default("controller.yaml", "policy")
        # Its answers reach the recorder too before it answers (answers.ANSWER_SUBSCRIBERS).
        answered = ["-p", f"{ANSWER_SUBSCRIBERS.name}:={PLANT_AND_RECORDER}", *sim_time]
        if policy in STANCE_FEEDBACK_POLICIES:  # the policy is that node's own
            nodes.append(node("stance_controller_node", "controller.yaml", answered))
        else:
            nodes.append(node("controller_node", "controller.yaml", [*_set(context, "policy"), *answered]))

    def end_of(event: ProcessExited, context: LaunchContext) -> list[Shutdown]:
        if event.returncode != 0:  # launch's exit status is 1 only when a handler raises
            raise RuntimeError(f"{event.action.name} failed (exit status {event.returncode})")
        return [Shutdown(reason=f"{event.action.name} ended")] if event.action is plant else []

    return [*nodes, RegisterEventHandler(OnProcessExit(on_exit=end_of))]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([*_arguments(), OpaqueFunction(function=_nodes)])
