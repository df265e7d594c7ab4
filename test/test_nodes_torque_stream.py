"""The plant node's torque interface (tdslip_ros.nodes.torque_stream), without a node."""

from __future__ import annotations

import math
from typing import Any

import pytest
from rclpy.serialization import serialize_message
from tdslip_msgs.msg import HipTorque

from tdslip_ros.model.events import Event, EventKind
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, ParameterError
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.stance_laws import StanceFeedback, TorqueStream
from tdslip_ros.nodes.plant_run import PlantRun, PlantSink, RunOutcome, RunSettings
from tdslip_ros.nodes.torque_stream import LateTorque, TorqueFields, TorqueInput, tick_of, torque_fields
from tdslip_ros.nodes.wire import serialized

MAX_TORQUE = 1000.0
AT = {"epoch": 2, "stride": 5, "tick": 700, "streaming": True, "stance_over": False}


def torque(epoch: int = 2, stride: int = 5, tick: int = 700, value: float = -12.5) -> TorqueFields:
    return TorqueFields(epoch, stride, tick, value)


def stream(lockstep: bool) -> TorqueInput:
    return TorqueInput(lockstep=lockstep, max_age_ticks=3, max_torque=MAX_TORQUE)


@pytest.mark.parametrize("frame_id", ["", "w", "wo", "wor", "world", "a much longer frame name"])
def test_the_fields_are_read_from_the_bytes_whatever_the_frame_id_s_padding(frame_id: str) -> None:
    msg = HipTorque(epoch=7, stride=123456, tick=2**40 + 3, torque=-273.25)
    msg.header.frame_id = frame_id
    expected = TorqueFields(7, 123456, 2**40 + 3, -273.25)
    assert torque_fields(bytes(serialize_message(msg))) == expected
    assert torque_fields(serialized(msg)) == expected


def test_bytes_that_are_not_a_little_endian_hip_torque_have_no_fields() -> None:
    data = serialized(HipTorque())
    assert torque_fields(data[:15]) is None
    assert torque_fields(data[:1] + b"\x00" + data[2:]) is None
    assert torque_fields(data[:-1]) is None


def test_a_state_s_stamp_names_its_tick() -> None:
    assert tick_of(3, 7_000_000) == 3007
    assert tick_of(0, 999_999_999) == 1000  # a stamp rounded to the nanosecond


def test_lockstep_holds_the_awaited_torque_only() -> None:
    torques = stream(lockstep=True)
    torques.await_tick(2, 5, 700)
    assert torques.take(torque(), **AT) and torques.latest == torque() and torques.awaited is None
    with pytest.raises(ParameterError, match="tick 700 needs no torque"):
        torques.take(torque(), **AT)  # nothing awaited at this tick any more
    with pytest.raises(LateTorque):
        torques.take(torque(tick=699), **AT)
    assert torques.late == 1 and torques.stale == 0


def test_realtime_holds_the_latest_torque_until_it_is_too_old() -> None:
    torques = stream(lockstep=False)
    assert torques.held(5, 700) == 0.0 and torques.stale == 1  # none yet: zero, stale
    torques.take(torque(tick=700, value=-1.0), **AT)
    torques.take(torque(tick=699, value=-2.0), **AT)  # late and older: counted, not held
    assert torques.late == 1
    assert torques.held(5, 701) == -1.0 and torques.held(5, 703) == -1.0
    assert torques.held(5, 704) == 0.0 and torques.stale == 2  # beyond max_age_ticks
    assert torques.held(6, 701) == 0.0  # another stride's stance never holds it
    torques.restart()
    assert torques.held(5, 701) == 0.0


@pytest.mark.parametrize(
    ("sent", "at", "reason"),
    [
        (torque(value=math.nan), {}, "not a plausible hip torque"),
        (torque(value=-1e6), {}, "not a plausible hip torque"),
        (torque(epoch=3), {}, "ahead of the plant: the run is in epoch 2"),
        (torque(stride=6), {}, "ahead of the plant: the latest apex is stride 5"),
        (torque(tick=701), {}, "it is for tick 701, but the plant's latest state is tick 700"),
        (torque(), {"streaming": False}, "the stance of stride 5 has a ramp command"),
    ],
)
@pytest.mark.parametrize("lockstep", [True, False])
def test_a_torque_the_plant_cannot_hold_is_refused_with_its_reason(
    sent: TorqueFields, at: dict[str, Any], reason: str, lockstep: bool
) -> None:
    torques = stream(lockstep)
    torques.await_tick(2, 5, 700)
    with pytest.raises(ParameterError, match=reason.replace("(", r"\(")):
        torques.take(sent, **(AT | at))
    assert torques.late == 0


@pytest.mark.parametrize("sent", [torque(epoch=1, tick=10), torque(stride=4, tick=600)])
def test_a_torque_for_an_earlier_stance_is_late_in_both_clock_modes(sent: TorqueFields) -> None:
    for lockstep in (True, False):
        torques = stream(lockstep)
        with pytest.raises(LateTorque):
            torques.take(sent, **AT)
        with pytest.raises(LateTorque):
            torques.take(torque(), **(AT | {"stance_over": True}))
        assert torques.late == 2 and torques.latest is None


class StanceRecord(PlantSink):
    """A sink that keeps each stance torque the plant applied (tdslip/applied_torque) and its touchdowns."""

    def __init__(self) -> None:
        self.applied: list[tuple[int, int, int, float]] = []
        self.touchdowns: list[int] = []
        self.outcome: RunOutcome | None = None

    @property
    def live(self) -> bool:
        return False

    def applied_torque(self, epoch: int, stride: int, tick: int, torque: float) -> None:
        self.applied.append((epoch, stride, tick, torque))

    def contact(self, epoch: int, event: Event, t: float) -> None:
        if event.kind is EventKind.TOUCHDOWN:
            self.touchdowns.append(event.stride)

    def finished(self, outcome: RunOutcome) -> None:
        self.outcome = outcome


def test_a_realtime_stance_tick_without_a_fresh_torque_holds_zero_and_is_counted_stale() -> None:
    """A realtime run streaming the hip torque (stance feedback on a TorqueStream) through one stance: no
    torque for the first samples, then one torque, held for max_age_ticks more ticks, then none again. Each
    sample that held zero is a stale tick in the run's counts; the samples that held the torque are not."""
    max_age = 3
    hopper = PAPER_PARAMS
    settings = RunSettings(
        hopper,
        PlausibilityLimits.for_hopper(hopper),
        Perturbations(),
        StanceFeedback(math.radians(22.0), TorqueStream()),
        lockstep=False,
        max_strides=1,
        max_stale_strides=0,
        torque_max_age_ticks=max_age,
    )
    sink = StanceRecord()
    run = PlantRun(settings, ApexState(1.0, 5.0), sink)
    run.start(0)
    sent = None
    while run.running:
        if sink.touchdowns and sent is None and len(sink.applied) == 5:
            sent = HipTorque(epoch=run.epoch, stride=sink.touchdowns[0], tick=run.ticks, torque=-50.0)
            run.take_torque(serialized(sent))
        run.advance_to(run.next_deadline_ns)
    assert sink.outcome is not None and sink.outcome.ok, sink.outcome
    assert sent is not None
    held = [torque for _, _, _, torque in sink.applied]
    assert held[:5] == [0.0] * 5  # nothing sent yet
    fresh = [tick for _, _, tick, torque in sink.applied if torque == sent.torque]
    assert fresh == list(range(sent.tick, sent.tick + max_age + 1))  # from its tick, max_age ticks more
    assert len(held) > len(fresh) + 5  # the stance went on without a torque
    counts = run.counts()
    assert counts.stale_torques == held.count(0.0) == len(held) - len(fresh)
    assert counts.late_torques == 0 and counts.rejected == 0
