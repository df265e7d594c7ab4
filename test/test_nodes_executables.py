"""The installed node executables, found where ``ros2 run`` looks (``<prefix>/lib/tdslip_ros``), hop
on their own: each its own process, configured by the installed config/*.yaml alone.

(test_package_layout.py checks the lookup itself; this checks that what it finds works together.)
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from ament_index_python.packages import get_package_prefix
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from support.ros_harness import RosGraph

from tdslip_ros.interfaces import resolve
from tdslip_ros.model.policies.registry import DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.plant_node import TICK_PERIOD

STRIDES = 3


@pytest.mark.usefixtures("ament_index")
def test_executables_hop_on_their_own_with_the_installed_config(ros: RosGraph, tmp_path: Path) -> None:
    lib = Path(get_package_prefix("tdslip_ros")) / "lib" / "tdslip_ros"
    bag = tmp_path / "bag"
    # end_with_run: the recorder and the controller end when the plant's run ends, as under tdslip run.
    ends = ["-p", "end_with_run:=true"]
    recorder = ros.start_process(
        [str(lib / "recorder_node"), "--ros-args", "-p", f"output:={bag}", *ends], tmp_path / "recorder.log"
    )
    controller = ros.start_process(
        [str(lib / "controller_node"), "--ros-args", *ends], tmp_path / "controller.log"
    )
    # Lockstep (plant.yaml): it waits for the controller, and here for the recorder (wait_for_recorder).
    plant = ros.start_process(
        [
            str(lib / "plant_node"),
            "--ros-args",
            "-p",
            f"max_strides:={STRIDES}",
            "-p",
            "wait_for_recorder:=true",
        ],
        tmp_path / "plant.log",
    )
    assert plant.wait(60) == 0, (tmp_path / "plant.log").read_text()  # exit_when_done, run complete
    assert controller.wait(30) == 0, (tmp_path / "controller.log").read_text()
    assert recorder.wait(30) == 0, (tmp_path / "recorder.log").read_text()  # its bag finalised

    messages: dict[str, list[Any]] = {}
    with (bag / "bag_0.mcap").open("rb") as stream:
        for _, channel, _, message in make_reader(
            stream, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            messages.setdefault(channel.topic, []).append(message)
    apexes = messages[resolve(topics.APEX)]
    assert [apex.stride for apex in apexes] == list(range(STRIDES + 1))
    assert (apexes[0].height, apexes[0].forward_speed) == (DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED)
    assert {command.policy for command in messages[resolve(topics.COMMAND)]} == {"energy"}
    assert [status.kind for status in messages[resolve(topics.STATUS)]] == ["run_complete"]
    # Samples at t = 0 and at the end of every tick up to the one of the last apex.
    assert len(messages[resolve(topics.STATE)]) == math.ceil(apexes[-1].sim_time / TICK_PERIOD) + 1
