"""The plant node: the exact TD-SLIP stepper of the model, advanced at 1 kHz and published.

Every tick it publishes the state (``tdslip/state``) and the ground reaction force (``tdslip/grf``) to
whoever subscribes to them, and to recorders in batches (``tdslip/samples``,
:mod:`tdslip_ros.nodes.plant_output`); and, stamped with the times the stepper located inside the tick,
the apex (``tdslip/apex``),
contact (``tdslip/contact``) and failure (``tdslip/status``) events; ``tdslip/markers`` draws the
hopper for Foxglove and RViz at ``marker_rate`` Hz of simulated time, and /clock carries the
simulated time while someone subscribes to it (``publish_clock``). Every stamp is simulated time,
in both clock modes; nodes that should follow it run with ``use_sim_time``. All physics is the
model's (:class:`~tdslip_ros.model.stepper.FixedStepStepper`); this node only schedules, validates
commands and converts records to messages. Names are relative, so ``__ns`` puts a hopper in a
namespace of its own; QoS is :mod:`tdslip_ros.nodes.topics`'s contract.

Clock modes (parameter ``clock_mode``):

* ``realtime``: a 1 kHz tick against the steady clock, on a thread of its own
  (:mod:`tdslip_ros.nodes.realtime`: why, and ``realtime_priority``); each tick steps the plant up
  to the tick due at that wall time (a late one catches up, so simulated time never drifts from
  wall time). The latest valid command for the current stride is used at touchdown; a controller
  that leaves ``max_stale_strides`` strides in a row unanswered ends the run (``command_timeout``).
  A lock keeps the tick thread and the executor's callbacks (commands, reset) apart.
* ``lockstep``: as fast as possible. At each apex (the initial one included) the plant stops and
  waits for the command answering that stride; nothing but the command decides what happens next,
  so runs with equal parameters give bit-identical results. No valid command within
  ``command_timeout`` seconds of wall time ends the run (Status ``command_timeout``).

Perturbations (:mod:`tdslip_ros.model.perturbations`; parameters ``terrain``, ``apex_height_noise``,
``apex_speed_noise``, ``apex_noise_seed``, ``angle_noise``, ``angle_noise_seed``, ``tau_max``, ``pushes``:
:data:`tdslip_ros.interfaces.PERTURBATION_PARAMETERS`)
are the stepper's: the hopper hops over the terrain (``terrain``: ``flat``, ``step:height=H,x=X``,
``blocks:sigma=S,length=L,seed=N``, ``profile:file=PATH.csv``), its hip saturates at tau_max, its leg
lands with a placement error and pushes hit it right after the apex. Heights are in the world frame:
state samples carry the ground height under the body, each contact event the ground under the toe of its
stance, each apex event the ground of the stance before it (the initial one: under the body; the initial
apex ``initial_height`` and a reset's height are above that ground) and, beside the true apex, the
measured one the controller's sensor reports (the true one without sensing noise). The random draws of
a run are those of trajectory ``epoch`` (:meth:`~tdslip_ros.model.perturbations.Perturbations.draws`), so a
run is reproduced by its parameters. A command is judged admissible on the apex the controller was given
(measured, above the ground of the last stance); a toe placed below the ground is toe stubbing, a failure.

A command answers one apex: it carries the apex's ``epoch`` (0 for the first run, one more at
every reset) and ``stride``. It is rejected (Status ``command_rejected``, never applied) when it
answers another apex, arrives after the touchdown it was for, repeats an already answered stride
in lockstep, or holds a value that :class:`~tdslip_ros.model.params.StanceCommand` or the stepper
refuses (non-finite, out of range, or a touchdown angle the body cannot reach). Answers to
other apexes are recognised from their bytes and cost next to nothing (a flood of them cannot delay
the valid one); late answers are only counted, other rejections are logged and reported, at most
:data:`~tdslip_ros.nodes.command_admission.REJECTION_REPORTS` per
:data:`~tdslip_ros.nodes.command_admission.REJECTION_REPORT_PERIOD`, the rest summed
(:mod:`tdslip_ros.nodes.command_admission`). A command may ask for stance feedback instead of the ramp:
the hip then holds the torques a controller streams on ``tdslip/hip_torque``, one per stance tick, judged
by :mod:`tdslip_ros.nodes.torque_stream`; each torque held goes out on ``tdslip/applied_torque``.
The parameters are :mod:`tdslip_ros.nodes.plant_parameters`.

With ``wait_for_recorder`` the plant treats a recorder_node (``tdslip/recorder_status``) as part
of the run (:mod:`tdslip_ros.nodes.flow_control`): it starts once the recorder hears every
publisher, a lockstep run never gets more than :data:`FLOW_WINDOW` messages ahead of what the
recorder has written, and the end of a run waits until everything is in the bag. No other
subscriber can slow or stop the plant: one that stalls only loses messages.

The run starts once each of the plant's topics has ``min_subscribers`` subscribers (a recorder of the
batches counts for the state and the force) and a controller
is connected (or ``command_timeout`` has passed). It ends, with a fatal Status, at a failure of
the hopper, at a command timeout, as ``publish_failed`` when a publication fails or the recorder
waited for stops reporting, or as ``run_complete`` at apex ``max_strides``. The reset service
(``tdslip/reset``) restarts it from a new apex in a new epoch: strides count from 0 again while
simulated time runs on.
"""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
from dataclasses import dataclass

from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.executors import Executor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.task import Future
from tdslip_msgs.msg import HipTorque, RecorderStatus, StanceCommand, Status
from tdslip_msgs.srv import Reset

from tdslip_ros.interfaces import (
    hopper_from_parameters,
    perturbations_from_parameters,
)
from tdslip_ros.model.events import Event, EventKind
from tdslip_ros.model.events import HopperState as ModelState
from tdslip_ros.model.limits import PlausibilityLimits, check_hopper
from tdslip_ros.model.params import ApexState, ParameterError
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.model.stance_laws import StanceFeedback
from tdslip_ros.model.stepper import FixedStepStepper
from tdslip_ros.nodes import parameters, topics
from tdslip_ros.nodes.command_admission import LateCommand, RejectionLog, admit, command_key, not_yet
from tdslip_ros.nodes.entry import run_node, spin_until, wait_for_delivery
from tdslip_ros.nodes.flow_control import FLOW_WINDOW, RecorderProgress
from tdslip_ros.nodes.plant_output import PlantOutput
from tdslip_ros.nodes.plant_parameters import SPECS
from tdslip_ros.nodes.realtime import Ticker, TickTiming
from tdslip_ros.nodes.torque_stream import LateTorque, TorqueInput, torque_fields

RCLError = rclpy_implementation.RCLError  # what a failed publish raises (as rclpy.subscription names it)

TICK_PERIOD = 1e-3  # s, the plant's fixed step
START_CHECK_PERIOD = 0.05  # s, how often an autostarting plant checks whether its peers are there
START_SETTLE = 0.2  # s the peers must have been there before the run starts
LOCKSTEP_BATCH = 50
"""Ticks per lockstep timer callback: amortises the executor's cost while keeping it responsive."""
GRAPH_CHECK_TICKS = 50
"""Ticks between two looks at who subscribes to the live state and force, /clock and the markers (a graph
query costs ~20 us); the plant also looks at every apex and touchdown."""
DELIVERY_TIMEOUT = 10.0
"""s a finished run waits for the recorder it waits for to write everything (and, without one, at
most :data:`ACK_TIMEOUT` for subscribers' acknowledgements)."""
ACK_TIMEOUT = 1.0  # s

_NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class RunOutcome:
    """How a run ended: a Status kind (a FailureKind value, command_timeout or run_complete), when
    in simulated time [s] and after how much wall time since start() [s]."""

    kind: str
    reason: str
    stride: int
    sim_time: float
    wall_time: float

    @property
    def ok(self) -> bool:
        return bool(self.kind == Status.KIND_RUN_COMPLETE)


class PlantNode(Node):
    """The 1 kHz TD-SLIP plant. ``done`` completes with the :class:`RunOutcome` when the run ends.

    It starts by itself once its peers are there (see the parameters ``min_subscribers`` and
    ``wait_for_recorder``, and :meth:`_start_when_ready`); with ``autostart=False`` it waits for
    :meth:`start` instead.
    """

    def __init__(self, *, autostart: bool = True, **node_options: object) -> None:
        super().__init__("plant", **node_options)  # type: ignore[arg-type]
        self._ticker: Ticker | None = None  # first: destroy_node must work if the rest raises
        self.add_on_set_parameters_callback(lambda changed: parameters.validate(SPECS, changed))
        values = parameters.declare(self, SPECS)
        self.hopper = hopper_from_parameters(values)
        check_hopper(self.hopper)
        self.limits = PlausibilityLimits.for_hopper(self.hopper)
        if float(values["max_torque"]) > 0.0:
            self.limits = dataclasses.replace(self.limits, max_torque=float(values["max_torque"]))
        self._initial_command = ModelCommand(
            float(values["initial_touchdown_angle"]),
            float(values["initial_tau0"]),
            float(values["initial_t_f"]),
        )
        self.limits.check_command(self._initial_command)
        initial_apex = ApexState(float(values["initial_height"]), float(values["initial_forward_speed"]))
        self.limits.check_apex(initial_apex)
        self.perturbations = perturbations_from_parameters(values)
        self.perturbations.check_limits(self.limits)
        self.lockstep = values["clock_mode"] == "lockstep"
        self._max_strides = int(values["max_strides"])
        self._max_stale_strides = int(values["max_stale_strides"])
        self._wait_for_recorder = bool(values["wait_for_recorder"])

        self.received_commands = 0
        self.received_torques = 0
        self.rejections = RejectionLog()
        self.command_latencies_ns: list[tuple[int, int, int]] = []
        """(epoch, stride, ns) of each answered apex: wall time from its publication to the valid command."""
        self.late_commands = 0
        """Realtime: answers that arrived after the touchdown of their stride (never applied)."""
        self.tick_timing = None if self.lockstep else TickTiming(round(TICK_PERIOD * _NS_PER_S))
        self.torques = TorqueInput(
            lockstep=self.lockstep,
            max_age_ticks=round(float(values["torque_max_age"]) / TICK_PERIOD),
            max_torque=self.limits.max_torque,
        )
        """Stance feedback: the streamed hip torques (tdslip/hip_torque), their late and stale counts."""
        self.recorders = RecorderProgress()
        self.outcome: RunOutcome | None = None
        self.done: Future[RunOutcome] = Future()

        marker_rate = float(values["marker_rate"])
        self._out = PlantOutput(
            self,
            publish_clock=bool(values["publish_clock"]),
            marker_period_ticks=max(1, round(1.0 / (marker_rate * TICK_PERIOD))) if marker_rate else 0,
        )
        self.published = self._out.published
        """Messages published per topic, by relative name (topics.STATE, ...)."""
        self.topic_names = self._out.topic_names
        """Fully qualified name of each published topic, by its relative name."""
        self.command_topic = self.resolve_topic_name(topics.COMMAND)
        # Raw: an answer to an earlier apex is recognised from its bytes (command_key), unparsed.
        self._command_subscription = self.create_subscription(
            StanceCommand, topics.COMMAND, self._on_command, topics.COMMAND_SUBSCRIPTION_QOS, raw=True
        )
        self._torque_subscription = self.create_subscription(
            HipTorque, topics.HIP_TORQUE, self._on_hip_torque, topics.COMMAND_SUBSCRIPTION_QOS, raw=True
        )
        self.torque_topic = self._torque_subscription.topic_name
        self.create_subscription(
            RecorderStatus, topics.RECORDER_STATUS, self._on_recorder_status, topics.RECORDER_STATUS_QOS
        )
        self.create_service(Reset, topics.RESET_SERVICE, self._on_reset)

        # Stepping: lockstep by a zero-period timer of the executor, realtime by a Ticker thread;
        # the lock keeps the tick thread and the executor's callbacks apart.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._lock = threading.Lock()
        self._lockstep_timer = self.create_timer(0.0, self._advance_lockstep, clock=steady, autostart=False)
        self._command_timeout = float(values["command_timeout"])
        self._timeout_timer = self.create_timer(
            self._command_timeout, self._on_command_timeout, clock=steady, autostart=False
        )
        self._held_by_recorder = False  # lockstep stepping paused until the recorder catches up
        self._recorder_timer = self.create_timer(
            self._command_timeout, self._on_recorder_timeout, clock=steady, autostart=False
        )
        self._realtime_priority = int(values["realtime_priority"])
        self._realtime_cpu = None if int(values["realtime_cpu"]) < 0 else int(values["realtime_cpu"])
        self._running = False
        self._epoch = 0
        self._ticks = 0  # since construction, over resets: simulated time = ticks * TICK_PERIOD
        self._tick0 = 0  # the tick at start(), due at start_wall_ns of the steady clock
        self.start_wall_ns = 0
        self._restart(initial_apex, time_offset_ticks=0)

        self._min_subscribers = int(values["min_subscribers"])
        self._created_ns = time.monotonic_ns()
        self._ready_since_ns: int | None = None
        self._start_check = self.create_timer(
            START_CHECK_PERIOD, self._start_when_ready, clock=steady, autostart=autostart
        )
        self.get_logger().info(self._startup_summary(initial_apex))

    def _startup_summary(self, apex: ApexState) -> str:
        hopper = self.hopper
        start = ["a controller on " + self.command_topic]
        if self._min_subscribers:
            start.append(f"{self._min_subscribers} subscriber(s) per topic")
        if self._wait_for_recorder:
            start.append("a recorder_node")
        return (
            f"{'lockstep' if self.lockstep else 'realtime'} plant, "
            f"max_strides {self._max_strides or 'none'}; "
            f"hopper m {hopper.m:g} kg, k {hopper.k:g} N/m, r0 {hopper.r0:g} m, c {hopper.c:g} N s/m, "
            f"g {hopper.g:g} m/s^2 (kbar {hopper.kbar:.4g}, zeta0 {hopper.zeta0:.4g}); "
            f"{self.perturbations.summary()}; initial apex "
            f"{apex.y:g} m, {apex.xdot:g} m/s; publishing {', '.join(self.topic_names.values())}; "
            f"service {self.resolve_topic_name(topics.RESET_SERVICE)}; "
            f"starts on {' and '.join(start)} (at most {self._command_timeout:g} s)"
        )

    # --- run control ----------------------------------------------------------------------------

    @property
    def sim_time(self) -> float:
        return self._ticks * TICK_PERIOD

    @property
    def stride(self) -> int:
        """The latest apex of the run (0: the initial one)."""
        return self._stepper.stride

    @property
    def saturated_strides(self) -> int:
        """Touchdowns of this run whose |tau0| exceeded tau_max (the hip saturated)."""
        return self._stepper.saturated_strides

    @property
    def epoch(self) -> int:
        """The run epoch: 0 for the first run, one more after every reset."""
        return self._epoch

    def matched_subscribers(self, topic: str) -> int:
        """Subscriptions matched with the plant's publisher on ``topic`` (relative name)."""
        return self._out.subscribers(topic)

    def _start_when_ready(self) -> None:
        """autostart: start once :meth:`ready_to_start`, or once command_timeout has passed."""
        waited = time.monotonic_ns() - self._created_ns >= self._command_timeout * _NS_PER_S
        if self.ready_to_start() or (waited and self._peers_required_present()):
            self.start()

    def _peers_required_present(self) -> bool:
        """min_subscribers listen to each topic and a recorder waited for has matched every publisher."""
        if any(self._out.listeners(topic) < self._min_subscribers for topic in topics.PLANT_TOPICS):
            return False
        return not self._wait_for_recorder or self.recorder_ready()

    def ready_to_start(self) -> bool:
        """The peers are there (:meth:`_peers_required_present`) and a controller is connected, and
        have been for START_SETTLE s: discovery is not symmetric, and a peer that has matched this
        plant may not yet be matched by the others."""
        if not (self._peers_required_present() and self._controller_connected()):
            self._ready_since_ns = None
            return False
        now = time.monotonic_ns()
        if self._ready_since_ns is None:
            self._ready_since_ns = now
        return now - self._ready_since_ns >= START_SETTLE * _NS_PER_S

    def recorder_ready(self) -> bool:
        """A recorder has matched this plant's publishers and every command and hip torque publisher of the
        graph."""
        published = [self.topic_names[topic] for topic in topics.PLANT_TOPICS]
        answers = {topic: self.count_publishers(topic) for topic in (self.command_topic, self.torque_topic)}
        return self.recorders.ready(published, answers)

    def _controller_connected(self) -> bool:
        """A node publishes commands and subscribes to the apex, every apex subscription of the graph
        has matched the plant's publisher (the first apex reaches the controller) and every command and
        hip torque publisher the plant's subscription (the answer reaches the plant)."""
        command_publishers = self.get_publishers_info_by_topic(self.command_topic)
        commanders = {(i.node_namespace, i.node_name) for i in command_publishers}
        apex_subscriptions = self.get_subscriptions_info_by_topic(self.topic_names[topics.APEX])
        listeners = {(i.node_namespace, i.node_name) for i in apex_subscriptions}
        matched = (
            self.matched_subscribers(topics.APEX) >= len(apex_subscriptions)
            and self._command_subscription.get_publisher_count() >= len(command_publishers)
            and self._torque_subscription.get_publisher_count() >= self.count_publishers(self.torque_topic)
        )
        return bool(commanders & listeners) and matched

    def start(self) -> None:
        """Publish the initial apex and sample, then start stepping (or wait for its command)."""
        self._start_check.cancel()
        with self._lock:
            self._start()

    def _start(self) -> None:
        if self._running:
            return
        self._running = True
        self.start_wall_ns = time.monotonic_ns()
        self._tick0 = self._ticks
        self._out.check_graph()
        self._publish_apex(0, self._stepper.apex_state)
        state = self._stepper.state
        self._out.sample(state, self._offset + state.t)
        if self.lockstep:
            self._await_command()
        else:
            assert self.tick_timing is not None
            self.tick_timing.resume()
            self._ticker = Ticker(
                round(TICK_PERIOD * _NS_PER_S),
                self._advance_realtime,
                priority=self._realtime_priority,
                cpu=self._realtime_cpu,
                on_error=self._log_warning,
            )
            self._ticker.start(self.start_wall_ns)

    def _log_warning(self, message: str) -> None:
        self.get_logger().warning(message)

    def end_run(self, reason: str) -> None:
        """End a running run now as complete (e.g. a caller's wall-time limit)."""
        with self._lock:
            if self._running:
                self._finish(Status.KIND_RUN_COMPLETE, reason, self.sim_time)

    def destroy_node(self) -> None:
        self._stop_ticker()
        super().destroy_node()

    def _stop_ticker(self) -> None:
        if self._ticker is not None:
            self._ticker.stop()
            self._ticker = None

    def _restart(self, apex: ApexState, time_offset_ticks: int) -> None:
        self._stepper = FixedStepStepper(
            self.hopper,
            apex,
            self._initial_command,
            dt=TICK_PERIOD,
            limits=self.limits,
            perturbations=self.perturbations,
            trajectory=self._epoch,
        )
        self._offset = time_offset_ticks * TICK_PERIOD
        self._offset_ticks = time_offset_ticks
        self._applied_published = 0  # samples of the current stance published on tdslip/applied_torque
        self.torques.restart()
        self._awaiting: int | None = None
        self._answered = -1  # the latest stride whose command was applied
        self._late_stride = -1  # the latest stride counted in late_commands
        self._stale_strides = 0  # realtime: strides in a row that no valid command answered
        self._apex_wall_ns = time.monotonic_ns()

    def _finish(self, kind: str, reason: str, t: float) -> None:
        self._running = False
        self._lockstep_timer.cancel()
        self._timeout_timer.cancel()
        self._recorder_timer.cancel()
        self._held_by_recorder = False
        if self._ticker is not None:
            self._ticker.request_stop()  # the lock is held: the tick thread may be waiting for it
        try:
            self._publish_status(kind, reason, t, fatal=True)
        except RCLError as error:
            self.get_logger().error(f"the final status could not be published: {error}")
        wall_time = (time.monotonic_ns() - self.start_wall_ns) * 1e-9
        self.outcome = RunOutcome(kind, reason, self._stepper.stride, t, wall_time)
        if self.tick_timing is not None:
            self.tick_timing.close_window()
            self.get_logger().info(f"realtime: {self.tick_timing.summary()}")
            if self.published[topics.APPLIED_TORQUE]:
                self.get_logger().info(
                    f"realtime: {self.torques.late} hip torque(s) came after their tick, "
                    f"{self.torques.stale} stance tick(s) held zero (no torque within torque_max_age)"
                )
            if self.late_commands:
                self.get_logger().warning(
                    f"realtime: {self.late_commands} command(s) arrived after their touchdown (the command "
                    "in force held)"
                )
        if self.perturbations.saturates:
            self.get_logger().info(f"the hip saturated in {self._stepper.saturated_strides} stride(s)")
        if kind == Status.KIND_RUN_COMPLETE:
            self.get_logger().info(f"run complete at stride {self._stepper.stride}, t = {t:.3f} s: {reason}")
        else:
            self.get_logger().error(
                f"run ended at stride {self._stepper.stride}, t = {t:.6f} s: {kind}: {reason}"
            )
        if not self.done.done():
            self.done.set_result(self.outcome)

    def recorded_everything(self) -> bool:
        """Every recorder waited for has written everything published on the topics it records."""
        return self.recorders.caught_up({self.topic_names[t]: n for t, n in self.published.items()})

    def deliver(self, executor: Executor) -> bool:
        """After a run: with ``wait_for_recorder``, spin until the recorder has written everything
        (False after DELIVERY_TIMEOUT s); without, wait at most ACK_TIMEOUT for the subscribers'
        acknowledgements, so that no stalled subscriber can keep the plant. The samples not yet batched go
        out first (a run stopped from outside, e.g. by SIGINT, published no final status)."""
        with self._lock:
            self._out.flush()
        if self._wait_for_recorder and self.recorders.heard:
            return spin_until(executor, self.recorded_everything, DELIVERY_TIMEOUT)
        return wait_for_delivery(self, ACK_TIMEOUT)

    # --- stepping -------------------------------------------------------------------------------

    def _advance_lockstep(self) -> None:
        with self._lock:
            if self._wait_for_recorder and self._recorder_lag() > FLOW_WINDOW:
                self._hold_for_recorder()
                return
            for _ in range(LOCKSTEP_BATCH):
                if self._tick_or_fail():
                    self._lockstep_timer.cancel()
                    return

    def _recorder_lag(self) -> int:
        """The most messages on any one topic that the recorder has not written yet: each topic, as
        DDS delivers a reliable topic in order, a lost sample holds up only its own topic."""
        return max(self.recorders.lag(self.topic_names[t], self.published[t]) for t in self.published)

    def _hold_for_recorder(self) -> None:
        """Pause lockstep stepping until the recorder reports that it caught up (or gives up)."""
        self._lockstep_timer.cancel()
        if not self._held_by_recorder:
            self._held_by_recorder = True
            self._recorder_timer.reset()

    def _on_recorder_status(self, msg: RecorderStatus) -> None:
        with self._lock:
            self.recorders.update(msg)
            if self._held_by_recorder and self._running and self._recorder_lag() <= FLOW_WINDOW // 2:
                self._held_by_recorder = False
                self._recorder_timer.cancel()
                self._lockstep_timer.reset()

    def _on_recorder_timeout(self) -> None:
        self._recorder_timer.cancel()
        with self._lock:
            if self._held_by_recorder and self._running:
                self._finish(
                    Status.KIND_PUBLISH_FAILED,
                    f"the recorder waited for stopped: it is {self._recorder_lag()} messages behind and "
                    f"reported nothing for {self.recorders.silent_for(time.monotonic_ns()):.1f} s",
                    self.sim_time,
                )

    def _advance_realtime(self, now_ns: int) -> None:
        """Tick thread: step up to the tick due at ``now_ns`` of the steady clock."""
        with self._lock:
            due = self._tick0 + round((now_ns - self.start_wall_ns) * 1e-9 / TICK_PERIOD)
            first = self._ticks
            while self._ticks < due and self._running:
                self._tick_or_fail()
            assert self.tick_timing is not None
            self.tick_timing.record(now_ns, self._ticks - first)

    def _tick_or_fail(self) -> bool:
        """:meth:`_tick`; a publication that fails ends the run with ``publish_failed``."""
        try:
            return self._tick()
        except RCLError as error:
            self._finish(Status.KIND_PUBLISH_FAILED, str(error).split(",", 1)[0], self.sim_time)
            return True

    def _tick(self) -> bool:
        """Step one tick and publish it; True when stepping must pause (awaited command or torque, end of
        run)."""
        stepper = self._stepper
        if not self.lockstep and stepper.torque_due:  # lockstep: the awaited torque is held already
            stepper.hold_torque(self.torques.held(stepper.stride, self._ticks))
        events = stepper.step()
        self._ticks += 1
        if self._ticks % GRAPH_CHECK_TICKS == 0:
            self._out.check_graph()
        apex: Event | None = None
        for event in events:
            if event.kind is EventKind.APEX:
                apex = event
                self._publish_apex(event.stride, event.state)
            elif event.kind is EventKind.FAILURE:
                assert event.failure is not None
                self._publish_applied_torques()  # the failing tick's torque was applied too
                self._finish(event.failure.value, event.reason, self._offset + event.t)
                return True
            else:
                if event.kind is EventKind.TOUCHDOWN:
                    self._applied_published = 0
                self._out.contact(self._epoch, event, self._offset + event.t)
        state = stepper.state
        t = self._offset + state.t
        self._out.sample(state, t)
        self._publish_applied_torques()
        self._out.markers(state, t, self._ticks)
        if apex is None:
            if self.lockstep and stepper.torque_due:
                self._await_torque()
                return True
            return False
        if apex.stride == self._max_strides:
            reason = f"reached max_strides = {self._max_strides}"
            self._finish(Status.KIND_RUN_COMPLETE, reason, self._offset + state.t)
            return True
        if self.lockstep:
            self._await_command()
            return True
        return self._count_stale_stride(apex.stride)

    def _count_stale_stride(self, stride: int) -> bool:
        """Realtime: at the apex of ``stride``, was the previous stride answered? Too many unanswered
        in a row end the run (a dead or silent controller must not go unnoticed)."""
        self._stale_strides = 0 if self._answered == stride - 1 else self._stale_strides + 1
        if self._max_stale_strides and self._stale_strides >= self._max_stale_strides:
            self._finish(
                Status.KIND_COMMAND_TIMEOUT,
                f"no valid command answered the last {self._stale_strides} strides (max_stale_strides)",
                self._offset + self._stepper.t,
            )
            return True
        return False

    def _await_command(self) -> None:
        self._awaiting = self._stepper.stride
        self._timeout_timer.reset()

    def _await_torque(self) -> None:
        self.torques.await_tick(self._epoch, self._stepper.stride, self._ticks)
        self._timeout_timer.reset()

    def _on_command_timeout(self) -> None:
        self._timeout_timer.cancel()
        with self._lock:
            self._time_out()

    def _time_out(self) -> None:
        awaited = self.torques.awaited
        if (self._awaiting is None and awaited is None) or not self._running:
            return
        rejected = self.rejections.total
        rejected_so_far = f"; {rejected} command(s) or torque(s) rejected so far" if rejected else ""
        what = (
            f"command for epoch {self._epoch}, stride {self._awaiting}"
            if awaited is None
            else f"hip torque for epoch {awaited[0]}, stride {awaited[1]}, tick {awaited[2]}"
        )
        self._finish(
            Status.KIND_COMMAND_TIMEOUT,
            f"no valid {what} within command_timeout = {self._command_timeout:g} s{rejected_so_far}",
            self._offset + self._stepper.t,
        )

    # --- commands and reset ---------------------------------------------------------------------

    def _on_command(self, data: bytes) -> None:
        self.received_commands += 1
        key = command_key(data)
        # Unlocked and unparsed: an answer to another apex costs next to nothing, so that a flood of
        # them cannot delay the one the plant waits for.
        if key is not None and key != (self._epoch, self._stepper.stride):
            if key > (self._epoch, self._stepper.stride):
                epoch, stride = key
                reason = not_yet(key, self._epoch, self._stepper.stride)
                with self._lock:  # its Status flushes the samples the tick thread is batching
                    self._report_rejection(f"command for epoch {epoch}, stride {stride} rejected: {reason}")
            else:
                self.rejections.total += 1  # a late answer: counted, not reported
                if key[0] == self._epoch and key[1] > self._answered:
                    self._count_late(key[1])  # its stride never had a command: it missed the touchdown
            return
        msg = deserialize_message(data, StanceCommand)
        with self._lock:
            self._take_command(msg)

    def _count_late(self, stride: int) -> None:
        """Count a stride in late_commands once, however many late answers it gets."""
        if stride != self._late_stride:
            self._late_stride = stride
            self.late_commands += 1

    def _report_rejection(self, reason: str, kind: str = Status.KIND_COMMAND_REJECTED) -> None:
        """Log and report a rejection (at most REJECTION_REPORTS per period, the rest summed)."""
        prefix = self.rejections.admit(time.monotonic_ns())
        if prefix is not None:
            self.get_logger().warning(prefix + reason)
            self._publish_status(kind, prefix + reason, self._offset + self._stepper.t, fatal=False)

    def _take_command(self, msg: StanceCommand) -> None:
        if not self._running:
            self.get_logger().debug(f"command for stride {msg.stride} ignored: no run in progress")
            return
        try:
            self._apply(msg)
        except ParameterError as error:
            self._report_rejection(
                f"command for epoch {msg.epoch}, stride {msg.stride} ({msg.policy or 'no policy'}) "
                f"rejected: {error}"
            )
            return
        if msg.stride != self._answered:
            latency = time.monotonic_ns() - self._apex_wall_ns
            self.command_latencies_ns.append((msg.epoch, msg.stride, latency))
            self._answered = msg.stride
        if self.lockstep:
            self._awaiting = None
            self._timeout_timer.cancel()
            self._lockstep_timer.reset()

    def _apply(self, msg: StanceCommand) -> None:
        """Admit a command and hand it to the stepper; ParameterError gives the reason to refuse it."""
        stride = self._stepper.stride
        try:
            command = admit(
                msg,
                epoch=self._epoch,
                stride=stride,
                lockstep=self.lockstep,
                awaiting=self._awaiting,
                past_touchdown=self._stepper.past_touchdown,
                limits=self.limits,
            )
        except LateCommand:
            self._count_late(stride)
            raise
        self._stepper.set_command(command)

    def _on_hip_torque(self, data: bytes) -> None:
        self.received_torques += 1
        fields = torque_fields(data)
        with self._lock:
            if not self._running:
                return
            if fields is None:
                self._report_rejection("hip torque rejected: not a HipTorque", Status.KIND_TORQUE_REJECTED)
                return
            stepper = self._stepper
            try:
                self.torques.take(
                    fields,
                    epoch=self._epoch,
                    stride=stepper.stride,
                    tick=self._ticks,
                    streaming=isinstance(stepper.command, StanceFeedback),
                    stance_over=stepper.past_touchdown and not stepper.torque_due,
                )
            except LateTorque:
                return
            except ParameterError as error:
                self._report_rejection(
                    f"hip torque for epoch {fields.epoch}, stride {fields.stride}, tick {fields.tick} "
                    f"rejected: {error}",
                    Status.KIND_TORQUE_REJECTED,
                )
                return
            if self.lockstep:  # the awaited torque: hold it and step on
                stepper.hold_torque(fields.torque)
                self._timeout_timer.cancel()
                self._lockstep_timer.reset()

    def _on_reset(self, request: Reset.Request, response: Reset.Response) -> Reset.Response:
        try:
            apex = ApexState(request.height, request.forward_speed)
            self.limits.check_apex(apex)
        except ParameterError as error:
            response.success, response.message = False, f"reset refused: {error}"
            response.epoch = self._epoch
            return response
        self._stop_ticker()  # outside the lock: the tick in progress needs it to finish
        with self._lock:
            response.message = self._reset(apex)
        response.success, response.epoch = True, self._epoch
        return response

    def _reset(self, apex: ApexState) -> str:
        self._lockstep_timer.cancel()
        self._timeout_timer.cancel()
        self._recorder_timer.cancel()
        self._held_by_recorder = False
        self._running = False
        message = (
            f"reset to apex height {apex.y} m, forward speed {apex.xdot} m/s at t = {self.sim_time:.3f} s "
            f"(epoch {self._epoch + 1})"
        )
        if not self.done.done():
            wall_time = (time.monotonic_ns() - self.start_wall_ns) * 1e-9
            self.done.set_result(
                RunOutcome(Status.KIND_RESET, message, self._stepper.stride, self.sim_time, wall_time)
            )
        self._publish_status(Status.KIND_RESET, message, self.sim_time, fatal=False)
        self._epoch += 1
        self._restart(apex, time_offset_ticks=self._ticks)
        self.outcome = None
        self.done = Future()
        self.get_logger().info(message)
        self._start()
        return message

    # --- publishing -----------------------------------------------------------------------------

    def _publish_apex(self, stride: int, state: ModelState) -> None:
        stepper = self._stepper
        flows = stepper.last_stride_energy if stride > 0 else None
        self._apex_wall_ns = time.monotonic_ns()
        self._out.apex(
            self._epoch, stride, self._offset + state.t, state, stepper.measured_apex, stepper.ground, flows
        )

    def _publish_applied_torques(self) -> None:
        """The stance's torques sampled since the last call, as held (tdslip/applied_torque): the record
        from which the analysis replays the stance (none under a ramp)."""
        if not isinstance(self._stepper.command, StanceFeedback):
            return
        samples = self._stepper.stance_torques
        for t, torque in samples[self._applied_published :]:
            tick = self._offset_ticks + round(t / TICK_PERIOD)
            self._out.applied_torque(self._epoch, self._stepper.stride, tick, torque)
        self._applied_published = len(samples)

    def _publish_status(self, kind: str, reason: str, t: float, *, fatal: bool) -> None:
        self._out.status(self._epoch, self._stepper.stride, kind, reason, t, fatal=fatal)


def main(argv: list[str] | None = None) -> int:
    """``plant_node [--ros-args ...]``: run one hop with the installed config/plant.yaml by default."""

    def finished(node: PlantNode) -> bool:
        return node.outcome is not None and bool(node.get_parameter("exit_when_done").value)

    def status(node: PlantNode) -> int:
        return 0 if node.outcome is None or node.outcome.ok else 1

    def deliver(node: PlantNode, executor: Executor) -> None:
        if not node.deliver(executor):
            node.get_logger().warning("not everything published reached the recorder before exit")

    return run_node(
        PlantNode,
        "plant.yaml",
        sys.argv if argv is None else argv,
        finished,
        status,
        specs=SPECS,
        deliver=deliver,
    )


if __name__ == "__main__":
    sys.exit(main())
