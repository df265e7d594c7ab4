"""The README's nodes started by hand with the real ``ros2`` command line, watched and steered with it.

One realtime hop, as the README's table starts it (``ros2 run`` of the recorder, then of the plant; the
suite's deadbeat controller): ``ros2 topic hz`` measures the 1 kHz state on the wall clock, ``ros2 topic
echo`` prints every apex, and ``ros2 param set /controller target_speed 4.5`` changes the target the next
commands aim at. A README command is run as written, followed by options of its own (a shorter run, no
daemon). Every README line naming a ``ros2`` command is run by a test here or in test_ros2_launch.py.

Skipped with one line where ../shared/ros2-tools is absent (support/ros2_tools.py). About 35 s.
"""

from __future__ import annotations

import re
import time
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

from tdslip_ros.interfaces import installed_parameters, resolve
from tdslip_ros.nodes import isolation, topics
from tdslip_ros.nodes.plant_node import TICK_PERIOD

pytestmark = pytest.mark.nodes

STRIDES = 30  # about 8 s of a realtime hop at 5 m/s: time for the tools to start and act within it
NO_DAEMON = ["--no-daemon", "--spin-time", "2"]
RECORDER = "ros2 run tdslip_ros recorder_node --ros-args -p output:=runs/mine"
PLANT = "ros2 run tdslip_ros plant_node --ros-args -p wait_for_recorder:=true -p command_timeout:=60.0"
ECHO = "ros2 topic echo /tdslip/apex"
PARAM_SET = "ros2 param set /controller target_speed 4.5"
NEW_TARGET_SPEED = 4.5  # m/s, as PARAM_SET sets it
DEADBEAT_TOLERANCE = (
    0.02  # m/s: deadbeat's apex reaches its target within the analytic map's error, ~0.005 m/s
)
RUN_HERE = (RECORDER, PLANT, ECHO, PARAM_SET)
NOT_IN_THE_TOOLS = {
    "ros2 bag play runs/mine": "test_nodes_replay.py runs its stand-in, tdslip replay",
    "ros2 bag reindex runs/mine": "test_bag_recover.py runs its stand-in, tdslip recover",
}
"""README commands of rosbag2, which ../shared/ros2-tools does not have, and where their stand-ins are run."""


def yaml_documents(text: str) -> list[dict[str, Any]]:
    """The messages ``ros2 topic echo`` printed: YAML documents ended by ``---``."""
    return [document for document in yaml.safe_load_all(text) if isinstance(document, dict)]


MIN_SEEN = (
    0.25  # share of the plant's rate that hz's best report reaches even on a busy 2-core VM (half of 0.5)
)
RATE = re.compile(r"average rate: ([0-9.]+)")


@dataclass
class HandRun:
    processes: Ros2Processes
    bag: Path
    plant_status: int
    param_set_status: int
    param_set_started_ns: int
    param_set_done_ns: int


@pytest.fixture(scope="module")
def hand_run(tmp_path_factory: pytest.TempPathFactory) -> HandRun:
    folder = tmp_path_factory.mktemp("hand_run")
    ros2 = str(ros2_command())
    with isolation.reserved_domain() as domain_id, ros2_processes(domain_id, folder) as processes:
        # With the type given, echo subscribes before the plant is there (it would otherwise exit).
        processes.start("echo", [*readme_command(ECHO), "tdslip_msgs/msg/ApexEvent", *NO_DAEMON])
        processes.start("hz", [ros2, "topic", "hz", resolve(topics.STATE), "--window", "1000"])
        processes.start("recorder", [*readme_command(RECORDER), "-p", f"output:={folder / 'bag'}"])
        controller = [ros2, "run", "tdslip_ros", "controller_node", "--ros-args", "-p", "policy:=deadbeat"]
        processes.start("controller", controller)
        realtime = ["-p", "clock_mode:=realtime", "-p", f"max_strides:={STRIDES}"]
        plant = processes.start("plant", [*readme_command(PLANT), *realtime])
        first_apex = time.monotonic() + 60.0
        while "stride: " not in processes.output("echo"):
            assert time.monotonic() < first_apex and plant.poll() is None, processes.output("plant")
            time.sleep(0.1)
        started = time.time_ns()
        param_set_status = processes.run("param_set", [*readme_command(PARAM_SET), *NO_DAEMON], timeout=30.0)
        done = time.time_ns()
        plant_status = plant.wait(60.0)
        processes.interrupt("hz")
        processes.interrupt("controller")
        processes.interrupt("echo")
        processes.interrupt("recorder")
        return HandRun(processes, folder / "bag", plant_status, param_set_status, started, done)


def test_the_hand_started_hop_completes_and_is_recorded(hand_run: HandRun) -> None:
    assert hand_run.plant_status == 0, hand_run.processes.output("plant")
    apexes = bag_messages(hand_run.bag)[resolve(topics.APEX)]
    assert [apex.stride for _, apex in apexes] == list(range(STRIDES + 1))


def test_topic_hz_sees_the_plants_1khz_and_never_more(hand_run: HandRun) -> None:
    """Each report of hz averages the last 1000 samples (1 s) it took. It never sees more than the plant's
    1 kHz; it may see less, since it drops what it does not take in time (best effort, a history of 5)
    when the plant's samples come in bursts: at a load average of 8 to 9 on the 2-core VM its best
    reports were 508 and 697 Hz."""
    rates = [float(rate) for rate in RATE.findall(hand_run.processes.output("hz"))]
    assert rates, hand_run.processes.output("hz")
    assert MIN_SEEN / TICK_PERIOD <= max(rates) <= 1.1 / TICK_PERIOD


def test_topic_echo_prints_every_apex_as_recorded(hand_run: HandRun) -> None:
    printed = yaml_documents(hand_run.processes.output("echo"))
    recorded = [apex for _, apex in bag_messages(hand_run.bag)[resolve(topics.APEX)]]
    assert [apex["stride"] for apex in printed] == list(range(STRIDES + 1))
    for shown, apex in zip(printed, recorded, strict=True):
        assert (shown["height"], shown["forward_speed"]) == (apex.height, apex.forward_speed)


def test_param_set_changes_the_target_of_the_next_command(hand_run: HandRun) -> None:
    assert hand_run.param_set_status == 0, hand_run.processes.output("param_set")
    assert "Set parameter successful" in hand_run.processes.output("param_set")
    messages = bag_messages(hand_run.bag)
    speeds = {apex.stride: apex.forward_speed for _, apex in messages[resolve(topics.APEX)]}
    commands = messages[resolve(topics.COMMAND)]
    before = [command.stride for log_time, command in commands if log_time < hand_run.param_set_started_ns]
    after = [command.stride for log_time, command in commands if log_time > hand_run.param_set_done_ns]
    assert before and after
    # Deadbeat answers an apex with the command that makes the next apex its target: the configured one
    # before, the one set after.
    configured = installed_parameters("controller.yaml")["target_speed"]
    assert speeds[before[-1] + 1] == pytest.approx(configured, abs=DEADBEAT_TOLERANCE)
    assert speeds[after[0] + 1] == pytest.approx(NEW_TARGET_SPEED, abs=DEADBEAT_TOLERANCE)


def test_every_readme_ros2_command_is_run_by_a_test() -> None:
    from test_ros2_launch import RUN_THERE

    untested = set(readme_ros2_commands()) - set(RUN_HERE) - set(RUN_THERE) - set(NOT_IN_THE_TOOLS)
    assert not untested, f"README.md names ros2 commands no test runs: {sorted(untested)}"
