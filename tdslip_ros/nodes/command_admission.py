"""Which StanceCommand the plant node applies, and how it reports the ones it rejects.

A command answers one apex: it carries the apex's ``epoch`` (0 for the first run, one more at every reset)
and ``stride``. :func:`command_key` reads those two from the serialised bytes, so that an answer to another
apex is told apart without deserialising it (a flood of them costs next to nothing); :func:`admit` checks
the rest of a command for the apex the plant is at and gives the model's command to step with, or raises
ParameterError with the reason to reject it (:class:`LateCommand` when it arrived after its touchdown).
A command's ``stance`` says what the hip does in the stance: the ramp (tau0, t_f), or stance feedback,
the torques a controller streams on tdslip/hip_torque (:mod:`tdslip_ros.nodes.torque_stream`).
:class:`RejectionLog` rate-limits the rejections that are reported.
"""

from __future__ import annotations

import struct

from tdslip_msgs.msg import StanceCommand

from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import ParameterError
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.model.plant.stance_laws import StanceFeedback, TorqueStream

REJECTION_REPORTS = 10
REJECTION_REPORT_PERIOD = 1.0
"""s: at most REJECTION_REPORTS rejections per period are logged and reported one by one."""

_NS_PER_S = 1_000_000_000
_CDR_LITTLE_ENDIAN = 1
_UINT32_PAIR = struct.Struct("<II")


def command_key(data: bytes) -> tuple[int, int] | None:
    """(epoch, stride) of a serialized StanceCommand, read without deserializing it (None if the
    bytes are not little-endian CDR of that layout). After the 4-byte encapsulation header come
    header.stamp (8 bytes), header.frame_id (uint32 length, then its bytes), then epoch and stride,
    each aligned to 4 bytes counted from the end of the encapsulation header."""
    if len(data) < 16 or data[1] != _CDR_LITTLE_ENDIAN:
        return None
    offset = 12 + int.from_bytes(data[12:16], "little")  # payload offset after frame_id
    offset += -offset % 4
    if 4 + offset + _UINT32_PAIR.size > len(data):
        return None
    epoch, stride = _UINT32_PAIR.unpack_from(data, 4 + offset)
    return epoch, stride


def not_yet(key: tuple[int, int], epoch: int, stride: int) -> str:
    """Why an answer to apex ``key`` (epoch, stride), ahead of the plant's ``epoch`` and ``stride``, is
    rejected."""
    if key[0] != epoch:
        return f"the run is in epoch {epoch}"
    return f"the latest apex is stride {stride}"


class LateCommand(ParameterError):
    """A command that arrived after the touchdown of the stride it answers."""


def admit(
    msg: StanceCommand,
    *,
    epoch: int,
    stride: int,
    lockstep: bool,
    awaiting: int | None,
    past_touchdown: bool,
    limits: PlausibilityLimits,
) -> ModelCommand | StanceFeedback:
    """The model's command of ``msg`` for the apex of ``epoch`` and ``stride``: a ramp, or stance feedback
    on a :class:`~tdslip_ros.model.plant.stance_laws.TorqueStream`. ParameterError with the reason to reject
    it if it answers another apex, repeats an answered stride in lockstep (``awaiting``: the stride waiting
    for its command), comes after the touchdown (``past_touchdown``: LateCommand) or holds values the model or
    ``limits`` refuse (stance feedback with a ramp's tau0 or t_f: which one was meant?)."""
    if msg.epoch != epoch:
        raise ParameterError(
            f"it answers epoch {msg.epoch}, but the run is in epoch {epoch} (copy the apex's epoch)"
        )
    if msg.stride != stride:
        raise ParameterError(f"it answers stride {msg.stride}, but the latest apex is stride {stride}")
    if lockstep and awaiting != stride:
        raise ParameterError(f"stride {stride} already has its command (lockstep)")
    if past_touchdown:  # in its stance, or rising after it
        raise LateCommand(f"it arrived after the touchdown of stride {stride}")
    if msg.stance == StanceCommand.STANCE_FEEDBACK:
        if msg.tau0 != 0.0 or msg.t_f != 0.0:
            raise ParameterError(
                f"stance feedback with a ramp (tau0 = {msg.tau0!r}, t_f = {msg.t_f!r}): set both 0"
            )
        return StanceFeedback(msg.touchdown_angle, TorqueStream())
    if msg.stance != StanceCommand.STANCE_RAMP:
        raise ParameterError(f"stance = {msg.stance} is neither STANCE_RAMP (0) nor STANCE_FEEDBACK (1)")
    command = ModelCommand(msg.touchdown_angle, msg.tau0, msg.t_f)
    limits.check_command(command)
    return command


class RejectionLog:
    """Rejected commands, logged and reported one by one up to REJECTION_REPORTS per
    REJECTION_REPORT_PERIOD, the rest summed into the next report: a flood of bad commands cannot
    flood the log or the status topic."""

    def __init__(self) -> None:
        self._period_start_ns = 0
        self._reports_in_period = 0
        self.suppressed = 0
        """Rejections since the latest report, not reported one by one: the next report sums them."""
        self.total = 0
        self.earlier_answers = 0
        """Answers to earlier apexes (late, or of an earlier epoch): counted in ``total``, never reported."""

    def count_earlier_answer(self) -> None:
        self.total += 1
        self.earlier_answers += 1

    def admit(self, now_ns: int) -> str | None:
        """Count a rejection; the prefix of its report if it is to be reported now, else None."""
        self.total += 1
        if now_ns - self._period_start_ns >= REJECTION_REPORT_PERIOD * _NS_PER_S:
            self._period_start_ns, self._reports_in_period = now_ns, 0
        if self._reports_in_period >= REJECTION_REPORTS:
            self.suppressed += 1
            return None
        self._reports_in_period += 1
        prefix = f"({self.suppressed} more rejected, not reported one by one) " if self.suppressed else ""
        self.suppressed = 0
        return prefix
