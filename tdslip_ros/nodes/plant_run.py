"""The plant's run without ROS: the model's stepper advanced tick by tick, the commands and hip torques it
takes, and everything it emits, told to a :class:`PlantSink`.

The plant node (:mod:`tdslip_ros.nodes.plant_node`) owns the ROS side: publishers, subscriptions, timers,
the recorder's flow control and when to start. It drives a :class:`PlantRun` in its own process in lockstep,
and in realtime :mod:`tdslip_ros.nodes.tick_process` drives it at 1 kHz in a process of its own, whose sink
sends every call back to the node. Either way the calls reach the same sink, in the same order, so both
modes publish alike.

A run is not thread-safe: its driver calls it from one thread at a time (under a lock where several could).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Protocol

from rclpy.serialization import deserialize_message, serialize_message
from tdslip_msgs.msg import StanceCommand, Status

from tdslip_ros.model.events import Event, EventKind, StrideEnergy
from tdslip_ros.model.events import HopperState as ModelState
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.stance_laws import StanceFeedback
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.nodes.command_admission import LateCommand, RejectionLog, admit, command_key, not_yet
from tdslip_ros.nodes.realtime import MissedTicks, TickTiming
from tdslip_ros.nodes.torque_stream import TICK_NS, LateTorque, TorqueInput, torque_fields

TICK_PERIOD = TICK_NS / 1e9  # s, the plant's fixed step
SAMPLES_PER_BATCH = 10
"""Ticks per tdslip/samples message at most (and per write of the realtime tick process to the node): a
realtime recording trails the plant by up to 10 ms. Larger batches cost the tick that sends them more and gain
little in lockstep (``bench_nodes.py realtime`` and ``lockstep`` measure both; docs/benchmarks.md)."""
APEX_REPEAT = 2.5
"""Lockstep: wall time [s] after which an apex no command has answered is published again (repeat_apex):
longer than the suite's controllers may wait for discovery before their first answer (2 s), less than the
default command_timeout (5 s)."""


@dataclass(frozen=True)
class RunOutcome:
    """How a run ended: a Status kind (a FailureKind value, command_timeout, publish_failed, run_complete, or
    reset for a run a reset ended), when in simulated time [s] and after how much wall time since start()
    [s]."""

    kind: str
    reason: str
    stride: int
    sim_time: float
    wall_time: float

    @property
    def ok(self) -> bool:
        return bool(self.kind == Status.KIND_RUN_COMPLETE)


@dataclass(frozen=True)
class RunSettings:
    """What a run is given once: the hopper, its limits and perturbations, the command in force until the
    first answer, the clock mode and when the run ends by itself (0: never)."""

    hopper: HopperParams
    limits: PlausibilityLimits
    perturbations: Perturbations
    initial_command: ModelCommand
    lockstep: bool
    max_strides: int
    max_stale_strides: int
    torque_max_age_ticks: int


@dataclass(frozen=True)
class RunCounts:
    """What a run has counted so far, over its resets."""

    late_commands: int = 0
    """Realtime: strides whose answer arrived after their touchdown (never applied)."""
    rejected: int = 0
    """Commands and torques rejected, late answers included: each reported by a Status of its own, summed
    into a later one's ``(N more rejected ...)``, one of ``unreported_rejections``, or an earlier answer."""
    earlier_answers: int = 0
    """Rejected answers to earlier apexes (late, or of an earlier epoch): counted, never reported."""
    unreported_rejections: int = 0
    """Rejections since the latest report that the next report will sum (none has come yet)."""
    late_torques: int = 0
    """Hip torques that came after their tick was stepped or after their stance."""
    stale_torques: int = 0
    """Realtime: stance ticks that held zero, as no torque within the age bound had come."""
    saturated_strides: int = 0
    """Touchdowns of the current epoch whose |tau0| exceeded tau_max (the hip saturated)."""
    missed_ticks: MissedTicks | None = None
    """Realtime: the tick's counts of missed ticks (at the end of a run those of its closing summary)."""


@dataclass(frozen=True)
class ApexReport:
    """Apex ``stride`` of ``epoch`` at ``t`` [s]: the true state, the ``measured`` (height, speed) the
    controller's sensor reports, the ground of the stance before it and that stance's energy ``flows`` (None:
    zero, the initial apex)."""

    epoch: int
    stride: int
    t: float
    state: ModelState
    measured: tuple[float, float]
    ground: float
    flows: StrideEnergy | None


class PublishFailed(Exception):
    """A sink could not publish (its reason); the run ends with ``publish_failed``."""


class PlantSink(Protocol):
    """Where a run's output goes. The first group publishes; the rest tell the driver how the run goes."""

    @property
    def live(self) -> bool:
        """Someone takes each tick's samples live, at once (the tick process then writes every tick)."""

    def tick(self, state: ModelState, t: float, tick: int) -> None: ...

    def apex(self, report: ApexReport) -> None: ...

    def contact(self, epoch: int, event: Event, t: float) -> None: ...

    def status(self, epoch: int, stride: int, kind: str, reason: str, t: float, *, fatal: bool) -> None: ...

    def applied_torque(self, epoch: int, stride: int, tick: int, torque: float) -> None: ...

    def awaiting(self) -> None:
        """Lockstep: stepping paused for a command or a torque (the driver times the wait)."""

    def resumed(self) -> None:
        """Lockstep: what was awaited came; step on."""

    def command_applied(self, epoch: int, stride: int, applied_ns: int) -> None:
        """The first valid answer to apex (epoch, stride), applied at ``applied_ns`` (steady clock)."""

    def counted(self, counts: RunCounts) -> None:
        """The counts, at every apex, every rejection reported and at the end of a run."""

    def timed(self, timing: TickTiming) -> None:
        """Realtime: the tick's wall-clock timing, once a run is over and its last firing recorded."""

    def log(self, level: str, text: str) -> None:
        """A line for the node's log (``info``, ``warning`` or ``error``)."""

    def finished(self, outcome: RunOutcome) -> None: ...

    def restarted(self, epoch: int, message: str, outcome: RunOutcome) -> None:
        """A reset began epoch ``epoch`` (``outcome``: how the one before ended)."""


class PlantRun:
    """The TD-SLIP plant's run (module docstring): :meth:`start`, then :meth:`advance` (lockstep) or
    :meth:`advance_to` (realtime) steps it; :meth:`take_command`, :meth:`take_torque`, :meth:`reset`,
    :meth:`end` and :meth:`time_out` are what reaches it from outside."""

    def __init__(self, settings: RunSettings, apex: ApexState, sink: PlantSink) -> None:
        self.settings = settings
        self._sink = sink
        self.rejections = RejectionLog()
        self.late_commands = 0
        self.applied_torques = 0  # samples published on tdslip/applied_torque, over resets
        self.tick_timing = None if self.settings.lockstep else TickTiming(TICK_NS)
        self.torques = TorqueInput(
            lockstep=self.settings.lockstep,
            max_age_ticks=settings.torque_max_age_ticks,
            max_torque=settings.limits.max_torque,
        )
        self.running = False
        self.epoch = 0
        self.ticks = 0  # since construction, over resets: simulated time = ticks * TICK_PERIOD
        self.start_wall_ns = 0
        self._firing = False  # realtime: advance_to is stepping
        self._restart(apex, time_offset_ticks=0)

    @staticmethod
    def load_message_support() -> None:
        """Load what parsing a command needs now, not at the first command: its first parse loads the type
        support (docs/benchmarks.md)."""
        deserialize_message(serialize_message(StanceCommand()), StanceCommand)

    @property
    def sim_time(self) -> float:
        return self.ticks * TICK_PERIOD

    def counts(self) -> RunCounts:
        return RunCounts(
            late_commands=self.late_commands,
            rejected=self.rejections.total,
            earlier_answers=self.rejections.earlier_answers,
            unreported_rejections=self.rejections.suppressed,
            late_torques=self.torques.late,
            stale_torques=self.torques.stale,
            saturated_strides=self._stepper.saturated_strides,
            missed_ticks=None if self.tick_timing is None else self.tick_timing.counts(),
        )

    def _restart(self, apex: ApexState, time_offset_ticks: int) -> None:
        settings = self.settings
        self._stepper = FixedStepStepper(
            settings.hopper,
            apex,
            settings.initial_command,
            dt=TICK_PERIOD,
            limits=settings.limits,
            perturbations=settings.perturbations,
            trajectory=self.epoch,
        )
        self._offset_ticks = time_offset_ticks  # the run's first tick, due at start_wall_ns once it starts
        self._offset = time_offset_ticks * TICK_PERIOD
        self._applied_published = 0  # samples of the current stance published on tdslip/applied_torque
        self.torques.restart()
        self._awaiting: int | None = None
        self._last_apex: ApexReport | None = None  # as published, for repeat_apex
        self._heard_since_apex = False  # a command (any) came after the latest apex went out
        self._apex_repeated = False
        self._answered = -1  # the latest stride whose command was applied
        self._late_stride = -1  # the latest stride counted in late_commands
        self._stale_strides = 0  # realtime: strides in a row that no valid command answered

    # --- run control ----------------------------------------------------------------------------

    def start(self, start_wall_ns: int) -> None:
        """Publish the initial apex and sample; lockstep: wait for its command."""
        if self.running:
            return
        self.running = True
        self.start_wall_ns = start_wall_ns
        self._publish_apex(0, self._stepper.apex_state)
        state = self._stepper.state
        self._sink.tick(state, self._offset + state.t, self.ticks)
        if self.settings.lockstep:
            self._await_command()
        else:
            assert self.tick_timing is not None
            self.tick_timing.resume()

    def end(self, kind: str, reason: str, epoch: int | None = None) -> None:
        """End a running run now (e.g. complete at a caller's wall-time limit, or a failed publication); only
        if it is still in ``epoch``, when given (a reset may have come first)."""
        if self.running and epoch in (None, self.epoch):
            self._finish(kind, reason, self.sim_time)

    def reset(self, apex: ApexState) -> str:
        """Restart from ``apex`` (checked by the caller) in a new epoch, simulated time running on."""
        message = (
            f"reset to apex height {apex.y} m, forward speed {apex.xdot} m/s at t = {self.sim_time:.3f} s "
            f"(epoch {self.epoch + 1})"
        )
        self.running = False
        wall_time = (time.monotonic_ns() - self.start_wall_ns) * 1e-9
        ended = RunOutcome(Status.KIND_RESET, message, self._stepper.stride, self.sim_time, wall_time)
        self._status(Status.KIND_RESET, message, self.sim_time, fatal=False)
        self.epoch += 1
        self._restart(apex, time_offset_ticks=self.ticks)
        self._sink.restarted(self.epoch, message, ended)
        self._sink.log("info", message)
        self.start(time.monotonic_ns())
        return message

    def time_out(self, command_timeout: float) -> None:
        """Lockstep: nothing awaited came within ``command_timeout`` s."""
        awaited = self.torques.awaited
        if (self._awaiting is None and awaited is None) or not self.running:
            return
        rejected = self.rejections.total
        rejected_so_far = f"; {rejected} command(s) or torque(s) rejected so far" if rejected else ""
        what = (
            f"command for epoch {self.epoch}, stride {self._awaiting}"
            if awaited is None
            else f"hip torque for epoch {awaited[0]}, stride {awaited[1]}, tick {awaited[2]}"
        )
        self._finish(
            Status.KIND_COMMAND_TIMEOUT,
            f"no valid {what} within command_timeout = {command_timeout:g} s{rejected_so_far}",
            self._offset + self._stepper.t,
        )

    def _finish(self, kind: str, reason: str, t: float) -> None:
        self.running = False
        try:
            self._status(kind, reason, t, fatal=True)
        except PublishFailed as error:
            self._sink.log("error", f"the final status could not be published: {error}")
        wall_time = (time.monotonic_ns() - self.start_wall_ns) * 1e-9
        outcome = RunOutcome(kind, reason, self._stepper.stride, t, wall_time)
        stride = self._stepper.stride
        if self.tick_timing is not None:
            if not self._firing:  # else the firing ends the timing once it is recorded
                self._end_timing()
            if self.applied_torques:
                self._sink.log(
                    "info",
                    f"realtime: {self.torques.late} hip torque(s) came after their tick, "
                    f"{self.torques.stale} stance tick(s) held zero (no torque within torque_max_age)",
                )
            if self.late_commands:
                self._sink.log(
                    "warning",
                    f"realtime: {self.late_commands} command(s) arrived after their touchdown (the command "
                    "in force held)",
                )
        if self.settings.perturbations.saturates:
            self._sink.log("info", f"the hip saturated in {self._stepper.saturated_strides} stride(s)")
        if kind == Status.KIND_RUN_COMPLETE:
            self._sink.log("info", f"run complete at stride {stride}, t = {t:.3f} s: {reason}")
        else:
            self._sink.log("error", f"run ended at stride {stride}, t = {t:.6f} s: {kind}: {reason}")
        self._sink.counted(self.counts())
        self._sink.finished(outcome)

    # --- stepping -------------------------------------------------------------------------------

    def advance(self, ticks: int) -> bool:
        """Lockstep: step up to ``ticks`` ticks; True when stepping must pause (an awaited command or torque,
        the end of the run)."""
        for _ in range(ticks):
            if self._tick_or_fail():
                return True
        return False

    def advance_to(self, now_ns: int, busy_ns: int | None = None, busy_cpu_ns: int | None = None) -> None:
        """Realtime: step up to the latest tick due by ``now_ns`` of the steady clock (a late call catches up;
        none is stepped before its time, so simulated time never leads wall time), the caller at its own work
        for ``busy_ns`` past the deadline before, on a CPU for ``busy_cpu_ns`` of it (:class:`TickTiming`)."""
        deadline_ns = self.next_deadline_ns
        due = self._offset_ticks + (now_ns - self.start_wall_ns) // TICK_NS
        first = self.ticks
        self._firing = True
        while self.ticks < due and self.running:
            self._tick_or_fail()
        self._firing = False
        assert self.tick_timing is not None
        self.tick_timing.record(now_ns, self.ticks - first, deadline_ns, busy_ns, busy_cpu_ns)
        if first < self.ticks and not self.running:  # it ended in this firing
            self._end_timing()

    def _end_timing(self) -> None:
        """Realtime, the run over: the tick's timing, logged and told."""
        assert self.tick_timing is not None
        self.tick_timing.close_window()
        self._sink.log("info", f"realtime: {self.tick_timing.summary()}")
        self._sink.timed(self.tick_timing)
        self._sink.counted(self.counts())  # the missed ticks of the summary, the last firing's included

    @property
    def next_deadline_ns(self) -> int:
        """Realtime: when the next tick to step is due (steady clock); past already if the run is behind."""
        return self.start_wall_ns + (self.ticks - self._offset_ticks + 1) * TICK_NS

    def _tick_or_fail(self) -> bool:
        """:meth:`_tick`; a publication that fails ends the run with ``publish_failed``."""
        try:
            return self._tick()
        except PublishFailed as error:
            self._finish(Status.KIND_PUBLISH_FAILED, str(error), self.sim_time)
            return True

    def _tick(self) -> bool:
        stepper = self._stepper
        if not self.settings.lockstep and stepper.torque_due:  # lockstep: the awaited torque is held already
            stepper.hold_torque(self.torques.held(stepper.stride, self.ticks))
        events = stepper.step()
        self.ticks += 1
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
                self._sink.contact(self.epoch, event, self._offset + event.t)
        state = stepper.state
        self._sink.tick(state, self._offset + state.t, self.ticks)
        self._publish_applied_torques()
        if apex is None:
            if self.settings.lockstep and stepper.torque_due:
                self.torques.await_tick(self.epoch, stepper.stride, self.ticks)
                self._sink.awaiting()
                return True
            return False
        max_strides = self.settings.max_strides
        if apex.stride == max_strides:
            reason = f"reached max_strides = {max_strides}"
            self._finish(Status.KIND_RUN_COMPLETE, reason, self._offset + state.t)
            return True
        if self.settings.lockstep:
            self._await_command()
            return True
        return self._count_stale_stride(apex.stride)

    def _count_stale_stride(self, stride: int) -> bool:
        """Realtime: at the apex of ``stride``, was the previous stride answered? Too many unanswered
        in a row end the run (a dead or silent controller must not go unnoticed)."""
        self._stale_strides = 0 if self._answered == stride - 1 else self._stale_strides + 1
        limit = self.settings.max_stale_strides
        if limit and self._stale_strides >= limit:
            self._finish(
                Status.KIND_COMMAND_TIMEOUT,
                f"no valid command answered the last {self._stale_strides} strides (max_stale_strides)",
                self._offset + self._stepper.t,
            )
            return True
        return False

    def _await_command(self) -> None:
        self._awaiting = self._stepper.stride
        self._sink.awaiting()

    def repeat_apex(self) -> None:
        """Lockstep: publish the apex awaited again if no command at all has come since it went out. A
        controller that started after it, or had not yet discovered the plant's command subscription when
        it answered (discovery is not symmetric; a volatile writer never resends to a reader it matches
        later), then answers it. Logged once per apex."""
        if not self.running or self._awaiting is None or self._heard_since_apex or self._last_apex is None:
            return
        if not self._apex_repeated:
            self._apex_repeated = True
            self._sink.log(
                "info",
                f"no command for epoch {self.epoch}, stride {self._awaiting} yet: its apex is published "
                f"again every {APEX_REPEAT:g} s until one comes, for a controller that missed it",
            )
        self._sink.apex(self._last_apex)

    # --- commands and torques -------------------------------------------------------------------

    def take_command(self, data: bytes) -> None:
        """A serialised StanceCommand: applied if it answers the current apex and is admissible, else
        counted and (unless merely late) reported."""
        self._heard_since_apex = True
        key = command_key(data)
        current = (self.epoch, self._stepper.stride)
        # An answer to another apex is recognised from its bytes, unparsed: a flood of them costs next to
        # nothing and cannot delay the one the plant waits for.
        if key is not None and key != current:
            if key > current:
                reason = not_yet(key, *current)
                self._report_rejection(f"command for epoch {key[0]}, stride {key[1]} rejected: {reason}")
            else:
                self.rejections.count_earlier_answer()  # a late answer: counted, not reported
                if key[0] == self.epoch and key[1] > self._answered:
                    self._count_late(key[1])  # its stride never had a command: it missed the touchdown
            return
        msg = deserialize_message(data, StanceCommand)
        if not self.running:
            self._sink.log("debug", f"command for stride {msg.stride} ignored: no run in progress")
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
            self._sink.command_applied(msg.epoch, msg.stride, time.monotonic_ns())
            self._answered = msg.stride
        if self.settings.lockstep:
            self._awaiting = None
            self._sink.resumed()

    def _count_late(self, stride: int) -> None:
        """Count a stride in late_commands once, however many late answers it gets."""
        if stride != self._late_stride:
            self._late_stride = stride
            self.late_commands += 1

    def _apply(self, msg: StanceCommand) -> None:
        """Admit a command and hand it to the stepper; ParameterError gives the reason to refuse it."""
        stride = self._stepper.stride
        try:
            command = admit(
                msg,
                epoch=self.epoch,
                stride=stride,
                lockstep=self.settings.lockstep,
                awaiting=self._awaiting,
                past_touchdown=self._stepper.past_touchdown,
                limits=self.settings.limits,
            )
        except LateCommand:
            self._count_late(stride)
            raise
        self._stepper.set_command(command)

    def take_torque(self, data: bytes) -> None:
        """A serialised HipTorque, judged by :class:`~tdslip_ros.nodes.torque_stream.TorqueInput`."""
        if not self.running:
            return
        fields = torque_fields(data)
        if fields is None:
            self._report_rejection("hip torque rejected: not a HipTorque", Status.KIND_TORQUE_REJECTED)
            return
        stepper = self._stepper
        try:
            self.torques.take(
                fields,
                epoch=self.epoch,
                stride=stepper.stride,
                tick=self.ticks,
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
        if self.settings.lockstep:  # the awaited torque: hold it and step on
            stepper.hold_torque(fields.torque)
            self._sink.resumed()

    def _report_rejection(self, reason: str, kind: str = Status.KIND_COMMAND_REJECTED) -> None:
        """Log and report a rejection (at most REJECTION_REPORTS per period, the rest summed)."""
        prefix = self.rejections.admit(time.monotonic_ns())
        if prefix is not None:
            self._sink.log("warning", prefix + reason)
            self._status(kind, prefix + reason, self._offset + self._stepper.t, fatal=False)
            self._sink.counted(self.counts())

    # --- output ---------------------------------------------------------------------------------

    def _publish_apex(self, stride: int, state: ModelState) -> None:
        stepper = self._stepper
        flows = stepper.last_stride_energy if stride > 0 else None
        report = ApexReport(
            self.epoch, stride, self._offset + state.t, state, stepper.measured_apex, stepper.ground, flows
        )
        self._last_apex, self._heard_since_apex, self._apex_repeated = report, False, False
        self._sink.apex(report)
        self._sink.counted(self.counts())

    def _publish_applied_torques(self) -> None:
        """The stance's torques sampled since the last call, as held (tdslip/applied_torque): the record
        from which the analysis replays the stance (none under a ramp)."""
        if not isinstance(self._stepper.command, StanceFeedback):
            return
        samples = self._stepper.stance_torques
        for t, torque in samples[self._applied_published :]:
            tick = self._offset_ticks + round(t / TICK_PERIOD)
            self._sink.applied_torque(self.epoch, self._stepper.stride, tick, torque)
            self.applied_torques += 1
        self._applied_published = len(samples)

    def _status(self, kind: str, reason: str, t: float, *, fatal: bool) -> None:
        self._sink.status(self.epoch, self._stepper.stride, kind, reason, t, fatal=fatal)


class LockedRun:
    """Lockstep: a run stepped in the node's process, reached as the realtime run in its tick process is
    (:class:`~tdslip_ros.nodes.tick_process.TickProcess`), each call under ``lock``, which the node's timers
    that step it take too."""

    def __init__(self, run: PlantRun, lock: threading.Lock) -> None:
        self._run = run
        self._lock = lock

    def start(self, start_wall_ns: int) -> None:
        with self._lock:
            self._run.start(start_wall_ns)

    def take_command(self, data: bytes) -> None:
        with self._lock:
            self._run.take_command(data)

    def take_torque(self, data: bytes) -> None:
        with self._lock:
            self._run.take_torque(data)

    def end(self, kind: str, reason: str) -> None:
        with self._lock:
            self._run.end(kind, reason)

    def reset(self, apex: ApexState) -> str:
        with self._lock:
            return self._run.reset(apex)

    def pause(self) -> None:
        """Nothing to do: the node's timers, which step this run, are held."""

    def resume(self) -> None:
        """Nothing to do: the node's timers run again."""
