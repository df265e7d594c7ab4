"""Managed nodes (tdslip_ros.nodes.lifecycle), driven as a lifecycle manager drives them: through their
lifecycle_msgs ChangeState and GetState services, from a client node of the test's own graph.

About 25 s in all on the 2-core VM (each test starts a recorder process or a realtime tick's).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from support.ros_harness import RosGraph, overrides, stop_process
from tdslip_msgs.msg import ApexEvent, Status

from tdslip_ros.bag.reader import Bag, iter_messages, open_bag, verify
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.plant_node import PlantNode

PAUSE = 1.0  # s a paused node is watched for anything it should not do


class Manager:
    """The ChangeState and GetState clients of one managed node, as a lifecycle manager holds them."""

    def __init__(self, ros: RosGraph, node: str) -> None:
        self._ros = ros
        client_node = ros.node(f"manager_{len(ros.nodes)}")
        self._change = client_node.create_client(ChangeState, f"/{node}/change_state")
        self._get = client_node.create_client(GetState, f"/{node}/get_state")
        ros.spin_until(lambda: self._change.service_is_ready() and self._get.service_is_ready(), node)

    def state(self) -> int:
        future = self._get.call_async(GetState.Request())
        self._ros.spin_until(future.done, "get_state")
        return int(future.result().current_state.id)

    def set(self, label: str) -> bool:
        future = self._change.call_async(ChangeState.Request(transition=Transition(label=label)))
        self._ros.spin_until(future.done, label, timeout=60.0)  # configure may compile kernels
        return bool(future.result().success)


def spin_for(ros: RosGraph, seconds: float) -> None:
    deadline = time.monotonic() + seconds
    ros.spin_until(lambda: time.monotonic() > deadline, f"{seconds} s", timeout=seconds + 5.0)


def apex_count(bag: Bag) -> int:
    return sum(1 for channel, _ in iter_messages(bag) if channel.topic == f"/{topics.APEX}")


def log_times(bag: Bag) -> list[int]:
    """Every message's log time [ns], each message read and CRC-checked."""
    return [message.log_time for _, message in iter_messages(bag)]


def test_recorder_walk_pauses_into_valid_bags(ros: RosGraph, tmp_path: Path) -> None:
    """configure -> activate -> deactivate -> activate -> shutdown, while a realtime plant hops throughout."""
    output, log = tmp_path / "bag", tmp_path / "recorder.log"
    process = ros.start_recorder(output, log, autostart=False)
    recorder = Manager(ros, "recorder")
    assert recorder.state() == State.PRIMARY_STATE_UNCONFIGURED
    assert not output.exists()  # autostart:=false waits: nothing opened yet

    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(clock_mode="realtime", max_strides=0))
    )
    ros.add(ControllerNode(context=ros.context))
    ros.spin_until(lambda: plant.running, "the plant's start")

    assert recorder.set("configure") and recorder.state() == State.PRIMARY_STATE_INACTIVE
    assert (output / "metadata.yaml").exists() is False and output.is_dir()  # opened, not finalised
    spin_for(ros, PAUSE)  # hopping, not recorded
    first_on = time.time_ns()
    assert recorder.set("activate") and recorder.state() == State.PRIMARY_STATE_ACTIVE
    stride = plant.stride
    ros.spin_until(lambda: plant.stride >= stride + 2, "two strides recorded")
    assert recorder.set("deactivate") and recorder.state() == State.PRIMARY_STATE_INACTIVE
    first_off = time.time_ns()

    # Paused: the first bag is complete and valid, and nothing more is written while inactive.
    first = open_bag(output)
    verify(first)
    first_times = log_times(first)
    assert first_times and first_on <= min(first_times) and max(first_times) <= first_off
    assert apex_count(first) >= 2
    paused_at = plant.published[topics.STATE]
    spin_for(ros, PAUSE)
    assert plant.published[topics.STATE] > paused_at + 100  # the plant hopped on meanwhile
    assert open_bag(output) == first and not (tmp_path / "bag_2").exists()

    second_on = time.time_ns()
    assert recorder.set("activate")
    stride = plant.stride
    ros.spin_until(lambda: plant.stride >= stride + 1, "a stride recorded in the second bag")
    assert recorder.set("shutdown") and recorder.state() == State.PRIMARY_STATE_FINALIZED
    second_off = time.time_ns()

    second = open_bag(tmp_path / "bag_2")
    verify(second)
    second_times = log_times(second)
    assert second_times and second_on <= min(second_times) and max(second_times) <= second_off
    assert apex_count(second) >= 1
    assert stop_process(process) == 0, log.read_text()
    assert "failed" not in log.read_text()


@pytest.mark.parametrize("clock_mode", ["lockstep", "realtime"])
def test_a_deactivated_plant_holds_its_state_and_resumes(ros: RosGraph, clock_mode: str) -> None:
    strides = 3
    plant = ros.add(
        PlantNode(
            context=ros.context,
            parameter_overrides=overrides(autostart=False, clock_mode=clock_mode, max_strides=strides),
        )
    )
    ros.add(ControllerNode(context=ros.context))
    apexes = ros.collect(ApexEvent, topics.APEX)
    statuses = ros.collect(Status, topics.STATUS)
    manager = Manager(ros, "plant")
    assert manager.state() == State.PRIMARY_STATE_UNCONFIGURED and not plant.running
    assert manager.set("configure") and manager.state() == State.PRIMARY_STATE_INACTIVE
    deadline = time.monotonic() + PAUSE
    ros.spin_until(lambda: time.monotonic() > deadline, "a configured plant's wait")
    assert not plant.running and plant.published[topics.STATE] == 0  # configured, not started

    assert manager.set("activate")
    ros.spin_until(lambda: plant.stride >= 1, "the first stride")
    assert manager.set("deactivate") and manager.state() == State.PRIMARY_STATE_INACTIVE
    held = (plant.sim_time, plant.stride, plant.published[topics.STATE])
    deadline = time.monotonic() + PAUSE
    ros.spin_until(lambda: time.monotonic() > deadline, "the pause")
    assert (plant.sim_time, plant.stride, plant.published[topics.STATE]) == held and plant.running

    resumed = time.monotonic()
    assert manager.set("activate")
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome.kind == Status.KIND_RUN_COMPLETE, plant.outcome
    ros.spin_until(lambda: len(apexes) == strides + 1 and statuses, "the last apex and the status")
    assert [apex.stride for apex in apexes] == list(range(strides + 1))
    # Simulated time runs on from where it was held: the samples leave no gap at the pause.
    assert plant.published[topics.STATE] == round(plant.sim_time / 1e-3) + 1
    if clock_mode == "realtime":  # the pause did not count as time the tick was late: no catch-up burst
        ran = time.monotonic() - resumed
        assert plant.sim_time - held[0] <= ran + 0.1, (plant.sim_time, held, ran)


def test_a_bad_parameter_fails_configure_and_leaves_the_node_unconfigured(
    ros: RosGraph, tmp_path: Path
) -> None:
    plant = ros.add(
        PlantNode(
            context=ros.context, parameter_overrides=overrides(autostart=False, initial_height=math.inf)
        )
    )
    manager = Manager(ros, "plant")
    assert not manager.set("configure")
    assert manager.state() == State.PRIMARY_STATE_UNCONFIGURED and "initial_height" in str(plant.refusal)

    taken, log = tmp_path / "taken", tmp_path / "recorder.log"
    taken.mkdir()  # an output that exists: the recorder must not write into it
    process = ros.start_recorder(taken, log, autostart=False)
    recorder = Manager(ros, "recorder")
    assert not recorder.set("configure")
    assert recorder.state() == State.PRIMARY_STATE_UNCONFIGURED
    assert list(taken.iterdir()) == []
    assert process.poll() is None  # it did not crash
    assert stop_process(process) == 0
    (line,) = [line for line in log.read_text().splitlines() if "failed" in line]
    assert "configure failed:" in line and str(taken) in line
