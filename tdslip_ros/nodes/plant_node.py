"""The plant node: the exact TD-SLIP stepper of the model, advanced at 1 kHz and published.

Every tick it publishes the state (``tdslip/state``) and the ground reaction force (``tdslip/grf``) to whoever
subscribes to them, and to recorders in batches (``tdslip/samples``, :mod:`tdslip_ros.nodes.plant_output`);
and, stamped with the times the stepper located inside the tick, the apex (``tdslip/apex``), contact
(``tdslip/contact``) and failure (``tdslip/status``) events; ``tdslip/markers`` draws the hopper for Foxglove
and RViz at ``marker_rate`` Hz of simulated time, and /clock carries the simulated time while someone
subscribes to it (``publish_clock``). Every stamp is simulated time, in both clock modes; nodes that should
follow it run with ``use_sim_time``. All physics is the model's
(:class:`~tdslip_ros.model.plant.stepper.FixedStepStepper`), and the run's rules (admission, torques, when it
ends) are :class:`~tdslip_ros.nodes.plant_run.PlantRun`'s; this node only schedules and converts what the run
emits to messages. Names are relative, so ``__ns`` puts a hopper in a namespace of its own; QoS is
:mod:`tdslip_ros.nodes.topics`'s contract.

Clock modes (parameter ``clock_mode``):

* ``realtime``: a 1 kHz tick against the steady clock, in a process of its own
  (:mod:`tdslip_ros.nodes.tick_process`: why; :mod:`tdslip_ros.nodes.realtime`: ``realtime_priority``);
  each tick steps the plant up to the tick due at that wall time (a late one catches up, so simulated
  time never drifts from wall time). This node publishes what that process steps and forwards it what
  arrives. The latest valid command for the current stride is used at touchdown; a controller
  that leaves ``max_stale_strides`` strides in a row unanswered ends the run (``command_timeout``).
* ``lockstep``: as fast as possible. At each apex (the initial one included) the plant stops and
  waits for the command answering that stride; nothing but the command decides what happens next,
  so runs with equal parameters give bit-identical results. No valid command within
  ``command_timeout`` seconds of wall time ends the run (Status ``command_timeout``). An apex that no
  command at all has answered is published again every ``APEX_REPEAT`` s until one comes
  (:meth:`~tdslip_ros.nodes.plant_run.PlantRun.repeat_apex`): a controller that missed it answers it.

Perturbations (:mod:`tdslip_ros.model.plant.perturbations`; parameters ``terrain``, ``apex_height_noise``,
``apex_speed_noise``, ``apex_noise_seed``, ``angle_noise``, ``angle_noise_seed``, ``tau_max``, ``pushes``:
:data:`tdslip_ros.interfaces.PERTURBATION_PARAMETERS`) are the stepper's: the hopper hops over the terrain
(``terrain``: ``flat``, ``step:height=H,x=X``, ``blocks:sigma=S,length=L,seed=N``, ``profile:file=PATH.csv``),
its hip saturates at tau_max, its leg lands with a placement error and pushes hit it right after the apex.
Heights are in the world frame: state samples carry the ground height under the body, each contact event the
ground under the toe of its stance, each apex event the ground of the stance before it (the initial one: under
the body; the initial apex ``initial_height`` and a reset's height are above that ground) and, beside the true
apex, the measured one the controller's sensor reports (the true one without sensing noise). The random draws
of a run are those of trajectory ``epoch``
(:meth:`~tdslip_ros.model.plant.perturbations.Perturbations.draws`), so a run is reproduced by its parameters.
A command is judged admissible on the apex the controller was given (measured, above the ground of the last
stance); a toe placed below the ground is toe stubbing, a failure.

A command answers one apex: it carries the apex's ``epoch`` (0 for the first run, one more at every reset) and
``stride``. It is rejected (Status ``command_rejected``, never applied) when it answers another apex, arrives
after the touchdown it was for, repeats an already answered stride in lockstep, or holds a value that
:class:`~tdslip_ros.model.params.StanceCommand` or the stepper refuses (non-finite, out of range, or a
touchdown angle the body cannot reach). Answers to other apexes are recognised from their bytes and cost next
to nothing (a flood of them cannot delay the valid one); late answers are only counted, other rejections are
logged and reported, at most :data:`~tdslip_ros.nodes.command_admission.REJECTION_REPORTS` per
:data:`~tdslip_ros.nodes.command_admission.REJECTION_REPORT_PERIOD`, the rest summed
(:mod:`tdslip_ros.nodes.command_admission`). A command may ask for stance feedback instead of the ramp: the
hip then holds the torques a controller streams on ``tdslip/hip_torque``, one per stance tick, judged by
:mod:`tdslip_ros.nodes.torque_stream`; each torque held goes out on ``tdslip/applied_torque``. The parameters
are :mod:`tdslip_ros.nodes.plant_parameters`.

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
from collections.abc import Callable
from typing import Any

from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.executors import Executor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.task import Future
from rclpy.timer import Timer
from tdslip_msgs.msg import HipTorque, RecorderStatus, StanceCommand, Status
from tdslip_msgs.srv import Reset

from tdslip_ros.interfaces import (
    hopper_from_parameters,
    perturbations_from_parameters,
)
from tdslip_ros.model.events import HopperState as ModelState
from tdslip_ros.model.limits import PlausibilityLimits, check_hopper
from tdslip_ros.model.params import ApexState, ParameterError
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.entry import run_node, spin_until, wait_for_delivery
from tdslip_ros.nodes.flow_control import FLOW_WINDOW, RecorderProgress
from tdslip_ros.nodes.lifecycle import ManagedNode
from tdslip_ros.nodes.node_status import plant_diagnostics
from tdslip_ros.nodes.parameters import ParameterValue
from tdslip_ros.nodes.plant_output import GRAPH_CHECK_TICKS, PlantOutput
from tdslip_ros.nodes.plant_parameters import SPECS
from tdslip_ros.nodes.plant_run import (
    APEX_REPEAT,
    TICK_PERIOD,
    ApexReport,
    LockedRun,
    PlantRun,
    PublishFailed,
    RunCounts,
    RunOutcome,
    RunSettings,
)
from tdslip_ros.nodes.realtime import TickTiming
from tdslip_ros.nodes.robot_model import RobotModelPublisher
from tdslip_ros.nodes.rows import Rows
from tdslip_ros.nodes.tick_process import TickProcess

__all__ = ["TICK_PERIOD", "PlantNode", "RunOutcome"]

RCLError = rclpy_implementation.RCLError  # what a failed publish raises (as rclpy.subscription names it)

START_CHECK_PERIOD = 0.05  # s, how often an autostarting plant checks whether its peers are there
START_SETTLE = 0.2  # s the peers must have been there before the run starts
LOCKSTEP_BATCH = 50
"""Ticks per lockstep timer callback: amortises the executor's cost while keeping it responsive."""
DELIVERY_TIMEOUT = 10.0
"""s a finished run waits for the recorder it waits for to write everything (and, without one, at
most :data:`ACK_TIMEOUT` for subscribers' acknowledgements)."""
ACK_TIMEOUT = 1.0  # s

_NS_PER_S = 1_000_000_000


class PlantNode(ManagedNode):
    """The 1 kHz TD-SLIP plant. ``done`` completes with the :class:`RunOutcome` when the run ends.

    A managed node (:mod:`tdslip_ros.nodes.lifecycle`): configure checks the parameters and readies the
    run (the realtime tick's process starts, its kernels loaded), activate starts it or resumes it,
    deactivate pauses it, holding its state (:meth:`deactivate`), cleanup ends a run in progress.
    Active, it starts the run by itself once its peers are there (see the parameters ``min_subscribers``
    and ``wait_for_recorder``, and :meth:`_start_when_ready`); with ``start_when_ready=False`` it waits
    for :meth:`start` instead.
    """

    def __init__(self, *, start_when_ready: bool = True, **node_options: object) -> None:
        self._ticking: TickProcess | None = None  # first: destroy_node must work if the rest raises
        self._driver: LockedRun | TickProcess | None = None  # None: not configured
        self._starts_when_ready = start_when_ready
        self._lock = threading.Lock()
        self._timers_on_hold: set[Timer] | None = None  # paused (inactive): the timers to run on activate
        self.outcome: RunOutcome | None = None
        self.done: Future[RunOutcome] = Future()
        self._started = False
        super().__init__("plant", SPECS, **node_options)

    def configure(self, values: dict[str, ParameterValue]) -> None:
        self.hopper = hopper_from_parameters(values)
        check_hopper(self.hopper)
        self.limits = PlausibilityLimits.for_hopper(self.hopper)
        if float(values["max_torque"]) > 0.0:
            self.limits = dataclasses.replace(self.limits, max_torque=float(values["max_torque"]))
        initial_command = ModelCommand(
            float(values["initial_touchdown_angle"]),
            float(values["initial_tau0"]),
            float(values["initial_t_f"]),
        )
        self.limits.check_command(initial_command)
        initial_apex = ApexState(float(values["initial_height"]), float(values["initial_forward_speed"]))
        self.limits.check_apex(initial_apex)
        self.perturbations = perturbations_from_parameters(values)
        self.perturbations.check_limits(self.limits)
        self.lockstep = values["clock_mode"] == "lockstep"
        self._max_strides = int(values["max_strides"])
        self._wait_for_recorder = bool(values["wait_for_recorder"])
        settings = RunSettings(
            self.hopper,
            self.limits,
            self.perturbations,
            initial_command,
            lockstep=self.lockstep,
            max_strides=self._max_strides,
            max_stale_strides=int(values["max_stale_strides"]),
            torque_max_age_ticks=round(float(values["torque_max_age"]) / TICK_PERIOD),
        )

        self.received_commands = 0
        self.received_torques = 0
        self.command_latencies_ns = Rows("CommandLatency", {"epoch": "I", "stride": "I", "latency_ns": "q"})
        """(epoch, stride, ns) of each answered apex: wall time from its publication to the valid command."""
        self.counts = RunCounts()
        """What the run counted (late commands, rejections, torques), as of its latest apex and its end."""
        self.tick_timing: TickTiming | None = None
        """Realtime: the tick's wall-clock timing, once a run is over."""
        self.recorders = RecorderProgress()
        self.outcome = None  # a run of its own, also after a cleanup
        self.done = Future()

        marker_rate = float(values["marker_rate"])
        marker_period_ticks = max(1, round(1.0 / (marker_rate * TICK_PERIOD))) if marker_rate else 0
        self._out = PlantOutput(
            self,
            publish_clock=bool(values["publish_clock"]),
            marker_period_ticks=marker_period_ticks,
            rigid=self.hopper.body is not None,
        )
        self.robot_model = RobotModelPublisher(self, self.hopper, marker_period_ticks)
        self.published = self._out.published
        """Messages published per topic, by relative name (topics.STATE, ...)."""
        self.topic_names = self._out.topic_names
        """Fully qualified name of each published topic, by its relative name."""
        self.command_topic = self.resolve_topic_name(topics.COMMAND)
        # Raw: the run recognises an answer to an earlier apex from its bytes (command_key), unparsed.
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

        # Stepping: lockstep by a zero-period timer of the executor, realtime in a process of its own whose
        # output a thread replays here; the lock keeps that thread and the executor's callbacks apart.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._lockstep_timer = self.create_timer(0.0, self._advance_lockstep, clock=steady, autostart=False)
        self._command_timeout = float(values["command_timeout"])
        self._timeout_timer = self.create_timer(
            self._command_timeout, self._on_command_timeout, clock=steady, autostart=False
        )
        self._repeat_timer = self.create_timer(APEX_REPEAT, self._on_repeat, clock=steady, autostart=False)
        self._held_by_recorder = False  # lockstep stepping paused until the recorder catches up
        self._recorder_timer = self.create_timer(
            self._command_timeout, self._on_recorder_timeout, clock=steady, autostart=False
        )
        self._run_timers = (
            self._lockstep_timer,
            self._timeout_timer,
            self._repeat_timer,
            self._recorder_timer,
        )
        """Every timer of a running run: held while paused, stopped when it ends or restarts."""
        self._started = False
        self._tick_process_lost: str | None = None  # why the realtime tick process ended by itself
        self._epoch = 0
        self._stride = 0
        self._ticks = 0  # of the latest sample published, since construction
        self._apex_wall_ns = time.monotonic_ns()
        self.start_wall_ns = 0
        sink = _NodeSink(self, self._out)
        self._run: PlantRun | None = None  # lockstep: the run this node steps
        if self.lockstep:
            self._run = PlantRun(settings, initial_apex, sink)
            self._driver = LockedRun(self._run, self._lock)
        else:
            self._driver = self._ticking = TickProcess(
                settings,
                initial_apex,
                sink,
                self._lock,
                priority=int(values["realtime_priority"]),
                cpu=None if int(values["realtime_cpu"]) < 0 else int(values["realtime_cpu"]),
                on_lost=self._on_tick_process_lost,
            )

        self._min_subscribers = int(values["min_subscribers"])
        self._ready_since_ns: int | None = None
        self._start_check = self.create_timer(
            START_CHECK_PERIOD, self._start_when_ready, clock=steady, autostart=False
        )
        self.diagnostics = plant_diagnostics(self, self)
        self.get_logger().info(self._startup_summary(initial_apex))

    def activate(self) -> None:
        """Start the run when ready, or resume the paused one."""
        with self._lock:
            if not self._started:
                if self._starts_when_ready:  # command_timeout counts from here, not from configure
                    self._waiting_since_ns = time.monotonic_ns()
                    self._start_check.reset()
                return
            if self._timers_on_hold is None:
                return
            for timer in self._timers_on_hold:
                timer.reset()
            self._timers_on_hold = None
        if self.running:
            assert self._driver is not None
            self._driver.resume()
            self.get_logger().info(f"resumed at stride {self._stride}, t = {self.sim_time:.3f} s")

    def deactivate(self) -> None:
        """Pause: lockstep stops stepping (its timers wait for activate), realtime stops its tick; the state,
        the stride and the command awaited are held."""
        self._start_check.cancel()
        with self._lock:
            if not self.running:
                return
            self._timers_on_hold = {timer for timer in self._run_timers if not timer.is_canceled()}
            for timer in self._run_timers:
                timer.cancel()
        assert self._driver is not None
        self._driver.pause()
        stopped = "stepping" if self.lockstep else "its tick"
        self.get_logger().info(
            f"paused at stride {self._stride}, t = {self.sim_time:.3f} s: {stopped} stopped until activate"
        )

    def cleanup(self) -> None:
        """End a run in progress (its final Status goes out) and stop the tick's process."""
        if self.running:
            self.end_run("the plant was cleaned up (lifecycle)")
        if self._ticking is not None:
            self._ticking.close()
            self._ticking = None
        self._driver = None
        self._timers_on_hold = None

    def _run_timer(self, timer: Timer) -> None:
        """Start ``timer``, or, paused, on activate (under the lock)."""
        if self._timers_on_hold is None:
            timer.reset()
        else:
            self._timers_on_hold.add(timer)

    def _stop_timer(self, timer: Timer) -> None:
        """Stop ``timer``, also for activate (under the lock)."""
        timer.cancel()
        if self._timers_on_hold is not None:
            self._timers_on_hold.discard(timer)

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
        """The simulated time of the latest sample published [s]."""
        return self._ticks * TICK_PERIOD

    @property
    def stride(self) -> int:
        """The latest apex of the run published (0: the initial one)."""
        return self._stride

    @property
    def epoch(self) -> int:
        """The run epoch: 0 for the first run, one more after every reset."""
        return self._epoch

    @property
    def tick_process_id(self) -> int | None:
        """Realtime: the process id of the tick's process (e.g. for ``chrt`` or ``taskset``)."""
        return None if self._ticking is None else self._ticking.pid

    @property
    def running(self) -> bool:
        return self._started and self.outcome is None

    def matched_subscribers(self, topic: str) -> int:
        """Subscriptions matched with the plant's publisher on ``topic`` (relative name)."""
        return self._out.subscribers(topic)

    def _start_when_ready(self) -> None:
        """autostart: start once :meth:`ready_to_start`, or once command_timeout has passed."""
        waited = time.monotonic_ns() - self._waiting_since_ns >= self._command_timeout * _NS_PER_S
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
            if self._started:
                return
            self._started = True
            self.start_wall_ns = time.monotonic_ns()
            if self._tick_process_lost is not None:
                self._end_lost_run()
                return
        self._driver.start(self.start_wall_ns)

    def end_run(self, reason: str) -> None:
        """End a running run as complete (e.g. a caller's wall-time limit): at once in lockstep; in realtime
        the tick process ends it, and ``outcome`` is set when that reaches the node."""
        self._driver.end(Status.KIND_RUN_COMPLETE, reason)

    def destroy_node(self) -> None:
        if self._ticking is not None:
            self._ticking.close()
        super().destroy_node()

    def _finished(self, outcome: RunOutcome) -> None:
        """The run ended (under the lock)."""
        for timer in self._run_timers:
            self._stop_timer(timer)
        self._held_by_recorder = False
        self.outcome = outcome
        if not self.done.done():
            self.done.set_result(outcome)

    def _restarted(self, epoch: int, ended: RunOutcome) -> None:
        """A reset began ``epoch`` (under the lock); ``ended``: how the run before ended, if it had not."""
        for timer in self._run_timers:
            self._stop_timer(timer)
        self._held_by_recorder = False
        if not self.done.done():
            self.done.set_result(ended)
        self._epoch = epoch
        self.outcome = None
        self.done = Future()
        self.start_wall_ns = time.monotonic_ns()

    def _on_tick_process_lost(self, reason: str) -> None:
        with self._lock:
            self._tick_process_lost = reason
            if self.running:
                self._end_lost_run()

    def _end_lost_run(self) -> None:
        """End the run that the tick process can no longer step (under the lock)."""
        reason = self._tick_process_lost
        assert reason is not None
        self.get_logger().error(f"run ended: {reason}")
        wall_time = (time.monotonic_ns() - self.start_wall_ns) * 1e-9
        self._finished(RunOutcome(Status.KIND_PUBLISH_FAILED, reason, self._stride, self.sim_time, wall_time))

    def recorded_everything(self) -> bool:
        """Every recorder waited for has written everything published on the topics it records."""
        return self.recorders.caught_up({self.topic_names[t]: n for t, n in self.published.items()})

    def deliver(self, executor: Executor) -> bool:
        """After a run: with ``wait_for_recorder``, spin until the recorder has written everything
        (False after DELIVERY_TIMEOUT s); without, wait at most ACK_TIMEOUT for the subscribers'
        acknowledgements, so that no stalled subscriber can keep the plant. What the tick process stepped and
        the samples not yet batched go out first (a run stopped from outside, e.g. by SIGINT, published no
        final status). Not configured (or cleaned up), there is nothing to deliver."""
        if self._driver is None:
            return True
        if self._ticking is not None:
            self._ticking.close()
        with self._lock:
            self._out.flush()
        if self._wait_for_recorder and self.recorders.heard:
            return spin_until(executor, self.recorded_everything, DELIVERY_TIMEOUT)
        return wait_for_delivery(self, ACK_TIMEOUT)

    # --- lockstep stepping ----------------------------------------------------------------------

    def _advance_lockstep(self) -> None:
        assert self._run is not None
        with self._lock:
            if self._wait_for_recorder and self._recorder_lag() > FLOW_WINDOW:
                self._hold_for_recorder()
                return
            if self._run.advance(LOCKSTEP_BATCH):
                self._lockstep_timer.cancel()

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
            published = {self.topic_names[t]: n for t, n in self.published.items()} if self.running else None
            self.recorders.update(msg, published)
            if self._held_by_recorder and self.running and self._recorder_lag() <= FLOW_WINDOW // 2:
                self._held_by_recorder = False
                self._stop_timer(self._recorder_timer)
                self._run_timer(self._lockstep_timer)

    def _on_recorder_timeout(self) -> None:
        self._recorder_timer.cancel()
        with self._lock:
            if self._held_by_recorder and self._run is not None:
                self._run.end(
                    Status.KIND_PUBLISH_FAILED,
                    f"the recorder waited for stopped: it is {self._recorder_lag()} messages behind and "
                    f"reported nothing for {self.recorders.silent_for(time.monotonic_ns()):.1f} s",
                )

    def _on_command_timeout(self) -> None:
        self._timeout_timer.cancel()
        with self._lock:
            if self._run is not None:
                self._run.time_out(self._command_timeout)

    def _on_repeat(self) -> None:
        with self._lock:
            if self._run is not None:
                self._run.repeat_apex()

    # --- commands, torques and reset ------------------------------------------------------------

    def _on_command(self, data: bytes) -> None:
        self.received_commands += 1
        self._driver.take_command(data)

    def _on_hip_torque(self, data: bytes) -> None:
        self.received_torques += 1
        self._driver.take_torque(data)

    def _on_reset(self, request: Reset.Request, response: Reset.Response) -> Reset.Response:
        try:
            apex = ApexState(request.height, request.forward_speed)
            self.limits.check_apex(apex)
        except ParameterError as error:
            response.success, response.message = False, f"reset refused: {error}"
            response.epoch = self._epoch
            return response
        try:
            response.message = self._driver.reset(apex)  # unlocked: the tick process's replay takes the lock
        except TimeoutError as error:
            response.success, response.message = False, f"reset failed: {error}"
            response.epoch = self._epoch
            return response
        response.success, response.epoch = True, self._epoch
        return response


class _NodeSink:
    """The node's side of a run (:class:`~tdslip_ros.nodes.plant_run.PlantSink`): publishes through the
    node's :class:`PlantOutput` and keeps the node's view of the run (called under the node's lock)."""

    def __init__(self, node: PlantNode, out: PlantOutput) -> None:
        self._node = node
        self._out = out

    @property
    def live(self) -> bool:
        return self._out.live

    @staticmethod
    def _publishing(publish: Callable[..., None], *args: Any, **kwargs: Any) -> None:
        try:
            publish(*args, **kwargs)
        except RCLError as error:
            raise PublishFailed(str(error).split(",", 1)[0]) from error

    def tick(self, state: ModelState, t: float, tick: int) -> None:
        if tick % GRAPH_CHECK_TICKS == 0:  # here, not in the run: who listens is the node's question
            self._out.check_graph()
            self._node.robot_model.check_graph()
        self._publishing(self._out.sample, state, t)
        self._publishing(self._out.markers, state, t, tick)
        self._publishing(self._node.robot_model.publish, state, t, tick)
        self._node._ticks = tick

    def apex(self, report: ApexReport) -> None:
        self._node._apex_wall_ns = time.monotonic_ns()
        self._node._stride = report.stride
        self._publishing(self._out.apex, report)

    def contact(self, *args: Any) -> None:
        self._publishing(self._out.contact, *args)

    def status(self, *args: Any, **kwargs: Any) -> None:
        self._publishing(self._out.status, *args, **kwargs)

    def applied_torque(self, *args: Any) -> None:
        self._publishing(self._out.applied_torque, *args)

    def awaiting(self) -> None:
        self._node._run_timer(self._node._timeout_timer)
        self._node._run_timer(self._node._repeat_timer)

    def resumed(self) -> None:
        self._node._stop_timer(self._node._timeout_timer)
        self._node._stop_timer(self._node._repeat_timer)
        self._node._run_timer(self._node._lockstep_timer)

    def command_applied(self, epoch: int, stride: int, applied_ns: int) -> None:
        self._node.command_latencies_ns.append(epoch, stride, applied_ns - self._node._apex_wall_ns)

    def counted(self, counts: RunCounts) -> None:
        self._node.counts = counts

    def timed(self, timing: TickTiming) -> None:
        self._node.tick_timing = timing

    def log(self, level: str, text: str) -> None:
        # One call per severity: rclpy fixes a call site's severity at its first call.
        logger = self._node.get_logger()
        if level == "error":
            logger.error(text)
        elif level == "warning":
            logger.warning(text)
        elif level == "info":
            logger.info(text)
        else:
            logger.debug(text)

    def finished(self, outcome: RunOutcome) -> None:
        self._node._finished(outcome)

    def restarted(self, epoch: int, message: str, outcome: RunOutcome) -> None:
        self._node._restarted(epoch, outcome)


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
