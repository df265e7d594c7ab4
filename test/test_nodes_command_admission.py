"""The plant node's command admission (tdslip_ros.nodes.command_admission), without a node."""

from __future__ import annotations

import math
import re
from typing import Any

import pytest
from rclpy.serialization import serialize_message
from tdslip_msgs.msg import StanceCommand

from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, ParameterError
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.stance_laws import StanceFeedback, TorqueStream
from tdslip_ros.nodes.command_admission import (
    REJECTION_REPORT_PERIOD,
    REJECTION_REPORTS,
    LateCommand,
    RejectionLog,
    admit,
    command_key,
    not_yet,
)
from tdslip_ros.nodes.plant_run import ApexReport, PlantRun, PlantSink, RunSettings

LIMITS = PlausibilityLimits.for_hopper(PAPER_PARAMS)
NS = 1_000_000_000


def command(epoch: int = 2, stride: int = 5, **values: Any) -> StanceCommand:
    msg = StanceCommand(epoch=epoch, stride=stride, touchdown_angle=0.4, tau0=-273.0, t_f=0.13)
    for name, value in values.items():
        setattr(msg, name, value)
    return msg


def admitted(msg: StanceCommand, **at: Any) -> ModelCommand | StanceFeedback:
    where = {"epoch": 2, "stride": 5, "lockstep": True, "awaiting": 5, "past_touchdown": False} | at
    return admit(msg, limits=LIMITS, **where)


@pytest.mark.parametrize("frame_id", ["", "w", "wo", "wor", "world", "a much longer frame name"])
def test_the_key_is_read_from_the_bytes_whatever_the_frame_id_s_padding(frame_id: str) -> None:
    msg = command(epoch=7, stride=123456)
    msg.header.frame_id = frame_id
    msg.policy = "energy"
    assert command_key(bytes(serialize_message(msg))) == (7, 123456)


def test_bytes_that_are_not_a_little_endian_command_have_no_key() -> None:
    data = bytes(serialize_message(command()))
    assert command_key(data[:15]) is None
    assert command_key(data[:1] + b"\x00" + data[2:]) is None  # big-endian encapsulation
    assert command_key(data[:16] + b"\x00") is None  # cut after the frame_id's length


def test_a_command_for_the_awaited_apex_is_the_model_s_command() -> None:
    assert admitted(command()) == ModelCommand(0.4, -273.0, 0.13)
    assert admitted(command(), lockstep=False, awaiting=None) == ModelCommand(0.4, -273.0, 0.13)


def test_a_stance_feedback_command_is_a_torque_stream_sampled_at_the_tick() -> None:
    msg = command(stance=StanceCommand.STANCE_FEEDBACK, tau0=0.0, t_f=0.0)
    assert admitted(msg) == StanceFeedback(0.4, TorqueStream(), sample_period=1e-3)


@pytest.mark.parametrize(
    ("msg", "at", "reason"),
    [
        (command(epoch=1), {}, "it answers epoch 1, but the run is in epoch 2 (copy the apex's epoch)"),
        (command(stride=4), {}, "it answers stride 4, but the latest apex is stride 5"),
        (command(), {"awaiting": None}, "stride 5 already has its command (lockstep)"),
        (command(tau0=-1e6), {}, "exceeds the actuator limit"),
        (command(t_f=math.nan), {}, "t_f"),
        (command(touchdown_angle=2.0), {}, "touchdown_angle must lie in (0, pi/2)"),
        (command(stance=2), {}, "stance = 2 is neither STANCE_RAMP (0) nor STANCE_FEEDBACK (1)"),
        (command(stance=StanceCommand.STANCE_FEEDBACK), {}, "stance feedback with a ramp"),
        (
            command(stance=StanceCommand.STANCE_FEEDBACK, tau0=0.0, t_f=0.0, touchdown_angle=math.nan),
            {},
            "touchdown_angle must be finite",
        ),
    ],
)
def test_a_command_the_plant_cannot_apply_is_refused_with_its_reason(
    msg: StanceCommand, at: dict[str, Any], reason: str
) -> None:
    with pytest.raises(ParameterError) as refused:
        admitted(msg, **at)
    assert reason in str(refused.value) and not isinstance(refused.value, LateCommand)


def test_a_command_after_its_touchdown_is_late_in_both_clock_modes() -> None:
    for lockstep in (True, False):
        with pytest.raises(LateCommand, match="it arrived after the touchdown of stride 5"):
            admitted(command(), lockstep=lockstep, past_touchdown=True)
    with pytest.raises(ParameterError) as refused:  # another apex's answer is refused as such first
        admitted(command(stride=4), past_touchdown=True)
    assert not isinstance(refused.value, LateCommand)


def test_an_answer_ahead_of_the_plant_names_what_it_is_ahead_of() -> None:
    assert not_yet((3, 0), 2, 5) == "the run is in epoch 2"
    assert not_yet((2, 6), 2, 5) == "the latest apex is stride 5"


def test_rejections_are_reported_up_to_the_limit_per_period_and_the_rest_summed() -> None:
    log = RejectionLog()
    start = 10 * NS
    prefixes = [log.admit(start + i) for i in range(REJECTION_REPORTS + 3)]
    assert prefixes == [""] * REJECTION_REPORTS + [None] * 3
    assert (log.total, log.suppressed) == (REJECTION_REPORTS + 3, 3)
    later = start + round(REJECTION_REPORT_PERIOD * NS)
    assert log.admit(later) == "(3 more rejected, not reported one by one) "
    assert (log.total, log.suppressed) == (REJECTION_REPORTS + 4, 0)
    assert log.admit(later + 1) == ""


class StatusRecord(PlantSink):
    """A sink that keeps the plant's Status reports (kind, reason) and the strides of its apexes."""

    def __init__(self) -> None:
        self.statuses: list[tuple[str, str]] = []
        self.apexes: list[int] = []

    @property
    def live(self) -> bool:
        return False

    def apex(self, report: ApexReport) -> None:
        self.apexes.append(report.stride)

    def status(self, epoch: int, stride: int, kind: str, reason: str, t: float, *, fatal: bool) -> None:
        self.statuses.append((kind, reason))


def summed(reason: str) -> int:
    """The rejections a report sums besides its own (its ``(N more rejected ...)`` prefix)."""
    found = re.match(r"\((\d+) more rejected", reason)
    return int(found.group(1)) if found else 0


def test_every_rejection_is_a_status_of_its_own_summed_into_a_later_one_or_an_earlier_answer() -> None:
    """A realtime run (PlantRun, no node) given a scripted mix of answers: its rejected count is accounted
    for by the Statuses alone: one report each, the ``(N more rejected ...)`` a report sums, the answers to
    earlier apexes (counted, never reported), and those the next report would sum."""
    settings = RunSettings(
        PAPER_PARAMS,
        LIMITS,
        Perturbations(),
        ModelCommand(math.radians(20.0), -273.0, 0.13),
        lockstep=False,
        max_strides=4,
        max_stale_strides=0,
        torque_max_age_ticks=3,
    )
    sink = StatusRecord()
    run = PlantRun(settings, ApexState(1.0, 5.0), sink)
    run.start(0)
    earlier_sent = bad_sent = 0
    while run.running:
        if len(sink.apexes) == 2 and earlier_sent == 0:  # at apex 1: answers to apex 0, and bad ones
            for _ in range(4):
                run.take_command(serialize_message(command(epoch=0, stride=0)))
                earlier_sent += 1
            flood = [command(epoch=0, stride=1, touchdown_angle=math.nan), command(epoch=0, stride=9)]
            for msg in flood * (REJECTION_REPORTS // 2 + 3):  # more than a period's reports
                run.take_command(serialize_message(msg))
                bad_sent += 1
        run.advance_to(run.next_deadline_ns)
    counts = run.counts()
    rejections = [reason for kind, reason in sink.statuses if kind == "command_rejected"]
    assert len(rejections) == REJECTION_REPORTS and counts.unreported_rejections == bad_sent - len(rejections)
    assert counts.earlier_answers == earlier_sent
    reported = len(rejections) + sum(summed(reason) for reason in rejections)
    assert (
        counts.rejected
        == earlier_sent + bad_sent
        == (reported + counts.earlier_answers + counts.unreported_rejections)
    )
