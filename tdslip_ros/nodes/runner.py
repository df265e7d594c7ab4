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
starts once the recorder and the controller have matched its topics. When the run ends, the plant's
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
from rclpy.exceptions import InvalidTopicNameException, ParameterException
from rclpy.executors import Executor
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rclpy.validate_full_topic_name import validate_full_topic_name
from tdslip_msgs.msg import ApexEvent

from tdslip_ros.bag.recover import recoverable_counts
from tdslip_ros.interfaces import (
    STOP_REQUESTED,
    config_file,
    custom_data_key,
    hopper_from_parameters,
    hopper_parameters,
    installed_parameters,
    perturbation_parameters,
    qualified_namespace,
    resolve,
)
from tdslip_ros.model import dynamics
from tdslip_ros.model.analytic.apex_map import ANALYTIC_MAPS
from tdslip_ros.model.limits import check_hopper
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.stepper import check_body
from tdslip_ros.model.policies.registry import (
    DEFAULT_APEX_HEIGHT,
    DEFAULT_APEX_SPEED,
    DEFAULT_STANCE_TOUCHDOWN_ANGLE,
    DEFAULT_TOUCHDOWN_ANGLE,
    FIXED_ANGLE_POLICIES,
    LEARNED,
    POLICIES,
    POSTURE,
    STANCE_FEEDBACK_POLICIES,
    PolicyError,
    check_policy_file,
)
from tdslip_ros.nodes import (
    controller_node,
    isolation,
    parameters,
    plant_parameters,
    stance_controller_node,
    topics,
)
from tdslip_ros.nodes.entry import (
    PARENT_PID_VARIABLE,
    spin_until,
)
from tdslip_ros.nodes.plant_node import PlantNode, RunOutcome
from tdslip_ros.nodes.plant_parameters import CLOCK_MODES
from tdslip_ros.nodes.plant_run import RunCounts
from tdslip_ros.nodes.realtime import TickTiming
from tdslip_ros.nodes.rows import Rows
from tdslip_ros.reporting.output import OutputError, check_output_directory

STARTUP_TIMEOUT = 30.0  # s for the child nodes to start and match the plant's topics
STOP_TIMEOUT = 30.0  # s for a child to stop after SIGINT
CLOSE_GRACE = 15.0  # s a child gets to stop on an error path before it is killed
QUIET = 0.2  # s without a new command: the controller's last commands have been received

ProgressCallback = Callable[[ApexEvent], None]


class RunError(RuntimeError):
    """The suite could not run or record (a node did not start, crashed, or lost messages). When a node
    died mid-run, ``published`` holds what had been published, and ``recorded`` what the finalised
    bag holds (None if it could not be finalised), both by topic."""

    published: dict[str, int] | None = None
    recorded: dict[str, int] | None = None
    recoverable: dict[str, int] | None = None
    """For a bag left unfinalised: what ``tdslip recover`` gets back, by topic."""
    recorder_stopped: bool = False
    """The recorder is the node that ended first (a full disk, a crash, a kill)."""


class RunOptionError(RunError):
    """An option ``run`` cannot use, found before any node process starts or any file is written."""


@dataclass
class RunOptions:
    """What ``tdslip run`` runs. ``None`` leaves a setting to the installed YAML files, except
    ``target_energy``, which defaults to the energy of the initial apex (energy regulation then
    holds the hopper's energy)."""

    out: Path
    strides: int = 50
    """The run ends at this apex (0: never; then give a ``duration``)."""
    policy: str = "energy"
    mode: str = "lockstep"
    height: float = DEFAULT_APEX_HEIGHT
    speed: float = DEFAULT_APEX_SPEED
    touchdown_angle: float | None = None  # rad
    stance_touchdown_angle: float | None = None
    """The fixed touchdown angle of a stance-feedback policy [rad] (its setting of the same name)."""
    target_energy: float | None = None
    target_height: float | None = None
    target_speed: float | None = None
    analytic_map: str | None = None
    """The analytic map the controller's policy plans on (model.analytic.ANALYTIC_MAPS: ours, paper)."""
    policy_file: str | None = None
    """The learned policy's file (model.learned), absolute: the controller node reads it."""
    command_timeout: float | None = None
    realtime_priority: int | None = None
    """SCHED_FIFO priority of the realtime plant's tick (0: normal scheduling)."""
    realtime_cpu: int | None = None
    """The CPU the realtime plant's tick is pinned to (None: the plant's default, -1, any); one of this
    machine's."""
    record_clock: bool = False
    duration: float | None = None
    """Wall-time limit [s]: the run ends as complete when it is reached."""
    domain_id: int | None = None
    namespace: str = "/"
    """Namespace of the three nodes (``tdslip run --namespace /h1``: topics /h1/tdslip/...)."""
    perturbations: Perturbations = field(default_factory=Perturbations)
    """Terrain, sensing noise, placement error, torque limit and pushes for the plant; mismatch for the
    controller, whose hopper parameters become the plant's times its factors."""
    hopper: HopperParams | None = None
    """The hopper of the plant and of the controller's model alike (``tdslip run --hopper FILE``, --mass,
    ...); None: the installed plant.yaml's."""
    own_controller: bool = False
    """Start no controller: the user's own answers the apexes (``tdslip run --controller none``)."""
    controller_wait: float = 300.0
    """s to wait for the user's own controller to connect (own_controller only)."""


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
    """Collects the apex events of the run (for progress and the summary)."""

    def __init__(self, progress: ProgressCallback | None, **node_options: object) -> None:
        super().__init__("run_monitor", **node_options)  # type: ignore[arg-type]
        self.apexes = Rows.of_message(ApexEvent)
        self._progress = progress
        self.create_subscription(ApexEvent, topics.APEX, self._on_apex, topics.STREAM_QOS)

    def _on_apex(self, msg: ApexEvent) -> None:
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


def _ros_value(value: object) -> str:
    """A -p override value in ROS's YAML syntax (floats keep their type, full precision)."""
    if isinstance(value, bool):
        return str(value).lower()
    return repr(value) if isinstance(value, float) else str(value)


def _overrides(values: dict[str, object]) -> list[str]:
    arguments = []
    for name, value in values.items():
        if value is not None:
            arguments += ["-p", f"{name}:={_ros_value(value)}"]
    return arguments


def hopper_overrides(hopper: HopperParams | None) -> dict[str, object]:
    """The node parameters of ``hopper`` (none: the installed files'), the same for plant and controller."""
    if hopper is None:
        return {}
    return dict(hopper_parameters(hopper))


def plant_overrides(options: RunOptions) -> dict[str, object]:
    return {
        **hopper_overrides(options.hopper),
        **perturbation_parameters(options.perturbations),
        "clock_mode": options.mode,
        "max_strides": options.strides,
        "initial_height": options.height,
        "initial_forward_speed": options.speed,
        "initial_touchdown_angle": options.touchdown_angle,
        "command_timeout": options.command_timeout,
        "realtime_priority": options.realtime_priority,
        "realtime_cpu": options.realtime_cpu,
        "wait_for_recorder": True,
    }


def controller_overrides(options: RunOptions, params: HopperParams) -> dict[str, object]:
    target_energy = options.target_energy
    if (
        target_energy is None
    ):  # the initial apex's; a rigid body's hip's at pitch 0 (posture plans on the hip)
        hip_height = options.height + (0.0 if params.body is None else params.body.hip_y)
        target_energy = params.m * (params.g * hip_height + 0.5 * options.speed**2)
    model = hopper_overrides(options.hopper)
    mismatch = options.perturbations.mismatch
    if mismatch.active:  # the controller plans with another hopper
        planned = mismatch.controller_params(params)
        assert isinstance(planned, HopperParams)  # scalar factors
        check_hopper(planned)
        model = hopper_overrides(planned)
    if options.policy in STANCE_FEEDBACK_POLICIES:
        return {
            **model,
            "policy": options.policy,  # stored with the run; the node's parameter is stance_policy
            "stance_policy": options.policy,
            "stance_touchdown_angle": options.stance_touchdown_angle,
            "target_energy": target_energy,
            "target_height": options.target_height,
            "target_speed": options.target_speed,
        }
    return {
        **model,
        "policy": options.policy,
        "touchdown_angle": options.touchdown_angle,
        "target_energy": target_energy,
        "target_height": options.target_height,
        "target_speed": options.target_speed,
        "analytic_map": options.analytic_map,
        "policy_file": options.policy_file,
    }


def run_custom_data(options: RunOptions, params: HopperParams) -> str:
    """The plant's and the controller's parameters of this run (installed defaults and overrides), as
    the recorder's ``custom_data`` (KEY=VALUE pairs): the bag then says how it was made."""
    pairs = []
    nodes = [("plant", plant_overrides(options))]
    if not options.own_controller:  # a controller of one's own stores nothing (tdslip analyze says so)
        nodes.append(("controller", controller_overrides(options, params)))
    for node, overrides in nodes:
        values = installed_parameters(f"{node}.yaml") | {k: v for k, v in overrides.items() if v is not None}
        pairs += [
            f"{custom_data_key(node, name)}={_ros_value(value)}" for name, value in sorted(values.items())
        ]
    return " ".join(pairs)


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


def check_options(options: RunOptions) -> None:
    """RunOptionError naming the first option ``run`` cannot use (nothing is created here)."""
    if options.mode not in CLOCK_MODES:
        raise RunOptionError(f"mode must be one of {', '.join(CLOCK_MODES)}, not {options.mode!r}")
    if options.policy not in (*POLICIES, *STANCE_FEEDBACK_POLICIES):
        choices = ", ".join((*POLICIES, *STANCE_FEEDBACK_POLICIES))
        raise RunOptionError(f"policy must be one of {choices}, not {options.policy!r}")
    if options.analytic_map is not None and options.analytic_map not in ANALYTIC_MAPS:
        raise RunOptionError(
            f"analytic map must be one of {', '.join(ANALYTIC_MAPS)}, not {options.analytic_map!r}"
        )
    if options.policy == LEARNED:
        if options.policy_file is None:
            raise RunOptionError("the learned policy needs its file (--policy-file)")
        if any(character.isspace() for character in options.policy_file):  # custom_data splits at spaces
            raise RunOptionError(f"the bag cannot name a file with spaces: {options.policy_file!r}")
        try:
            check_policy_file(options.policy_file)
        except PolicyError as error:
            raise RunOptionError(str(error)) from None
    try:
        perturbation_parameters(options.perturbations)  # per-lane values have no node parameters
    except ParameterError as error:
        raise RunOptionError(str(error)) from None
    if options.strides < 0:
        raise RunOptionError(f"strides must be 0 (no limit) or positive, not {options.strides}")
    if options.duration is not None and not (math.isfinite(options.duration) and options.duration > 0):
        raise RunOptionError(f"duration must be a positive number of seconds, not {options.duration}")
    if not (math.isfinite(options.controller_wait) and options.controller_wait > 0):
        raise RunOptionError(
            f"the wait for a controller must be positive seconds, not {options.controller_wait}"
        )
    if options.strides == 0 and options.duration is None:
        raise RunOptionError("a run without a stride limit (strides 0) needs a duration")
    if options.domain_id is not None and options.domain_id not in isolation.VALID_DOMAIN_IDS:
        valid = isolation.VALID_DOMAIN_IDS
        raise RunOptionError(f"domain id must be in {valid.start}-{valid.stop - 1}, not {options.domain_id}")
    try:
        validate_full_topic_name(resolve(topics.STATE, options.namespace))
    except InvalidTopicNameException:
        raise RunOptionError(f"{options.namespace!r} is not a valid ROS namespace") from None
    bag = Path(options.out)
    if bag.exists():
        raise RunOptionError(f"{bag} exists already; choose a new --out")
    try:
        check_output_directory(bag)
    except OutputError as error:
        raise RunOptionError(str(error)) from None
    if options.realtime_cpu not in (None, -1) and options.realtime_cpu not in os.sched_getaffinity(0):
        cpus = ", ".join(map(str, sorted(os.sched_getaffinity(0))))
        raise RunOptionError(f"realtime CPU {options.realtime_cpu} is not one this run may use ({cpus})")
    try:  # the plant's first: the controller's values derive from them (--height sets its target energy)
        parameters.check_values(plant_parameters.SPECS, plant_overrides(options))
    except ParameterError as error:
        raise RunOptionError(f"plant parameters: {error}") from None
    if options.hopper is not None:
        try:
            check_hopper(options.hopper)
        except ParameterError as error:
            raise RunOptionError(f"the hopper: {error}") from None
    hopper = options.hopper or hopper_from_parameters(installed_parameters("plant.yaml"))
    if options.policy == POSTURE and hopper.body is None:
        raise RunOptionError(f"the {POSTURE} policy balances a rigid body: give --body rigid")
    if hopper.body is not None and options.policy in POLICIES and not options.own_controller:
        raise RunOptionError(
            f"the {options.policy} policy plans on the paper's fixed body; a rigid body runs under --policy "
            f"{POSTURE} or stance_pd_speed_energy, or a controller of one's own (--controller none)"
        )
    try:
        check_body(hopper, ApexState(options.height, options.speed), options.perturbations)
    except ParameterError as error:
        raise RunOptionError(str(error)) from None
    check_placement(options, hopper)
    if not options.own_controller:
        check_controller_parameters(options, hopper)


def check_controller_parameters(options: RunOptions, params: HopperParams) -> None:
    """RunOptionError for what the controller node would refuse at its start (a value out of its range), said
    before anything starts, as the plant's are; the stance controller's policy is its own."""
    try:
        values = controller_overrides(options, params)
    except ParameterError as error:
        raise RunOptionError(f"the controller's model (--mismatch): {error}") from None
    specs = controller_node.SPECS
    if options.policy in STANCE_FEEDBACK_POLICIES:
        specs, values = stance_controller_node.SPECS, {k: v for k, v in values.items() if k != "policy"}
    try:
        parameters.check_values(specs, values)
    except ParameterError as error:
        raise RunOptionError(f"controller parameters: {error}") from None


def check_placement(options: RunOptions, params: HopperParams) -> None:
    """RunOptionError if the leg cannot be placed from the initial apex: at the policy's touchdown angle
    for a fixed-angle policy, at any angle for the others."""
    angle = None
    if options.policy in FIXED_ANGLE_POLICIES:
        angle = DEFAULT_TOUCHDOWN_ANGLE if options.touchdown_angle is None else options.touchdown_angle
    elif options.policy in STANCE_FEEDBACK_POLICIES:  # its angle, else config/controller.yaml's
        angle = options.stance_touchdown_angle
        if angle is None:
            installed = installed_parameters("controller.yaml")
            angle = float(installed.get("stance_touchdown_angle", DEFAULT_STANCE_TOUCHDOWN_ANGLE))
    hip_height = options.height + (0.0 if params.body is None else params.body.hip_y)  # at pitch 0
    try:
        dynamics.check_placement(params, hip_height, angle)
    except ParameterError as error:
        where = "" if params.body is None else f" (the hip's: the height {options.height:g} m plus hip_y)"
        raise RunOptionError(f"{error}{where}") from None


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
            + _overrides(
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
                ["--params-file", str(config_file("controller.yaml"))] + _overrides(controller_parameters),
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
        if controller is not None:
            controller.stop()
        _spin_until_quiet(executor, lambda: plant.received_commands + plant.received_torques)
        spin_until(executor, lambda: len(monitor.apexes) == plant.published[topics.APEX], timeout=5.0)
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
