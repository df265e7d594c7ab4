"""The hopper's k, c and r0 (and m) estimated from a recording's stances: :func:`identify`.

**The stance seen from the toe.** In stance the toe stands still on the ground. The leg's length r, angle
theta and their rates come from the recorded leg length and angle where the run has them, else from the body's
position relative to the toe: the toe is where the leg, at the recorded touchdown angle, meets the ground
(y = 0, the run's vertical position being the height above the ground) at touchdown. rdot and r thetadot are
the body's velocity along e_r = (-sin theta, cos theta) (toe to body) and e_theta = (-cos theta, -sin theta).

**The leg-axis force balance** (where force is recorded). The stance equations of
:mod:`tdslip_ros.model.dynamics` (eq. 2) are Newton's law for the body under gravity and the ground's force

    F = f_leg e_r + (tau / r) e_theta,      f_leg = k (r0 - r) - c rdot,

(:func:`.dynamics.ground_reaction_force`): the leg's axial spring-damper force plus the hip torque's
tangential force at the toe. Along the leg the hip torque drops out, so the recorded force's axial part
F . e_r = (k r0) - k r - c rdot is linear in (k r0, k, c): one linear least-squares problem over every
stance sample, r0 = (k r0)/k. The tangential part gives the hip torque, tau = r F . e_theta, where no torque
is recorded. The mass, where force is recorded, from m (a + g y_hat) = F: the acceleration a of the body
(the recorded velocity differentiated) regressed on F, which keeps the acceleration's noise in the
dependent variable.

**The exact stance** (where only kinematics are recorded). Each stance is integrated from its first sample's
state (DOP853 on :func:`.dynamics.stance_derivatives`, the model's one right-hand side) with trial
(k, c, r0) and the paper's ramp (tau0, t_f), or the recorded torque, and ``scipy.optimize.least_squares``
matches the recorded body positions. Kinematics alone fix only k/m, c/m and tau/m: the mass is the caller's.

**Uncertainty.** The pooled force balance's covariance is cluster-robust with the stances as clusters (the
residuals inside one stance are correlated: smoothing, model error), its interval Student's t with (stances
- parameters) degrees of freedom; r0's and m's by the delta method. The exact-stance fit pools its per-stance
estimates: their mean and the interval of the mean. A parameter is *identified* when its interval's half
width is at most ``IDENTIFIED_HALF_WIDTH`` of its scale (k, r0, m: their value; c: c at damping ratio
``DAMPING_RATIO_SCALE``, 2 zeta sqrt(m k), so that a leg without damping is judged in the same terms).
When one is not, the result says why: the condition number of the scaled problem above
``ILL_CONDITIONED`` (and the parameters of its weakest direction: what this data cannot tell apart), else
too much noise for its length.

**Per stance**: the estimates alone, the residual's rms, the hip torque's ramp (tau0, t_f fitted to the
measured or derived torque); **drift**: each parameter's per-stance estimates regressed on time, flagged where
the slope's t-statistic exceeds ``DRIFT_T`` and the change over the run exceeds both the pooled interval's
half width and ``DRIFT_FRACTION`` of the scale.

Speed: ``bench/bench_identification.py`` (docs/benchmarks.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy import integrate, optimize, stats

from tdslip_ros.analysis.measured import MeasuredRun, MeasuredStride
from tdslip_ros.model import dynamics
from tdslip_ros.model.params import HopperParams

FloatArray = npt.NDArray[np.float64]

CONFIDENCE = 0.95
"""The level of every confidence interval."""
IDENTIFIED_HALF_WIDTH = 0.05
"""A parameter is identified when its interval's half width is at most this fraction of its scale."""
DAMPING_RATIO_SCALE = 0.1
"""The damping ratio whose c, 2 zeta sqrt(m k), is the damping's scale (so c = 0 has a scale too)."""
SINGULAR = 1e10
"""Condition number above which the problem is ill-conditioned whatever the intervals say."""
ILL_CONDITIONED = 300.0
"""Condition number of the column-scaled problem above which an unidentified parameter is put down to the
data's conditioning (the weakest direction named) rather than to its noise. In the force balance it is
about r0 over the stance's compression: 300 is a compression of a third of a percent of the leg."""
DRIFT_T = 4.0
"""|t| of a parameter's trend over the run above which (with a change beyond its interval) it drifts."""
DRIFT_FRACTION = 0.01
"""The least change over the run, as a fraction of the parameter's scale, that counts as drift (below it a
trend, however significant, is rounding)."""
MIN_STANCES = 3
"""Fewest usable stances an identification needs (an interval needs stances beyond the parameters)."""
MIN_STANCE_SAMPLES = 8
"""Fewest samples inside a stance for it to enter the fit."""
PROGRESS_EVERY = 50
"""Strides between two calls of identify's progress while the stances are gathered."""
STANCE_RTOL = 1e-9
"""Relative tolerance of the exact stance's DOP853 (absolute: 1e-12 m, m/s, rad)."""

FORCE_BALANCE = "force balance"
EXACT_STANCE = "exact stance"

IDENTIFIED = "identified"
ILL_CONDITIONED_STATUS = "ill_conditioned"
TOO_NOISY = "too_noisy"
TOO_SHORT = "too_short"


@dataclass(frozen=True)
class Estimate:
    """One parameter: value, standard error and the CONFIDENCE interval [low, high] (SI)."""

    value: float
    stderr: float
    low: float
    high: float
    scale: float
    """What the half width is judged against (the value; for c, 2 zeta sqrt(m k) at DAMPING_RATIO_SCALE)."""

    @property
    def relative_half_width(self) -> float:
        return 0.5 * (self.high - self.low) / self.scale

    def covers(self, truth: float) -> bool:
        return self.low <= truth <= self.high


@dataclass(frozen=True)
class Ramp:
    """The paper's ramp tau0 (1 - s/t_f) fitted to one stance's hip torque; rms its residual [N m]."""

    tau0: float
    t_f: float
    rms: float


@dataclass(frozen=True)
class StanceFit:
    """One stance: its stride's index in the run's list, its mid time [s], the parameters from it alone
    (NaN where it alone cannot give one), the residual's rms (force [N] or position [m]), the ramp."""

    stride: int
    time: float
    values: dict[str, float]
    rms: float
    ramp: Ramp


@dataclass(frozen=True)
class Drift:
    """A parameter's per-stance estimates against time: slope [unit/s], its t-statistic, the change over
    the run, and whether that is drift (module docstring)."""

    slope: float
    t: float
    change: float
    drifts: bool


@dataclass(frozen=True)
class IdentificationResult:
    """What :func:`identify` found, in the manner of ``scipy.optimize.OptimizeResult``.

    ``success`` is True when every estimated parameter is identified; then ``params`` is the hopper (the
    caller's values for what was not estimated). Otherwise ``status`` says why (ILL_CONDITIONED_STATUS,
    TOO_NOISY, TOO_SHORT) and ``message`` in one line, with the condition number and the parameter(s) this
    data cannot identify; the estimates are kept for the record but must not be used.
    """

    success: bool
    status: str
    message: str
    method: str
    params: HopperParams | None
    estimates: dict[str, Estimate]
    condition_number: float
    unidentified: tuple[str, ...]
    stances: tuple[StanceFit, ...]
    drift: dict[str, Drift]
    set_aside: tuple[tuple[int, str], ...]
    """Strides not used, by index, with the reason (the detector's, or too few samples in stance)."""
    residual_rms: float


@dataclass(frozen=True)
class StanceData:
    """The samples of one stance seen from the toe (module docstring); s is the time since touchdown."""

    stride: int
    time: FloatArray
    s: FloatArray
    r: FloatArray
    theta: FloatArray
    rdot: FloatArray
    thetadot: FloatArray
    toe: tuple[float, float]
    body: FloatArray
    force_axial: FloatArray | None
    force: FloatArray | None
    acceleration: FloatArray | None
    torque: FloatArray | None


def run_acceleration(run: MeasuredRun) -> FloatArray | None:
    """The body's acceleration (n, 2) [m/s^2], the velocity differentiated (second order), where the run
    records force (the mass needs both); None otherwise."""
    if run.ground_force is None:
        return None
    return np.stack([np.gradient(run.body_velocity[:, i], run.time) for i in (0, 1)], axis=1)


def stance_data(
    run: MeasuredRun, stride: MeasuredStride, index: int, acceleration: FloatArray | None
) -> StanceData:
    """The samples of ``stride``'s stance strictly between its touchdown and liftoff times (``acceleration``:
    :func:`run_acceleration`'s)."""
    lo, hi = stride.touchdown_index, stride.liftoff_index + 2
    time = run.time[lo:hi]
    inside = (time > stride.touchdown_time) & (time < stride.liftoff_time)
    at = np.arange(lo, min(hi, run.time.size))[inside[: max(0, min(hi, run.time.size) - lo)]]
    body = run.body_position[at]
    velocity = run.body_velocity[at]
    if run.leg_length is not None and run.leg_angle is not None:
        r, theta = run.leg_length[at], run.leg_angle[at]
        sin_t, cos_t = np.sin(theta), np.cos(theta)
        toe = (float(np.mean(body[:, 0] + r * sin_t)), float(np.mean(body[:, 1] - r * cos_t)))
    else:
        near = slice(max(stride.touchdown_index - 1, 0), stride.touchdown_index + 2)
        td = [np.interp(stride.touchdown_time, run.time[near], run.body_position[near, i]) for i in (0, 1)]
        toe = (float(td[0] + td[1] * math.tan(stride.touchdown_angle)), 0.0)
        relative = body - np.asarray(toe)
        r = np.hypot(relative[:, 0], relative[:, 1])
        theta = np.arctan2(-relative[:, 0], relative[:, 1])
        sin_t, cos_t = np.sin(theta), np.cos(theta)
    rdot, thetadot = dynamics.polar_velocity(r, sin_t, cos_t, velocity[:, 0], velocity[:, 1])
    force = force_axial = None
    torque = None if run.hip_torque is None else run.hip_torque[at]
    if run.ground_force is not None:
        force = run.ground_force[at]
        force_axial = -force[:, 0] * sin_t + force[:, 1] * cos_t
        if torque is None:  # tau / r is the force along e_theta = (-cos, -sin)
            torque = r * (-force[:, 0] * cos_t - force[:, 1] * sin_t)
    return StanceData(
        index, run.time[at], run.time[at] - stride.touchdown_time, r, theta, rdot, thetadot, toe, body,
        force_axial, force, None if acceleration is None else acceleration[at], torque,
    )  # fmt: skip


def fit_ramp(s: FloatArray, torque: FloatArray) -> Ramp:
    """The ramp tau0 (1 - s/t_f) for s <= t_f, 0 after (eq. 18), least squares on ``torque`` [N m] at times
    ``s`` since touchdown: tau0 is linear for a given t_f, t_f found by a bounded scalar search between
    the first sample and ten stance lengths (a ramp that outlasts the stance shows only its slope)."""

    def solved(t_f: float) -> tuple[float, float]:
        shape = np.where(s <= t_f, 1.0 - s / t_f, 0.0)
        norm = float(shape @ shape)
        tau0 = float(shape @ torque) / norm if norm > 0.0 else 0.0
        return tau0, float(np.sum((torque - tau0 * shape) ** 2))

    if s.size < 2 or not np.any(torque):
        return Ramp(0.0, math.nan, float(np.sqrt(np.mean(torque**2))) if torque.size else math.nan)
    span = float(s[-1])
    search = optimize.minimize_scalar(
        lambda t_f: solved(t_f)[1], bounds=(max(float(s[0]), 1e-6), 10.0 * span), method="bounded",
        options={"xatol": 1e-7 * span},
    )  # fmt: skip
    tau0, square = solved(float(search.x))
    return Ramp(tau0, float(search.x), math.sqrt(square / s.size))


def _interval(value: float, stderr: float, dof: int, scale: float) -> Estimate:
    half = float(stats.t.ppf(0.5 + CONFIDENCE / 2.0, max(dof, 1))) * stderr
    return Estimate(value, stderr, value - half, value + half, scale)


def _clustered_covariance(
    design: FloatArray, residual: FloatArray, clusters: list[slice]
) -> tuple[FloatArray, FloatArray]:
    """(XtX^-1, the cluster-robust covariance of least squares coefficients), CR1's small-sample factor."""
    inverse = np.linalg.pinv(design.T @ design)
    meat = np.zeros_like(inverse)
    for cluster in clusters:
        score = design[cluster].T @ residual[cluster]
        meat += np.outer(score, score)
    groups, n, p = len(clusters), design.shape[0], design.shape[1]
    factor = groups / max(groups - 1, 1) * (n - 1) / max(n - p, 1)
    return inverse, factor * inverse @ meat @ inverse


def _condition(jacobian: FloatArray, names: tuple[str, ...]) -> tuple[float, tuple[str, ...]]:
    """Condition number of the column-scaled ``jacobian`` and the parameters of its weakest direction (the
    components of the last right singular vector above half the largest)."""
    singular, vectors = np.linalg.svd(jacobian, full_matrices=False)[1:]
    number = float(singular[0] / singular[-1]) if singular[-1] > 0.0 else math.inf
    weakest = np.abs(vectors[-1])
    return number, tuple(name for name, w in zip(names, weakest, strict=True) if w >= 0.5 * weakest.max())


def _scale(name: str, value: float, m: float, k: float) -> float:
    if name == "c":
        return 2.0 * DAMPING_RATIO_SCALE * math.sqrt(m * abs(k))
    return abs(value)


def _force_balance(
    stances: list[StanceData], m_guess: float, g: float
) -> tuple[dict[str, Estimate], float, tuple[str, ...], list[dict[str, float]], list[float], float]:
    """The pooled leg-axis least squares and its per-stance twins (module docstring)."""
    design = np.concatenate([np.stack([np.ones_like(d.r), -d.r, -d.rdot], axis=1) for d in stances])
    target = np.concatenate([d.force_axial for d in stances if d.force_axial is not None])
    bounds = np.cumsum([0] + [d.r.size for d in stances])
    clusters = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    beta = np.linalg.lstsq(design, target, rcond=None)[0]
    residual = target - design @ beta
    _, covariance = _clustered_covariance(design, residual, clusters)
    kr0, k, c = (float(v) for v in beta)
    r0 = kr0 / k
    # r0 = (k r0) / k: its gradient in (k r0, k, c)
    gradient = np.array([1.0 / k, -kr0 / k**2, 0.0])
    dof = len(stances) - design.shape[1]
    m_value, m_se = _mass(stances, g)
    m_scale = m_value if math.isfinite(m_value) else m_guess
    estimates = {
        "k": _interval(k, math.sqrt(covariance[1, 1]), dof, abs(k)),
        "c": _interval(c, math.sqrt(covariance[2, 2]), dof, _scale("c", c, m_scale, k)),
        "r0": _interval(r0, math.sqrt(float(gradient @ covariance @ gradient)), dof, abs(r0)),
    }
    if math.isfinite(m_value):
        estimates["m"] = _interval(m_value, m_se, len(stances) - 1, m_value)
    # the Jacobian in the physical parameters (k, c, r0), each column scaled by its scale
    # d/dk, d/dc, d/dr0 of k (r0 - r) - c rdot: (r0 - r, -rdot, k)
    physical = np.stack([r0 + design[:, 1], design[:, 2], np.full(len(design), k)], axis=1)
    scaled = physical * np.array([estimates[n].scale for n in ("k", "c", "r0")])
    number, weakest = _condition(scaled, ("k", "c", "r0"))
    per_stance = []
    for cluster in clusters:
        alone = np.linalg.lstsq(design[cluster], target[cluster], rcond=None)[0]
        per_stance.append({"k": float(alone[1]), "c": float(alone[2]), "r0": float(alone[0] / alone[1])})
    rms = [float(np.sqrt(np.mean(residual[cluster] ** 2))) for cluster in clusters]
    return estimates, number, weakest, per_stance, rms, float(np.sqrt(np.mean(residual**2)))


def _mass(stances: list[StanceData], g: float) -> tuple[float, float]:
    """m and its standard error from a + g y_hat = F / m (the acceleration regressed on the force, both axes,
    the stances as clusters); NaN without force or acceleration."""
    # The central difference of the velocity is the mean acceleration over two samples, a + a'' dt^2/6;
    # the force weighted 1, 4, 1 is F + F'' dt^2/6, the same mean to that order. The first and last samples
    # of a stance are left out: their difference straddles touchdown or liftoff.
    pairs = [
        ((d.force[:-2] + 4.0 * d.force[1:-1] + d.force[2:]) / 6.0, d.acceleration[1:-1])
        for d in stances
        if d.force is not None and d.acceleration is not None
    ]
    if len(pairs) < 2:
        return math.nan, math.nan
    force = np.concatenate([f.reshape(-1) for f, _ in pairs])[:, None]
    specific = np.concatenate([(a + np.array([0.0, g])).reshape(-1) for _, a in pairs])
    bounds = np.cumsum([0] + [f.size for f, _ in pairs])
    clusters = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    slope = float(np.linalg.lstsq(force, specific, rcond=None)[0][0])
    _, covariance = _clustered_covariance(force, specific - force[:, 0] * slope, clusters)
    return 1.0 / slope, math.sqrt(covariance[0, 0]) / slope**2


class _Trial(NamedTuple):
    """A trial hopper as dynamics.Hopper: no validation, so that the optimiser may pass through any value."""

    m: float
    k: float
    r0: float
    c: float
    g: float


def _stance_positions(trial: _Trial, data: StanceData, torque: Callable[[float], float]) -> FloatArray:
    """The body's positions (n, 2) at ``data``'s sample times, integrated from its first sample's state."""

    def field(s: float, y: FloatArray) -> list[float]:
        r, theta, rdot, thetadot = y
        return list(dynamics.stance_derivatives(
            trial, r, math.sin(theta), math.cos(theta), rdot, thetadot, torque(s)
        )[:4])  # fmt: skip

    start = [data.r[0], data.theta[0], data.rdot[0], data.thetadot[0]]
    span = (float(data.s[0]), float(data.s[-1]))
    solution = integrate.solve_ivp(
        field, span, start, method="DOP853", t_eval=data.s, rtol=STANCE_RTOL, atol=1e-12
    )
    r, theta = solution.y[0], solution.y[1]
    if r.size != data.s.size:
        return np.full((data.s.size, 2), np.nan)
    return np.stack([data.toe[0] - r * np.sin(theta), data.toe[1] + r * np.cos(theta)], axis=1)


def _stance_torque(data: StanceData, tau0: float, t_f: float) -> Callable[[float], float]:
    """The hip torque [N m] at a time s since touchdown: the stance's recorded torque (linear between its
    samples) where it has one, else the ramp tau0 (1 - s/t_f) of eq. 18."""
    recorded = data.torque
    if recorded is not None:
        return lambda s: float(np.interp(s, data.s, recorded))
    return lambda s: float(dynamics.ramp_torque(tau0, t_f, s))


def _exact_stance_fit(data: StanceData, m: float, g: float, guess: tuple[float, float, float]) -> tuple[
    dict[str, float], FloatArray, float, Ramp
]:  # fmt: skip
    """(k, c, r0) of one stance fitted by least squares on its positions; the ramp fitted with them unless
    the torque is recorded. Returns the values, the Jacobian at the solution in the parameters divided by
    their scales (k, c, r0, then tau0, t_f where fitted), the rms [m] and the ramp."""
    k0, c0, r00 = guess
    scale = np.array([k0, 2.0 * DAMPING_RATIO_SCALE * math.sqrt(m * k0), r00])
    measured = data.torque
    ramp_scale = np.array([m * g * r00, float(data.s[-1])])

    def unpack(p: FloatArray) -> tuple[_Trial, Callable[[float], float]]:
        k, c, r0 = p[:3] * scale
        tau0, t_f = (math.nan, math.nan) if measured is not None else p[3:] * ramp_scale
        return _Trial(m, k, r0, c, g), _stance_torque(data, tau0, t_f)

    def residual(p: FloatArray) -> FloatArray:
        trial, torque = unpack(p)
        return (_stance_positions(trial, data, torque) - data.body).reshape(-1)

    start = np.array([1.0, c0 / scale[1], 1.0] + ([] if measured is not None else [0.0, 1.0]))
    lower = np.array([1e-3, 0.0, 0.5] + ([] if measured is not None else [-np.inf, 1e-3]))
    upper = np.array([1e3, np.inf, 2.0] + ([] if measured is not None else [np.inf, 1e3]))
    fit = optimize.least_squares(residual, start, bounds=(lower, upper), x_scale=1.0, xtol=1e-10, ftol=1e-12)
    k, c, r0 = fit.x[:3] * scale
    if measured is None:
        tau0, t_f = fit.x[3:] * ramp_scale
        ramp = Ramp(float(tau0), float(t_f), math.nan)
    else:
        ramp = fit_ramp(data.s, measured)
    rms = float(np.sqrt(np.mean(fit.fun**2)))
    return {"k": float(k), "c": float(c), "r0": float(r0)}, fit.jac, rms, ramp


def usable_stances(
    run: MeasuredRun, strides: list[MeasuredStride], progress: Callable[[int, int], None] | None = None
) -> tuple[list[StanceData], list[tuple[int, str]]]:
    """The stance samples of the usable strides with at least MIN_STANCE_SAMPLES in stance, and the strides
    set aside (index, reason); ``progress`` as :func:`identify`'s, every PROGRESS_EVERY strides."""
    set_aside = [(i, s.reason or "set aside") for i, s in enumerate(strides) if not s.usable]
    acceleration = run_acceleration(run)
    stances = []
    for done, (i, stride) in enumerate(((i, s) for i, s in enumerate(strides) if s.usable), start=1):
        data = stance_data(run, stride, i, acceleration)
        if data.s.size >= MIN_STANCE_SAMPLES:
            stances.append(data)
        else:
            set_aside.append((i, f"{data.s.size} samples in stance, fewer than {MIN_STANCE_SAMPLES}"))
        if progress is not None and done % PROGRESS_EVERY == 0:
            progress(done, len(strides))
    return stances, sorted(set_aside)


def identify(
    run: MeasuredRun,
    strides: list[MeasuredStride],
    hopper: HopperParams,
    progress: Callable[[int, int], None] | None = None,
) -> IdentificationResult:
    """Estimate the hopper of ``run`` from the stances of ``strides`` (module docstring): by the leg-axis
    force balance where the run records force, else by fitting the exact stance. ``hopper`` gives the
    starting guess of the exact-stance fit, the mass where it cannot be estimated, and g. ``progress`` is
    called with (strides done, strides) as the stances are gathered, then, fitting exact stances, with
    (stances fitted, stances)."""
    stances, set_aside = usable_stances(run, strides, progress)
    method = FORCE_BALANCE if run.ground_force is not None else EXACT_STANCE
    if len(stances) < MIN_STANCES:
        message = (
            f"too short to identify the hopper: {len(stances)} usable stance(s) of {len(strides)} stride(s), "
            f"at least {MIN_STANCES} needed"
        )
        return IdentificationResult(
            False,
            TOO_SHORT,
            message,
            method,
            None,
            {},
            math.nan,
            (),
            (),
            {},
            tuple(sorted(set_aside)),
            math.nan,
        )
    if method == FORCE_BALANCE:
        estimates, number, weakest, values, rms, residual = _force_balance(stances, hopper.m, hopper.g)
        ramps = [fit_ramp(d.s, d.torque) if d.torque is not None else _NO_RAMP for d in stances]
    else:
        estimates, number, weakest, values, rms, ramps, residual = _exact_stances(stances, hopper, progress)
    fits = tuple(
        StanceFit(d.stride, float(np.mean(d.time)), v, e, ramp)
        for d, v, e, ramp in zip(stances, values, rms, ramps, strict=True)
    )
    drift = {name: _drift(fits, name, estimates[name]) for name in ("k", "c", "r0")}
    unidentified = tuple(
        name for name, e in estimates.items() if not e.relative_half_width <= IDENTIFIED_HALF_WIDTH
    )
    status, message = _verdict(estimates, unidentified, number, weakest, len(stances), method)
    params = None
    if status == IDENTIFIED:
        mass = estimates["m"].value if "m" in estimates else hopper.m
        value = {name: e.value for name, e in estimates.items()}
        params = HopperParams(m=mass, k=value["k"], r0=value["r0"], c=max(value["c"], 0.0), g=hopper.g)
    return IdentificationResult(
        status == IDENTIFIED, status, message, method, params, estimates, number,
        unidentified if status != IDENTIFIED else (), fits, drift, tuple(set_aside), residual,
    )  # fmt: skip


_NO_RAMP = Ramp(math.nan, math.nan, math.nan)


def _exact_stances(
    stances: list[StanceData], hopper: HopperParams, progress: Callable[[int, int], None] | None
) -> tuple[
    dict[str, Estimate], float, tuple[str, ...], list[dict[str, float]], list[float], list[Ramp], float
]:  # fmt: skip
    """Each stance's exact fit, pooled: the mean of the per-stance values and its interval."""
    values, rms, ramps, conditions = [], [], [], []
    names = ("k", "c", "r0", "tau0", "t_f")
    guess = (hopper.k, hopper.c, hopper.r0)
    for done, data in enumerate(stances, start=1):
        fitted, jacobian, error, ramp = _exact_stance_fit(data, hopper.m, hopper.g, guess)
        values.append(fitted)
        rms.append(error)
        ramps.append(ramp)
        conditions.append(_condition(jacobian, names[: jacobian.shape[1]]))
        if progress is not None:
            progress(done, len(stances))
    n = len(stances)
    estimates = {}
    for name in ("k", "c", "r0"):
        column = np.array([v[name] for v in values])
        mean = float(np.mean(column))
        scale = _scale(name, mean, hopper.m, float(np.mean([v["k"] for v in values])))
        estimates[name] = _interval(mean, float(np.std(column, ddof=1)) / math.sqrt(n), n - 1, scale)
    number, weakest = sorted(conditions, key=lambda pair: pair[0])[n // 2]
    residual = float(np.sqrt(np.mean(np.square(rms))))
    return estimates, number, weakest, values, rms, ramps, residual


def _drift(fits: tuple[StanceFit, ...], name: str, pooled: Estimate) -> Drift:
    """The trend of ``name``'s per-stance estimates over the run (module docstring)."""
    times = np.array([f.time for f in fits])
    values = np.array([f.values[name] for f in fits])
    keep = np.isfinite(values)
    if keep.sum() < 4 or np.ptp(times[keep]) == 0.0:
        return Drift(math.nan, math.nan, math.nan, False)
    trend = stats.linregress(times[keep], values[keep])
    t = trend.slope / trend.stderr if trend.stderr > 0.0 else math.inf * np.sign(trend.slope)
    change = float(trend.slope * np.ptp(times[keep]))
    least = max(0.5 * (pooled.high - pooled.low), DRIFT_FRACTION * pooled.scale)
    return Drift(float(trend.slope), float(t), change, bool(abs(t) > DRIFT_T and abs(change) > least))


def _verdict(
    estimates: dict[str, Estimate],
    unidentified: tuple[str, ...],
    number: float,
    weakest: tuple[str, ...],
    stances: int,
    method: str,
) -> tuple[str, str]:
    """(status, one line) of an identification."""
    if not unidentified and number <= SINGULAR:
        return (
            IDENTIFIED,
            f"identified by the {method} over {stances} stances (condition number {number:.3g})",
        )
    if number > ILL_CONDITIONED or not unidentified:
        return ILL_CONDITIONED_STATUS, (
            f"{' and '.join(unidentified or weakest)} cannot be identified from this data: the {method} is "
            f"ill-conditioned (condition number {number:.3g}; its weakest direction moves "
            f"{' with '.join(weakest)})"
        )
    worst = max(unidentified, key=lambda name: estimates[name].relative_half_width)
    return TOO_NOISY, (
        f"too noisy or too short to identify {', '.join(unidentified)}: the {CONFIDENCE:.0%} interval of "
        f"{worst} spans +-{estimates[worst].relative_half_width:.1%} of its scale over {stances} stances "
        f"(at most {IDENTIFIED_HALF_WIDTH:.0%} identifies it)"
    )


def stance_curves(params: HopperParams, method: str, data: StanceData, fit: StanceFit) -> tuple[
    FloatArray, FloatArray
]:  # fmt: skip
    """(measured, fitted) over ``data``'s stance under the identified ``params``: the force along the leg [N]
    of the force balance, or the body's height [m] of the exact stance (with the stance's fitted ramp, or its
    recorded torque)."""
    if method == FORCE_BALANCE:
        assert data.force_axial is not None
        return data.force_axial, dynamics.leg_force(params, data.r, data.rdot)
    trial = _Trial(params.m, params.k, params.r0, params.c, params.g)
    torque = _stance_torque(data, fit.ramp.tau0, fit.ramp.t_f)
    return data.body[:, 1], _stance_positions(trial, data, torque)[:, 1]
