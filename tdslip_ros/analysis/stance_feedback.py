"""The stance-feedback strides of a recorded run, predicted on the exact map from their recorded torques.

A stride under stance feedback has no ramp for the maps of :mod:`.compare` to replay. Its hip held the torques
the plant recorded on ``tdslip/applied_torque``, each from its tick on (zero-order hold, as applied, zero from
touchdown to the first tick: :mod:`tdslip_ros.model.plant.stance_laws`). The exact map
(:func:`tdslip_ros.model.plant.exact_map.apex_return_map`, DOP853 with event location) replays them
(:class:`~tdslip_ros.model.plant.stance_laws.RecordedTorques`, the stride's ``stance_feedback``) from the
recorded apex at its time on the plant's clock, which puts the replay on the plant's tick grid, with the run's
perturbations as :mod:`.compare` applies them. The prediction then differs from the recorded next apex by the
1 kHz plant's own integration error alone (RK4, 4 sub-steps per tick: :mod:`tdslip_ros.model.plant.stepper`).
Recordings of several epochs (resets) are refused by the reader, so the plant's clock is the epoch's.

**The policy replayed** (:func:`law_deviation`): a stance-feedback policy of the suite
(``model.policies.registry.STANCE_FEEDBACK_POLICIES``) is checked as a ramp policy is in :mod:`.compare`. Its
law, computing with the hopper the controller planned with, is evaluated on the recorded state of each tick at
which a torque was applied (the state the stance controller answered, with the torque held until then) and
clipped as the controller and the plant clip it; its touchdown angle is compared with the one applied.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tdslip_ros.analysis.records import Run
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.perturbations import StrideConditions
from tdslip_ros.model.plant.stance_laws import (
    RECORD_TIME_TOLERANCE,
    RecordedTorques,
    StanceSample,
    clip_torque,
)
from tdslip_ros.model.policies.registry import PolicySpec

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class FeedbackPredictions:
    """Next apexes of the strides under stance feedback with a recorded next apex: recorded and replayed
    on the exact map, (n, 2) of (y [m, world frame], xdot [m/s]); NaN where the map foresaw a failure
    (``failures``: its kind, else None); a rigid body's pitch beside them."""

    stride: npt.NDArray[np.int64]
    recorded: FloatArray
    exact: FloatArray
    failures: list[str | None]
    recorded_pitch: FloatArray
    exact_pitch: FloatArray
    """A rigid body's next-apex (pitch [rad], pitch rate [rad/s]), (n, 2), recorded and replayed (NaN where
    the replay failed); 0 for the fixed body."""

    @property
    def error(self) -> FloatArray:
        """|exact - recorded| per stride, (n, 2) [m, m/s]."""
        return np.abs(self.exact - self.recorded)


def predict_stance_feedback(run: Run) -> FeedbackPredictions:
    """Replay each stance-feedback stride of ``run`` on the exact map (module docstring)."""
    by_stride = {s.stride: s for s in run.strides}
    perturbations = run.perturbations
    tau_max = float(perturbations.tau_max)
    rows, recorded, exact, failures, recorded_pitch, exact_pitch = [], [], [], [], [], []
    for stride in run.strides:
        after = by_stride.get(stride.stride + 1)
        if stride.stance_feedback is None or after is None:
            continue
        result = apex_return_map(
            run.params,
            stride.apex,
            stride.stance_feedback,
            apex_time=stride.t,
            conditions=StrideConditions(
                x=stride.x,
                ground=stride.ground,
                terrain=perturbations.terrain,
                tau_max=tau_max,
                push=stride.push,
                angle_error=stride.angle_error,
            ),
        )
        rows.append(stride.stride)
        recorded.append((after.y, after.xdot))
        recorded_pitch.append((after.pitch, after.pitch_rate))
        if result.apex is None:
            exact.append((np.nan, np.nan))
            exact_pitch.append((np.nan, np.nan))
            failures.append(None if result.failure is None else str(result.failure.value))
        else:
            assert result.ground is not None  # a stride that reached its next apex touched down
            exact.append((result.ground + result.apex.y, result.apex.xdot))
            exact_pitch.append((result.apex.pitch, result.apex.pitch_rate))
            failures.append(None)

    def pairs(values: list[tuple[float, float]]) -> FloatArray:
        return np.array(values, dtype=float).reshape(-1, 2)

    return FeedbackPredictions(
        stride=np.array(rows, dtype=np.int64),
        recorded=pairs(recorded),
        exact=pairs(exact),
        failures=failures,
        recorded_pitch=pairs(recorded_pitch),
        exact_pitch=pairs(exact_pitch),
    )


def law_deviation(run: Run, policy: PolicySpec) -> float:
    """Largest deviation of ``policy``'s stance feedback, replayed on the recorded stances (module docstring),
    from what was applied: each torque relative to the largest applied |torque| of the run, the touchdown
    angle relative to itself; NaN without a stance under feedback or with a torque at no recorded state."""
    limit = min(PlausibilityLimits.for_hopper(run.planner).max_torque, float(run.perturbations.tau_max))
    samples = run.samples
    replayed, applied, angle_deviation = [], [], 0.0
    for stride in run.strides:
        if stride.stance_feedback is None or not isinstance(stride.stance_feedback.law, RecordedTorques):
            continue
        feedback = policy.stance_feedback(run.planner, stride.seen_apex)
        recorded = stride.stance_feedback.law
        angle = stride.stance_feedback.touchdown_angle
        angle_deviation = max(angle_deviation, abs(feedback.touchdown_angle - angle) / abs(angle))
        at = np.clip(np.searchsorted(samples.t, recorded.times - RECORD_TIME_TOLERANCE), 0, len(samples) - 1)
        if not np.all(np.abs(samples.t[at] - recorded.times) <= RECORD_TIME_TOLERANCE):
            return math.nan
        sample = StanceSample(
            samples.t[at],
            samples.t[at] - stride.touchdown_time,
            samples.r[at],
            samples.theta[at],
            samples.rdot[at],
            samples.thetadot[at],
            samples.hip_torque[at],
            samples.pitch[at],
            samples.pitch_rate[at],
        )
        replayed.append(clip_torque(np.asarray(feedback.law.torque(sample), dtype=float), limit))
        applied.append(recorded.torques)
    if not applied:
        return math.nan
    torques, laws = np.concatenate(applied), np.concatenate(replayed)
    scale = max(float(np.max(np.abs(torques))), 1e-300)
    return max(angle_deviation, float(np.max(np.abs(laws - torques))) / scale)


def largest_errors(predictions: FeedbackPredictions) -> tuple[float, float] | None:
    """The largest next-apex errors (height [m], speed [m/s]) of the strides whose replay has an apex (a
    replay predicted to fail has none, and is counted among the failures); None without one."""
    return _largest(predictions.error)


def largest_pitch_errors(predictions: FeedbackPredictions) -> tuple[float, float] | None:
    """The largest next-apex errors of a rigid body's pitch [rad] and pitch rate [rad/s] where the replay has
    an apex; None without one."""
    return _largest(np.abs(predictions.exact_pitch - predictions.recorded_pitch))


def _largest(error: FloatArray) -> tuple[float, float] | None:
    replayed = error[~np.isnan(error).any(axis=1)]
    return (float(replayed[:, 0].max()), float(replayed[:, 1].max())) if len(replayed) else None


def feedback_summary(predictions: FeedbackPredictions) -> dict[str, Any]:
    """The replay's errors for the summary: strides, largest height and speed errors, and a rigid body's
    pitch and pitch rate errors (SI)."""
    largest, pitch = largest_errors(predictions), largest_pitch_errors(predictions)
    return {
        "strides": len(predictions.stride),
        "failures": sum(f is not None for f in predictions.failures),
        "max_height_error_m": None if largest is None else largest[0],
        "max_speed_error_m_per_s": None if largest is None else largest[1],
        "max_pitch_error_rad": None if pitch is None else pitch[0],
        "max_pitch_rate_error_rad_per_s": None if pitch is None else pitch[1],
    }
