"""Strides found in a :class:`~.measured.MeasuredRun`: apex, touchdown, liftoff, next apex, the touchdown
angle, and whether the stride can serve (docs/identify.md, "Strides from data").

Stance is found, in this order of preference, from the vertical ground force (above FORCE_ON of the run's
peak force to enter, below FORCE_OFF to leave: a threshold with hysteresis, so that noise around one level
does not chatter), from the contact flag, or from the leg length against the rest length (shorter than
r0 (1 - LEG_ON) to enter, longer than r0 (1 - LEG_OFF) to leave). Liftoff is where the force, extrapolated
from the last two stance samples, reaches zero; the contact flag and the leg length cross their leaving level
there, interpolated between the two samples around it.

Touchdown and its angle come from the leg's geometry where the map gives it (leg length and angle, or the
toe): the toe is fixed in stance, so the first stance sample places it; touchdown is where the body's
distance from that toe, interpolated from the last flight sample, equals the leg length of that flight
sample, and the touchdown angle is the direction from the body to the toe then (atan2 of the toe ahead of
the body over the body above the toe: the model's theta, positive with the toe ahead). Without the leg's
geometry touchdown is where the detection signal rises through its leaving level, and the angle is unknown.

An apex is where the vertical velocity falls through zero in flight, interpolated. A stride runs from one
apex to the next; one with a gap in any source, without exactly one stance between its apexes, without a
next apex or without a touchdown angle is set aside (``usable`` False) with its reason, never guessed.
Timed with the reading by bench/bench_measured.py (docs/benchmarks.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tdslip_ros.analysis.measured import FloatArray, MeasuredRun, MeasuredStride
from tdslip_ros.analysis.measured_reading import MeasuredDataError

FORCE_ON = 0.05
"""Stance begins where the vertical ground force exceeds this fraction of its 99.9th percentile."""
FORCE_OFF = 0.02
"""... and ends where it falls below this fraction."""
LEG_ON = 2e-3
"""Without force or contact: stance begins where the leg is shorter than r0 (1 - LEG_ON) ..."""
LEG_OFF = 5e-4
"""... and ends where it is longer than r0 (1 - LEG_OFF)."""


class NoStanceError(MeasuredDataError):
    """The recording holds no stance, or nothing to find one from."""


@dataclass(frozen=True)
class StanceSignal:
    """What stance is found from: a signal that is high in stance, its entering and leaving levels, and
    the words for the report."""

    values: FloatArray
    enter: float
    leave: float
    how: str
    vanishes: bool = False
    """The signal falls to zero at liftoff (a force): liftoff is where the line through the last two stance
    samples reaches zero, not where it passes the leaving level (which comes up to a sample early)."""


def stance_signal(run: MeasuredRun, rest_length: float | None = None) -> StanceSignal:
    """The signal stance is detected from (module docstring); NoStanceError if there is none."""
    if run.ground_force is not None:
        force = run.ground_force[:, 1]
        peak = float(np.percentile(force, 99.9))
        if not peak > 0.0:
            raise NoStanceError("no stance: the vertical ground force is never positive")
        how = "the vertical ground force, with hysteresis"
        return StanceSignal(force, FORCE_ON * peak, FORCE_OFF * peak, how, vanishes=True)
    if run.contact is not None:
        return StanceSignal(run.contact.astype(float), 0.5, 0.5, "the contact flag")
    if run.leg_length is not None and rest_length is not None:
        compression = (rest_length - run.leg_length) / rest_length
        return StanceSignal(compression, LEG_ON, LEG_OFF, f"the leg length against r0 = {rest_length:g} m")
    raise NoStanceError(
        "no way to find stance: the map gives no ground force, no contact and no leg length "
        "(or no rest length was given for it)"
    )


def _hysteresis(signal: StanceSignal) -> npt.NDArray[np.bool_]:
    """True in stance: entered above ``enter``, left below ``leave``, held in between (vectorised)."""
    decided = np.full(len(signal.values), -1, dtype=np.int8)
    decided[signal.values > signal.enter] = 1
    decided[signal.values < signal.leave] = 0
    index = np.where(decided >= 0, np.arange(len(decided)), 0)
    np.maximum.accumulate(index, out=index)
    return decided[index] == 1


def _crossing(time: FloatArray, values: FloatArray, level: float, before: int) -> float:
    """The time where ``values`` crosses ``level`` between samples ``before`` and ``before + 1``."""
    v0, v1 = values[before], values[before + 1]
    fraction = 0.0 if v1 == v0 else (level - v0) / (v1 - v0)
    return float(time[before] + min(max(fraction, 0.0), 1.0) * (time[before + 1] - time[before]))


def _liftoff(time: FloatArray, signal: StanceSignal, up: int) -> float:
    """Liftoff between the last stance sample ``up - 1`` and the first flight sample ``up``."""
    values = signal.values
    if not signal.vanishes or up < 2:
        return _crossing(time, values, signal.leave, up - 1)
    last = up - 1  # the last sample of the falling force, which may lie below the leaving level
    while last + 2 < len(values) and 0.0 < values[last + 1] < values[last]:
        last += 1
    fraction = values[last] / (values[last - 1] - values[last]) if values[last - 1] > values[last] else 1.0
    return float(time[last] + min(max(fraction, 0.0), 1.0) * (time[last + 1] - time[last]))


@dataclass(frozen=True)
class Touchdown:
    time: float
    angle: float
    reason: str = ""
    index: int = -1
    """The sample before it (-1: the last flight sample by the detection's leaving level)."""


TOUCHDOWN_LOOKBACK = 5
"""Samples before the last flight sample (by the detection's leaving level) searched for the touchdown."""


def _touchdown(run: MeasuredRun, signal: StanceSignal, first: int, last_flight: int) -> Touchdown:
    """Touchdown before the stance sample ``first`` (module docstring): the toe is placed from that
    sample, the flight's leg length is the longest among the samples before it, and touchdown lies between
    the last sample whose body is that far from the toe and the next."""
    time = run.time
    if run.leg_length is None or run.leg_angle is None:
        when = _crossing(time, signal.values, signal.leave, last_flight)
        return Touchdown(when, math.nan, "no leg geometry in the map (leg length and angle, or the toe)")
    start = max(last_flight - TOUCHDOWN_LOOKBACK, 0)
    r, theta = run.leg_length[first], run.leg_angle[first]
    toe = run.body_position[first] + r * np.array([math.sin(theta), -math.cos(theta)])
    flight_length = float(np.max(run.leg_length[start:first]))
    distance = np.hypot(*(run.body_position[start : first + 1] - toe).T) - flight_length
    away = np.flatnonzero(distance >= 0.0)
    if not len(away) or away[-1] == len(distance) - 1:
        return Touchdown(
            _crossing(time, signal.values, signal.leave, last_flight),
            math.nan,
            f"the leg did not touch down between {time[start]:.4f} s and {time[first]:.4f} s by its geometry",
        )
    a = start + int(away[-1])
    fraction = float(distance[away[-1]] / (distance[away[-1]] - distance[away[-1] + 1]))
    body = run.body_position[a] + fraction * (run.body_position[a + 1] - run.body_position[a])
    angle = math.atan2(float(toe[0] - body[0]), float(body[1] - toe[1]))
    return Touchdown(float(time[a] + fraction * (time[a + 1] - time[a])), angle, index=a)


def find_strides(run: MeasuredRun, rest_length: float | None = None) -> list[MeasuredStride]:
    """The strides of ``run`` (module docstring), one per recorded apex that a stance follows, in order.
    ``rest_length`` [m] is needed only where stance must be found from the leg length. NoStanceError if
    the run holds no stance."""
    signal = stance_signal(run, rest_length)
    stance = _hysteresis(signal)
    time, n = run.time, len(run.time)
    change = np.diff(stance.astype(np.int8))
    touchdowns = np.flatnonzero(change == 1) + 1  # the first stance sample
    liftoffs = np.flatnonzero(change == -1) + 1  # the first flight sample
    if not len(touchdowns) and not len(liftoffs):
        raise NoStanceError(f"no stance in the recording ({signal.how} never marks one)")
    below = signal.values <= signal.leave
    last_below = np.maximum.accumulate(np.where(below, np.arange(n), -1))
    vy = run.body_velocity[:, 1]
    falling = np.flatnonzero((vy[:-1] > 0.0) & (vy[1:] <= 0.0) & ~stance[:-1] & ~stance[1:])
    apex_times = time[falling] + vy[falling] / (vy[falling] - vy[falling + 1]) * (
        time[falling + 1] - time[falling]
    )
    in_gap = run.in_gap if run.in_gap is not None else np.zeros(n, dtype=bool)
    gap_before = np.concatenate([[0], np.cumsum(in_gap)])
    strides = []
    for k, (apex, apex_time) in enumerate(zip(falling, apex_times, strict=True)):
        after = int(falling[k + 1]) if k + 1 < len(falling) else n
        downs = touchdowns[(touchdowns > apex) & (touchdowns <= after)]
        ups = liftoffs[(liftoffs > apex) & (liftoffs <= after)]
        if not len(downs):
            continue  # a flight without a stance after it (the recording's end): no stride begins
        reasons = []
        next_apex, next_time = (after, float(apex_times[k + 1])) if k + 1 < len(falling) else (-1, math.nan)
        if next_apex < 0:
            reasons.append("the recording ends before the next apex")
        if len(downs) > 1 or len(ups) > 1:
            reasons.append(f"{max(len(downs), len(ups))} stances between two apexes (an apex not found)")
        if not len(ups):
            reasons.append("no liftoff recorded")
        down = int(downs[0])
        last_flight = int(last_below[down - 1])
        touchdown = (
            _touchdown(run, signal, down, last_flight)
            if last_flight >= 0
            else Touchdown(math.nan, math.nan, "no flight sample before the stance")
        )
        if touchdown.reason:
            reasons.append(touchdown.reason)
        up = int(ups[0]) if len(ups) else -1
        liftoff_time = _liftoff(time, signal, up) if up > 0 else math.nan
        end = next_apex if next_apex >= 0 else n - 1
        if gap_before[end + 1] - gap_before[apex] > 0:
            gap = np.flatnonzero(in_gap[apex : end + 1]) + apex
            reasons.append(f"a gap in the recording from {time[gap[0]]:.4f} s to {time[gap[-1]]:.4f} s")
        strides.append(
            MeasuredStride(
                apex_index=int(apex),
                touchdown_index=touchdown.index if touchdown.index >= 0 else max(last_flight, 0),
                liftoff_index=up - 1 if up > 0 else -1,
                next_apex_index=next_apex,
                apex_time=float(apex_time),
                touchdown_time=touchdown.time,
                liftoff_time=liftoff_time,
                next_apex_time=next_time,
                touchdown_angle=touchdown.angle,
                usable=not reasons,
                reason="; ".join(reasons),
            )
        )
    return strides
