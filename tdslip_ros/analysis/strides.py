"""The strides of a recorded run rebuilt from its events: which command the plant applied at each
touchdown (:func:`applied_commands`), and one :class:`~.records.StrideRecord` per apex
(:func:`stride_records`). The plant does not record which command it applied: its touchdown state shows it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tdslip_ros.analysis.records import (
    FAILURE_KINDS,
    STANCE_FEEDBACK,
    ApexRecord,
    CommandRecord,
    ContactRecord,
    FloatArray,
    StatusRecord,
    StrideRecord,
    TorqueRecord,
)
from tdslip_ros.model import dynamics
from tdslip_ros.model.params import StanceCommand
from tdslip_ros.model.plant.perturbations import Perturbations, placed_angle
from tdslip_ros.model.plant.stance_laws import DEFAULT_SAMPLE_PERIOD, RecordedTorques, StanceFeedback


def applied_commands(
    contacts: Sequence[ContactRecord],
    commands: Sequence[CommandRecord],
    perturbations: Perturbations | None = None,
) -> dict[int, CommandRecord]:
    """The command applied at each recorded touchdown, by stride.

    The plant applies the latest valid command answering the stride, or keeps the one in force. At
    touchdown the leg is at the commanded angle (plus the stride's placement error, reproduced from the
    ``perturbations``) and the hip torque equals tau0 (saturated at tau_max), both copied exactly into
    the touchdown state, so the applied command is the last command answering the stride that matches
    them bit for bit, else the command applied before it if that one matches. A touchdown that no
    recorded command matches (the plant's initial command) gets none.
    """
    perturbations = perturbations or Perturbations()
    by_stride: dict[int, list[CommandRecord]] = {}
    for command in sorted(commands, key=lambda c: c.log_time_ns):
        by_stride.setdefault(command.stride, []).append(command)
    applied: dict[int, CommandRecord] = {}
    in_force: CommandRecord | None = None
    touchdowns = [c for c in contacts if c.kind == "touchdown"]
    errors = _angle_errors(perturbations, max((c.stride for c in touchdowns), default=-1) + 1)
    for touchdown in touchdowns:

        def matches(command: CommandRecord | None, touchdown: ContactRecord = touchdown) -> bool:
            return command is not None and _applied_at(command, touchdown, perturbations, errors)

        candidates = [c for c in by_stride.get(touchdown.stride, []) if matches(c)]
        chosen = candidates[-1] if candidates else in_force if matches(in_force) else None
        if chosen is not None:
            applied[touchdown.stride] = chosen
        in_force = chosen
    return applied


def _angle_errors(perturbations: Perturbations, strides: int) -> FloatArray:
    """The placement errors of the first ``strides`` strides of the run (trajectory 0: epoch 0)."""
    return perturbations.draws([0], 0, strides).angle_error[:, 0]


def _applied_at(
    command: CommandRecord, touchdown: ContactRecord, perturbations: Perturbations, errors: FloatArray
) -> bool:
    placed = placed_angle(command.touchdown_angle, float(errors[touchdown.stride]))
    torque = command.tau0  # stance feedback: 0, the hold from touchdown to the first sample instant
    if perturbations.saturates and command.stance != STANCE_FEEDBACK:
        torque = float(dynamics.hip_torque(command.tau0, command.t_f, 0.0, float(perturbations.tau_max)))
    return bool(placed == touchdown.state.theta and torque == touchdown.state.hip_torque)


def stride_records(
    apexes: Sequence[ApexRecord],
    contacts: Sequence[ContactRecord],
    commands: Sequence[CommandRecord],
    outcome: StatusRecord | None,
    perturbations: Perturbations,
    torques: Sequence[TorqueRecord] = (),
) -> tuple[StrideRecord, ...]:
    """One record per apex: the apex, the command or stance feedback applied in the stance after it (see
    :func:`applied_commands`; the torques held from ``torques``), that stance's touchdown, liftoff and energy
    flows (from the next apex), the stride's perturbation draws, and the failure ``outcome`` if it ended
    the run in this stride."""
    applied = applied_commands(contacts, commands, perturbations)
    held: dict[int, list[TorqueRecord]] = {}
    for torque in torques:
        held.setdefault(torque.stride, []).append(torque)
    event_times = {(c.kind, c.stride): c.t for c in contacts}
    stance_grounds = {c.stride: c.ground for c in contacts if c.kind == "touchdown"}
    next_apex = {a.stride - 1: a for a in apexes}
    draws = perturbations.draws([0], 0, max((a.stride for a in apexes), default=-1) + 1)
    tau_max = float(perturbations.tau_max) if perturbations.saturates else math.inf
    records = []
    for apex in apexes:
        record = applied.get(apex.stride)
        feedback, command, saturated = None, None, False
        if record is not None and record.stance == STANCE_FEEDBACK:
            stance_torques = held.get(apex.stride, [])
            feedback = _feedback(record, stance_torques)
            saturated = any(abs(r.torque) >= tau_max for r in stance_torques)
        elif record is not None:
            command = StanceCommand(record.touchdown_angle, record.tau0, record.t_f)
            saturated = abs(command.tau0) > tau_max
        after = next_apex.get(apex.stride)
        failed = outcome is not None and outcome.kind in FAILURE_KINDS and outcome.stride == apex.stride
        error = float(draws.angle_error[apex.stride, 0])
        records.append(
            StrideRecord(
                stride=apex.stride,
                t=apex.t,
                x=apex.x,
                y=apex.y,
                xdot=apex.xdot,
                energy=apex.energy,
                command=command,
                policy="" if record is None else record.policy,
                touchdown_time=event_times.get(("touchdown", apex.stride), math.nan),
                liftoff_time=event_times.get(("liftoff", apex.stride), math.nan),
                hip_work=math.nan if after is None else after.hip_work,
                damping_loss=math.nan if after is None else after.damping_loss,
                spring_loss=math.nan if after is None else after.spring_loss,
                failure=outcome.kind if failed and outcome is not None else None,
                failure_reason=outcome.reason if failed and outcome is not None else "",
                ground=apex.ground,
                stance_ground=stance_grounds.get(apex.stride, math.nan),
                measured_y=apex.measured_y,
                measured_xdot=apex.measured_xdot,
                angle_error=error,
                placed_angle=math.nan if record is None else placed_angle(record.touchdown_angle, error),
                push=float(draws.push[apex.stride, 0]),
                saturated=saturated,
                stance_feedback=feedback,
                pitch=apex.pitch,
                pitch_rate=apex.pitch_rate,
            )
        )
    return tuple(records)


def _feedback(command: CommandRecord, torques: Sequence[TorqueRecord]) -> StanceFeedback:
    """The stance feedback of a stride as applied: the command's touchdown angle, and each torque held from
    its tick's instant on the plant's clock (tick * the sample period, the stepper's own arithmetic)."""
    times = np.array([r.tick for r in torques], dtype=float) * DEFAULT_SAMPLE_PERIOD
    law = RecordedTorques(times, np.array([r.torque for r in torques], dtype=float))
    return StanceFeedback(command.touchdown_angle, law)
