"""The batched exact stance: DOP853 over many lanes at once, from touchdown to each lane's first terminal
event, vectorised with numpy (the stance of :mod:`.batch`'s strides).

Stance (eq. 2 with the ramp torque of eq. 18, :mod:`.dynamics`) is integrated by the DOP853 Runge-Kutta
pair (scipy's coefficients) with a step size adapted per lane, scipy's error norm and step-size rule, and
the stance split at the kinks of the torque (the end of a saturation, the ramp end s = t_f; under stance
feedback, each lane's sample instants, where its law sets the torque it holds next). When a lane's
step crosses a terminal event (liftoff, reversal, fall; see :func:`.dynamics.stance_event_values`), the
lane stops and keeps the step's start as a bracket; all brackets are then solved together by safeguarded
Newton iteration, each trial being a DOP853 step of the trial length from the bracket start, to 1e-14 s.
Lanes that finish are dropped from the arrays, so the work follows the lanes still in stance. A lane's
result depends on that lane alone.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Protocol, Self

import numpy as np
import numpy.typing as npt
from scipy.integrate._ivp import dop853_coefficients as _dop853

from tdslip_ros.model import dynamics
from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.events import FailureKind
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.stance_laws import StanceLaw, StanceSample, clip_torque, first_sample

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

# DOP853 (Hairer, Norsett & Wanner), the tableau scipy's solve_ivp uses; stage 12 is the FSAL stage. Held
# C-contiguous: compiled kernels (exact_kernels) take them as constants, which numba caches only then.
STAGES = _dop853.N_STAGES
A: FloatArray = np.ascontiguousarray(_dop853.A[:STAGES, :STAGES])
B: FloatArray = np.ascontiguousarray(_dop853.B)
C: FloatArray = np.ascontiguousarray(_dop853.C[:STAGES])
E3: FloatArray = _dop853.E3
E5: FloatArray = _dop853.E5
SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0  # scipy's step-size rule
ERROR_EXPONENT = -1.0 / 8.0
INITIAL_STEP_PERIODS = 0.01  # first step, in natural periods of the leg spring
EVENT_TIME_TOLERANCE = 1e-14  # s
MAX_ROOT_ITERATIONS = 100

# How a lane's stance ends (integrate_stance's outcome per lane).
STANCE_LIFTOFF, STANCE_REVERSAL, STANCE_FALL, STANCE_TIME_LIMIT, STANCE_STEP_COLLAPSE = 0, 1, 2, 3, 4
STANCE_FAILURES = {
    STANCE_REVERSAL: FailureKind.REVERSAL,
    STANCE_FALL: FailureKind.FALL,
    STANCE_TIME_LIMIT: FailureKind.NO_LIFTOFF,
    STANCE_STEP_COLLAPSE: FailureKind.STATE_LIMIT,
}
"""The failure each outcome of a stance other than liftoff is (a collapsed step size: state_limit)."""
_TERMINAL_EVENTS = (
    dynamics.STANCE_EVENT_NAMES.index("liftoff"),
    dynamics.STANCE_EVENT_NAMES.index("reversal"),
    dynamics.STANCE_EVENT_NAMES.index("fall"),
)
STATE_SIZE = 6  # r, theta, rdot, thetadot, hip work, damper loss


class LaneField(Protocol):
    """The stance right-hand side of a set of lanes, in place into ``out``, and the kinks of its torque:
    :class:`StanceField` for ramps, :class:`SampledField` under stance feedback."""

    def __call__(self, s: FloatArray, y: FloatArray, out: FloatArray) -> None: ...

    def kink(self, s: FloatArray) -> FloatArray:
        """The next kink of each lane's torque after s."""

    def sample(self, landed: BoolArray, s: FloatArray, y: FloatArray) -> BoolArray | None:
        """The lanes ``landed`` stand on their kink at (s, y). Returns where the torque jumped there (the
        field must be evaluated again), or None for a torque that never jumps."""

    def select(self, keep: BoolArray) -> None:
        """Keep only these lanes."""

    def take(self, lanes: BoolArray) -> Self:
        """A field of these lanes, as they are now (for their event brackets)."""

    @classmethod
    def concatenate(cls, fields: list[Self]) -> Self:
        """One field of the lanes of ``fields``, in order."""


class _PerLane:
    """Lane selection for a field whose per-lane arrays are the attributes named in PER_LANE (None where
    a kind is off)."""

    PER_LANE: tuple[str, ...] = ()

    def select(self, keep: BoolArray) -> None:
        for name in self.PER_LANE:
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, value[keep])

    def take(self, lanes: BoolArray) -> Self:
        taken = copy.copy(self)
        taken.select(lanes)
        return taken

    @classmethod
    def concatenate(cls, fields: list[Self]) -> Self:
        joined = copy.copy(fields[0])
        for name in cls.PER_LANE:
            if getattr(joined, name) is not None:
                setattr(joined, name, np.concatenate([getattr(field, name) for field in fields]))
        return joined


class StanceField(_PerLane):
    """The stance right-hand side for lanes under the torque ramps of eq. 18, saturated at tau_max unless
    None. The torque is a function of s, continuous at its kinks."""

    PER_LANE = ("tau0", "t_f", "tau_max", "saturation_end")

    def __init__(
        self, params: HopperParams, tau0: FloatArray, t_f: FloatArray, tau_max: FloatArray | None
    ) -> None:
        self.params, self.tau0, self.t_f, self.tau_max = params, tau0, t_f, tau_max
        self.saturation_end = None if tau_max is None else dynamics.saturation_end(tau0, t_f, tau_max)

    def kink(self, s: FloatArray) -> FloatArray:
        """The next kink of the torque after s (the end of the saturation, else the ramp's end t_f)."""
        if self.saturation_end is None:
            return self.t_f
        return np.where(s < self.saturation_end, self.saturation_end, self.t_f)

    def sample(self, landed: BoolArray, s: FloatArray, y: FloatArray) -> BoolArray | None:
        return None

    def __call__(self, s: FloatArray, y: FloatArray, out: FloatArray) -> None:
        r, theta, rdot, thetadot = y[0], y[1], y[2], y[3]
        tau = dynamics.hip_torque(self.tau0, self.t_f, s, self.tau_max)
        out[:] = dynamics.stance_derivatives(
            self.params, r, np.sin(theta), np.cos(theta), rdot, thetadot, tau
        )


class SampledField(_PerLane):
    """The stance right-hand side for lanes under stance feedback (:mod:`.stance_laws`): each lane holds
    the torque its law set at its last sample instant (zero before its first), clipped at ``limit``; its
    kinks are its sample instants index * period, on the absolute clock of its touchdown t_touchdown.

    ``lane`` indexes the law's per-lane fields; ``saturated`` (by that index, over every lane of the
    stride) records whether tau_max clipped a sample (tau_max None: no saturation)."""

    PER_LANE = ("t_touchdown", "limit", "tau_max", "lane", "index", "held")

    def __init__(
        self,
        params: HopperParams,
        law: StanceLaw,
        period: float,
        t_touchdown: FloatArray,
        limit: FloatArray,
        tau_max: FloatArray | None,
        lane: IntArray,
        y0: FloatArray,
        saturated: BoolArray,
    ) -> None:
        self.params, self.law, self.period = params, law, period
        self.t_touchdown, self.limit, self.tau_max, self.lane = t_touchdown, limit, tau_max, lane
        self.index: FloatArray = first_sample(t_touchdown, period)
        self.held = np.zeros(t_touchdown.size)
        self.saturated = saturated
        self.sample(self.kink(np.zeros(t_touchdown.size)) == 0.0, np.zeros(t_touchdown.size), y0)

    def kink(self, s: FloatArray) -> FloatArray:
        kinks: FloatArray = self.index * self.period - self.t_touchdown
        return kinks

    def sample(self, landed: BoolArray, s: FloatArray, y: FloatArray) -> BoolArray | None:
        if not landed.any():
            return landed
        at = np.flatnonzero(landed)
        t = self.index[at] * self.period
        seen = StanceSample(t, s[at], y[0, at], y[1, at], y[2, at], y[3, at], self.held[at])
        tau = np.broadcast_to(np.asarray(self.law.torque(seen, self.lane[at]), dtype=np.float64), at.shape)
        if self.tau_max is not None:
            self.saturated[self.lane[at]] |= np.abs(tau) > self.tau_max[at]
        self.held[at] = clip_torque(tau, self.limit[at])
        self.index[at] += 1.0
        return landed

    def __call__(self, s: FloatArray, y: FloatArray, out: FloatArray) -> None:
        r, theta, rdot, thetadot = y[0], y[1], y[2], y[3]
        out[:] = dynamics.stance_derivatives(
            self.params, r, np.sin(theta), np.cos(theta), rdot, thetadot, self.held
        )


def _dop853_step(field: LaneField, s: FloatArray, y: FloatArray, h: FloatArray, k: FloatArray) -> FloatArray:
    """One DOP853 step of lengths h; k[0] must hold the field at (s, y); fills k[1:12]."""
    for stage in range(1, STAGES):
        field(s + C[stage] * h, y + h * _combine(A[stage, :stage], k), k[stage])
    return y + h * _combine(B, k)


def _combine(weights: FloatArray, k: FloatArray) -> FloatArray:
    """sum_j weights[j] k[j], term by term in the order of j, skipping the tableau's zero weights.

    Elementwise, so every lane's value is a function of that lane alone: a BLAS product (np.tensordot)
    sums in an order that depends on how many lanes the call holds, which would make a lane's last bits
    depend on the other lanes of its call (and a study's results on how it is split into calls)."""
    terms = [(weight, k[j]) for j, weight in enumerate(weights) if weight != 0.0]
    total: FloatArray = terms[0][0] * terms[0][1]
    term = np.empty_like(total)
    for weight, stage in terms[1:]:
        np.multiply(stage, weight, out=term)
        total += term
    return total


def _terminal_values(params: HopperParams, y: FloatArray) -> FloatArray:
    values = dynamics.stance_event_values(params, y[0], np.cos(y[1]), y[2], y[3])
    stacked: FloatArray = np.stack([values[i] for i in _TERMINAL_EVENTS])
    return stacked


def integrate_stance(
    params: HopperParams, y0: FloatArray, field: LaneField, t_limit: float, rtol: float, atol: float
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Integrate lanes from touchdown (s = 0) to their first terminal event or the time limit, under the
    torques of ``field`` (a StanceField or a SampledField of these lanes, which it consumes).

    Returns per lane the outcome (STANCE_LIFTOFF, STANCE_REVERSAL, STANCE_FALL, STANCE_TIME_LIMIT or
    STANCE_STEP_COLLAPSE), its time s since touchdown and the stance state there (the last accepted one on
    a step collapse).
    """
    lanes = y0.shape[1]
    outcome = np.full(lanes, STANCE_TIME_LIMIT, dtype=np.int64)
    s_end = np.full(lanes, t_limit)
    y_end = np.empty_like(y0)
    # Brackets of the lanes whose last step crossed a terminal event.
    bracket_lane: list[IntArray] = []
    bracket_parts: list[tuple[npt.NDArray[Any], ...]] = []
    bracket_fields: list[LaneField] = []

    lane = np.arange(lanes)
    s = np.zeros(lanes)
    y = y0.copy()
    k = np.empty((STAGES + 1, STATE_SIZE, lanes))
    field(s, y, k[0])
    g_before = _terminal_values(params, y)
    h = np.full(lanes, INITIAL_STEP_PERIODS * 2.0 * math.pi / params.omega0)
    rejected = np.zeros(lanes, dtype=bool)
    while lane.size:
        kink = field.kink(s)
        in_ramp = s < kink
        h = np.where(in_ramp, np.minimum(h, kink - s), h)
        h = np.minimum(h, t_limit - s)
        # A trial step may overflow (a stiff leg, a too long first step); it then fails its error test.
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            y_new = _dop853_step(field, s, y, h, k)
            field(s + h, y_new, k[STAGES])
            scale = atol + np.maximum(np.abs(y), np.abs(y_new)) * rtol
            err5 = np.sum((_combine(E5, k) / scale) ** 2, axis=0)
            err3 = np.sum((_combine(E3, k) / scale) ** 2, axis=0)
            denominator = err5 + 0.01 * err3
            error = np.where(denominator > 0.0, h * err5 / np.sqrt(denominator * STATE_SIZE), 0.0)
            # A step that left the floats (overflow, NaN) fails its error test and shrinks by MIN_FACTOR.
            left_floats = np.isnan(denominator) | np.isnan(error) | ~np.isfinite(y_new).all(axis=0)
            error = np.where(left_floats, np.inf, error)
            growth = SAFETY * error**ERROR_EXPONENT
        accepted = error < 1.0
        factor = np.where(
            accepted,
            np.where(rejected, np.minimum(1.0, growth), np.minimum(MAX_FACTOR, growth)),
            np.maximum(MIN_FACTOR, growth),
        )
        g_after = _terminal_values(params, y_new)
        crossed = (g_before > 0.0) & (g_after <= 0.0) & accepted
        stops = crossed.any(axis=0)
        if stops.any():
            bracket_lane.append(lane[stops])
            bracket_fields.append(field.take(np.asarray(stops)))
            bracket_parts.append(
                (
                    s[stops],
                    y[:, stops],
                    h[stops],
                    k[0][:, stops],
                    crossed[:, stops],
                    g_before[:, stops],
                    g_after[:, stops],
                )
            )
        advance = accepted & ~stops
        # Land exactly on the kink, so that the next segment (torque-free after t_f) starts there.
        on_kink = in_ramp & (h == kink - s)
        s_next = np.where(on_kink, kink, s + h)
        s = np.where(advance, s_next, s)
        y = np.where(advance, y_new, y)
        k[0] = np.where(advance, k[STAGES], k[0])
        jumped = field.sample(advance & on_kink, s, y)
        if jumped is not None and jumped.any():  # the step's last stage saw the torque held before
            fresh = np.empty_like(k[0])
            field(s, y, fresh)
            k[0] = np.where(jumped, fresh, k[0])
        g_before = np.where(advance, g_after, g_before)
        rejected = ~accepted
        h = h * factor
        at_limit = advance & (s >= t_limit)
        y_end[:, lane[at_limit]] = y[:, at_limit]
        collapsed = rejected & (h < 10.0 * (np.nextafter(s, np.inf) - s))  # scipy's smallest step
        outcome[lane[collapsed]], s_end[lane[collapsed]] = STANCE_STEP_COLLAPSE, s[collapsed]
        y_end[:, lane[collapsed]] = y[:, collapsed]
        keep = ~stops & ~at_limit & ~collapsed
        if not keep.all():
            lane, s, y, h, rejected, g_before = (
                lane[keep],
                s[keep],
                y[:, keep],
                h[keep],
                rejected[keep],
                g_before[:, keep],
            )
            k = np.ascontiguousarray(k[:, :, keep])
            field.select(keep)

    if bracket_lane:
        lanes_hit = np.concatenate(bracket_lane)
        parts = [np.concatenate(p, axis=-1) for p in zip(*bracket_parts, strict=True)]
        event, s_event, y_event = _locate(params, type(field).concatenate(bracket_fields), *parts)
        outcome[lanes_hit], s_end[lanes_hit], y_end[:, lanes_hit] = event, s_event, y_event
    return outcome, s_end, y_end


def _locate(
    params: HopperParams,
    field: LaneField,
    s0: FloatArray,
    y0: FloatArray,
    h: FloatArray,
    k0: FloatArray,
    crossed: npt.NDArray[np.bool_],
    g_start: FloatArray,
    g_end: FloatArray,
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Earliest terminal event inside each bracket [s0, s0 + h], by safeguarded Newton iteration.

    The function is the smallest of the crossed events' values after a DOP853 step of trial
    length sigma from the bracket start (positive at 0, non-positive at h); its slope is the
    event's rate at that state. A Newton step that leaves the shrinking bracket is replaced by
    bisection. Converges in 2-3 steps from the regula falsi start (the time a step costs).
    """
    lanes = np.arange(s0.size)
    k = np.empty((STAGES + 1, STATE_SIZE, s0.size))
    k[0] = k0
    velocity = np.empty((STATE_SIZE, s0.size))
    a, b = np.zeros_like(s0), h.copy()
    g_a = np.where(crossed, g_start, np.inf).min(axis=0)
    g_b = np.where(crossed, g_end, np.inf).min(axis=0)
    sigma = np.clip(g_a * h / (g_a - g_b), 0.0, h)
    for _ in range(MAX_ROOT_ITERATIONS):
        y_sigma = _dop853_step(field, s0, y0, sigma, k)
        values = np.where(crossed, _terminal_values(params, y_sigma), np.inf)
        active = np.argmin(values, axis=0)
        g = values[active, lanes]
        field(s0 + sigma, y_sigma, velocity)
        rate = _terminal_rates(params, y_sigma, velocity)[active, lanes]
        a, b = np.where(g > 0.0, sigma, a), np.where(g <= 0.0, sigma, b)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton_step = g / rate
        converged = (np.abs(newton_step) <= EVENT_TIME_TOLERANCE) | (g == 0.0)
        if converged.all():
            break
        newton = sigma - newton_step
        sigma = np.where(converged, sigma, np.where((newton > a) & (newton < b), newton, 0.5 * (a + b)))
    return active.astype(np.int64), s0 + sigma, y_sigma


def _terminal_rates(params: HopperParams, y: FloatArray, velocity: FloatArray) -> FloatArray:
    theta = y[1]
    rates = dynamics.stance_event_rates(
        params, y[0], np.sin(theta), np.cos(theta), y[2], y[3], velocity[2], velocity[3]
    )
    stacked: FloatArray = np.stack([rates[i] for i in _TERMINAL_EVENTS])
    return stacked
