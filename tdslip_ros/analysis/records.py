"""The records of a recorded run (:class:`Run`), as :mod:`.decoding` reads them from a bag: one type per
message (apex, contact, command, applied torque, status), the 1 kHz samples as arrays, and one
:class:`StrideRecord` per apex, which :mod:`.strides` assembles.

A contact event's state is the model's :class:`~tdslip_ros.model.events.HopperState`; the recording holds
no ground reaction force with it, so its ``grf_x`` and ``grf_y`` are NaN (the force is in
:attr:`Samples.grf_x`, :attr:`Samples.grf_y`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from tdslip_ros.interfaces import RUN_COMPLETE, STOP_REQUESTED
from tdslip_ros.model.events import HopperState
from tdslip_ros.model.params import ApexState, HopperParams, StanceCommand
from tdslip_ros.model.plant.perturbations import MISMATCH_FIELDS, Perturbations
from tdslip_ros.model.plant.stance_laws import StanceFeedback

FloatArray = npt.NDArray[np.float64]

FAILURE_KINDS = (
    "toe_stubbing",
    "no_liftoff",
    "fall",
    "reversal",
    "state_limit",
    "command_timeout",
    "publish_failed",
)
"""Status kinds that end a run as a failure (the model's FailureKind values and the plant's own)."""
STANCE_FEEDBACK = 1
"""StanceCommand.stance of a command answering with stance feedback (0: the ramp)."""


@dataclass(frozen=True)
class ApexRecord:
    """An ApexEvent: apex ``stride`` at sim time t [s]; energy flows of the stance before it [J]; ground
    height of that stance [m] and the apex the controller's sensor reported (world frame); a rigid body's
    pitch [rad] and pitch rate [rad/s] (0 for the fixed body)."""

    stride: int
    t: float
    x: float
    y: float
    xdot: float
    energy: float
    hip_work: float
    damping_loss: float
    spring_loss: float
    ground: float = 0.0
    measured_y: float = math.nan
    measured_xdot: float = math.nan
    pitch: float = 0.0
    pitch_rate: float = 0.0


@dataclass(frozen=True)
class ContactRecord:
    """A touchdown, bottom or liftoff of the stance after apex ``stride``, on ground [m] (the toe's)."""

    kind: str
    stride: int
    t: float
    state: HopperState
    ground: float = 0.0


@dataclass(frozen=True)
class CommandRecord:
    """A StanceCommand message as received by the recorder (log_time_ns: reception time)."""

    stride: int
    touchdown_angle: float
    tau0: float
    t_f: float
    policy: str
    log_time_ns: int
    stance: int = 0
    """0: the ramp tau0, t_f; STANCE_FEEDBACK: torques streamed per tick (0 where the recorded message
    type has no ``stance`` field: such a plant applies the ramp only)."""


@dataclass(frozen=True)
class TorqueRecord:
    """A hip torque the plant applied (tdslip/applied_torque): held from plant tick ``tick`` on in the
    stance of ``stride``."""

    stride: int
    tick: int
    torque: float


@dataclass(frozen=True)
class StatusRecord:
    stride: int
    t: float
    kind: str
    reason: str
    fatal: bool


@dataclass(frozen=True)
class StrideRecord:
    """Stride k: from apex k through the stance after it (to apex k + 1, if recorded).

    ``command`` is the command the plant applied at that stance's touchdown (None if the stance was not
    reached, or if no recorded command matches the touchdown, see :func:`.strides.applied_commands`).
    Energy flows [J] are those of the stance after apex k (NaN if apex k + 1 was not recorded).
    ``failure`` is the status kind that ended the run during this stride, with its reason.

    Perturbations: y is the apex height in the world frame, ``ground`` that of the stance before the apex
    (y - ground the height the maps and policies use), ``stance_ground`` that of this stride's stance (NaN
    without a touchdown); measured_y, measured_xdot: the apex as the controller's sensor reported it;
    angle_error [rad]: the placement error drawn for the stride; placed_angle [rad]: where the leg landed
    (the command's angle plus the placement error, NaN without a command); push [m/s]:
    applied right after the apex; saturated: |tau0| exceeded tau_max.

    Stance feedback: ``command`` is None and ``stance_feedback`` the stance as applied, its touchdown angle
    and the torques held (sample times on the plant's clock,
    :class:`~tdslip_ros.model.plant.stance_laws.RecordedTorques`); saturated: one of them is at tau_max.

    A rigid body: pitch [rad] and pitch_rate [rad/s] at the apex (0 for the fixed body).
    """

    stride: int
    t: float
    x: float
    y: float
    xdot: float
    energy: float
    command: StanceCommand | None
    policy: str
    touchdown_time: float
    liftoff_time: float
    hip_work: float
    damping_loss: float
    spring_loss: float
    failure: str | None
    failure_reason: str
    ground: float = 0.0
    stance_ground: float = math.nan
    measured_y: float = math.nan
    measured_xdot: float = math.nan
    angle_error: float = 0.0
    placed_angle: float = math.nan
    push: float = 0.0
    saturated: bool = False
    stance_feedback: StanceFeedback | None = None
    pitch: float = 0.0
    pitch_rate: float = 0.0

    @property
    def height(self) -> float:
        """The apex height above the ground of the last stance [m]."""
        return self.y - self.ground

    @property
    def apex(self) -> ApexState:
        """The apex as the model takes it: its height above the ground of the last stance, speed and pitch."""
        return ApexState(self.height, self.xdot, self.pitch, self.pitch_rate)

    @property
    def seen_apex(self) -> ApexState:
        """The apex as the controller was given it: measured, above the ground of the last stance (the true
        one where the recording predates the sensor's model), with the pitch."""
        if math.isnan(self.measured_y):
            return self.apex
        return ApexState(self.measured_y - self.ground, self.measured_xdot, self.pitch, self.pitch_rate)


@dataclass(frozen=True)
class Samples:
    """1 kHz state and ground reaction force, as arrays over the samples (SI; phase 1 = stance); a rigid
    body's pitch and pitch rate (0 for the fixed body, and in a bag recorded before tdslip_msgs 0.2.0)."""

    t: FloatArray
    stride: npt.NDArray[np.int64]
    phase: npt.NDArray[np.int64]
    x: FloatArray
    y: FloatArray
    xdot: FloatArray
    ydot: FloatArray
    toe_x: FloatArray
    toe_y: FloatArray
    r: FloatArray
    theta: FloatArray
    rdot: FloatArray
    thetadot: FloatArray
    hip_torque: FloatArray
    energy: FloatArray
    ground_height: FloatArray
    pitch: FloatArray
    pitch_rate: FloatArray
    grf_t: FloatArray
    grf_x: FloatArray
    grf_y: FloatArray

    def __len__(self) -> int:
        return len(self.t)


@dataclass(frozen=True)
class Run:
    """A recorded run, tidy. ``params`` are the hopper parameters (given, stored or inferred, see
    ``params_source``); ``outcome`` the fatal status that ended the run (None if the recording
    ends before the run did)."""

    path: Path
    params: HopperParams
    params_source: str
    strides: tuple[StrideRecord, ...]
    apexes: tuple[ApexRecord, ...]
    contacts: tuple[ContactRecord, ...]
    commands: tuple[CommandRecord, ...]
    statuses: tuple[StatusRecord, ...]
    samples: Samples
    outcome: StatusRecord | None
    message_counts: dict[str, int]
    custom_data: dict[str, str]
    perturbations: Perturbations = field(default_factory=Perturbations)
    controller_params: HopperParams | None = None
    """The hopper the controller planned with (None: the plant's, ``params``)."""
    samples_recorded: int = 0
    """The state samples recorded; ``samples`` holds them all, up to FULL_RATE_SAMPLES of them."""
    sample_bucket: float = 0.0
    """0: ``samples`` holds every recorded sample; else the recording was long, and outside the windows
    of :mod:`.sample_keeping` it holds one sample per this many seconds [s]."""

    @property
    def planner(self) -> HopperParams:
        """The hopper the controller planned with: controller_params, else the plant's."""
        return self.params if self.controller_params is None else self.controller_params

    @property
    def saturated_strides(self) -> int:
        return sum(s.saturated for s in self.strides)

    @property
    def policies(self) -> tuple[str, ...]:
        """Names of the policies whose commands were applied, in order of first use."""
        applied = (s for s in self.strides if s.command is not None or s.stance_feedback is not None)
        return tuple(dict.fromkeys(s.policy for s in applied))

    @property
    def ending(self) -> str:
        """How the run ended: one of report_text.RUN_ENDINGS ("completed", "stopped", "failed", "unknown"),
        from the Status that ended it (the plant marks it ``fatal``, whether the run failed or completed)."""
        outcome = self.outcome
        if outcome is None:
            return "unknown"
        if outcome.kind != RUN_COMPLETE:
            return "failed"
        return "stopped" if outcome.reason == STOP_REQUESTED else "completed"

    @property
    def mismatch(self) -> dict[str, float] | None:
        """The factors by which the controller's model differs from the plant's (None: it does not)."""
        if self.planner == self.params:
            return None
        return {
            name: getattr(self.planner, field) / getattr(self.params, field)
            for name, field in MISMATCH_FIELDS.items()
        }

    @property
    def failure_location(self) -> dict[str, float] | None:
        """Where a failed run failed: the body's x and the ground under it at the last sample, and the toe
        and ground of the failed stride's stance if it touched down (None for a run that did not fail)."""
        if self.outcome is None or self.outcome.kind not in FAILURE_KINDS:
            return None
        failed = next((s for s in self.strides if s.failure is not None), self.strides[-1])
        touchdown = next(
            (c for c in self.contacts if c.kind == "touchdown" and c.stride == failed.stride), None
        )
        samples = self.samples
        return {
            "x_m": float(samples.x[-1]) if len(samples) else failed.x,
            "ground_under_body_m": float(samples.ground_height[-1]) if len(samples) else failed.ground,
            "toe_x_m": math.nan if touchdown is None else touchdown.state.toe_x,
            "stance_ground_m": math.nan if touchdown is None else touchdown.ground,
        }

    def apex_array(self) -> FloatArray:
        """(n, 2) apex heights above the ground of the last stance [m] and speeds [m/s] of the recorded
        strides (on flat ground the recorded heights)."""
        return np.array([(s.height, s.xdot) for s in self.strides], dtype=float).reshape(-1, 2)
