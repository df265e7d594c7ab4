"""The plant's 1 kHz torque interface: the hip torques a controller streams through a stance under stance
feedback (a StanceCommand with ``stance`` STANCE_FEEDBACK), one per stance tick on ``tdslip/hip_torque``.

A torque is identified as a command is, by the ``epoch`` and ``stride`` of the stance it is for, and by the
plant ``tick`` of the state sample it answers (the sample's stamp in milliseconds, :func:`tick_of`). Ticks
count on over resets, like simulated time, so nothing of an earlier epoch can pass for the current one.
:func:`torque_fields` reads all four from the bytes, without deserialising.

At each tick of a streamed stance (:attr:`~tdslip_ros.model.plant.stepper.FixedStepStepper.torque_due`) the
plant holds a torque from that tick on:

* **lockstep**: it waits for the torque of exactly that (epoch, stride, tick) and holds it: the run is
  decided by the torques alone, as a lockstep run is by its commands;
* **realtime**: it holds the latest torque received for the stance (zero-order hold) while that torque's
  tick is at most ``max_age_ticks`` older; an older one, or none, is stale: the hip holds zero (a silent
  controller must not keep pushing) and the tick is counted in :attr:`TorqueInput.stale`.

A received torque (:meth:`TorqueInput.take`) is *late* when the plant has stepped past its tick (realtime:
it may still be held at the next ticks, within the age bound) or its stance is over; late torques are
counted, not reported, as late commands are. It is refused with the reason (ParameterError; the plant
reports it with a Status ``torque_rejected``) when its value is not finite or beyond the plausible torque,
when it is ahead of the plant (epoch, stride or tick), when the stance it is for has a ramp, or, in
lockstep, when its tick is not awaited.
"""

from __future__ import annotations

import math
import struct
from typing import NamedTuple

from tdslip_ros.model.params import ParameterError
from tdslip_ros.nodes.command_admission import not_yet

_CDR_LITTLE_ENDIAN = 1
_UINT32_PAIR = struct.Struct("<II")
_UINT64_FLOAT64 = struct.Struct("<Qd")
TICK_NS = 1_000_000  # the plant's 1 ms tick, here for all of the nodes
_NS_PER_S = 1_000_000_000


class TorqueFields(NamedTuple):
    """What identifies a streamed torque, and its value [N m]."""

    epoch: int
    stride: int
    tick: int
    torque: float


def tick_of(sec: int, nanosec: int) -> int:
    """The plant tick of a state sample stamped (sec, nanosec): its stamp in milliseconds."""
    return round((sec * _NS_PER_S + nanosec) / TICK_NS)


def tick_stamp(tick: int) -> tuple[int, int]:
    """The stamp (sec, nanosec) of plant ``tick``: the inverse of :func:`tick_of`."""
    sec, nanosec = divmod(tick * TICK_NS, _NS_PER_S)
    return sec, nanosec


def torque_fields(data: bytes) -> TorqueFields | None:
    """The fields of a serialised HipTorque (None if the bytes are not little-endian CDR of its layout).
    After the 4-byte encapsulation header come header.stamp (8 bytes), header.frame_id (uint32 length,
    then its bytes), epoch and stride (each aligned to 4), then tick and torque (aligned to 8), alignment
    counted from the end of the encapsulation header."""
    if len(data) < 16 or data[1] != _CDR_LITTLE_ENDIAN:
        return None
    offset = 12 + int.from_bytes(data[12:16], "little")  # payload offset after frame_id
    offset += -offset % 4
    tick_offset = offset + _UINT32_PAIR.size
    tick_offset += -tick_offset % 8
    if 4 + tick_offset + _UINT64_FLOAT64.size > len(data):
        return None
    epoch, stride = _UINT32_PAIR.unpack_from(data, 4 + offset)
    tick, torque = _UINT64_FLOAT64.unpack_from(data, 4 + tick_offset)
    return TorqueFields(epoch, stride, tick, torque)


class LateTorque(Exception):
    """A torque that came after its tick was stepped, or after its stance: counted, never reported."""


class TorqueInput:
    """The plant's side of the stream (module docstring): the torque it holds or waits for, and the counts.

    Not thread-safe: the plant calls it under its lock.
    """

    def __init__(self, *, lockstep: bool, max_age_ticks: int, max_torque: float) -> None:
        self.lockstep = lockstep
        self.max_age_ticks = max_age_ticks
        self.max_torque = max_torque
        self.latest: TorqueFields | None = None
        """The latest torque taken for the current stance (realtime), or the awaited one (lockstep)."""
        self.awaited: tuple[int, int, int] | None = None
        """Lockstep: the (epoch, stride, tick) whose torque the plant waits for."""
        self.late = 0
        """Torques that came after their tick was stepped or after their stance (lockstep: never held)."""
        self.stale = 0
        """Realtime: stance ticks that held zero, as no torque within the age bound had come."""

    def restart(self) -> None:
        """A new epoch: nothing held, nothing awaited (the counts run on)."""
        self.latest, self.awaited = None, None

    def take(
        self, torque: TorqueFields, *, epoch: int, stride: int, tick: int, streaming: bool, stance_over: bool
    ) -> bool:
        """Judge a torque received while the plant is at (``epoch``, ``stride``) with its latest state at
        ``tick``; ``streaming``: the stance of ``stride`` is streamed; ``stance_over``: it has lifted off.
        True when it is to be held now (lockstep: the awaited one; it is :attr:`latest` then). A late one is
        counted (LateTorque); ParameterError gives the reason to refuse one."""
        if not (math.isfinite(torque.torque) and abs(torque.torque) <= self.max_torque):
            raise ParameterError(
                f"torque {torque.torque!r} N m is not a plausible hip torque "
                f"(|tau| <= {self.max_torque:.6g} N m)"
            )
        key, now = (torque.epoch, torque.stride), (epoch, stride)
        if key > now:
            raise ParameterError(f"it is ahead of the plant: {not_yet(key, epoch, stride)}")
        if torque.tick > tick:
            raise ParameterError(f"it is for tick {torque.tick}, but the plant's latest state is tick {tick}")
        if key < now or stance_over:
            self.late += 1
            raise LateTorque
        if not streaming:
            raise ParameterError(f"the stance of stride {stride} has a ramp command, not stance feedback")
        if self.lockstep:
            if self.awaited == (torque.epoch, torque.stride, torque.tick):
                self.latest, self.awaited = torque, None
                return True
            if torque.tick < tick:
                self.late += 1
                raise LateTorque
            raise ParameterError(f"tick {torque.tick} needs no torque: it is not a sample of the stance")
        if torque.tick < tick:
            self.late += 1  # its own tick was stepped without it; it may still be held at the next ones
        if self.latest is None or self.latest.stride != stride or torque.tick > self.latest.tick:
            self.latest = torque
        return True

    def await_tick(self, epoch: int, stride: int, tick: int) -> None:
        """Lockstep: wait for the torque of (epoch, stride, tick)."""
        self.awaited = (epoch, stride, tick)

    def held(self, stride: int, tick: int) -> float:
        """Realtime: the torque [N m] to hold from ``tick`` in the stance of ``stride`` (a stale tick: 0)."""
        latest = self.latest
        if latest is not None and latest.stride == stride and tick - latest.tick <= self.max_age_ticks:
            return latest.torque
        self.stale += 1
        return 0.0
