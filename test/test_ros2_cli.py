"""The README's nodes started by hand with the real ``ros2`` command line, watched and steered with it.

One lockstep hop, as the README's table starts it (``ros2 run`` of the recorder, then of the plant; the
suite's deadbeat controller, which has answered a one-stride hop before): ``ros2 param set /controller
target_speed 4.5`` changes the target the next command aims at, and ``ros2 topic echo`` prints every apex
as recorded. (``ros2 topic hz`` is in test_ros2_launch.py, on a realtime launch.) A README command is run
as written, followed by options of its own (a shorter run, no daemon). Every README line naming a ``ros2``
command is run by a test here or in test_ros2_launch.py.

Skipped with one line where ../shared/ros2-tools is absent (support/ros2_tools.py). About 40 s.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from support.ros2_processes import (
    Ros2Processes,
    bag_messages,
    readme_command,
    readme_ros2_commands,
    ros2_processes,
)
from support.ros2_tools import ros2_command
from support.ros_harness import RosGraph, ros_graph

from tdslip_ros.interfaces import installed_parameters, resolve
from tdslip_ros.nodes import isolation, topics

STRIDES = 30
NO_DAEMON = ["--no-daemon", "--spin-time", "2"]
RECORDER = "ros2 run tdslip_ros recorder_node --ros-args -p output:=runs/mine"
PLANT = "ros2 run tdslip_ros plant_node --ros-args -p wait_for_recorder:=true -p command_timeout:=60.0"
ECHO = "ros2 topic echo /tdslip/apex"
PARAM_SET = "ros2 param set /controller target_speed 4.5"
NEW_TARGET_SPEED = 4.5  # m/s, as PARAM_SET sets it
DEADBEAT_TOLERANCE = 0.02  # m/s: deadbeat misses by the analytic map's error (0.0067 m/s seen at 5 m/s)
RUN_HERE = (RECORDER, PLANT, ECHO, PARAM_SET)
NOT_IN_THE_TOOLS = {
    "ros2 bag play runs/mine": "test_nodes_replay.py runs its stand-in, tdslip replay",
    "ros2 bag reindex runs/mine": "test_bag_recover.py runs its stand-in, tdslip recover",
}
"""README commands of rosbag2, which ../shared/ros2-tools does not have, and where their stand-ins are run."""


def yaml_documents(text: str) -> list[dict[str, Any]]:
    """The messages ``ros2 topic echo`` printed: YAML documents ended by ``---``."""
    return [document for document in yaml.safe_load_all(text) if isinstance(document, dict)]


@dataclass
class HandRun:
    processes: Ros2Processes
    bag: Path
    plant_status: int
    param_set_status: int


@pytest.fixture(scope="module")
def hand_run(tmp_path_factory: pytest.TempPathFactory) -> HandRun:
    folder = tmp_path_factory.mktemp("hand_run")
    with pytest.MonkeyPatch.context() as monkeypatch:
        for name, value in isolation.process_settings().items():
            monkeypatch.setenv(name, value)  # read when this process creates its first participant
        with ros_graph() as graph, ros2_processes(graph.domain_id, folder) as processes:
            return hand_run_on(graph, processes, folder)


def hand_run_on(graph: RosGraph, processes: Ros2Processes, folder: Path) -> HandRun:
    ros2 = str(ros2_command())
    controller = [ros2, "run", "tdslip_ros", "controller_node", "--ros-args", "-p", "policy:=deadbeat"]
    processes.start("controller", controller)
    # A first, one-stride hop: the controller has answered with the configured target (and keeps the
    # policy it planned with) before the parameter changes; its plant waits for the controller.
    first_hop = [ros2, "run", "tdslip_ros", "plant_node", "--ros-args", "-p", "max_strides:=1"]
    first_hop_status = processes.run("first_hop", [*first_hop, "-p", "command_timeout:=60.0"], 90.0)
    assert first_hop_status == 0, processes.output("first_hop")
    param_set_status = processes.run("param_set", [*readme_command(PARAM_SET), *NO_DAEMON], 30.0)
    # With the type given, echo subscribes before the plant is there (it would otherwise exit).
    processes.start("echo", [*readme_command(ECHO), "tdslip_msgs/msg/ApexEvent", *NO_DAEMON])
    processes.start("recorder", [*readme_command(RECORDER), "-p", f"output:={folder / 'bag'}"])
    # The plant waits for the controller and the recorder, not for echo: it starts once both listen.
    probe = graph.node("probe")
    # The controller listens there too: three subscribers (the controller's alone met ">= 2" with echo late).
    graph.spin_until(
        lambda: probe.count_subscribers(resolve(topics.APEX)) >= 3, "the controller, echo and the recorder"
    )
    plant = processes.start("plant", [*readme_command(PLANT), "-p", f"max_strides:={STRIDES}"])
    plant_status = plant.wait(60.0)
    processes.interrupt("controller")
    processes.interrupt("echo")
    processes.interrupt("recorder")
    return HandRun(processes, folder / "bag", plant_status, param_set_status)


@pytest.mark.nodes
def test_the_hand_started_hop_completes_and_is_recorded(hand_run: HandRun) -> None:
    assert hand_run.plant_status == 0, hand_run.processes.output("plant")
    apexes = bag_messages(hand_run.bag)[resolve(topics.APEX)]
    assert [apex.stride for _, apex in apexes] == list(range(STRIDES + 1))


@pytest.mark.nodes
def test_topic_echo_prints_the_apexes_as_recorded(hand_run: HandRun) -> None:
    """Every apex from the first echo heard to the last, each as the recorder wrote it. The plant starts once
    the recorder and the controller listen, not echo: its publisher can match echo's subscription a few
    strides late (seen once: from stride 14 of 30, in a fresh clone), and a volatile topic keeps nothing for
    it."""
    printed = yaml_documents(hand_run.processes.output("echo"))
    recorded = [apex for _, apex in bag_messages(hand_run.bag)[resolve(topics.APEX)]]
    first = printed[0]["stride"]
    assert [apex["stride"] for apex in printed] == list(range(first, STRIDES + 1))
    assert first <= STRIDES // 2
    for shown, apex in zip(printed, recorded[first:], strict=True):
        assert (shown["height"], shown["forward_speed"]) == (apex.height, apex.forward_speed)


@pytest.mark.nodes
def test_param_set_changes_the_target_of_the_next_command(hand_run: HandRun) -> None:
    assert hand_run.param_set_status == 0, hand_run.processes.output("param_set")
    assert "Set parameter successful" in hand_run.processes.output("param_set")
    speeds = [apex.forward_speed for _, apex in bag_messages(hand_run.bag)[resolve(topics.APEX)]]
    # Deadbeat answers an apex with the command that makes the next apex its target: from the initial apex
    # at config/controller.yaml's target speed, the first command after the change aims at the one set.
    assert speeds[0] == installed_parameters("controller.yaml")["target_speed"]
    assert speeds[1:] == pytest.approx([NEW_TARGET_SPEED] * STRIDES, abs=DEADBEAT_TOLERANCE)


def test_every_readme_ros2_command_is_run_by_a_test() -> None:
    """No node: the README's text against the commands the tests run (fast tier, also without ../shared)."""
    from test_ros2_launch import RUN_THERE

    untested = set(readme_ros2_commands()) - set(RUN_HERE) - set(RUN_THERE) - set(NOT_IN_THE_TOOLS)
    assert not untested, f"README.md names ros2 commands no test runs: {sorted(untested)}"
