"""Managed nodes (tdslip_ros.nodes.lifecycle), driven as a lifecycle manager drives them: through their
lifecycle_msgs ChangeState and GetState services, from a client node of the test's own graph; and the
recorder's walk once more with the real ``ros2 lifecycle set/get`` (skipped, in one line, without
../shared/ros2-tools).

Times on the loaded 2-core VM (load average 6-9): the recorder's walk 9 s by clients and 60-85 s by ros2
(each call a process and SPIN_TIME of discovery), the plant's pause 5 s (lockstep) and 7 s (realtime), the
refused configure 4 s, the recorder paused under a lockstep plant 9 s, the managed launch 9 s.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import time
from collections import Counter
from pathlib import Path
from typing import Protocol

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.serialization import deserialize_message
from rclpy.task import Future
from support.ros2_tools import ros2_command, ros2_environment
from support.ros_harness import RosGraph, overrides, stop_process
from tdslip_msgs.msg import ApexEvent, Status

from tdslip_ros.bag.reader import Bag, iter_messages, open_bag, verify
from tdslip_ros.interfaces import resolve
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.plant_node import PlantNode
from tdslip_ros.nodes.recorder_node import DROPPED_WHILE_PAUSED_KEY

PAUSE = 1.0  # s a paused node is watched for anything it should not do
APEX_PERIOD = 0.02  # s between two apexes the recorder's walk publishes
SPIN_TIME = "3"
"""s a ros2 call spends discovering the graph: 2 s missed the recorder now and then on the loaded VM."""
ROS2_ATTEMPTS = 3
"""ros2 calls per lifecycle request: with 3 s of discovery a call still missed the recorder once in a full
suite on the quiet VM ("Node not found"), a miss of discovery and not an answer of the node."""
NOT_FOUND = "Node not found"
MANAGER = "tdslip_ros.nodes.lifecycle_manager"


class Lifecycle(Protocol):
    """What drives one managed node: its state's id (lifecycle_msgs/State), and a transition by label."""

    def state(self) -> int: ...

    def set(self, label: str) -> bool: ...


STATE_ASK_PERIOD = 2.0  # s


class Manager:
    """The ChangeState and GetState clients of one managed node, as a lifecycle manager holds them."""

    def __init__(self, ros: RosGraph, node: str) -> None:
        self._ros = ros
        client_node = ros.node(f"manager_{len(ros.nodes)}")
        self._change = client_node.create_client(ChangeState, f"/{node}/change_state")
        self._get = client_node.create_client(GetState, f"/{node}/get_state")
        ros.spin_until(lambda: self._change.service_is_ready() and self._get.service_is_ready(), node)

    def state(self) -> int:
        """Asked again every STATE_ASK_PERIOD s until answered: a server sends its response only if it has
        matched the client's response reader within 100 ms (rmw_fastrtps), which a loaded machine can miss
        (a fresh clone's suite: the first get_state unanswered for 20 s)."""
        futures: list[Future] = []
        deadline = time.monotonic() + 20.0
        while not any(future.done() for future in futures):
            assert time.monotonic() < deadline, "get_state unanswered for 20 s"
            futures.append(self._get.call_async(GetState.Request()))
            until = time.monotonic() + STATE_ASK_PERIOD
            self._ros.spin_until(
                lambda until=until: any(f.done() for f in futures) or time.monotonic() > until, "get_state"
            )
        return int(next(f for f in futures if f.done()).result().current_state.id)

    def set(self, label: str) -> bool:
        future = self._change.call_async(ChangeState.Request(transition=Transition(label=label)))
        self._ros.spin_until(future.done, label, timeout=60.0)  # configure may compile kernels
        return bool(future.result().success)


class Ros2Lifecycle:
    """``ros2 lifecycle get/set`` on one node, without a daemon, in the test's graph."""

    def __init__(self, ros: RosGraph, node: str, log_dir: Path) -> None:
        self._ros2 = str(ros2_command())
        self._node = f"/{node}"
        self._environment = ros2_environment(ros.domain_id, log_dir)

    def _run(self, *arguments: str) -> str:
        """The call's output; again, up to ROS2_ATTEMPTS times, while discovery has not found the node."""
        command = [self._ros2, "lifecycle", *arguments, "--no-daemon", "--spin-time", SPIN_TIME]
        for _ in range(ROS2_ATTEMPTS):
            result = subprocess.run(
                command, capture_output=True, text=True, timeout=60, env=self._environment
            )
            output = result.stdout + result.stderr
            if NOT_FOUND not in output:
                break
        return output

    def state(self) -> int:
        output = self._run("get", self._node)
        found = re.search(r"\[(\d+)\]", output)
        assert found, output
        return int(found.group(1))

    def set(self, label: str) -> bool:
        return "Transitioning successful" in self._run("set", self._node, label)


def spin_for(ros: RosGraph, seconds: float) -> None:
    deadline = time.monotonic() + seconds
    ros.spin_until(lambda: time.monotonic() > deadline, f"{seconds} s", timeout=seconds + 5.0)


def test_recorder_walk_pauses_into_valid_bags(ros: RosGraph, tmp_path: Path) -> None:
    """configure -> activate -> deactivate -> activate -> shutdown by ChangeState and GetState, while a
    realtime plant hops throughout."""
    process = ros.start_recorder(tmp_path / "bag", tmp_path / "recorder.log", autostart=False)
    recorder_walk(ros, tmp_path, process, Manager(ros, "recorder"))


def test_recorder_walk_with_ros2_lifecycle(ros: RosGraph, tmp_path: Path) -> None:
    """The same walk, each transition and state by the real ``ros2 lifecycle set`` and ``get``."""
    manager = Ros2Lifecycle(ros, "recorder", tmp_path)
    process = ros.start_recorder(tmp_path / "bag", tmp_path / "recorder.log", autostart=False)
    recorder_walk(ros, tmp_path, process, manager)


def recorder_walk(
    ros: RosGraph, tmp_path: Path, process: subprocess.Popen[bytes], recorder: Lifecycle
) -> None:
    """The recorder (``process``, autostart false, writing tmp_path/bag) through its transitions by
    ``recorder``, while the test publishes an apex every APEX_PERIOD s: each bag valid when the recorder
    stops writing, holding exactly a run of the apexes published while it was active, none of the others."""
    output, log = tmp_path / "bag", tmp_path / "recorder.log"
    probe = ros.node("apex_source")
    ros.spin_until(
        lambda: (
            ("/recorder/get_state", ["lifecycle_msgs/srv/GetState"]) in probe.get_service_names_and_types()
        ),
        "the recorder's lifecycle services",
    )
    assert recorder.state() == State.PRIMARY_STATE_UNCONFIGURED
    assert not output.exists()  # autostart:=false waits: nothing opened yet

    publisher = probe.create_publisher(ApexEvent, topics.APEX, topics.STREAM_QOS)
    sent: list[int] = []  # wall time [ns] at which each stride's apex was published

    def publish() -> None:
        sent.append(time.time_ns())
        publisher.publish(ApexEvent(stride=len(sent) - 1))

    probe.create_timer(APEX_PERIOD, publish)
    assert recorder.set("configure") and recorder.state() == State.PRIMARY_STATE_INACTIVE
    assert output.is_dir() and not (output / "metadata.yaml").exists()  # opened, not finalised
    spin_for(ros, PAUSE)  # published, not recorded
    first_on = time.time_ns()
    assert recorder.set("activate")
    spin_for(ros, PAUSE)
    assert recorder.set("deactivate") and recorder.state() == State.PRIMARY_STATE_INACTIVE
    first_off = time.time_ns()

    # Paused: the first bag is complete and valid, and nothing more is written while inactive.
    first = open_bag(output)
    first_strides = recorded_strides(first, first_on, first_off)
    spin_for(ros, PAUSE)
    assert open_bag(output) == first and not (tmp_path / "bag_2").exists()

    second_on = time.time_ns()
    assert recorder.set("activate")
    spin_for(ros, PAUSE)
    assert recorder.set("shutdown") and recorder.state() == State.PRIMARY_STATE_FINALIZED
    second_off = time.time_ns()
    second_strides = recorded_strides(open_bag(tmp_path / "bag_2"), second_on, second_off)

    # Every apex published while the recorder was inactive is in neither bag.
    inactive = {stride for stride, at in enumerate(sent) if not first_on <= at <= first_off}
    inactive &= {stride for stride, at in enumerate(sent) if not second_on <= at <= second_off}
    assert len(inactive) > 2 * PAUSE / APEX_PERIOD
    assert not inactive & (set(first_strides) | set(second_strides))
    assert stop_process(process) == 0, log.read_text()
    assert "failed" not in log.read_text()


def recorded_strides(bag: Bag, active_from: int, active_until: int) -> list[int]:
    """The strides of the apexes in ``bag``, each message read and CRC-checked: a run of consecutive strides,
    each taken (its log time) while the recorder was active."""
    verify(bag)
    strides, times = [], []
    for channel, message in iter_messages(bag):
        assert channel.topic == f"/{topics.APEX}"
        strides.append(deserialize_message(message.data, ApexEvent).stride)
        times.append(message.log_time)
    assert len(strides) > 10 and strides == list(range(strides[0], strides[0] + len(strides)))
    assert active_from <= min(times) and max(times) <= active_until
    return strides


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
    spin_for(ros, 0.2)  # realtime: the ticks stepped before the pause reached the tick's process come in
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

    # Cleaned up and configured again, it hops a run of its own.
    assert manager.set("deactivate") and manager.set("cleanup") and manager.set("configure")
    assert manager.set("activate")
    ros.spin_until(lambda: plant.outcome is not None, "the end of the second run")
    assert plant.outcome.kind == Status.KIND_RUN_COMPLETE and plant.stride == strides
    ros.spin_until(lambda: len(apexes) == 2 * (strides + 1), "the second run's apexes")
    assert [apex.stride for apex in apexes[strides + 1 :]] == list(range(strides + 1))


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


def test_the_managed_launch_drives_the_nodes_and_ends_with_the_run(ros: RosGraph, tmp_path: Path) -> None:
    """``ros2 launch launch/hop_managed.launch.py``: the three nodes, unconfigured at start, are configured
    and activated by the lifecycle manager; it ends by itself with status 0 when the run ends, the bag
    finalised with every apex of the run (about 10 s)."""
    strides, bag = 3, tmp_path / "bag"
    launch_file = Path(__file__).resolve().parents[1] / "launch" / "hop_managed.launch.py"
    launched = subprocess.Popen(
        [str(ros2_command()), "launch", str(launch_file), f"strides:={strides}", f"output:={bag}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ros2_environment(ros.domain_id, tmp_path),
        start_new_session=True,  # a group of its own: the nodes too are killed if it hangs
    )
    try:
        printed, _ = launched.communicate(timeout=180)
    except subprocess.TimeoutExpired:
        os.killpg(launched.pid, signal.SIGKILL)
        printed, _ = launched.communicate()
        pytest.fail(f"the managed launch did not end within 180 s; it printed:\n{printed[-5000:]}")
    finally:
        if launched.poll() is None:
            os.killpg(launched.pid, signal.SIGKILL)
            launched.wait()
    assert launched.returncode == 0, printed[-3000:]
    assert printed.count("is active") == 3  # the manager's line per node
    for node in ("recorder", "controller", "plant"):  # each came up unconfigured, the launch took it on
        assert f"[{node}]: activate failed" not in printed and f"[{node}]: configure failed" not in printed
    recorded = open_bag(bag)
    verify(recorded)
    apexes = [
        deserialize_message(message.data, ApexEvent).stride
        for channel, message in iter_messages(recorded)
        if channel.topic == f"/{topics.APEX}"
    ]
    statuses = [
        deserialize_message(message.data, Status).kind
        for channel, message in iter_messages(recorded)
        if channel.topic == f"/{topics.STATUS}"
    ]
    assert apexes == list(range(strides + 1)) and statuses == [Status.KIND_RUN_COMPLETE]
    assert printed.count("ending with it (end_with_run)") == 2  # the controller and the recorder


def test_the_lifecycle_manager_stops_at_a_refused_configure_and_at_a_node_that_never_appears(
    ros: RosGraph, tmp_path: Path
) -> None:
    """A refused transition ends the manager with status 1 and one line naming it, before it takes on the
    next node; so does a node whose services do not appear within service_timeout."""
    ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(autostart=False, initial_height=-1.0))
    )
    controller = ros.add(ControllerNode(context=ros.context, parameter_overrides=overrides(autostart=False)))
    refused = ros.start_module(MANAGER, ["-p", "managed_nodes:=plant,controller"], tmp_path / "refused.log")
    ros.spin_until(lambda: refused.poll() is not None, "the manager's exit", timeout=60.0)
    assert refused.returncode == 1
    (line,) = [line for line in (tmp_path / "refused.log").read_text().splitlines() if "ERROR" in line]
    assert "configure of plant failed" in line
    assert (
        Manager(ros, "controller").state() == State.PRIMARY_STATE_UNCONFIGURED and controller.refusal is None
    )

    absent = ros.start_module(
        MANAGER, ["-p", "managed_nodes:=nobody", "-p", "service_timeout:=1.0"], tmp_path / "absent.log"
    )
    ros.spin_until(lambda: absent.poll() is not None, "the manager's exit", timeout=60.0)
    assert absent.returncode == 1
    assert "/nobody/change_state did not appear within 1.0 s" in (tmp_path / "absent.log").read_text()


def test_a_lockstep_plant_hops_on_through_its_recorders_pause(ros: RosGraph, tmp_path: Path) -> None:
    """The recorder a lockstep plant waits for (wait_for_recorder) is paused and activated again mid-run:
    the plant is not held by the paused recorder, nor by what the second bag never saw, and waits at the end
    for the second bag to hold every apex from its first to the last (about 15 s). The recorder's
    /diagnostics count every message the plant published: written into one of the two bags, or dropped
    while paused, none lost."""
    strides = 40
    statuses: list[DiagnosticStatus] = []
    ros.node("diagnostics_probe").create_subscription(
        DiagnosticArray,
        topics.DIAGNOSTICS,
        lambda array: statuses.extend(s for s in array.status if s.name == "/recorder"),
        topics.DIAGNOSTICS_QOS,
    )
    process = ros.start_recorder(tmp_path / "bag", tmp_path / "recorder.log")
    plant = ros.add(
        PlantNode(
            context=ros.context, parameter_overrides=overrides(wait_for_recorder=True, max_strides=strides)
        )
    )
    controller = ros.add(ControllerNode(context=ros.context))
    recorder = Manager(ros, "recorder")
    ros.spin_until(lambda: plant.stride >= 5, "five strides")
    assert recorder.set("deactivate")
    paused_at = plant.stride
    ros.spin_until(
        lambda: plant.stride >= paused_at + 5 or plant.outcome is not None, "hopping on, unrecorded"
    )
    assert recorder.set("activate")
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run", timeout=60.0)
    assert plant.outcome.kind == Status.KIND_RUN_COMPLETE, plant.outcome
    assert plant.deliver(ros.executor)  # the second bag has everything published since it opened
    published = {resolve(t): n for t, n in plant.published.items() if t in topics.RECORDED_TOPICS}
    # The controller's, all of them: its answer to the last apex may reach the plant after the run ended
    # (then the plant does not count it, but the recorder does).
    published[resolve(topics.COMMAND)] = controller.published
    seen = len(statuses)
    ros.spin_until(lambda: len(statuses) > seen + 1, "the recorder's diagnostics after the run")
    final = {pair.key: pair.value for pair in statuses[-1].values}
    assert recorder.set("shutdown")
    bags = [open_bag(path) for path in (tmp_path / "bag", tmp_path / "bag_2")]
    first, second = (recorded_apexes(bag) for bag in bags)
    assert first == list(range(len(first))) and len(first) >= 3  # the plant runs a window ahead
    assert second == list(range(second[0], strides + 1)) and second[0] > first[-1] + 1
    assert stop_process(process) == 0

    in_bags = Counter(channel.topic for bag in bags for channel, _ in iter_messages(bag))
    written = {key.removeprefix("written "): int(n) for key, n in final.items() if key.startswith("written ")}
    assert {topic: written[topic] for topic in published} == {topic: in_bags[topic] for topic in published}
    dropped = int(final["dropped while paused"])
    assert dropped > 0 and dropped == sum(published.values()) - sum(in_bags[t] for t in published)
    assert final["messages lost"] == "0"
    # The second bag's metadata holds the same count per topic; the first, closed before the pause, none.
    assert DROPPED_WHILE_PAUSED_KEY not in bags[0].custom_data
    per_topic = json.loads(bags[1].custom_data[DROPPED_WHILE_PAUSED_KEY])
    assert {topic: published[topic] - in_bags[topic] for topic in published} == {
        topic: per_topic.get(topic, 0) for topic in published
    }


def recorded_apexes(bag: Bag) -> list[int]:
    verify(bag)
    return [
        deserialize_message(message.data, ApexEvent).stride
        for channel, message in iter_messages(bag)
        if channel.topic == f"/{topics.APEX}"
    ]
