"""One hop of the node suite, recorded and checked: what ``tdslip run`` runs.

Three processes on a private ROS graph (:mod:`tdslip_ros.nodes.isolation`: a free domain id from
120-229 reserved per run unless ``--domain-id`` is given, ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``,
and a Fast DDS profile with prompt acknowledgements):

* this one hosts the plant node (so it knows exactly what was published) and a small monitor that
  follows /tdslip/apex for the progress line and the summary table; a realtime plant ticks in a process of
  its own (:mod:`tdslip_ros.nodes.tick_process`);
* ``controller_node`` in a child process: in the plant's, its planning would hold the GIL against the
  plant's publishing, and the plant would miss ticks; apart, an answer costs a DDS round trip on top of
  the planning (docs/realtime.md, "Why four processes"; ``bench_nodes.py latency``); a stance-feedback
  policy (:data:`~tdslip_ros.model.policies.registry.STANCE_FEEDBACK_POLICIES`) runs in
  ``stance_controller_node`` instead, which answers the apexes and streams a hip torque per stance tick;
* ``recorder_node`` in a child process: a Python callback per message would otherwise share one
  interpreter with the plant; on two cores the plant and the recorder each get one.

The children take the installed config/*.yaml plus the overrides of the run's options. The plant
starts once the recorder and the controller have matched its topics; the controller subscribes to the apex
only once its answers have matched the recorder too (``min_subscribers``,
:data:`~tdslip_ros.nodes.answers.PLANT_AND_RECORDER`). When the run ends, the plant's
messages are acknowledged by every subscriber, the controller is stopped (it delivers its last
command), then the recorder (it records what reached it and finalises the bag). Last, the message
counts of the bag are compared with what was published: the plant's own counts, and for
/tdslip/command and /tdslip/hip_torque the commands and torques the plant received. The bag directory
(:attr:`RunOptions.out`) holds ``metadata.yaml`` and ``<name>_0.mcap``; :attr:`RunReport.ok` says whether
the run completed and its recording is complete.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import rclpy
import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from tdslip_msgs.msg import ApexEvent

from tdslip_ros.bag.recover import recoverable_counts
from tdslip_ros.interfaces import (
    STOP_REQUESTED,
    config_file,
    qualified_namespace,
    resolve,
)
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.policies.registry import (
    STANCE_FEEDBACK_POLICIES,
)
from tdslip_ros.nodes import (
    isolation,
    topics,
)
from tdslip_ros.nodes.entry import (
    PARENT_PID_VARIABLE,
    spin_until,
)
from tdslip_ros.nodes.plant_node import PlantNode, RunOutcome
from tdslip_ros.nodes.plant_run import RunCounts
from tdslip_ros.nodes.realtime import TickTiming
from tdslip_ros.nodes.rows import Rows
from tdslip_ros.nodes.run_options import (
    RunError,
    RunOptionError,
    RunOptions,
    check_options,
    controller_overrides,
    overrides_arguments,
    plant_overrides,
    run_custom_data,
)

STARTUP_TIMEOUT = 30.0  # s for the child nodes to start and match the plant's topics
STOP_TIMEOUT = 30.0  # s for a child to stop after SIGINT
CLOSE_GRACE = 15.0  # s a child gets to stop on an error path before it is killed
QUIET = 0.2  # s without a new command: the controller's last commands have been received
LAST_ANSWER_WAIT = 1.0  # s the suite's controller is given to answer the last apex before it is stopped

ProgressCallback = Callable[[ApexEvent], None]


@dataclass
class RunReport:
    outcome: RunOutcome
    params: HopperParams
    apexes: Rows
    """The fields of each apex event (:meth:`Rows.of_message`), in the order the monitor heard them."""
    published: dict[str, int]
    """Messages per recorded topic (fully qualified name): the plant's, and the commands it received."""
    recorded: dict[str, int]
    """Messages per recorded topic in the bag."""
    command_latencies_ns: Rows
    """(epoch, stride, ns) of each answered apex: wall time from its publication to the plant's receipt of the
    valid command for it."""
    delivery_time: float
    """s from the plant's start until every subscriber had acknowledged all its messages."""
    tick_timing: TickTiming | None
    """Realtime mode: the timing statistics of the plant's tick."""
    bag: Path
    controller_log: str
    """What the controller process printed: why it could not answer an apex, if it could not."""
    saturated_strides: int = 0
    """Touchdowns at which the commanded |tau0| exceeded tau_max (the hip saturated)."""
    late_commands: int = 0
    """Realtime: commands that arrived after the touchdown of their stride (the previous command held)."""
    stale_torques: int = 0
    """Realtime, stance feedback: stance ticks that held zero, no torque within torque_max_age."""
    late_torques: int = 0
    """Stance feedback: torques that came after their tick was stepped or after their stance."""
    counts: RunCounts = field(default_factory=RunCounts)
    """Everything the plant counted, as of the end of the run: its rejections among them."""
    problems: list[str] = field(default_factory=list)

    @property
    def recording_complete(self) -> bool:
        return self.published == self.recorded

    @property
    def ok(self) -> bool:
        return self.outcome.ok and self.recording_complete and not self.problems


class ApexMonitor(Node):
    """Collects the apex events of the run (for progress and the summary), each once: a lockstep plant
    publishes an unanswered apex again (PlantRun.repeat_apex)."""

    def __init__(self, progress: ProgressCallback | None, **node_options: object) -> None:
        super().__init__("run_monitor", **node_options)  # type: ignore[arg-type]
        self.apexes = Rows.of_message(ApexEvent)
        self.heard = 0  # apex messages, repeats included
        self._last: tuple[int, int] | None = None  # (epoch, stride) of the latest
        self._progress = progress
        self.create_subscription(ApexEvent, topics.APEX, self._on_apex, topics.STREAM_QOS)

    def _on_apex(self, msg: ApexEvent) -> None:
        self.heard += 1
        if (msg.epoch, msg.stride) == self._last:
            return
        self._last = (msg.epoch, msg.stride)
        self.apexes.append_message(msg)
        if self._progress is not None:
            self._progress(msg)


@dataclass
class ChildNode:
    """A node executable in a child process, its output kept in a temporary file."""

    name: str
    process: subprocess.Popen[bytes]
    log: IO[bytes]

    @classmethod
    def start(
        cls, module: str, arguments: list[str], environment: dict[str, str], namespace: str = "/"
    ) -> ChildNode:
        log = tempfile.TemporaryFile()
        ros_arguments = ["--ros-args", "-r", f"__ns:={qualified_namespace(namespace)}"]
        command = [sys.executable, "-m", module, *ros_arguments, *arguments]
        # A session of its own: a Ctrl-C at the terminal reaches only this process, which stops the
        # children in order; and they stop by themselves should this process die.
        process = subprocess.Popen(
            command,
            env={**environment, PARENT_PID_VARIABLE: str(os.getpid())},
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        return cls(module.rsplit(".", 1)[-1], process, log)

    def output(self) -> str:
        self.log.seek(0)
        return self.log.read().decode(errors="replace")

    def check_alive(self) -> None:
        if self.process.poll() is not None:
            raise RunError(f"{self.name} exited early ({self.process.returncode}):\n{self.output()}")

    def stop(self, timeout: float = STOP_TIMEOUT) -> None:
        """SIGINT, then wait; a node that does not stop in time is killed and reported."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            code = self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
            raise RunError(f"{self.name} did not stop within {timeout} s:\n{self.output()}") from None
        if code != 0:
            raise RunError(f"{self.name} failed ({code}):\n{self.output()}")

    def close(self, grace: float = CLOSE_GRACE) -> None:
        """Stop the node if it still runs (an error path): SIGINT first, so that a recorder still
        finalises its bag, and SIGKILL only after ``grace`` seconds."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(grace)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.log.close()


def read_bag_counts(bag: Path) -> dict[str, int]:
    """Messages per topic from a bag directory's metadata.yaml (rosbag2's layout)."""
    information = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {
        entry["topic_metadata"]["name"]: int(entry["message_count"])
        for entry in information["topics_with_message_count"]
    }


@contextmanager
def _ros_context(domain_id: int) -> Iterator[Context]:
    context = Context()
    rclpy.init(context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


def run(
    options: RunOptions,
    progress: ProgressCallback | None = None,
    stop_requested: Callable[[], bool] = lambda: False,
) -> RunReport:
    """Run the suite once (see the module docstring); RunError if it could not run or record.

    ``stop_requested`` is polled while running; when it turns true the run ends as complete. On
    every way out (a child's crash, an exception, a second Ctrl-C) the children are stopped with
    SIGINT first, so the recorder finalises the bag with what it has.
    """
    check_options(options)
    bag = Path(options.out)
    os.environ.update(isolation.process_settings())  # before the first participant of this process
    with ExitStack() as stack:
        try:
            domain_id = stack.enter_context(isolation.reserved_domain(options.domain_id))
        except RuntimeError as error:
            raise RunError(str(error)) from None
        environment = isolation.isolated_environment(domain_id)
        context = stack.enter_context(_ros_context(domain_id))
        try:
            plant = PlantNode(
                start_when_ready=False,
                context=context,
                namespace=options.namespace,
                cli_args=["--ros-args", "--params-file", str(config_file("plant.yaml"))],
                parameter_overrides=[
                    Parameter(name, value=value)
                    for name, value in plant_overrides(options).items()
                    if value is not None
                ],
            )
        except (ParameterException, ParameterError) as error:
            raise RunOptionError(f"plant parameters: {error}") from None
        stack.callback(plant.destroy_node)
        try:
            controller_parameters = controller_overrides(options, plant.hopper)
        except ParameterError as error:
            raise RunOptionError(f"the controller's model (--mismatch): {error}") from None
        try:
            bag.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise RunOptionError(f"cannot create the directory for --out {bag}: {error.strerror}") from None
        monitor = ApexMonitor(progress, context=context, namespace=options.namespace)
        stack.callback(monitor.destroy_node)
        executor = EventsExecutor(context=context)
        stack.callback(executor.shutdown)
        executor.add_node(plant)
        executor.add_node(monitor)

        # Closed last: on an error path the recorder still gets the plant's last messages.
        recorder = ChildNode.start(
            "tdslip_ros.nodes.recorder_node",
            ["--params-file", str(config_file("recorder.yaml")), "-p", f"output:={bag}"]
            + overrides_arguments(
                {
                    "record_clock": options.record_clock,
                    "custom_data": run_custom_data(options, plant.hopper),
                }
            ),
            environment,
            options.namespace,
        )
        stack.callback(recorder.close)
        controller = None
        if not options.own_controller:
            module = "tdslip_ros.nodes.controller_node"
            if options.policy in STANCE_FEEDBACK_POLICIES:  # the policy is the node's own
                module = "tdslip_ros.nodes.stance_controller_node"
                controller_parameters.pop("policy")
            controller = ChildNode.start(
                module,
                ["--params-file", str(config_file("controller.yaml"))]
                + overrides_arguments(controller_parameters),
                environment,
                options.namespace,
            )
            stack.callback(controller.close)
        children = (recorder,) if controller is None else (recorder, controller)

        recorded_topics = [*topics.RECORDED_TOPICS, *((topics.CLOCK,) if options.record_clock else ())]

        def published_counts() -> dict[str, int]:
            counts = {
                **plant.published,
                topics.COMMAND: plant.received_commands,
                topics.HIP_TORQUE: plant.received_torques,
            }
            # A ramp controller has no hip torque publisher: the bag has no such channel to count.
            streamed = plant.received_torques or options.policy in STANCE_FEEDBACK_POLICIES
            return {
                resolve(topic, options.namespace): counts.get(topic, 0)
                for topic in recorded_topics
                if topic != topics.HIP_TORQUE or streamed
            }

        try:
            _wait_for_graph(
                executor,
                plant,
                monitor,
                children,
                options.controller_wait if controller is None else STARTUP_TIMEOUT,
            )
            start = time.monotonic()
            deadline = math.inf if options.duration is None else start + options.duration
            plant.start()
            while plant.outcome is None:
                executor.spin_once(timeout_sec=0.1)
                if time.monotonic() >= deadline:
                    plant.end_run(f"reached the wall-time limit of {options.duration} s")
                elif stop_requested():
                    plant.end_run(STOP_REQUESTED)
                for child in children:
                    child.check_alive()
        except RunError as error:
            # A node died: stop the others (the recorder finalises what it has), then say what is in the bag.
            error.published = published_counts()
            error.recorder_stopped = recorder.process.poll() is not None
            stack.close()
            if (bag / "metadata.yaml").is_file():
                error.recorded = read_bag_counts(bag)
            elif bag.is_dir():
                error.recoverable = recoverable_counts(bag)
            raise
        outcome = plant.outcome

        problems = []
        if not plant.deliver(executor):
            problems.append("the recorder did not write everything the plant published")
        delivery_time = (time.monotonic_ns() - plant.start_wall_ns) * 1e-9
        spin_until(executor, lambda: monitor.heard == plant.published[topics.APEX], timeout=5.0)
        if controller is not None:
            # Its answer to the last apex, sent as the run ends, is in every bag of equal options alike
            # (unless it has none to give), not only in those where it came before the stop.
            spin_until(
                executor, lambda: plant.received_commands >= len(monitor.apexes), timeout=LAST_ANSWER_WAIT
            )
            controller.stop()
        _spin_until_quiet(executor, lambda: plant.received_commands + plant.received_torques)
        recorder.stop()
        published = published_counts()
        in_bag = read_bag_counts(bag)
        recorded = {topic: in_bag.get(topic, 0) for topic in published}
        report = RunReport(
            outcome=outcome,
            params=plant.hopper,
            apexes=monitor.apexes,
            published=dict(sorted(published.items())),
            recorded=dict(sorted(recorded.items())),
            command_latencies_ns=plant.command_latencies_ns,
            delivery_time=delivery_time,
            tick_timing=plant.tick_timing,
            bag=bag,
            controller_log="" if controller is None else controller.output(),
            saturated_strides=plant.counts.saturated_strides,
            late_commands=plant.counts.late_commands,
            stale_torques=plant.counts.stale_torques,
            late_torques=plant.counts.late_torques,
            counts=plant.counts,
            problems=problems,
        )
    return report


def _wait_for_graph(
    executor: Executor,
    plant: PlantNode,
    monitor: ApexMonitor,
    children: tuple[ChildNode, ...],
    timeout: float,
) -> None:
    """Until the recorder has matched every publisher (the plant's, the controller's) and the
    controller (the suite's, or the user's own) and the monitor hear the apex."""

    def ready() -> bool:
        for child in children:
            child.check_alive()
        return (
            plant.matched_subscribers(topics.APEX) >= 3  # recorder, controller, monitor
            and monitor.count_publishers(topics.APEX) >= 1
            and plant.ready_to_start()
        )

    if not spin_until(executor, ready, timeout=timeout):
        logs = "\n".join(f"--- {child.name}:\n{child.output()}" for child in children)
        raise RunError(f"the controller and recorder did not connect within {timeout:g} s\n{logs}")


def _spin_until_quiet(executor: Executor, count: Callable[[], int]) -> None:
    last, since = count(), time.monotonic()
    while time.monotonic() - since < QUIET:
        executor.spin_once(timeout_sec=QUIET / 4)
        if count() != last:
            last, since = count(), time.monotonic()
