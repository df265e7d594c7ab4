"""The soak: the realtime suite for an hour under fire, all at once (issue 35). One command:

    .venv/bin/python bench/bench_soak.py [--duration 3600] [--seed 1] [--realtime-priority 50] [--out DIR]
                                         [--json FILE]
    .venv/bin/python bench/bench_soak.py lockstep [--strides 20000] [--out DIR] [--json FILE]

The second is the long run bounded: a recorded lockstep run of 20,000 strides (about 2 hours simulated,
a bag of about 1 GB), its processes sampled as below, then ``tdslip analyze`` of its bag (time against
0.01 x the recording, and its peak RSS).

``tdslip run``'s realtime plant and recorder run as ``tdslip run`` runs them (the plant in this process,
the recorder in a child). Beside them, each in a process of its own on the run's ROS domain:

* **a hostile controller** (:class:`HostileController`, default QoS): it mostly answers each apex with
  energy regulation, but also sends bursts of answers to wrong epochs and strides, NaN and out-of-range
  commands, duplicates, answers 0.2-0.6 s late, stays silent for a stride, and now and then resets the
  plant (from its apex callback, so that no answer of its own is in flight). For stretches of 3-8
  strides it answers with stance feedback and streams the suite's stance PD law at 1 kHz, some torques
  dropped and some sent a tick late. Its ``touchdown_angle`` is a parameter, set at runtime;
* **yesterday's recording replayed**: a short lockstep run recorded first in namespace ``/yesterday``,
  replayed over and over (``tdslip replay``) on the same domain;
* **a viewer that stalls**: a reliable subscriber to ``tdslip/state`` that sleeps 2-5 s every 30 s;
* **a chaos agent** (:class:`ChaosAgent`): at random times it sets parameters at runtime (valid values,
  and out-of-range ones that must be refused) and pauses and resumes the plant and the recorder through
  their lifecycle; it also keeps every ``tdslip/status`` and the latest ``/diagnostics`` of each node.

Every 10 s the RSS, open descriptors and threads of every process are sampled from /proc. At the end it
prints, each against its target:

* per topic, the messages published, recorded (over every bag the recorder's pauses made) and dropped
  while the recorder was paused (the recorder's count, in its last bag's metadata): lost, 0;
* every command and torque the hostile controller sent, by kind, beside the Statuses that refused them;
  the plant's rejections, each accounted for by a Status of its own, the sum a later one carries, or as an
  answer to an earlier apex;
* the realtime tick's missed ticks by cause: 0 unexplained;
* the slopes of RSS and descriptors of every process after the warm-up (the first 5 minutes, a fifth of a
  shorter run): under 1 MiB per 10 minutes;
* whether every bag is finalised and valid, and whether ``tdslip analyze`` reads the first bag that holds
  one run (it refuses a recording in which the plant was reset), with its time and peak memory;
* the parameter changes and transitions asked for, and their answers.

``--json FILE`` writes the same figures (test/test_nodes_soak.py runs a short soak and asserts its
invariants from them). The machine's load average and the CPU time its hypervisor stole are printed beside
the timings. Results: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.task import Future
from tdslip_msgs.msg import ApexEvent, HipTorque, HopperState, StanceCommand, Status
from tdslip_msgs.srv import Reset

from tdslip_ros.bag.reader import open_bag, verify
from tdslip_ros.model.dynamics import apex_energy
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.plant.stance_laws import StanceSample, clip_torque
from tdslip_ros.model.policies.registry import SETTING_DEFAULTS, STANCE_PD_SPEED_ENERGY, PolicySpec
from tdslip_ros.nodes import isolation, topics
from tdslip_ros.nodes.recorder_node import DROPPED_WHILE_PAUSED_KEY
from tdslip_ros.nodes.runner import RunError, RunOptions, RunReport, read_bag_counts, run
from tdslip_ros.nodes.torque_stream import tick_of

FULL_PACE = 600.0
"""s: a soak at least this long runs the actors at the pace below; a shorter one scales their periods down
(a 60 s soak pauses, stalls and samples ten times as often)."""
SAMPLE_PERIOD = 10.0  # s between two samples of every process's RSS, descriptors and threads
WARM_UP = 300.0  # s before the slopes are measured (a fifth of a shorter run)
SLOPE_TARGET_MIB = 1.0  # per 10 minutes
ANALYZE_TARGET = 0.01  # of the recording's length
INITIAL_APEX = (1.0, 5.0)  # m, m/s: tdslip run's default
HOPPER = PAPER_PARAMS  # tdslip run's default hopper (config/plant.yaml)
CHAOS_PERIOD = 15.0  # s, the mean time between two of the chaos agent's actions
CHAOS_QUIET_END = 20.0  # s before the end in which the chaos agent changes nothing
HELPER_STOP_TIMEOUT = 20.0  # s
SUMMED = re.compile(r"\((\d+) more rejected")

# What the hostile controller does at an apex, and how often (the rest: a good answer). An apex it leaves
# unanswered is followed by an answered one: the plant ends a run after max_stale_strides (3) in a row.
BEHAVIOURS = {
    "burst": 0.08,  # 2-5 bad commands, then the good answer
    "bad_only": 0.03,  # one bad command and nothing else
    "duplicate": 0.05,  # the good answer three times
    "late": 0.04,  # the good answer 0.2-0.6 s after the apex
    "silent": 0.03,  # nothing
    "feedback": 0.03,  # a stretch of FEEDBACK_STRETCH strides of stance feedback begins
    "reset": 0.004,  # no answer; the plant is reset to the initial apex
}
HOSTILE_TOPICS = (f"/{topics.COMMAND}", f"/{topics.HIP_TORQUE}")
BAD_KINDS = ("nan", "out_of_range", "wrong_epoch", "wrong_stride")
REFUSAL_WORDS = {  # what the plant's Status reason says of each bad kind
    "nan": "must be a finite number",
    "out_of_range": "touchdown_angle",
    "wrong_epoch": "the run is in epoch",
    "wrong_stride": "the latest apex is stride",
    "late": "arrived after the touchdown",
}
TORQUE_DROP, TORQUE_DELAY = 0.02, 0.02  # of the streamed torques
FEEDBACK_STRETCH = (3, 8)  # strides
SAFE_ENERGY = 0.9
"""Of the target: below it the hostile controller answers its best until the energy is back. Under load about
half of the streamed torques come too late for their tick and the plant holds zero (stale), so a long stretch
of stance feedback loses energy stride by stride; the soak is of the suite, not of this controller's gait."""
STALL_EVERY, STALL_SECONDS = 30.0, (2.0, 5.0)  # s


# --- the actors, each in a process of its own -----------------------------------------------------


class HostileController(Node):
    """Answers the plant's apexes, mostly well (module docstring); counts what it sent, by kind."""

    def __init__(self, seed: int) -> None:
        super().__init__("hostile_controller")
        self.rng = random.Random(seed)
        self.declare_parameter("touchdown_angle", math.radians(20.0))
        self.target_energy = float(apex_energy(HOPPER.m, HOPPER.g, *INITIAL_APEX))
        self.feedback = PolicySpec.default(STANCE_PD_SPEED_ENERGY).stance_feedback(HOPPER)
        self.max_torque = PlausibilityLimits.for_hopper(HOPPER).max_torque
        self.plan(*INITIAL_APEX)  # the policy's kernels loaded before the first apex
        self.sent: Counter[str] = Counter()
        self.sent_at_last_apex: Counter[str] = Counter()  # bad commands: they may come after the run's end
        self.commands = self.create_publisher(StanceCommand, topics.COMMAND, 10)
        self.torques = self.create_publisher(HipTorque, topics.HIP_TORQUE, 10)
        self.reset_client = self.create_client(Reset, topics.RESET_SERVICE)
        self.create_subscription(ApexEvent, topics.APEX, self.on_apex, 10)
        self.create_subscription(HopperState, topics.STATE, self.on_state, 10)
        self.create_subscription(Status, topics.STATUS, self.on_status, 10)
        self.run_ended = Future()
        self.answered_last = True
        self.stretch = 0  # strides of stance feedback left
        self.streaming: tuple[int, int] | None = None  # the (epoch, stride) whose stance takes torques
        self.delayed: HipTorque | None = None

    def on_status(self, status: Status) -> None:
        if status.fatal and not self.run_ended.done():
            self.run_ended.set_result(status.kind)

    def publish_command(self, command: StanceCommand) -> None:
        self.commands.publish(command)
        self.sent[topics.COMMAND] += 1

    def publish_torque(self, torque: HipTorque) -> None:
        self.torques.publish(torque)
        self.sent[topics.HIP_TORQUE] += 1

    def plan(self, height: float, speed: float) -> Any:
        settings = {
            **SETTING_DEFAULTS,
            "target_energy": self.target_energy,
            "touchdown_angle": self.get_parameter("touchdown_angle").value,
        }
        return PolicySpec.of("energy", settings).commands(HOPPER, height, speed, speed).command()

    def on_apex(self, apex: ApexEvent) -> None:
        self.sent_at_last_apex.clear()
        try:
            planned = self.plan(apex.measured_height - apex.ground_height, apex.measured_forward_speed)
        except ValueError:  # no command at this apex (NoCommandError): the plant holds the one in force
            self.sent["no command found"] += 1
            self.answered_last = False
            return
        good = StanceCommand(
            epoch=apex.epoch,
            stride=apex.stride,
            touchdown_angle=planned.touchdown_angle,
            tau0=planned.tau0,
            t_f=planned.t_f,
            policy="hostile",
        )
        behaviour = "good"
        if self.stretch > 0:
            self.stretch -= 1
            behaviour = "feedback"
        elif self.answered_last:
            draw = self.rng.random()
            for name, share in BEHAVIOURS.items():
                if draw < share:
                    behaviour = name
                    break
                draw -= share
            if behaviour == "feedback":
                self.stretch = self.rng.randint(*FEEDBACK_STRETCH) - 1  # the strides after this one
        if (
            apex.energy < SAFE_ENERGY * self.target_energy
        ):  # hostile, not fatal: energy regulation restores it
            behaviour, self.stretch = "good", 0
        self.answered_last = behaviour in ("good", "burst", "duplicate", "feedback")
        if behaviour == "burst":
            for _ in range(self.rng.randint(2, 5)):
                self.send_bad(good)
        if behaviour in ("good", "burst", "duplicate"):
            for _ in range(3 if behaviour == "duplicate" else 1):
                self.publish_command(good)
            self.sent[behaviour if behaviour == "duplicate" else "good"] += 1
        elif behaviour == "feedback":
            good.touchdown_angle, good.tau0, good.t_f = self.feedback.touchdown_angle, 0.0, 0.0
            good.stance = StanceCommand.STANCE_FEEDBACK
            self.streaming = (apex.epoch, apex.stride)
            self.publish_command(good)
            self.sent["stance feedback"] += 1
        elif behaviour == "late":
            timer = self.create_timer(self.rng.uniform(0.2, 0.6), lambda: self.send_late(timer, good))
        elif behaviour == "bad_only":
            self.send_bad(good)
        elif behaviour == "silent":
            self.sent["silent"] += 1
        else:  # reset: no answer of ours is on its way to the run that ends
            self.reset_client.call_async(Reset.Request(height=INITIAL_APEX[0], forward_speed=INITIAL_APEX[1]))
            self.sent["reset"] += 1
            self.streaming = None

    def send_bad(self, good: StanceCommand) -> None:
        kind = self.rng.choice(BAD_KINDS)
        bad = StanceCommand(
            epoch=good.epoch,
            stride=good.stride,
            touchdown_angle=good.touchdown_angle,
            tau0=good.tau0,
            t_f=good.t_f,
            policy="hostile",
        )
        if kind == "nan":
            bad.tau0 = math.nan
        elif kind == "out_of_range":
            bad.touchdown_angle = 3.0  # rad, beyond pi/2
        elif kind == "wrong_epoch":
            bad.epoch += 3  # ahead of the plant: reported (an earlier epoch's is only counted)
        else:
            bad.stride += 7
        self.publish_command(bad)
        self.sent[kind] += 1
        self.sent_at_last_apex[kind] += 1

    def send_late(self, timer: Any, good: StanceCommand) -> None:
        self.destroy_timer(timer)
        if self.run_ended.done():
            # ``tdslip run`` stops its recorder once no command has come for QUIET (0.2 s) after the run's
            # end, so an answer sent later is nobody's to record (one was counted lost in a 600 s soak).
            self.sent["late, after the run's end: not sent"] += 1
            return
        self.publish_command(good)
        self.sent["late"] += 1

    def on_state(self, state: HopperState) -> None:
        if self.delayed is not None:  # one tick late
            self.publish_torque(self.delayed)
            self.delayed = None
            self.sent["torque a tick late"] += 1
        if state.phase != HopperState.PHASE_STANCE or self.streaming is None:
            return
        epoch, stride = self.streaming
        if state.stride != stride:
            return
        stamp = state.header.stamp
        sample = StanceSample(
            stamp.sec + stamp.nanosec * 1e-9,
            math.nan,  # the time since touchdown, which the baseline does not read
            state.leg_length,
            state.leg_angle,
            state.leg_length_rate,
            state.leg_angle_rate,
            state.hip_torque,
        )
        torque = HipTorque(
            header=state.header,
            epoch=epoch,
            stride=state.stride,
            tick=tick_of(stamp.sec, stamp.nanosec),
            torque=clip_torque(float(self.feedback.law.torque(sample)), self.max_torque),
        )
        draw = self.rng.random()
        if draw < TORQUE_DROP:
            self.sent["torque dropped"] += 1
        elif draw < TORQUE_DROP + TORQUE_DELAY:
            self.delayed = torque
        else:
            self.publish_torque(torque)
            self.sent["torque"] += 1


class StalledViewer(Node):
    """A reliable subscriber to tdslip/state that stalls for seconds at a time."""

    def __init__(self, seed: int, pace: float) -> None:
        super().__init__("stalled_viewer")
        self.rng = random.Random(seed)
        self.pace = pace
        self.received = 0
        self.stalls: list[float] = []
        self.next_stall = time.monotonic() + STALL_EVERY * pace
        self.create_subscription(HopperState, topics.STATE, self.on_state, 10)

    def on_state(self, _: HopperState) -> None:
        self.received += 1
        if time.monotonic() >= self.next_stall:
            seconds = self.rng.uniform(*STALL_SECONDS) * self.pace
            time.sleep(seconds)
            self.stalls.append(seconds)
            self.next_stall = time.monotonic() + STALL_EVERY * self.pace


class ChaosAgent(Node):
    """Runtime parameters and lifecycle transitions at random times; the Statuses and diagnostics heard."""

    def __init__(self, seed: int, pace: float, quiet_after: float) -> None:
        super().__init__("chaos_agent")
        self.rng = random.Random(seed)
        self.period = CHAOS_PERIOD * pace
        self.quiet_at = time.monotonic() + quiet_after
        self.asked: Counter[str] = Counter()
        self.answers: Counter[str] = Counter()
        self.statuses: Counter[str] = Counter()
        self.refusals: Counter[str] = Counter()
        self.summed = 0
        self.other_reasons: list[str] = []
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.parameters = {
            name: AsyncParameterClient(self, name) for name in ("plant", "recorder", "hostile_controller")
        }
        self.lifecycle = {
            name: self.create_client(ChangeState, f"/{name}/change_state") for name in ("plant", "recorder")
        }
        self.paused: set[str] = set()
        self.started = False
        self.create_subscription(ApexEvent, topics.APEX, self.on_apex, 10)
        self.create_subscription(Status, topics.STATUS, self.on_status, topics.STREAM_QOS)
        self.create_subscription(
            DiagnosticArray, topics.DIAGNOSTICS, self.on_diagnostics, topics.DIAGNOSTICS_QOS
        )
        self.timer = self.create_timer(1.0, self.act)
        self.next_action = math.inf

    def on_apex(self, _: ApexEvent) -> None:
        if not self.started:
            self.started = True
            self.next_action = time.monotonic() + self.rng.expovariate(1.0 / self.period)

    def on_status(self, status: Status) -> None:
        self.statuses[status.kind] += 1
        if status.kind not in (Status.KIND_COMMAND_REJECTED, Status.KIND_TORQUE_REJECTED):
            return
        if found := SUMMED.match(status.reason):
            self.summed += int(found.group(1))
        kind = next((k for k, words in REFUSAL_WORDS.items() if words in status.reason), None)
        if kind is None:
            kind = "other"
            if len(self.other_reasons) < 10:
                self.other_reasons.append(status.reason)
        self.refusals[f"{status.kind}: {kind}"] += 1

    def on_diagnostics(self, array: DiagnosticArray) -> None:
        for status in array.status:
            self.diagnostics[status.name] = {pair.key: pair.value for pair in status.values}

    def act(self) -> None:
        now = time.monotonic()
        if now < self.next_action or now > self.quiet_at:
            return
        self.next_action = now + self.rng.expovariate(1.0 / self.period)
        action = self.rng.choice(("parameter", "refused parameter", "pause plant", "pause recorder"))
        if action == "parameter":
            node, name, value = self.rng.choice(
                (
                    ("hostile_controller", "touchdown_angle", math.radians(self.rng.uniform(19.0, 22.0))),
                    ("plant", "diagnostics_warn_rejected", self.rng.randrange(0, 1000)),
                    ("recorder", "diagnostics_warn_lost", self.rng.randrange(0, 1000)),
                )
            )
            self.set_parameter(f"set {node} {name}", node, name, value, expected=True)
        elif action == "refused parameter":
            node, name, value = self.rng.choice(
                (("plant", "diagnostics_warn_rejected", -5), ("plant", "max_strides", 7))  # range; read-only
            )
            self.set_parameter(f"refused {node} {name}", node, name, value, expected=False)
        else:
            self.pause(action.removeprefix("pause "), self.rng.uniform(0.5, 3.0))

    def set_parameter(self, label: str, node: str, name: str, value: Any, expected: bool) -> None:
        client = self.parameters[node]
        if not client.services_are_ready():
            self.answers[f"{label}: service not ready"] += 1
            return
        self.asked[label] += 1
        future = client.set_parameters([Parameter(name, value=value)])

        def answered(done: Future) -> None:
            result = done.result()
            success = bool(result is not None and result.results[0].successful)
            self.answers[f"{label}: {'as expected' if success == expected else 'NOT as expected'}"] += 1

        future.add_done_callback(answered)

    def pause(self, node: str, seconds: float) -> None:
        if node in self.paused or not self.lifecycle[node].service_is_ready():
            return
        self.paused.add(node)
        self.transition(node, "deactivate")

        def resume() -> None:
            self.destroy_timer(timer)
            self.transition(node, "activate", then=lambda: self.paused.discard(node))

        timer = self.create_timer(seconds, resume)

    def transition(self, node: str, label: str, then: Callable[[], None] | None = None) -> None:
        self.asked[f"{label} {node}"] += 1
        future = self.lifecycle[node].call_async(ChangeState.Request(transition=Transition(label=label)))

        def answered(done: Future) -> None:
            result = done.result()
            self.answers[
                f"{label} {node}: {'done' if result is not None and result.success else 'REFUSED'}"
            ] += 1
            if then is not None:
                then()

        future.add_done_callback(answered)

    def report(self) -> dict[str, Any]:
        return {
            "asked": dict(self.asked),
            "answers": dict(self.answers),
            "statuses": dict(self.statuses),
            "refusals": dict(self.refusals),
            "summed": self.summed,
            "other_reasons": self.other_reasons,
            "diagnostics": self.diagnostics,
        }


def actor_main(arguments: argparse.Namespace) -> int:
    """An actor's process: its node until SIGINT or the plant's run's end; its report as JSON."""
    report: dict[str, Any] = {}
    try:
        with rclpy.init():
            if arguments.role == "hostile":
                node: Node = HostileController(arguments.seed)
                done = node.run_ended
            elif arguments.role == "viewer":
                node, done = StalledViewer(arguments.seed, arguments.pace), Future()
            else:
                node, done = ChaosAgent(arguments.seed, arguments.pace, arguments.quiet_after), Future()
            try:
                rclpy.spin_until_future_complete(node, done)
            finally:
                if isinstance(node, HostileController):
                    report = {"sent": node.sent, "sent_at_last_apex": node.sent_at_last_apex}
                elif isinstance(node, StalledViewer):
                    report = {"received": node.received, "stalls": node.stalls}
                else:
                    report = node.report()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    Path(arguments.report).write_text(json.dumps(report))
    return 0


# --- the bench --------------------------------------------------------------------------------------


def load() -> str:
    return "load average " + " ".join(f"{value:.2f}" for value in os.getloadavg())


def steal_seconds() -> float:
    """CPU time the hypervisor gave to others while this VM wanted it (Linux /proc/stat, all CPUs)."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    return int(fields[8]) / os.sysconf("SC_CLK_TCK")


def descendants(root: int) -> list[int]:
    """``root`` and every process below it."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            parent = int(stat.rsplit(")", 1)[1].split()[1])
            parents.setdefault(parent, []).append(int(entry.name))
    found, frontier = [root], [root]
    while frontier:
        children = parents.get(frontier.pop(), [])
        found += children
        frontier += children
    return found


def label_of(pid: int, own: int) -> str | None:
    """What process ``pid`` is in the soak (None: one of no interest)."""
    if pid == own:
        return "plant (tdslip run)"
    try:
        comm = Path(f"/proc/{pid}/comm").read_text().strip()
        command = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return None
    if comm == "tdslip-tick":
        return "tick process"
    if "recorder_node" in command:
        return "recorder"
    for role in ("hostile", "viewer", "chaos"):
        if f"bench_soak.py {role}" in command:
            return {"hostile": "hostile controller", "viewer": "stalled viewer", "chaos": "chaos agent"}[role]
    return "replay" if " replay " in command else None


def sample_process(pid: int) -> tuple[float, int, int] | None:
    """(RSS [MiB], open descriptors, threads) of ``pid``, or None if it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        descriptors = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
    return int(fields["VmRSS"].split()[0]) / 1024.0, descriptors, int(fields["Threads"])


class Sampler(threading.Thread):
    """Every ``period`` s, (time, RSS, descriptors, threads) of every process of the soak, by label."""

    def __init__(self, period: float) -> None:
        super().__init__(name="soak-sampler", daemon=True)
        self.period = period
        self.samples: dict[str, list[tuple[float, float, int, int]]] = {}
        self.stop = threading.Event()
        self.start_time = time.monotonic()

    def run(self) -> None:
        own = os.getpid()
        while not self.stop.wait(0 if not self.samples else self.period):
            now = time.monotonic() - self.start_time
            for pid in descendants(own):
                label = label_of(pid, own)
                if label is None or label == "replay":  # a replay lives for a minute: no slope of its own
                    continue
                if (sample := sample_process(pid)) is not None:
                    self.samples.setdefault(label, []).append((now, *sample))

    def slopes(self, warm_up: float) -> dict[str, dict[str, float]]:
        """Per process: RSS [MiB] and descriptors per 10 minutes after ``warm_up`` s (least squares),
        with the first and last RSS and the thread counts."""
        result = {}
        for label, rows in self.samples.items():
            kept = np.array([row for row in rows if row[0] >= warm_up])
            if len(kept) < 3:
                continue
            result[label] = {
                "rss_mib_per_10min": float(np.polyfit(kept[:, 0], kept[:, 1], 1)[0] * 600.0),
                "descriptors_per_10min": float(np.polyfit(kept[:, 0], kept[:, 2], 1)[0] * 600.0),
                "rss_first_mib": float(rows[0][1]),
                "rss_last_mib": float(rows[-1][1]),
                "descriptors_min": int(kept[:, 2].min()),
                "descriptors_max": int(kept[:, 2].max()),
                "threads_min": int(kept[:, 3].min()),
                "threads_max": int(kept[:, 3].max()),
                "samples": len(kept),
            }
        return result


class Replayer(threading.Thread):
    """``tdslip replay`` of yesterday's bag, over and over, until stopped."""

    def __init__(self, bag: Path, environment: dict[str, str]) -> None:
        super().__init__(name="soak-replay", daemon=True)
        self.bag, self.environment = bag, environment
        self.stop = threading.Event()
        self.exits: Counter[int] = Counter()
        self.process: subprocess.Popen[bytes] | None = None

    def run(self) -> None:
        while not self.stop.is_set():
            self.process = subprocess.Popen(
                [sys.executable, "-m", "tdslip_ros.commands.cli", "replay", str(self.bag)],
                env=self.environment,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            self.exits[self.process.wait()] += 1

    def end(self) -> None:
        self.stop.set()
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        self.join(HELPER_STOP_TIMEOUT)


def start_actor(
    role: str, arguments: list[str], environment: dict[str, str], out: Path
) -> subprocess.Popen[bytes]:
    log = (out / f"{role}.log").open("wb")
    return subprocess.Popen(
        [sys.executable, __file__, role, "--report", str(out / f"{role}.json"), *arguments],
        env=environment,
        stdout=log,
        stderr=subprocess.STDOUT,
    )


def stop_actor(process: subprocess.Popen[bytes]) -> int:
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    try:
        return process.wait(HELPER_STOP_TIMEOUT)
    except subprocess.TimeoutExpired:
        process.kill()
        return process.wait()


def analyze(bag: Path, out: Path) -> dict[str, Any]:
    """``tdslip analyze`` of the run: its exit status, wall time and peak RSS (its own, from wait4)."""
    start = time.monotonic()
    process = subprocess.Popen(
        [sys.executable, "-m", "tdslip_ros.commands.cli", "analyze", str(bag), "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    error = process.stderr.read().decode() if process.stderr else ""
    return {
        "exit": process.returncode,
        "seconds": time.monotonic() - start,
        "peak_rss_mib": usage.ru_maxrss / 1024.0,
        "error": error.strip().splitlines()[-1:] if process.returncode else [],
    }


def analyze_one_run(bags: list[Path], out: Path) -> dict[str, Any]:
    """:func:`analyze` of the first bag that holds one run: ``tdslip analyze`` refuses by name a recording in
    which the plant was reset (analysis/decoding.py, "several runs"), and the hostile controller resets it
    about once a minute."""
    for index, bag in enumerate(bags):
        analysis = analyze(bag, out)
        several_runs = analysis["exit"] != 0 and any("several runs" in line for line in analysis["error"])
        if not several_runs or index == len(bags) - 1:  # (the last one's refusal is the figure)
            break
    return analysis | {"bag": bag.name, "skipped_for_resets": [skipped.name for skipped in bags[:index]]}


def bags_of(run_bag: Path) -> list[Path]:
    """The recorder's bags of a run: ``run``, then ``run_2``, ``run_3``, ... (one per activation)."""
    bags, index = [run_bag], 2
    while (candidate := run_bag.with_name(f"{run_bag.name}_{index}")).exists():
        bags.append(candidate)
        index += 1
    return bags


def soak(arguments: argparse.Namespace) -> dict[str, Any]:
    out = Path(arguments.out or tempfile.mkdtemp(prefix="tdslip-soak-"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"soak of {arguments.duration:g} s, seed {arguments.seed}, in {out}", flush=True)
    yesterday = run(RunOptions(out / "yesterday", strides=20, namespace="/yesterday"))
    with isolation.reserved_domain() as domain_id:
        pass  # a free id, for the run and the actors
    environment = isolation.isolated_environment(domain_id)
    pace = min(1.0, arguments.duration / FULL_PACE)
    common = ["--seed", str(arguments.seed), "--pace", str(pace)]
    quiet_after = ["--quiet-after", str(arguments.duration - CHAOS_QUIET_END)]
    actors = {
        "hostile": start_actor("hostile", common, environment, out),
        "viewer": start_actor("viewer", common, environment, out),
        "chaos": start_actor("chaos", common + quiet_after, environment, out),
    }
    replayer = Replayer(yesterday.bag, environment)
    sampler = Sampler(SAMPLE_PERIOD * pace)
    steal_before, wall_before = steal_seconds(), time.monotonic()
    run_bag = out / "run"
    report: RunReport | None = None
    try:
        sampler.start()
        replayer.start()

        def progress(apex: ApexEvent) -> None:
            if apex.stride % 500 == 0:
                elapsed = time.monotonic() - wall_before
                print(f"  {elapsed:7.0f} s: epoch {apex.epoch}, stride {apex.stride}; {load()}", flush=True)

        report = run(
            RunOptions(
                run_bag,
                strides=0,
                mode="realtime",
                duration=arguments.duration,
                own_controller=True,
                controller_wait=120.0,
                domain_id=domain_id,
                realtime_priority=arguments.realtime_priority,
            ),
            progress,
        )
    finally:
        sampler.stop.set()
        replayer.end()
        exits = {role: stop_actor(process) for role, process in actors.items()}
    steal = steal_seconds() - steal_before
    reports = {role: json.loads((out / f"{role}.json").read_text()) for role in actors}
    return summarise(arguments, report, reports, exits, sampler, replayer, run_bag, out, steal, wall_before)


def summarise(
    arguments: argparse.Namespace,
    report: RunReport,
    reports: dict[str, Any],
    exits: dict[str, int],
    sampler: Sampler,
    replayer: Replayer,
    run_bag: Path,
    out: Path,
    steal: float,
    wall_start: float,
) -> dict[str, Any]:
    chaos, hostile = reports["chaos"], reports["hostile"]["sent"]
    recorder_diagnostics = chaos["diagnostics"].get("/recorder", {})
    bags = bags_of(run_bag)
    finalised = all((bag / "metadata.yaml").is_file() for bag in bags)
    opened = [open_bag(bag) for bag in bags]
    for bag in opened:
        verify(bag)
    # The last bag's metadata holds the recorder's total (the diagnostics the chaos agent heard last may be
    # older than the recorder's last count).
    dropped_per_topic = json.loads(opened[-1].custom_data.get(DROPPED_WHILE_PAUSED_KEY, "{}"))
    dropped = sum(dropped_per_topic.values())
    recorded: Counter[str] = Counter()
    for bag in bags:
        recorded.update(read_bag_counts(bag))
    # The plant counts what it published and what it received; the commands and torques were published by
    # the hostile controller, which counted them itself.
    published = dict(report.published)
    for topic in HOSTILE_TOPICS:
        published[topic] = hostile.get(topic.lstrip("/"), 0)
    topics_table = {
        topic: {
            "published": n,
            "recorded": recorded.get(topic, 0),
            "dropped": dropped_per_topic.get(topic, 0),
            "plant": report.published.get(topic),
        }
        for topic, n in sorted(published.items())
    }
    lost = sum(row["published"] - row["recorded"] - row["dropped"] for row in topics_table.values())
    counts = report.counts
    reported = sum(n for kind, n in chaos["refusals"].items())
    accounted = reported + chaos["summed"] + counts.earlier_answers + counts.unreported_rejections
    missed = counts.missed_ticks
    warm_up = min(WARM_UP, arguments.duration / 5.0)
    slopes = sampler.slopes(warm_up)
    analysis = analyze_one_run(bags, out / "analysis")
    length = report.apexes[-1].sim_time if len(report.apexes) else 0.0
    return {
        "duration_s": arguments.duration,
        "wall_s": time.monotonic() - wall_start,
        "steal_s": steal,
        "load": os.getloadavg(),
        "outcome": f"{report.outcome.kind}: {report.outcome.reason}",
        "strides": len(report.apexes),
        "topics": topics_table,
        "dropped_while_paused": dropped,
        "dropped_while_paused_per_topic": dropped_per_topic,
        "recorder_diagnostics": recorder_diagnostics,
        "lost": lost,
        "hostile_sent": hostile,
        "hostile_sent_at_last_apex": reports["hostile"]["sent_at_last_apex"],
        "plant_refusals_by_status": chaos["refusals"],
        "summed_in_later_reports": chaos["summed"],
        "other_refusal_reasons": chaos["other_reasons"],
        "rejected": counts.rejected,
        "earlier_answers": counts.earlier_answers,
        "unreported_rejections": counts.unreported_rejections,
        "rejections_accounted": accounted,
        "late_commands": counts.late_commands,
        "late_torques": counts.late_torques,
        "stale_torques": counts.stale_torques,
        "statuses": chaos["statuses"],
        "missed_ticks": None
        if missed is None
        else {
            "ticks": missed.ticks,
            "missed": missed.missed,
            "hypervisor steal": missed.stolen,
            "waiting for a CPU": missed.waiting,
            "woken late": missed.woken_late,
            "interrupted or catching up": missed.interrupted,
            "unexplained": missed.unexplained,
        },
        "slopes": slopes,
        "warm_up_s": warm_up,
        "bags": [str(bag) for bag in bags],
        "bags_finalised": finalised,
        "analysis": analysis | {"recording_s": length},
        "parameter_and_lifecycle": {"asked": chaos["asked"], "answers": chaos["answers"]},
        "viewer": reports["viewer"] | {"stalled_s": sum(reports["viewer"].get("stalls", []))},
        "replays": {str(code): n for code, n in replayer.exits.items()},
        "actor_exits": exits,
    }


def print_summary(figures: dict[str, Any]) -> None:
    def verdict(ok: bool) -> str:
        return "ok" if ok else "MISSED"

    print(f"\nsoak of {figures['duration_s']:g} s ({figures['wall_s']:.0f} s wall): {figures['outcome']}")
    print(
        f"  {figures['strides']} strides; steal {figures['steal_s']:.1f} s; "
        f"load average at the end {figures['load']}"
    )
    print(
        "\nmessages per topic                   published   recorded    dropped"
        "  (published = recorded + dropped while the recorder was paused)"
    )
    for topic, row in figures["topics"].items():
        received = "" if topic not in HOSTILE_TOPICS else f"   (the plant received {row['plant']})"
        print(f"  {topic:<32}{row['published']:>11}{row['recorded']:>11}{row['dropped']:>11}{received}")
    print(
        f"  dropped while the recorder was paused: {figures['dropped_while_paused']}; "
        f"lost: {figures['lost']} (target 0: {verdict(figures['lost'] == 0)})"
    )
    print("\nwhat the hostile controller sent")
    for kind, n in sorted(figures["hostile_sent"].items()):
        print(f"  {kind:<28}{n:>8}")
    print("refusals, by the Status that reported each")
    for kind, n in sorted(figures["plant_refusals_by_status"].items()):
        print(f"  {kind:<40}{n:>8}")
    accounted = figures["rejections_accounted"]
    print(
        f"  the plant rejected {figures['rejected']}: reported one by one "
        f"{sum(figures['plant_refusals_by_status'].values())}, summed in later reports "
        f"{figures['summed_in_later_reports']}, answers to earlier apexes {figures['earlier_answers']}, "
        f"awaiting a report {figures['unreported_rejections']}: {accounted} "
        f"(target: every one: {verdict(accounted == figures['rejected'])})"
    )
    print(
        f"  late commands (strides) {figures['late_commands']}, late torques {figures['late_torques']}, "
        f"stale torque ticks {figures['stale_torques']}"
    )
    missed = figures["missed_ticks"]
    if missed is not None:
        print(
            f"\nmissed ticks {missed['missed']} of {missed['ticks']}: hypervisor steal "
            f"{missed['hypervisor steal']}, waiting for a CPU {missed['waiting for a CPU']}, woken late "
            f"{missed['woken late']}, interrupted or catching up {missed['interrupted or catching up']}, "
            f"unexplained {missed['unexplained']} "
            f"(target 0: {verdict(missed['unexplained'] == 0)})"
        )
    print(
        f"\nafter a warm-up of {figures['warm_up_s']:.0f} s, per 10 minutes   RSS [MiB]  descriptors  threads"
    )
    for label, slope in figures["slopes"].items():
        ok = slope["rss_mib_per_10min"] < SLOPE_TARGET_MIB
        print(
            f"  {label:<24}{slope['rss_mib_per_10min']:>+12.2f}{slope['descriptors_per_10min']:>+13.2f}"
            f"  {slope['threads_min']}-{slope['threads_max']}   RSS {slope['rss_first_mib']:.1f} -> "
            f"{slope['rss_last_mib']:.1f} MiB ({verdict(ok)})"
        )
    analysis = figures["analysis"]
    print(
        f"\nbags {len(figures['bags'])}, finalised and valid: {verdict(figures['bags_finalised'])}; "
        f"tdslip analyze of {analysis['bag']} ({len(analysis['skipped_for_resets'])} bag(s) before it hold "
        f"resets, refused as several runs): exit {analysis['exit']} in {analysis['seconds']:.1f} s "
        f"({analysis['seconds'] / max(analysis['recording_s'], 1e-9):.4f} x the recording, target <= "
        f"{ANALYZE_TARGET}), peak RSS {analysis['peak_rss_mib']:.0f} MiB"
    )
    print("\nparameters and lifecycle asked:", json.dumps(figures["parameter_and_lifecycle"]["asked"]))
    print("answers:", json.dumps(figures["parameter_and_lifecycle"]["answers"]))
    viewer = figures["viewer"]
    print(
        f"stalled viewer: {len(viewer.get('stalls', []))} stalls, {viewer['stalled_s']:.0f} s; "
        f"replays by exit status: {figures['replays']}; actors' exits: {figures['actor_exits']}"
    )


def long_lockstep(arguments: argparse.Namespace) -> dict[str, Any]:
    """A lockstep run of ``--strides`` strides, recorded, its processes sampled as the soak's are; then
    ``tdslip analyze`` of its bag."""
    out = Path(arguments.out or tempfile.mkdtemp(prefix="tdslip-long-"))
    out.mkdir(parents=True, exist_ok=True)
    sampler = Sampler(SAMPLE_PERIOD)
    steal_before, wall_before = steal_seconds(), time.monotonic()

    def progress(apex: ApexEvent) -> None:
        if apex.stride % 1000 == 0:
            elapsed = time.monotonic() - wall_before
            print(f"  {elapsed:7.0f} s: stride {apex.stride}; {load()}", flush=True)

    sampler.start()
    try:
        report = run(RunOptions(out / "run", strides=arguments.strides), progress)
    finally:
        sampler.stop.set()
    wall = time.monotonic() - wall_before
    length = report.apexes[-1].sim_time
    bag_bytes = sum(path.stat().st_size for path in (out / "run").iterdir())
    analysis = analyze(out / "run", out / "analysis")
    return {
        "strides": len(report.apexes) - 1,
        "outcome": f"{report.outcome.kind}: {report.outcome.reason}",
        "simulated_s": length,
        "wall_s": wall,
        "steal_s": steal_seconds() - steal_before,
        "load": os.getloadavg(),
        "recording_complete": report.recording_complete,
        "bag_bytes": bag_bytes,
        "slopes": sampler.slopes(min(WARM_UP, wall / 5.0)),
        "samples": sampler.samples,
        "analysis": analysis | {"recording_s": length},
    }


def print_long_lockstep(figures: dict[str, Any]) -> None:
    print(
        f"\nlockstep run of {figures['strides']} strides ({figures['simulated_s']:.0f} s simulated) in "
        f"{figures['wall_s']:.0f} s wall: {figures['outcome']}; recorded equal to published: "
        f"{figures['recording_complete']}; bag {figures['bag_bytes'] / 1e9:.2f} GB; steal "
        f"{figures['steal_s']:.1f} s; load average at the end {figures['load']}"
    )
    print("per 10 minutes of wall time after the warm-up   RSS [MiB]  descriptors")
    for label, slope in figures["slopes"].items():
        print(
            f"  {label:<24}{slope['rss_mib_per_10min']:>+12.2f}{slope['descriptors_per_10min']:>+13.2f}"
            f"   RSS {slope['rss_first_mib']:.1f} -> {slope['rss_last_mib']:.1f} MiB"
        )
    analysis = figures["analysis"]
    print(
        f"tdslip analyze: exit {analysis['exit']} in {analysis['seconds']:.1f} s "
        f"({analysis['seconds'] / analysis['recording_s']:.4f} x the recording, target <= {ANALYZE_TARGET}), "
        f"peak RSS {analysis['peak_rss_mib']:.0f} MiB"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument(
        "role", nargs="?", default="soak", choices=("soak", "lockstep", "hostile", "viewer", "chaos")
    )
    parser.add_argument("--duration", type=float, default=3600.0, help="s of realtime hopping")
    parser.add_argument("--strides", type=int, default=20_000, help="lockstep: the run's strides")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--realtime-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority of the plant's tick (0: normal scheduling; docs/realtime.md)",
    )
    parser.add_argument(
        "--out", help="where the bags and the actors' logs go (default: a temporary directory)"
    )
    parser.add_argument("--json", help="write the figures to this file")
    parser.add_argument("--report", help=argparse.SUPPRESS)
    parser.add_argument("--quiet-after", type=float, default=math.inf, help=argparse.SUPPRESS)
    parser.add_argument("--pace", type=float, default=1.0, help=argparse.SUPPRESS)
    arguments = parser.parse_args(argv)
    if arguments.role == "lockstep":
        figures = long_lockstep(arguments)
        print_long_lockstep(figures)
    elif arguments.role == "soak":
        try:
            figures = soak(arguments)
        except RunError as error:  # the actors are stopped; their reports and logs are in --out
            print(f"soak failed: {error}", file=sys.stderr)
            return 1
        print_summary(figures)
    else:
        return actor_main(arguments)
    if arguments.json:
        Path(arguments.json).write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
