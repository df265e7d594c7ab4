"""The plant node: the exact TD-SLIP stepper of the model, advanced at 1 kHz and published.

Every tick it publishes the state (/tdslip/state) and the ground reaction force (/tdslip/grf),
and, stamped with the times the stepper located inside the tick, the apex (/tdslip/apex), contact
(/tdslip/contact) and failure (/tdslip/status) events. All physics is the model's
(:class:`~tdslip_ros.model.stepper.FixedStepStepper`); this node only schedules, validates commands
and converts records to messages.

Clock modes (parameter ``clock_mode``):

* ``realtime``: a 1 kHz tick against the steady clock, on a thread of its own
  (:mod:`tdslip_ros.nodes.realtime`: why, and ``realtime_priority``); each tick steps the plant up
  to the tick due at that wall time (a late one catches up, so simulated time never drifts from
  wall time). The latest valid command for the current stride is used at touchdown. A lock keeps
  the tick thread and the executor's callbacks (commands, reset) apart.
* ``lockstep``: as fast as possible, /clock published every tick. At each apex (the initial one
  included) the plant stops and waits for the command answering that stride; nothing but the
  command decides what happens next, so runs with equal parameters give bit-identical results. No
  valid command within ``command_timeout`` seconds of wall time ends the run (Status
  ``command_timeout``).

A command is rejected (logged, Status ``command_rejected``, never applied) when it answers another
stride than the latest apex, arrives after the touchdown it was for, repeats an already answered
stride in lockstep, or holds a value that :class:`~tdslip_ros.model.params.StanceCommand` or the
stepper refuses (non-finite, out of range, or a touchdown angle the body cannot reach).

The run starts once each /tdslip/* topic has ``min_subscribers`` subscribers (default 0) and, in
lockstep, a controller is connected or ``command_timeout`` has passed. It ends, with a fatal Status,
at a failure of the hopper, at a command timeout, as ``publish_failed`` when a subscriber stops
taking messages until the plant can publish no more, or as ``run_complete`` at apex ``max_strides``.
The /tdslip/reset service restarts it from a new apex: strides count from 0 again while simulated
time runs on.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

from builtin_interfaces.msg import Time
from geometry_msgs.msg import WrenchStamped
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from tdslip_msgs.msg import ApexEvent, ContactEvent, HopperState, StanceCommand, Status
from tdslip_msgs.srv import Reset

from tdslip_ros.interfaces import hopper_from_parameters
from tdslip_ros.model.events import Event, EventKind, Phase
from tdslip_ros.model.events import HopperState as ModelState
from tdslip_ros.model.params import ApexState, ParameterError
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.model.stepper import FixedStepStepper
from tdslip_ros.nodes import parameters, topics
from tdslip_ros.nodes.entry import run_node
from tdslip_ros.nodes.parameters import ParameterSpec
from tdslip_ros.nodes.realtime import Ticker, TickTiming

RCLError = rclpy_implementation.RCLError  # what a failed publish raises (as rclpy.subscription names it)

TICK_PERIOD = 1e-3  # s, the plant's fixed step
START_CHECK_PERIOD = 0.05  # s, how often an autostarting plant checks whether its peers are there
LOCKSTEP_BATCH = 50
"""Ticks per lockstep timer callback: amortises the executor's cost while keeping it responsive."""

CLOCK_MODES = ("realtime", "lockstep")
SPECS: tuple[ParameterSpec, ...] = (
    *parameters.HOPPER,
    ParameterSpec(
        "initial_height", parameters.DEFAULT_APEX_HEIGHT, "initial apex height [m]", 1e-3, 1e2, read_only=True
    ),
    ParameterSpec(
        "initial_forward_speed",
        parameters.DEFAULT_APEX_SPEED,
        "initial apex forward speed [m/s]",
        0.0,
        1e2,
        read_only=True,
    ),
    ParameterSpec(
        "initial_touchdown_angle",
        parameters.DEFAULT_TOUCHDOWN_ANGLE,
        "touchdown angle [rad] of the command in force until a controller answers",
        1e-6,
        1.5707953,
        read_only=True,
    ),
    ParameterSpec(
        "initial_tau0",
        -273.0,
        "ramp torque tau0 [N m] of the initial command (negative = forward thrust)",
        -1e6,
        1e6,
        read_only=True,
    ),
    ParameterSpec(
        "initial_t_f", 0.13, "ramp duration t_f [s] of the initial command", 1e-4, 1e2, read_only=True
    ),
    ParameterSpec(
        "clock_mode",
        "lockstep",
        "realtime: 1 kHz against wall time; lockstep: as fast as possible, each apex waiting for its command",
        choices=CLOCK_MODES,
        read_only=True,
    ),
    ParameterSpec(
        "command_timeout",
        5.0,
        "lockstep: wall time [s] to wait at an apex for its command before the run ends",
        1e-3,
        3600.0,
        read_only=True,
    ),
    ParameterSpec(
        "max_strides", 50, "the run ends at this apex (0: never)", 0, 2_000_000_000, read_only=True
    ),
    ParameterSpec(
        "realtime_priority",
        0,
        "realtime: SCHED_FIFO priority of the tick thread (0: normal scheduling; needs CAP_SYS_NICE)",
        0,
        99,
        read_only=True,
    ),
    ParameterSpec(
        "min_subscribers",
        0,
        "the run starts once each /tdslip/* topic has this many subscribers (e.g. 1: a recorder)",
        0,
        1000,
        read_only=True,
    ),
    ParameterSpec(
        "exit_when_done", True, "plant_node exits when the run has ended (else it stays for /tdslip/reset)"
    ),
)

_CONTACT_KINDS = {
    EventKind.TOUCHDOWN: ContactEvent.TOUCHDOWN,
    EventKind.BOTTOM: ContactEvent.BOTTOM,
    EventKind.LIFTOFF: ContactEvent.LIFTOFF,
}
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


def set_stamp(stamp: Time, t: float) -> None:
    stamp.sec, stamp.nanosec = divmod(round(t * _NS_PER_S), _NS_PER_S)


def fill_state(msg: HopperState, state: ModelState, t: float) -> None:
    """Copy a model state into a HopperState message stamped t [s]."""
    set_stamp(msg.header.stamp, t)
    msg.stride = state.stride
    msg.phase = HopperState.PHASE_STANCE if state.phase is Phase.STANCE else HopperState.PHASE_FLIGHT
    msg.x = state.x
    msg.y = state.y
    msg.xdot = state.xdot
    msg.ydot = state.ydot
    msg.toe_x = state.toe_x
    msg.toe_y = state.toe_y
    msg.leg_length = state.r
    msg.leg_angle = state.theta
    msg.leg_length_rate = state.rdot
    msg.leg_angle_rate = state.thetadot
    msg.hip_torque = state.hip_torque
    msg.energy = state.energy


class PlantNode(Node):
    """The 1 kHz TD-SLIP plant. ``done`` completes with the :class:`RunOutcome` when the run ends.

    It starts by itself once its peers are there (see the parameter ``min_subscribers`` and
    :meth:`_start_when_ready`); with ``autostart=False`` it waits for :meth:`start` instead.
    """

    def __init__(self, *, autostart: bool = True, **node_options: object) -> None:
        super().__init__("plant", **node_options)  # type: ignore[arg-type]
        self._ticker: Ticker | None = None  # first: destroy_node must work if the rest raises
        self.add_on_set_parameters_callback(lambda changed: parameters.validate(SPECS, changed))
        values = parameters.declare(self, SPECS)
        self.hopper = hopper_from_parameters(values)
        self._initial_command = ModelCommand(
            float(values["initial_touchdown_angle"]),
            float(values["initial_tau0"]),
            float(values["initial_t_f"]),
        )
        initial_apex = ApexState(float(values["initial_height"]), float(values["initial_forward_speed"]))
        self.lockstep = values["clock_mode"] == "lockstep"
        self._max_strides = int(values["max_strides"])

        self.published: Counter[str] = Counter()
        self.received_commands = 0
        self.command_latencies_ns: list[int] = []
        """Wall time from each apex's publication to the valid command answering it."""
        self.tick_timing = None if self.lockstep else TickTiming(round(TICK_PERIOD * _NS_PER_S))
        self.outcome: RunOutcome | None = None
        self.done: Future[RunOutcome] = Future()

        self._topic_publishers: dict[str, Publisher[Any]] = {
            topic: self.create_publisher(message, topic, topics.QOS)
            for topic, message in topics.MESSAGE_TYPES.items()
            if topic != topics.COMMAND and (topic != topics.CLOCK or self.lockstep)
        }
        self._state_pub = self._topic_publishers[topics.STATE]
        self._grf_pub = self._topic_publishers[topics.GRF]
        self._apex_pub = self._topic_publishers[topics.APEX]
        self._clock_pub = self._topic_publishers.get(topics.CLOCK)
        self._clock_out: Publisher[Any] | None = None  # _clock_pub while it has subscribers
        self._state_msg = HopperState()
        self._state_msg.header.frame_id = topics.FRAME_ID
        self._grf_msg = WrenchStamped()
        self._grf_msg.header.frame_id = topics.FRAME_ID
        self._clock_msg = ClockMsg()
        # One stamp object shared by the three per-tick messages: set once per tick.
        self._grf_msg.header.stamp = self._clock_msg.clock = self._state_msg.header.stamp
        # Volatile on purpose (topics.COMMAND_QOS keeps old answers): none is for a run starting now.
        self.create_subscription(StanceCommand, topics.COMMAND, self._on_command, topics.QOS)
        self.create_service(Reset, topics.RESET_SERVICE, self._on_reset)

        # Stepping: lockstep by a zero-period timer of the executor, realtime by a Ticker thread;
        # the lock keeps the tick thread and the executor's callbacks apart.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._lock = threading.Lock()
        self._lockstep_timer = self.create_timer(0.0, self._advance_lockstep, clock=steady, autostart=False)
        self._timeout_timer = self.create_timer(
            float(values["command_timeout"]), self._on_command_timeout, clock=steady, autostart=False
        )
        self._realtime_priority = int(values["realtime_priority"])
        self._running = False
        self._ticks = 0  # since construction, over resets: simulated time = ticks * TICK_PERIOD
        self._tick0 = 0  # the tick at start(), due at start_wall_ns of the steady clock
        self.start_wall_ns = 0
        self._restart(initial_apex, time_offset_ticks=0)

        self._min_subscribers = int(values["min_subscribers"])
        self._controller_wait_ns = round(float(values["command_timeout"]) * _NS_PER_S)
        self._created_ns = time.monotonic_ns()
        self._start_check = self.create_timer(
            START_CHECK_PERIOD, self._start_when_ready, clock=steady, autostart=autostart
        )

    # --- run control ----------------------------------------------------------------------------

    @property
    def sim_time(self) -> float:
        return self._ticks * TICK_PERIOD

    def matched_subscribers(self, topic: str) -> int:
        """Subscriptions matched with the plant's publisher on ``topic``."""
        return self._topic_publishers[topic].get_subscription_count()

    def _start_when_ready(self) -> None:
        """autostart: start once min_subscribers listen to each /tdslip/* topic and, in lockstep, a
        controller is connected (apex subscribed, command published) or command_timeout has passed."""
        if any(
            self.matched_subscribers(topic) < self._min_subscribers
            for topic in topics.TDSLIP_TOPICS
            if topic != topics.COMMAND
        ):
            return
        waited = time.monotonic_ns() - self._created_ns >= self._controller_wait_ns
        if self.lockstep and not (self._controller_connected() or waited):
            return
        self.start()

    def _controller_connected(self) -> bool:
        """A node publishes commands and subscribes to the apex, and every apex subscription of the
        graph has matched the plant's publisher, so the first apex reaches the controller."""
        commanders = {
            (i.node_namespace, i.node_name) for i in self.get_publishers_info_by_topic(topics.COMMAND)
        }
        apex_subscriptions = self.get_subscriptions_info_by_topic(topics.APEX)
        listeners = {(i.node_namespace, i.node_name) for i in apex_subscriptions}
        matched = self.matched_subscribers(topics.APEX) >= len(apex_subscriptions)
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
        self._check_clock_subscribers()
        self._publish_apex(0, self._stepper.state)
        self._publish_sample(self._stepper.state)
        if self.lockstep:
            self._await_command()
        else:
            assert self.tick_timing is not None
            self.tick_timing.resume()
            self._ticker = Ticker(
                round(TICK_PERIOD * _NS_PER_S),
                self._advance_realtime,
                priority=self._realtime_priority,
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
        self._stepper = FixedStepStepper(self.hopper, apex, self._initial_command, dt=TICK_PERIOD)
        self._offset = time_offset_ticks * TICK_PERIOD
        self._awaiting: int | None = None
        self._answered = -1  # the latest stride whose command was applied
        self._apex_wall_ns = time.monotonic_ns()

    def _finish(self, kind: str, reason: str, t: float) -> None:
        self._running = False
        self._lockstep_timer.cancel()
        self._timeout_timer.cancel()
        if self._ticker is not None:
            self._ticker.request_stop()  # the lock is held: the tick thread may be waiting for it
        try:
            self._publish_status(kind, reason, t, fatal=True)
        except RCLError as error:  # the status topic's subscriber is the one that stalled
            self.get_logger().error(f"the final status could not be published: {error}")
        wall_time = (time.monotonic_ns() - self.start_wall_ns) * 1e-9
        self.outcome = RunOutcome(kind, reason, self._stepper.stride, t, wall_time)
        if self.tick_timing is not None:
            self.get_logger().info(f"realtime: {self.tick_timing.summary()}")
        if kind == Status.KIND_RUN_COMPLETE:
            self.get_logger().info(f"run complete at stride {self._stepper.stride}, t = {t:.3f} s: {reason}")
        else:
            self.get_logger().error(
                f"run ended at stride {self._stepper.stride}, t = {t:.6f} s: {kind}: {reason}"
            )
        if not self.done.done():
            self.done.set_result(self.outcome)

    # --- stepping -------------------------------------------------------------------------------

    def _advance_lockstep(self) -> None:
        with self._lock:
            self._check_clock_subscribers()
            for _ in range(LOCKSTEP_BATCH):
                if self._tick_or_fail():
                    self._lockstep_timer.cancel()
                    return

    def _check_clock_subscribers(self) -> None:
        # /clock costs a publish per tick even when nobody listens: it is sent while someone does.
        listened = self._clock_pub is not None and self._clock_pub.get_subscription_count() > 0
        self._clock_out = self._clock_pub if listened else None

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
            # A reliable KEEP_ALL subscriber that stops taking messages fills the publisher's
            # history; publishing then blocks and fails. The run ends, reported, the node lives on.
            self._finish(Status.KIND_PUBLISH_FAILED, str(error).split(",", 1)[0], self.sim_time)
            return True

    def _tick(self) -> bool:
        """Step one tick and publish it; True when stepping must pause (awaited command, end of run)."""
        events = self._stepper.step()
        self._ticks += 1
        apex: Event | None = None
        for event in events:
            if event.kind is EventKind.APEX:
                apex = event
                self._publish_apex(event.stride, event.state)
            elif event.kind is EventKind.FAILURE:
                assert event.failure is not None
                self._finish(event.failure.value, event.reason, self._offset + event.t)
                return True
            else:
                self._publish_contact(event)
        state = self._stepper.state
        self._publish_sample(state)
        if apex is None:
            return False
        if apex.stride == self._max_strides:
            reason = f"reached max_strides = {self._max_strides}"
            self._finish(Status.KIND_RUN_COMPLETE, reason, self._offset + state.t)
            return True
        if self.lockstep:
            self._await_command()
            return True
        return False

    def _await_command(self) -> None:
        self._awaiting = self._stepper.stride
        self._timeout_timer.reset()

    def _on_command_timeout(self) -> None:
        self._timeout_timer.cancel()
        with self._lock:
            self._time_out()

    def _time_out(self) -> None:
        if self._awaiting is not None and self._running:
            period = self._timeout_timer.timer_period_ns * 1e-9
            self._finish(
                Status.KIND_COMMAND_TIMEOUT,
                f"no valid command for stride {self._awaiting} within command_timeout = {period:g} s",
                self._offset + self._stepper.t,
            )

    # --- commands and reset ---------------------------------------------------------------------

    def _on_command(self, msg: StanceCommand) -> None:
        with self._lock:
            self._take_command(msg)

    def _take_command(self, msg: StanceCommand) -> None:
        self.received_commands += 1
        if not self._running:
            self.get_logger().debug(f"command for stride {msg.stride} ignored: no run in progress")
            return
        try:
            self._apply(msg)
        except ParameterError as error:
            reason = f"command for stride {msg.stride} ({msg.policy or 'no policy'}) rejected: {error}"
            self.get_logger().warning(reason)
            self._publish_status(
                Status.KIND_COMMAND_REJECTED, reason, self._offset + self._stepper.t, fatal=False
            )
            return
        if msg.stride != self._answered:
            self.command_latencies_ns.append(time.monotonic_ns() - self._apex_wall_ns)
            self._answered = msg.stride
        if self.lockstep:
            self._awaiting = None
            self._timeout_timer.cancel()
            self._lockstep_timer.reset()

    def _apply(self, msg: StanceCommand) -> None:
        """Validate a command and hand it to the stepper; ParameterError gives the reason to refuse it."""
        stride = self._stepper.stride
        if msg.stride != stride:
            raise ParameterError(f"it answers stride {msg.stride}, but the latest apex is stride {stride}")
        if self.lockstep and self._awaiting != stride:
            raise ParameterError(f"stride {stride} already has its command (lockstep)")
        if self._stepper.state.phase is Phase.STANCE:
            raise ParameterError(f"it arrived after the touchdown of stride {stride}")
        self._stepper.set_command(ModelCommand(msg.touchdown_angle, msg.tau0, msg.t_f))

    def _on_reset(self, request: Reset.Request, response: Reset.Response) -> Reset.Response:
        try:
            apex = ApexState(request.height, request.forward_speed)
        except ParameterError as error:
            response.success, response.message = False, f"reset refused: {error}"
            return response
        self._stop_ticker()  # outside the lock: the tick in progress needs it to finish
        with self._lock:
            response.message = self._reset(apex)
        response.success = True
        return response

    def _reset(self, apex: ApexState) -> str:
        self._lockstep_timer.cancel()
        self._timeout_timer.cancel()
        self._running = False
        message = (
            f"reset to apex height {apex.y} m, forward speed {apex.xdot} m/s at t = {self.sim_time:.3f} s"
        )
        if not self.done.done():
            wall_time = (time.monotonic_ns() - self.start_wall_ns) * 1e-9
            self.done.set_result(
                RunOutcome(Status.KIND_RESET, message, self._stepper.stride, self.sim_time, wall_time)
            )
        self._restart(apex, time_offset_ticks=self._ticks)
        self.outcome = None
        self.done = Future()
        self._publish_status(Status.KIND_RESET, message, self.sim_time, fatal=False)
        self.get_logger().info(message)
        self._start()
        return message

    # --- publishing -----------------------------------------------------------------------------

    def _publish(self, topic: str, msg: object) -> None:
        self._topic_publishers[topic].publish(msg)
        self.published[topic] += 1

    def _publish_sample(self, state: ModelState) -> None:
        fill_state(self._state_msg, state, self._offset + state.t)
        self._state_pub.publish(self._state_msg)
        force = self._grf_msg.wrench.force
        force.x = state.grf_x
        force.y = state.grf_y
        self._grf_pub.publish(self._grf_msg)
        published = self.published
        published[topics.STATE] += 1
        published[topics.GRF] += 1
        if self._clock_out is not None:
            self._clock_out.publish(self._clock_msg)
            published[topics.CLOCK] += 1

    def _publish_apex(self, stride: int, state: ModelState) -> None:
        msg = ApexEvent(stride=stride, sim_time=self._offset + state.t, x=state.x, height=state.y)
        msg.header.frame_id = topics.FRAME_ID
        set_stamp(msg.header.stamp, msg.sim_time)
        msg.forward_speed = msg.measured_forward_speed = state.xdot
        msg.measured_height = state.y
        msg.energy = state.energy
        flows = self._stepper.last_stride_energy if stride > 0 else None
        if flows is not None:
            msg.hip_work, msg.damping_loss, msg.spring_loss = (
                flows.hip_work,
                flows.damping_loss,
                flows.spring_loss,
            )
        self._apex_wall_ns = time.monotonic_ns()
        self._publish(topics.APEX, msg)

    def _publish_contact(self, event: Event) -> None:
        t = self._offset + event.t
        msg = ContactEvent(kind=_CONTACT_KINDS[event.kind], stride=event.stride, sim_time=t)
        msg.header.frame_id = msg.state.header.frame_id = topics.FRAME_ID
        set_stamp(msg.header.stamp, t)
        fill_state(msg.state, event.state, t)
        self._publish(topics.CONTACT, msg)

    def _publish_status(self, kind: str, reason: str, t: float, *, fatal: bool) -> None:
        msg = Status(stride=self._stepper.stride, sim_time=t, kind=kind, reason=reason, fatal=fatal)
        msg.header.frame_id = topics.FRAME_ID
        set_stamp(msg.header.stamp, t)
        self._publish(topics.STATUS, msg)


def main(argv: list[str] | None = None) -> int:
    """``plant_node [--ros-args ...]``: run one hop with the installed config/plant.yaml by default."""

    def finished(node: PlantNode) -> bool:
        return node.outcome is not None and bool(node.get_parameter("exit_when_done").value)

    def status(node: PlantNode) -> int:
        return 0 if node.outcome is None or node.outcome.ok else 1

    return run_node(PlantNode, "plant.yaml", sys.argv if argv is None else argv, finished, status)


if __name__ == "__main__":
    sys.exit(main())
