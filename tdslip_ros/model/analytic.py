"""Approximate (analytic) apex return map of the TD-SLIP hopper, paper sections II.C-D, III, IV.A.

Everything is SI and follows the sign convention of :mod:`tdslip_ros.model.params`: forward running
touches down at ``theta_td > 0``, theta decreases in stance, ``p = m r^2 thetadot < 0``, hip power
``tau thetadot`` (forward thrust needs ``tau0 < 0``). The paper writes ``omega := p/(m r0^2)``, so
``omega`` equals ``thetadot_td`` for the unforced approximation and is negative here.

Derivation of the stance approximation (each closed form is re-derived; the text is partly garbled):

* Radial equation (8). With a constant angular momentum ``thetadot = omega r0^2/r^2`` the centripetal
  term is ``r thetadot^2 = omega^2 r0^4/r^3 ~ omega^2 (4 r0 - 3 r)`` (first order about r0) and gravity is
  taken along the leg (``cos theta ~ 1``)::

      rddot + (c/m) rdot + (w0^2 + 3 omega^2) r = F,   F = -g + r0 w0^2 + 4 r0 omega^2.

* Its solution (9)-(13), with ``wh = sqrt(w0^2 + 3 omega^2)``, ``zeta = c/(2 m wh)``, decay rate
  ``a = zeta wh = c/(2m)``, ``wd = wh sqrt(1 - zeta^2)``, ``A = r0 - F/wh^2``, ``B = (rdot_td + a A)/wd``::

      r(t)    = M e^{-a t} cos(wd t + phi1) + F/wh^2,        M = hypot(A, B), phi1 = atan2(-B, A)
      rdot(t) = -M wh e^{-a t} cos(wd t + phi1 + phi2),        phi2 = -arccos(zeta) in (-pi/2, 0]

  (``-a cos x - wd sin x = -wh cos(x + phi2)`` with ``cos phi2 = zeta``, ``sin phi2 = -sqrt(1 - zeta^2)``).
* Angular rate (14): ``1/r^2 ~ (3 - 2 r/r0)/r0^2`` gives
  ``thetadot = X - (2 omega M/r0) e^{-a t} cos(wd t + phi1)`` with ``X = omega (3 - 2 F/(r0 wh^2))``.
  Integrating with ``d/dt[e^{-a t} cos(x - phi2)] = -wh e^{-a t} cos x`` gives (15):
  ``theta = theta_td + X t + Y (e^{-a t} cos(wd t + phi1 - phi2) - cos(phi1 - phi2))``,
  ``Y = 2 omega M/(r0 wh)``.
* Leg force (16): ``k (r0 - r) - c rdot = k A - Mbar M e^{-a t} cos(wd t + phi1 + phi3)`` with
  ``Mbar cos phi3 = k - c wh cos phi2 = k - c^2/(2m)`` and ``Mbar sin phi3 = -c wh sin phi2 = c wd``, i.e.
  ``Mbar = hypot(k - c^2/(2m), c wd)``, ``phi3 = atan2(c wd, k - c^2/(2m))`` in [0, pi).
  Bottom (``rdot = 0`` from below) is at ``wd t_b + phi1 + phi2 = pi/2`` (mod 2 pi), where the force phase is
  ``pi/2 - phi2 + phi3``. After the bottom the force decreases monotonically until its minimum at the phase
  ``3 pi/2 - phi2``; liftoff is its zero in that window, so it exists iff the force minimum is <= 0.
  The paper's approximation (default, ``liftoff="paper"``) freezes the envelope at ``e^{-2 a t_b}``
  (compression and decompression taking equally long), leaving ``cos(phase) = q = k A/(Mbar M e^{-2 a t_b})``
  whose root on the rising branch of the cosine is ``phase = 2 pi - arccos(q)``::

      t_lo = t_b + (3 pi/2 + phi2 - phi3 - arccos(q))/wd        (the paper's eq. 16 in unwrapped form).

  ``liftoff="force_root"`` instead finds the exact zero of the approximate force in the window (safeguarded
  Newton). For ``c = 0`` both are exact and coincide.
* Damping loss (30)-(31): ``E_c = int_0^T c rdot^2 = c M^2 wh^2 int e^{-2at} cos^2(wd t + phi12)``,
  ``phi12 = phi1 + phi2``; with ``cos^2 = (1 + cos 2x)/2`` and ``alpha^2 + beta^2 = 4 wh^2`` for
  ``alpha = 2a, beta = 2 wd``::

      E_c = (m M^2 wh^2/2) [1 - e^{-2aT} + zeta (cos(2 phi12 - phi2) - e^{-2aT} cos(2 wd T + 2 phi12 - phi2))]

  (the text's ``+phi3`` is our ``-phi2``; ``c/(4 zeta) = m wh/2``, so c = 0 needs no special case).
* Leftover spring energy ``E_k = k (r_lo - r0)^2/2`` (the text drops k).
* Hip energy (25) for the ramp ``tau = tau0 (1 - t/t_f)`` on ``[0, T]``, ``T = min(t_f, t_lo)``::

      E_tau = tau0 [X (T - T^2/(2 t_f)) - (2 omega M/r0) (I0(T) - I1(T)/t_f)],
      I0 = int_0^T e^{-at} cos(wd t + phi1) = -(e^{-aT} cos(wd T + phi1 - phi2) - cos(phi1 - phi2))/wh,
      I1 = int_0^T t e^{-at} cos(wd t + phi1)
         = -T e^{-aT} cos(wd T + phi1 - phi2)/wh
           - (e^{-aT} cos(wd T + phi1 - 2 phi2) - cos(phi1 - 2 phi2))/wh^2.

* Corrections (19)-(22) of the angular momentum, ``p_hat = p(0) + dp_tau + dp_g``, where each term is the
  time average over [0, t_lo] of the integrated torque. For the ramp, with ``u = min(t_lo, t_f)`` and
  ``v = max(t_lo, t_f)``, ``dp_tau = tau0 (u/2 - u^2/(6 v))`` (both cases t_lo <= t_f and t_lo > t_f give this
  one expression; it is ``tau0 t_lo/3`` for ``t_f = t_lo``). Gravity, with ``r sin(theta)`` interpolated
  linearly between touchdown and liftoff: ``dp_g = (m g t_lo/6)(2 r0 sin(theta_td) + r_lo sin(theta_lo))``.
  Each correction re-evaluates the stance with the previous estimate of t_lo, r_lo, theta_lo.

Next apex. The stance ends in the liftoff state of the approximation; the ascent (7) gives the next apex
height ``y' = r_lo cos(theta_lo) + ydot_lo^2/(2 g)``. The next apex *energy* is taken from the closed-form
energy balance ``E' = E + E_tau - E_c - E_k`` (exact for the true plant), and the speed from it,
``xdot' = sqrt(2 (E'/m - g y'))``. This makes the (y, xdot) and (y, E) maps one map in two coordinates,
keeps the torque's effect even with zero corrections, makes eq. (32) (``E_tau = E_loss``) conserve the map's
energy exactly as the paper states, and is more accurate than the liftoff speed of (7) (see
``bench/bench_analytic.py``, which prints the accuracy table).

Implementation. The equations are written once, as compiled scalar kernels of one lane (``lane_*``,
:mod:`tdslip_ros.model.compiled`): the one-apex controller calls them directly and the vectorised API
below runs them in a compiled loop over the lanes of a batch. The public functions broadcast over arrays
of states, parameters and commands and are complex-step safe (the imaginary parts are treated as
infinitesimal perturbations; a batch with any complex input runs the complex128 specialisation of the same
kernels) so that :func:`map_jacobian` can differentiate them, including the controllers of
:mod:`tdslip_ros.model.controllers`. Iterations (the corrections, the force root) stop per lane, so a lane's
result does not depend on the other lanes of its batch.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any, Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.compiled import atan2, inlined_kernel, is_complex, kernel, real
from tdslip_ros.model.events import (
    FAILURE_KINDS,
    NO_FAILURE_CODE,
    FailureKind,
    failure_code,
    failure_from_code,
)
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import (
    ApexState,
    HopperParams,
    ParameterError,
    StanceCommand,
)

Array = npt.NDArray[Any]
ArrayLike = npt.ArrayLike
LiftoffMethod = Literal["paper", "force_root"]
Coordinates = Literal["speed", "energy"]

CORRECTION_TOLERANCE = 1e-12
"""Relative change of p_hat below which further correction iterations stop."""
FORCE_ROOT_TOLERANCE = 1e-14
"""Relative step in t below which the safeguarded Newton search for the force root stops."""
FORCE_ROOT_ITERATIONS = 100
"""Bound on the steps of the force-root search (bisection alone needs about 50)."""
COMPLEX_STEP = 1e-30
"""Imaginary step of the complex-step Jacobian (any tiny value works: there is no subtraction)."""


# Failure codes per lane, shared with the exact plant (tdslip_ros.model.events): NO_FAILURE_CODE (-1) or the
# index of the FailureKind, so failure arrays of both maps compare directly (failure_from_code names them).
TOE_STUBBING = failure_code(FailureKind.TOE_STUBBING)  # apex below r0 cos(theta_td): the leg cannot be placed
NO_LIFTOFF = failure_code(FailureKind.NO_LIFTOFF)  # the approximate leg force never vanishes after the bottom
FALL = failure_code(FailureKind.FALL)  # liftoff with ydot <= 0: no next apex
REVERSAL = failure_code(FailureKind.REVERSAL)  # thetadot_td >= 0, or no forward speed at the next apex


@dataclass(frozen=True)
class ParamArrays:
    """Hopper parameters as arrays that broadcast against states and commands (SI, like HopperParams)."""

    m: Array
    k: Array
    r0: Array
    c: Array
    g: Array

    def __post_init__(self) -> None:
        for name in ("m", "k", "r0", "c", "g"):
            value = np.asarray(getattr(self, name), dtype=float)
            if not np.all(np.isfinite(value)):
                raise ParameterError(f"{name} must be finite everywhere")
            if name == "c":
                if np.any(value < 0.0):
                    raise ParameterError("c (damping) must be non-negative")
            elif np.any(value <= 0.0):
                raise ParameterError(f"{name} must be positive everywhere, got min {value.min()!r}")
            object.__setattr__(self, name, value)
        zeta0 = self.c / (2.0 * np.sqrt(self.m * self.k))
        if np.any(zeta0 >= 1.0):
            # zeta = c/(2 m wh) <= zeta0 for every stance, so zeta0 < 1 keeps every stance underdamped.
            raise ParameterError(
                "zeta0 = c/(2 sqrt(m k)) must be < 1 (underdamped leg) for the analytic map, "
                f"got max {zeta0.max()!r}"
            )

    @cached_property
    def column(self) -> Array | None:
        """m, k, r0, c, g as one (5, 1) column where they are scalars (one parameter set), else None: the
        compiled lane loops' parameter block for one lane, kept (a controller plans every apex with the same
        parameters). The loops only read it."""
        fields = (self.m, self.k, self.r0, self.c, self.g)
        if any(np.ndim(field) != 0 for field in fields):
            return None
        return np.array(fields, dtype=float).reshape(5, 1)

    @classmethod
    def of(cls, params: HopperParams | ParamArrays | Sequence[HopperParams]) -> ParamArrays:
        """Arrays from one parameter set (0-d arrays), several (1-d arrays) or an existing ParamArrays."""
        if isinstance(params, ParamArrays):
            return params
        if isinstance(params, HopperParams):
            return _arrays_of_hopper(params)
        return cls(*(np.array([getattr(p, name) for p in params]) for name in ("m", "k", "r0", "c", "g")))

    @classmethod
    def from_dimensionless(
        cls,
        kbar: ArrayLike,
        zeta0: ArrayLike,
        m: ArrayLike = 80.0,
        r0: ArrayLike = 1.0,
        g: ArrayLike = 9.81,
    ) -> ParamArrays:
        """Arrays from the paper's kbar = k r0/(m g) and zeta0 = c/(2 sqrt(m k)) (eq. 24), broadcast."""
        m_, r0_, g_ = (np.asarray(v, dtype=float) for v in (m, r0, g))
        k = np.asarray(kbar, dtype=float) * m_ * g_ / r0_
        return cls(
            m=m_,
            k=k,
            r0=r0_,
            c=2.0 * np.asarray(zeta0, dtype=float) * np.sqrt(m_ * k),
            g=g_,
        )


@lru_cache(maxsize=64)
def _arrays_of_hopper(params: HopperParams) -> ParamArrays:
    """ParamArrays of one parameter set, kept: a controller plans every apex with the same parameters, and
    building and checking the arrays costs more than planning (their arrays are read-only, being shared)."""
    arrays = [np.array(getattr(params, name)) for name in ("m", "k", "r0", "c", "g")]
    for array in arrays:
        array.flags.writeable = False
    return ParamArrays(*arrays)


class NoCommand(enum.StrEnum):
    """Why a policy has no command for an apex (codes per lane: the index in NO_COMMAND_KINDS)."""

    LEG_PLACEMENT = "leg_placement"  # the leg cannot be placed at the angle (dynamics.can_place_leg)
    NO_LIFTOFF = "no_liftoff"  # the map the policy plans with predicts no liftoff
    PREDICTED_FALL = "predicted_fall"  # ... predicts a fall with the policy's command
    PREDICTED_REVERSAL = "predicted_reversal"  # ... predicts a reversal (or touchdown swings back)
    NO_SOLUTION = "no_solution"  # no torque solves the policy's equations with the body swinging forward

    def describe(self) -> str:
        return _NO_COMMAND_TEXT[self]


_NO_COMMAND_TEXT = {
    NoCommand.LEG_PLACEMENT: "the leg cannot be placed at the touchdown angle from this apex "
    "(dynamics.can_place_leg)",
    NoCommand.NO_LIFTOFF: "the map the policy plans with predicts no liftoff",
    NoCommand.PREDICTED_FALL: "the map the policy plans with predicts a fall with its command",
    NoCommand.PREDICTED_REVERSAL: "the map the policy plans with predicts a reversal with its command",
    NoCommand.NO_SOLUTION: "no torque solves the policy's equations with the body swinging forward",
}
NO_COMMAND_KINDS: tuple[NoCommand, ...] = tuple(NoCommand)
HAS_COMMAND = -1
"""no_command code of a lane that has its command."""
_NO_COMMAND_OF_FAILURE = {
    FailureKind.TOE_STUBBING: NoCommand.LEG_PLACEMENT,
    FailureKind.NO_LIFTOFF: NoCommand.NO_LIFTOFF,
    FailureKind.FALL: NoCommand.PREDICTED_FALL,
    FailureKind.REVERSAL: NoCommand.PREDICTED_REVERSAL,
}


def no_command_code(kind: NoCommand) -> int:
    return NO_COMMAND_KINDS.index(kind)


REASON_OF_FAILURE = np.array(
    [
        no_command_code(_NO_COMMAND_OF_FAILURE[kind]) if kind in _NO_COMMAND_OF_FAILURE else HAS_COMMAND
        for kind in FAILURE_KINDS
    ]
)
"""The no_command code for each failure code (HAS_COMMAND for the exact plant's other kinds)."""


def no_command_of_failure(failure: ArrayLike) -> Array:
    """no_command codes for map failure codes (events.failure_code); HAS_COMMAND where none."""
    failure = np.asarray(failure)
    return np.where(failure == NO_FAILURE_CODE, HAS_COMMAND, REASON_OF_FAILURE[failure])


@kernel
def reason_of_failure(failure: int) -> int:
    """The no_command code of one lane's failure code."""
    return HAS_COMMAND if failure == NO_FAILURE_CODE else int(REASON_OF_FAILURE[failure])


class NoCommandError(ParameterError):
    """A policy has no command for the apex; ``reason`` says why."""

    def __init__(self, reason: NoCommand) -> None:
        super().__init__(f"no command ({reason.value}): {reason.describe()}")
        self.reason = reason


@dataclass(frozen=True, eq=False)
class CommandArrays:
    """The fields of :class:`StanceCommand` as broadcastable arrays (rad, N m, s).

    Iterates (and unpacks) as (touchdown_angle, tau0, t_f). ``no_command`` is set by the policies
    (:mod:`tdslip_ros.model.controllers`): per lane HAS_COMMAND, or the code of the reason
    (:class:`NoCommand`) why the policy has none there, where the fields are NaN.
    """

    touchdown_angle: Array
    tau0: Array
    t_f: Array
    no_command: Array | None = None

    def __iter__(self) -> Iterator[Array]:
        return iter((self.touchdown_angle, self.tau0, self.t_f))

    def reason(self, index: int | tuple[int, ...] = ()) -> NoCommand | None:
        """Why lane ``index`` has no command, or None where it has one (or no reason was given)."""
        if self.no_command is None:
            return None
        code = int(np.asarray(self.no_command)[index])
        return None if code == HAS_COMMAND else NO_COMMAND_KINDS[code]

    def command(self, index: int | tuple[int, ...] = ()) -> StanceCommand:
        """One lane as a validated StanceCommand; NoCommandError (a ParameterError) where the policy has
        none."""
        reason = self.reason(index)
        if reason is not None:
            raise NoCommandError(reason)
        return StanceCommand(*(float(np.real(np.asarray(field)[index])) for field in self))


# --- the equations: compiled kernels of one lane (float or complex; see the module docstring) -------------


class Angle(NamedTuple):
    """A constant phase held as its cosine and sine, so that cos(wd t + phase) needs no new trigonometry
    (scalars in a kernel, arrays in StanceApproximation)."""

    cos: Any
    sin: Any


@kernel
def angle_sum(a: Angle, b: Angle) -> Angle:
    return Angle(a.cos * b.cos - a.sin * b.sin, a.sin * b.cos + a.cos * b.sin)


@kernel
def angle_difference(a: Angle, b: Angle) -> Angle:
    return Angle(a.cos * b.cos + a.sin * b.sin, a.sin * b.cos - a.cos * b.sin)


@kernel
def angle_of(a: Angle) -> complex:
    return atan2(a.sin, a.cos)


class Wave(NamedTuple):
    """e^{-a t}, cos(wd t) and sin(wd t) at a time t: the only transcendental functions of t needed."""

    envelope: complex
    cos: complex
    sin: complex


@kernel
def wave_at(wave: Wave, phase: Angle) -> complex:
    """e^{-a t} cos(wd t + phase)."""
    value: complex = wave.envelope * (wave.cos * phase.cos - wave.sin * phase.sin)
    return value


class LaneApproximation(NamedTuple):
    """The closed-form stance of one lane (the fields of :class:`StanceApproximation`, parameters inline)."""

    m: float
    k: float
    r0: float
    c: float
    g: float
    theta_td: complex
    rdot_td: complex
    omega: complex
    omega_hat: complex
    zeta: complex
    omega_d: complex
    decay: float  # a = zeta omega_hat = c/(2m)
    equilibrium: complex  # F/omega_hat^2
    amplitude_a: complex  # A
    amplitude: complex  # M
    force_amplitude: complex  # Mbar
    x_rate: complex  # X
    y_amplitude: complex  # Y
    bottom_time: complex
    phase1: Angle
    phase2: Angle
    phase3: Angle


@kernel
def lane_approximation(
    m: float, k: float, r0: float, c: float, g: float, theta_td: complex, rdot_td: complex, omega: complex
) -> LaneApproximation:
    omega_hat = np.sqrt(k / m + 3.0 * omega**2)
    zeta = c / (2.0 * m * omega_hat)
    decay = c / (2.0 * m)
    damped_fraction = np.sqrt(1.0 - zeta**2)
    omega_d = omega_hat * damped_fraction
    amplitude_a = (g - r0 * omega**2) / omega_hat**2  # A = r0 - F/wh^2
    amplitude_b = (rdot_td + decay * amplitude_a) / omega_d
    amplitude = np.sqrt(amplitude_a**2 + amplitude_b**2)
    spring_term = k - c**2 / (2.0 * m)
    force_amplitude = np.sqrt(spring_term**2 + (c * omega_d) ** 2)
    phase1 = Angle(amplitude_a / amplitude, -amplitude_b / amplitude)
    phase2 = Angle(zeta, -damped_fraction)
    # Bottom: wd t_b + phi1 + phi2 = pi/2 (mod 2 pi), the first such t_b > 0.
    bottom_phase = np.pi / 2 - angle_of(angle_sum(phase1, phase2))
    bottom_phase = bottom_phase - 2.0 * np.pi * np.floor(real(bottom_phase) / (2.0 * np.pi))
    equilibrium = r0 - amplitude_a
    return LaneApproximation(
        m,
        k,
        r0,
        c,
        g,
        theta_td,
        rdot_td,
        omega,
        omega_hat,
        zeta,
        omega_d,
        decay,
        equilibrium,
        amplitude_a,
        amplitude,
        force_amplitude,
        omega * (3.0 - 2.0 * equilibrium / r0),
        2.0 * omega * amplitude / (r0 * omega_hat),
        bottom_phase / omega_d,
        phase1,
        phase2,
        Angle(spring_term / force_amplitude, c * omega_d / force_amplitude),
    )


@kernel
def lane_real_part(s: LaneApproximation) -> LaneApproximation:
    return LaneApproximation(
        s.m,
        s.k,
        s.r0,
        s.c,
        s.g,
        real(s.theta_td),
        real(s.rdot_td),
        real(s.omega),
        real(s.omega_hat),
        real(s.zeta),
        real(s.omega_d),
        s.decay,
        real(s.equilibrium),
        real(s.amplitude_a),
        real(s.amplitude),
        real(s.force_amplitude),
        real(s.x_rate),
        real(s.y_amplitude),
        real(s.bottom_time),
        Angle(real(s.phase1.cos), real(s.phase1.sin)),
        Angle(real(s.phase2.cos), real(s.phase2.sin)),
        Angle(real(s.phase3.cos), real(s.phase3.sin)),
    )


@kernel
def lane_wave(s: LaneApproximation, t: complex) -> Wave:
    angle = s.omega_d * t
    return Wave(np.exp(-s.decay * t), np.cos(angle), np.sin(angle))


class StanceState(NamedTuple):
    """Arrays in the API, scalars in a kernel."""

    r: Any
    rdot: Any
    theta: Any
    thetadot: Any


@kernel
def lane_state(s: LaneApproximation, wave: Wave, t: complex) -> StanceState:
    """r, rdot, theta, thetadot at t (eqs. 12-15), from the wave at t."""
    radial = wave_at(wave, s.phase1)
    lag = angle_difference(s.phase1, s.phase2)
    swing = wave_at(wave, lag) - lag.cos
    return StanceState(
        s.amplitude * radial + s.equilibrium,
        -s.omega_hat * s.amplitude * wave_at(wave, angle_sum(s.phase1, s.phase2)),
        s.theta_td + s.x_rate * t + s.y_amplitude * swing,
        s.x_rate - 2.0 * s.omega * s.amplitude * radial / s.r0,
    )


@kernel
def lane_leg_force(s: LaneApproximation, t: complex) -> complex:
    """Spring-damper force along the leg, k (r0 - r) - c rdot, in the closed form of (16)."""
    oscillation = wave_at(lane_wave(s, t), angle_sum(s.phase1, s.phase3))
    return s.k * s.amplitude_a - s.force_amplitude * s.amplitude * oscillation


@kernel
def lane_leg_force_rate(s: LaneApproximation, t: complex) -> complex:
    """Time derivative of :func:`lane_leg_force`."""
    oscillation = wave_at(lane_wave(s, t), angle_sum(angle_sum(s.phase1, s.phase3), s.phase2))
    return s.force_amplitude * s.omega_hat * s.amplitude * oscillation


@kernel
def lane_paper_liftoff(s: LaneApproximation) -> tuple[complex, bool]:
    q = s.k * s.amplitude_a / (s.force_amplitude * s.amplitude * np.exp(-2.0 * s.decay * s.bottom_time))
    after_bottom = (1.5 * np.pi + angle_of(angle_difference(s.phase2, s.phase3)) - np.arccos(q)) / s.omega_d
    exists = abs(real(q)) <= 1.0 and real(after_bottom) > 0.0
    return s.bottom_time + after_bottom, exists


@kernel
def lane_force_root_liftoff(s: LaneApproximation) -> tuple[complex, bool]:
    # The force decreases monotonically from the bottom to its minimum at phase 3 pi/2 - phi2.
    lower = real(s.bottom_time)
    upper = lower + real((np.pi - angle_of(s.phase3)) / s.omega_d)
    exists = real(lane_leg_force(s, upper)) <= 0.0
    start = real(lane_paper_liftoff(s)[0])
    t = start if np.isfinite(start) else 0.5 * (lower + upper)
    t = min(max(t, lower), upper)
    real_s = lane_real_part(s)
    for _ in range(FORCE_ROOT_ITERATIONS):
        force = real(lane_leg_force(real_s, t))
        rate = real(lane_leg_force_rate(real_s, t))
        if force > 0.0:
            lower = t
        else:
            upper = t
        newton = t - force / (rate if rate < 0.0 else -np.inf)
        t_new = newton if newton > lower and newton < upper else 0.5 * (lower + upper)
        done = abs(t_new - t) <= FORCE_ROOT_TOLERANCE * abs(t_new)
        t = t_new
        if done or not exists:
            break
    if is_complex(s.omega) or is_complex(s.rdot_td):
        # One complex Newton step from the real root carries the perturbation (implicit function theorem).
        return t - lane_leg_force(s, t) / lane_leg_force_rate(s, t), exists
    return t, exists


PAPER_LIFTOFF, FORCE_ROOT_LIFTOFF = 0, 1
"""Codes of the liftoff methods in the kernels."""


@kernel
def lane_liftoff(s: LaneApproximation, method: int) -> tuple[complex, bool]:
    """Liftoff time and whether it exists (see the module docstring for both methods)."""
    if method == FORCE_ROOT_LIFTOFF:
        return lane_force_root_liftoff(s)
    return lane_paper_liftoff(s)


@kernel
def lane_damping_loss(s: LaneApproximation, wave: Wave) -> complex:
    """E_c = int_0^t c rdot^2 (closed form of eq. 31, re-derived), from the wave at t."""
    double = Wave(wave.envelope**2, wave.cos**2 - wave.sin**2, 2.0 * wave.sin * wave.cos)
    phase = angle_sum(angle_sum(s.phase1, s.phase2), s.phase1)
    oscillation = phase.cos - wave_at(double, phase)
    scale = 0.5 * s.m * (s.amplitude * s.omega_hat) ** 2
    loss: complex = scale * (1.0 - double.envelope + s.zeta * oscillation)
    return loss


@kernel
def lane_hip_energy(
    s: LaneApproximation, tau0: complex, t_f: complex, t_end: complex, wave_end: Wave
) -> complex:
    """E_tau = int_0^T tau thetadot dt for the ramp tau0 (1 - t/t_f), T = min(t_f, t_end) (eq. 25);
    wave_end is the wave at t_end."""
    energy: complex = tau0 * lane_energy_per_torque(s, t_f, t_end, wave_end)
    return energy


@kernel
def lane_energy_per_torque(s: LaneApproximation, t_f: complex, t_end: complex, wave_end: Wave) -> complex:
    """E_tau/tau0 (:func:`lane_hip_energy`): the ramp-weighted mean angular rate, times the ramp's length."""
    if real(t_f) <= real(t_end):
        t = t_f
        wave = lane_wave(s, t_f)
    else:
        t = t_end
        wave = wave_end
    lag1 = angle_difference(s.phase1, s.phase2)
    lag2 = angle_difference(lag1, s.phase2)
    i0 = -(wave_at(wave, lag1) - lag1.cos) / s.omega_hat
    i1 = -t * wave_at(wave, lag1) / s.omega_hat - (wave_at(wave, lag2) - lag2.cos) / s.omega_hat**2
    mean_part = s.x_rate * (t - t**2 / (2.0 * t_f))
    oscillating_part = 2.0 * s.omega * s.amplitude / s.r0 * (i0 - i1 / t_f)
    rate: complex = mean_part - oscillating_part
    return rate


@kernel
def lane_torque_correction(tau0: complex, t_f: complex, t_lo: complex) -> complex:
    """dp_tau: time average over [0, t_lo] of the integrated ramp torque (eq. 21 for general t_f)."""
    shorter = t_lo if real(t_lo) <= real(t_f) else t_f
    longer = t_lo + t_f - shorter
    return tau0 * (shorter / 2.0 - shorter**2 / (6.0 * longer))


@kernel
def lane_gravity_correction(
    m: float, g: float, r0: float, theta_td: complex, t_lo: complex, r_lo: complex, theta_lo: complex
) -> complex:
    """dp_g of eq. 22: r sin(theta) interpolated linearly from touchdown to liftoff, then time-averaged."""
    correction: complex = m * g * t_lo / 6.0 * (2.0 * r0 * np.sin(theta_td) + r_lo * np.sin(theta_lo))
    return correction


class Touchdown(NamedTuple):
    """Arrays in the API, scalars in a kernel."""

    rdot: Any
    thetadot: Any
    failure: Any


@kernel
def lane_descent(r0: float, g: float, y: complex, xdot: complex, theta_td: complex) -> Touchdown:
    """P_d (eq. 6): apex (y, xdot) and touchdown angle to the polar touchdown velocities."""
    drop = y - r0 * np.cos(theta_td)
    ydot = -np.sqrt(2.0 * g * drop)
    sin, cos = np.sin(theta_td), np.cos(theta_td)
    rdot = -xdot * sin + ydot * cos
    thetadot = (-xdot * cos - ydot * sin) / r0
    failure = NO_FAILURE_CODE
    if real(drop) < 0.0:
        failure = TOE_STUBBING
    elif real(thetadot) >= 0.0:
        failure = REVERSAL
    return Touchdown(rdot, thetadot, failure)


@kernel
def converged(new: complex, old: complex, tolerance: float) -> bool:
    """new and old agree to ``tolerance`` relative, real and imaginary parts separately."""
    ok = abs(real(new) - real(old)) <= tolerance * abs(real(new))
    if is_complex(new) or is_complex(old):
        ok = ok and abs(new.imag - old.imag) <= tolerance * abs(new.imag)
    return ok


class StanceStart(NamedTuple):
    """The unforced stance of a touchdown: the start of the corrections, whatever the ramp (probes of the
    policies' solvers share it)."""

    momentum_td: complex
    approximation: LaneApproximation
    t_lo: complex
    liftoff_exists: bool
    wave: Wave  # at t_lo
    gravity_correction: complex  # dp_g of the first correction


@inlined_kernel
def lane_stance_start(
    m: float,
    k: float,
    r0: float,
    c: float,
    g: float,
    theta_td: complex,
    rdot_td: complex,
    thetadot_td: complex,
    liftoff: int,
) -> StanceStart:
    momentum_td = m * r0**2 * thetadot_td
    s = lane_approximation(m, k, r0, c, g, theta_td, rdot_td, momentum_td / (m * r0**2))
    t_lo, exists = lane_liftoff(s, liftoff)
    wave = lane_wave(s, t_lo)
    at_liftoff = lane_state(s, wave, t_lo)
    gravity = lane_gravity_correction(m, g, r0, theta_td, t_lo, at_liftoff.r, at_liftoff.theta)
    return StanceStart(momentum_td, s, t_lo, exists, wave, gravity)


class LaneStance(NamedTuple):
    """Outcome of the approximate stance map P_s with corrections, one lane (fields of :class:`Stance`)."""

    momentum: complex
    t_lo: complex
    r_lo: complex
    theta_lo: complex
    rdot_lo: complex
    thetadot_lo: complex
    hip_energy: complex
    damping_loss: complex
    spring_energy: complex
    liftoff_exists: bool
    corrections_done: int
    approximation: LaneApproximation  # the last (most corrected) one
    energy_per_torque: complex  # e = E_tau/tau0: negative while the body swings forward over the ramp


LANE_STANCE_VALUES = 11
"""The fields of LaneStance that Stance holds as arrays (the others stay in the kernels)."""


@inlined_kernel
def lane_stance(
    start: StanceStart, tau0: complex, t_f: complex, corrections: int, liftoff: int
) -> LaneStance:
    """P_s (eqs. 17, 19-22) from the unforced stance: ``corrections`` updates of p_hat = p(0) + dp_tau + dp_g,
    fewer once p_hat changes by less than CORRECTION_TOLERANCE (relative)."""
    s = start.approximation
    m, k, r0, c, g = s.m, s.k, s.r0, s.c, s.g
    momentum = start.momentum_td
    t_lo, exists, gravity = start.t_lo, start.liftoff_exists, start.gravity_correction
    done = 0
    while done < corrections:
        if done > 0:
            at_liftoff = lane_state(s, lane_wave(s, t_lo), t_lo)
            gravity = lane_gravity_correction(m, g, r0, s.theta_td, t_lo, at_liftoff.r, at_liftoff.theta)
        corrected = start.momentum_td + lane_torque_correction(tau0, t_f, t_lo) + gravity
        stop = converged(corrected, momentum, CORRECTION_TOLERANCE) or not exists
        momentum = corrected
        done += 1
        s = lane_approximation(m, k, r0, c, g, s.theta_td, s.rdot_td, momentum / (m * r0**2))
        t_lo, exists = lane_liftoff(s, liftoff)
        if stop:
            break
    wave = start.wave if done == 0 else lane_wave(s, t_lo)
    at_liftoff = lane_state(s, wave, t_lo)
    energy_per_torque = lane_energy_per_torque(s, t_f, t_lo, wave)
    return LaneStance(
        momentum,
        t_lo,
        at_liftoff.r,
        at_liftoff.theta,
        at_liftoff.rdot,
        at_liftoff.thetadot,
        tau0 * energy_per_torque,
        lane_damping_loss(s, wave),
        0.5 * k * (at_liftoff.r - r0) ** 2,
        exists,
        done,
        s,
        energy_per_torque,
    )


class LaneStride(NamedTuple):
    """One stride of the approximate map, one lane (fields of :class:`Stride`)."""

    y: complex
    xdot: complex
    energy: complex
    failure: int
    touchdown: Touchdown
    stance: LaneStance
    liftoff_xdot: complex


@kernel
def apex_energy(m: float, g: float, y: complex, xdot: complex) -> complex:
    return m * (g * y + 0.5 * xdot**2)


@inlined_kernel
def lane_stride(
    m: float,
    k: float,
    r0: float,
    c: float,
    g: float,
    y: complex,
    xdot: complex,
    angle: complex,
    tau0: complex,
    t_f: complex,
    corrections: int,
    liftoff: int,
) -> LaneStride:
    """The approximate apex return map P = P_a o P_s o P_d (eqs. 3-7) of one lane."""
    touchdown = lane_descent(r0, g, y, xdot, angle)
    start = lane_stance_start(m, k, r0, c, g, angle, touchdown.rdot, touchdown.thetadot, liftoff)
    stance = lane_stance(start, tau0, t_f, corrections, liftoff)
    return lane_ascent(m, g, y, xdot, touchdown, stance)


@inlined_kernel
def lane_ascent(
    m: float, g: float, y: complex, xdot: complex, touchdown: Touchdown, stance: LaneStance
) -> LaneStride:
    """The stride from the apex (y, xdot) through its touchdown and stance: the ascent P_a (eq. 7) to the next
    apex, the next energy from the energy balance, and the stride's failure."""
    sin, cos = np.sin(stance.theta_lo), np.cos(stance.theta_lo)
    ydot_lo = stance.rdot_lo * cos - stance.r_lo * stance.thetadot_lo * sin
    xdot_lo = -stance.rdot_lo * sin - stance.r_lo * stance.thetadot_lo * cos
    y_next = stance.r_lo * cos + ydot_lo**2 / (2.0 * g)
    energy_next = (
        apex_energy(m, g, y, xdot) + stance.hip_energy - (stance.damping_loss + stance.spring_energy)
    )
    kinetic = energy_next / m - g * y_next
    xdot_next = np.sqrt(2.0 * kinetic)
    failure = touchdown.failure
    if failure == NO_FAILURE_CODE and not stance.liftoff_exists:
        failure = NO_LIFTOFF
    if failure == NO_FAILURE_CODE and not real(ydot_lo) > 0.0:
        failure = FALL
    if failure == NO_FAILURE_CODE and not (real(kinetic) > 0.0 and real(xdot_lo) > 0.0):
        failure = REVERSAL
    if failure != NO_FAILURE_CODE:
        y_next, xdot_next, energy_next, xdot_lo = np.nan, np.nan, np.nan, np.nan
    return LaneStride(y_next, xdot_next, energy_next, failure, touchdown, stance, xdot_lo)


# --- the vectorised API: broadcasting, lane loops, results as arrays --------------------------------------


def liftoff_code(method: str) -> int:
    """The kernels' code of a liftoff method; ValueError names the methods."""
    if method == "paper":
        return PAPER_LIFTOFF
    if method == "force_root":
        return FORCE_ROOT_LIFTOFF
    raise ValueError(f"unknown liftoff method {method!r}; use 'paper' or 'force_root'")


def check_corrections(corrections: int) -> None:
    if corrections < 0:
        raise ValueError(f"corrections must be >= 0, got {corrections}")


@dataclass(frozen=True)
class Lanes:
    """Inputs broadcast to one shape and flattened for a compiled lane loop: the hopper parameters as rows
    m, k, r0, c, g of one float64 block, the values as complex128 where any of them is complex (the complex
    step), else float64."""

    shape: tuple[int, ...]
    params: Array
    values: tuple[Array, ...]
    dtype: type

    @classmethod
    def of(cls, params: ParamArrays, *values: ArrayLike) -> Lanes:
        if params.column is not None and all(map(_is_scalar, values)):
            # One lane, the controller's call: nothing to broadcast, and the values in one array (at one
            # apex a time, this packaging costs about as much as the policies' kernels).
            together = np.array(values)
            kind: type = complex if together.dtype.kind == "c" else float
            together = together.astype(kind)
            return cls((), params.column, tuple(together[i : i + 1] for i in range(len(values))), kind)
        fields = (params.m, params.k, params.r0, params.c, params.g)
        arrays = [np.asarray(value) for value in values]
        dtype: type = complex if any(a.dtype.kind == "c" for a in arrays) else float
        shape = np.broadcast_shapes(*(np.shape(field) for field in fields), *(a.shape for a in arrays))

        def flat(value: Array, kind: type) -> Array:
            return np.ascontiguousarray(np.broadcast_to(value, shape), dtype=kind).reshape(-1)

        block = np.stack([flat(field, float) for field in fields])
        return cls(shape, block, tuple(flat(a, dtype) for a in arrays), dtype)

    def run(self, loop: Callable[..., None], *arguments: Any) -> None:
        """Call a compiled lane loop with the parameters, the values and then ``arguments``."""
        loop(self.params, *self.values, *arguments)

    def rows(self, count: int) -> Array:
        """An output block of ``count`` rows, one column per lane."""
        return np.empty((count, math.prod(self.shape)), dtype=self.dtype)

    def shaped(self, row: Array) -> Array:
        return np.asarray(row.reshape(self.shape))

    def codes(self, row: Array) -> Array:
        """A row of integer codes (failure, no-command reason), held as numbers in the block."""
        return np.asarray(np.real(row).astype(int).reshape(self.shape))


def _is_scalar(value: ArrayLike) -> bool:
    return isinstance(value, (int, float, complex, np.number)) or (
        isinstance(value, np.ndarray) and value.ndim == 0
    )


def elementwise(function: Callable[..., Any], kinds: Sequence[type], *args: ArrayLike) -> tuple[Array, ...]:
    """``function`` (of one lane's scalars, returning len(kinds) scalars) over broadcast arrays, one Python
    call per lane: for the closed forms' API (checks, plots), not for batches. A kind of complex means the
    dtype of the arguments (complex128 if any is complex, else float64)."""
    dtype = complex if any(np.iscomplexobj(a) for a in args) else float
    otypes = [dtype if kind is complex else kind for kind in kinds]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # failed lanes: NaN, inf
        results = np.vectorize(function, otypes=otypes)(*args)
    return tuple(np.asarray(r) for r in (results if len(kinds) > 1 else (results,)))


_FLAT_APPROXIMATION = 25
"""Scalars of a LaneApproximation with its three phases flattened to (cos, sin)."""


def _flatten(lane: LaneApproximation) -> tuple[Any, ...]:
    return (*lane[:19], *lane.phase1, *lane.phase2, *lane.phase3)


def _unflatten(values: Sequence[Any]) -> LaneApproximation:
    phases = (Angle(*values[19:21]), Angle(*values[21:23]), Angle(*values[23:25]))
    return LaneApproximation._make((*values[:19], *phases))


@dataclass(frozen=True)
class StanceApproximation:
    """Closed-form stance of section II.C for a constant angular momentum ``m r0^2 omega`` (module docstring),
    as arrays: ``lanes`` is a LaneApproximation whose fields are arrays, readable as attributes of this
    object (``amplitude``, ``bottom_time``, ``phase1``, ...; ``params`` gives m, k, r0, c, g as ParamArrays).

    ``t`` arguments broadcast against the fields. The phases phi1, phi2, phi3 are kept as (cos, sin) pairs:
    cos phi1 = A/M, sin phi1 = -B/M, cos phi2 = zeta, sin phi2 = -sqrt(1 - zeta^2),
    cos phi3 = (k - c^2/(2m))/Mbar, sin phi3 = c wd/Mbar, which makes every evaluation cost one exp, one cos
    and one sin per time, whatever is evaluated. The methods run the lane kernels one lane at a time (they
    serve checks against quadrature and plots; the map itself runs in the compiled lane loop).
    """

    lanes: LaneApproximation

    @classmethod
    def build(
        cls, params: ParamArrays, theta_td: ArrayLike, rdot_td: ArrayLike, omega: ArrayLike
    ) -> StanceApproximation:
        fields = (params.m, params.k, params.r0, params.c, params.g)
        values = elementwise(
            lambda *lane: _flatten(lane_approximation(*lane)),
            [float] * 5 + [complex] * 20,
            *fields,
            theta_td,
            rdot_td,
            omega,
        )
        return cls(_unflatten(values))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.lanes, name)

    @property
    def params(self) -> ParamArrays:
        return ParamArrays(*(np.asarray(value) for value in self.lanes[:5]))

    def _call(
        self, function: Callable[..., Any], kinds: Sequence[type], *args: ArrayLike
    ) -> tuple[Array, ...]:
        """function(lane, *args) per lane, lane the LaneApproximation of that lane."""

        def one(*values: Any) -> Any:
            return function(_unflatten(values[:_FLAT_APPROXIMATION]), *values[_FLAT_APPROXIMATION:])

        return elementwise(one, kinds, *_flatten(self.lanes), *args)

    @property
    def phi1(self) -> Array:
        return self._call(lambda s: angle_of(s.phase1), [complex])[0]

    @property
    def phi3(self) -> Array:
        """In [0, pi): the force phase lag of the damper."""
        return self._call(lambda s: angle_of(s.phase3), [complex])[0]

    def state(self, t: ArrayLike) -> StanceState:
        """r, rdot, theta, thetadot at t (eqs. 12-15), sharing one exp, cos and sin."""
        return StanceState(*self._call(lambda s, t: lane_state(s, lane_wave(s, t), t), [complex] * 4, t))

    def length_and_angle(self, t: ArrayLike) -> tuple[Array, Array]:
        """r and theta at t (eqs. 12 and 15), all the momentum corrections need."""
        state = self.state(t)
        return state.r, state.theta

    def r(self, t: ArrayLike) -> Array:
        """Leg length (12)."""
        return np.asarray(self.state(t).r)

    def rdot(self, t: ArrayLike) -> Array:
        """Leg length rate (13)."""
        return np.asarray(self.state(t).rdot)

    def thetadot(self, t: ArrayLike) -> Array:
        """Leg angular rate (14), from the linearised 1/r^2."""
        return np.asarray(self.state(t).thetadot)

    def theta(self, t: ArrayLike) -> Array:
        """Leg angle (15), the integral of (14)."""
        return np.asarray(self.state(t).theta)

    def leg_force(self, t: ArrayLike) -> Array:
        """Spring-damper force along the leg, k (r0 - r) - c rdot, in the closed form of (16)."""
        return self._call(lane_leg_force, [complex], t)[0]

    def leg_force_rate(self, t: ArrayLike) -> Array:
        """Time derivative of :meth:`leg_force`."""
        return self._call(lane_leg_force_rate, [complex], t)[0]

    def liftoff_time(self, method: LiftoffMethod = "paper") -> tuple[Array, Array]:
        """Liftoff time and a mask of lanes where it exists (see the module docstring for both methods)."""
        code = liftoff_code(method)
        t_lo, exists = self._call(lambda s: lane_liftoff(s, code), [complex, bool])
        return t_lo, exists

    def damping_loss(self, t: ArrayLike) -> Array:
        """E_c = int_0^t c rdot^2 (closed form of eq. 31, re-derived)."""
        return self._call(lambda s, t: lane_damping_loss(s, lane_wave(s, t)), [complex], t)[0]

    def hip_energy(self, tau0: ArrayLike, t_f: ArrayLike, t_end: ArrayLike) -> Array:
        """E_tau = int_0^T tau thetadot dt for the ramp tau0 (1 - t/t_f), T = min(t_f, t_end) (eq. 25)."""

        def energy(s: LaneApproximation, tau0: complex, t_f: complex, t_end: complex) -> complex:
            return lane_hip_energy(s, tau0, t_f, t_end, lane_wave(s, t_end))

        return self._call(energy, [complex], tau0, t_f, t_end)[0]


def torque_momentum_correction(tau0: ArrayLike, t_f: ArrayLike, t_lo: ArrayLike) -> Array:
    """dp_tau: time average over [0, t_lo] of the integrated ramp torque (eq. 21 for general t_f)."""
    return elementwise(lane_torque_correction, [complex], tau0, t_f, t_lo)[0]


def gravity_momentum_correction(
    params: ParamArrays, theta_td: ArrayLike, t_lo: ArrayLike, r_lo: ArrayLike, theta_lo: ArrayLike
) -> Array:
    """dp_g of eq. 22: r sin(theta) interpolated linearly from touchdown to liftoff, then time-averaged."""
    return elementwise(
        lane_gravity_correction, [complex], params.m, params.g, params.r0, theta_td, t_lo, r_lo, theta_lo
    )[0]


def descent_map(params: ParamArrays, y: ArrayLike, xdot: ArrayLike, theta_td: ArrayLike) -> Touchdown:
    """P_d (eq. 6): apex (y, xdot) and touchdown angle to the polar touchdown velocities."""
    return Touchdown(
        *elementwise(lane_descent, [complex, complex, int], params.r0, params.g, y, xdot, theta_td)
    )


@dataclass(frozen=True)
class Stance:
    """Outcome of the approximate stance map P_s with corrections, per lane."""

    params: ParamArrays
    theta_td: Array
    rdot_td: Array
    momentum: Array  # p_hat [kg m^2/s]
    t_lo: Array
    r_lo: Array
    theta_lo: Array
    rdot_lo: Array
    thetadot_lo: Array
    hip_energy: Array  # E_tau
    damping_loss: Array  # E_c
    spring_energy: Array  # E_k
    liftoff_exists: Array  # bool
    corrections_done: int  # the most of any lane

    @classmethod
    def of_rows(
        cls,
        params: ParamArrays,
        theta_td: Array,
        rdot_td: Array,
        rows: Sequence[Array],
        liftoff_exists: Array,
        corrections_done: int,
    ) -> Stance:
        """From the rows momentum, t_lo, r_lo, theta_lo, rdot_lo, thetadot_lo, hip_energy, damping_loss,
        spring_energy (the order of LaneStance)."""
        return cls(
            params,
            theta_td,
            rdot_td,
            momentum=rows[0],
            t_lo=rows[1],
            r_lo=rows[2],
            theta_lo=rows[3],
            rdot_lo=rows[4],
            thetadot_lo=rows[5],
            hip_energy=rows[6],
            damping_loss=rows[7],
            spring_energy=rows[8],
            liftoff_exists=liftoff_exists,
            corrections_done=corrections_done,
        )

    @property
    def energy_loss(self) -> Array:
        return self.damping_loss + self.spring_energy

    @cached_property
    def approximation(self) -> StanceApproximation:
        """The last (most corrected) closed-form stance, for p_hat."""
        omega = self.momentum / (self.params.m * self.params.r0**2)
        return StanceApproximation.build(self.params, self.theta_td, self.rdot_td, omega)


def stance_map(
    params: ParamArrays,
    theta_td: ArrayLike,
    rdot_td: ArrayLike,
    thetadot_td: ArrayLike,
    tau0: ArrayLike,
    t_f: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> Stance:
    """P_s (eqs. 17, 19-22): touchdown state and ramp torque to liftoff state and energy pieces.

    ``corrections`` is the number of p_hat = p(0) + dp_tau + dp_g updates (0 = the unforced map of II.C);
    iterations stop early once p_hat changes by less than CORRECTION_TOLERANCE (relative).
    """
    check_corrections(corrections)
    code = liftoff_code(liftoff)

    def one(
        m: float, k: float, r0: float, c: float, g: float, *touchdown_and_ramp: complex
    ) -> tuple[Any, ...]:
        theta, rdot, thetadot, tau0, t_f = touchdown_and_ramp
        start = lane_stance_start(m, k, r0, c, g, theta, rdot, thetadot, code)
        return lane_stance(start, tau0, t_f, corrections, code)[:LANE_STANCE_VALUES]

    fields = (params.m, params.k, params.r0, params.c, params.g)
    values = elementwise(one, [complex] * 9 + [bool, int], *fields, theta_td, rdot_td, thetadot_td, tau0, t_f)
    done = int(values[10].max(initial=0))
    return Stance.of_rows(params, np.asarray(theta_td), np.asarray(rdot_td), values[:9], values[9], done)


@dataclass(frozen=True)
class Stride:
    """One stride of the approximate map P = P_a o P_s o P_d, per lane. Failed lanes hold NaN.

    ``liftoff_xdot`` is the horizontal liftoff velocity of eq. 7, kept for comparison with ``xdot``
    (which the map takes from the energy balance, see the module docstring).
    """

    y: Array
    xdot: Array
    energy: Array
    failure: Array  # NO_FAILURE_CODE or events.failure_code(FailureKind)
    touchdown: Touchdown
    stance: Stance
    liftoff_xdot: Array

    @property
    def ok(self) -> Array:
        return np.asarray(self.failure == NO_FAILURE_CODE)


STRIDE_ROWS = 19
"""Rows of a block of strides (write_stride)."""


@kernel
def write_stride(out: Array, lane: int, stride: LaneStride) -> None:
    """One lane's stride into column ``lane`` of a block, in the order strides_of_block reads."""
    stance = stride.stance
    out[0, lane] = stride.y
    out[1, lane] = stride.xdot
    out[2, lane] = stride.energy
    out[3, lane] = stride.failure
    out[4, lane] = stride.touchdown.rdot
    out[5, lane] = stride.touchdown.thetadot
    out[6, lane] = stride.touchdown.failure
    out[7, lane] = stance.momentum
    out[8, lane] = stance.t_lo
    out[9, lane] = stance.r_lo
    out[10, lane] = stance.theta_lo
    out[11, lane] = stance.rdot_lo
    out[12, lane] = stance.thetadot_lo
    out[13, lane] = stance.hip_energy
    out[14, lane] = stance.damping_loss
    out[15, lane] = stance.spring_energy
    out[16, lane] = stance.liftoff_exists
    out[17, lane] = stance.corrections_done
    out[18, lane] = stride.liftoff_xdot


def strides_of_block(params: ParamArrays, lanes: Lanes, angle: Array, block: Array) -> Stride:
    """The Stride of a block of lanes written by write_stride (angle: the lanes' touchdown angles)."""
    row = [lanes.shaped(values) for values in block]
    done = int(np.real(block[17]).max(initial=0))
    stance = Stance.of_rows(params, lanes.shaped(angle), row[4], row[7:16], row[16].real != 0.0, done)
    touchdown = Touchdown(row[4], row[5], lanes.codes(block[6]))
    return Stride(row[0], row[1], row[2], lanes.codes(block[3]), touchdown, stance, row[18])


@kernel
def _stride_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    angle: Array,
    tau0: Array,
    t_f: Array,
    corrections: int,
    liftoff: int,
    out: Array,
) -> None:
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        stride = lane_stride(m, k, r0, c, g, y[i], xdot[i], angle[i], tau0[i], t_f[i], corrections, liftoff)
        write_stride(out, i, stride)


def command_arrays(command: CommandArrays | StanceCommand) -> CommandArrays:
    """A StanceCommand (or command arrays) as command arrays."""
    if isinstance(command, StanceCommand):
        return CommandArrays(
            np.asarray(command.touchdown_angle),
            np.asarray(command.tau0),
            np.asarray(command.t_f),
        )
    return CommandArrays(*(np.asarray(field) for field in command))


def approximate_map(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    command: CommandArrays | StanceCommand,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> Stride:
    """The approximate apex return map (eqs. 3-7) from apex (y, xdot), vectorised with broadcasting.

    NaN in a command field (a policy that found no command) propagates to a failed lane; other
    out-of-range command values raise ParameterError.
    """
    params = ParamArrays.of(params)
    angle, tau0, t_f = command_arrays(command)
    validate_command(angle, t_f)
    check_corrections(corrections)
    code = liftoff_code(liftoff)
    lanes = Lanes.of(params, y, xdot, angle, tau0, t_f)
    block = lanes.rows(STRIDE_ROWS)
    lanes.run(_stride_lanes, corrections, code, block)
    return strides_of_block(params, lanes, lanes.values[2], block)


def validate_angle(angle: ArrayLike) -> None:
    angle = np.real(angle)
    if np.any((angle <= 0.0) | (angle >= np.pi / 2)):
        raise ParameterError("touchdown_angle must lie in (0, pi/2) rad on every lane")


def validate_command(angle: Array, t_f: Array) -> None:
    validate_angle(angle)
    if np.any(np.real(t_f) <= 0.0):
        raise ParameterError("t_f (ramp duration) must be positive on every lane")


def speed_from_energy(params: HopperParams | ParamArrays, y: ArrayLike, energy: ArrayLike) -> Array:
    """Forward apex speed with apex height y and energy E (eq. 23 coordinates); NaN where E < m g y."""
    params = ParamArrays.of(params)
    with np.errstate(invalid="ignore"):
        return np.asarray(np.sqrt(2.0 * (np.asarray(energy) / params.m - params.g * np.asarray(y))))


def approximate_map_energy(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    energy: ArrayLike,
    command: CommandArrays | StanceCommand,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> Stride:
    """The same map from apex (y, E) coordinates (eq. 23); read ``.y`` and ``.energy`` of the result."""
    return approximate_map(params, y, speed_from_energy(params, y, energy), command, corrections, liftoff)


def approximate_return_map(
    params: HopperParams,
    apex: ApexState,
    command: StanceCommand,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    limits: PlausibilityLimits | None = None,
) -> tuple[ApexState | None, FailureKind | None]:
    """Scalar convenience: the next apex and None, or None and the failure. An apex or command beyond
    ``limits`` (default: the hopper's, :mod:`.limits`) is refused with ParameterError, as the plant
    and the exact map refuse it."""
    checked = PlausibilityLimits.of(params, limits)
    checked.check_apex(apex)
    checked.check_command(command)
    stride = approximate_map(params, apex.y, apex.xdot, command, corrections, liftoff)
    failure = failure_from_code(int(stride.failure))
    if failure is not None:
        return None, failure
    return ApexState(float(stride.y), float(stride.xdot)), None


Policy = Callable[[ParamArrays, Array, Array], CommandArrays]
"""A stance policy: (params, y, xdot) -> command arrays. Must be complex-step safe to be differentiated."""


def fixed_command(command: CommandArrays | StanceCommand) -> Policy:
    """The policy that always returns ``command``."""
    fields = command_arrays(command)
    return lambda params, y, xdot: fields


def closed_loop_map(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    second: ArrayLike,
    policy: Policy,
    coordinates: Coordinates = "speed",
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> Stride:
    """One stride with the command chosen by ``policy`` from the apex; ``second`` is xdot or E."""
    params = ParamArrays.of(params)
    y = np.asarray(y)
    xdot = np.asarray(second) if coordinates == "speed" else speed_from_energy(params, y, second)
    return approximate_map(params, y, xdot, policy(params, y, xdot), corrections, liftoff)


def map_jacobian(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    second: ArrayLike,
    policy: Policy,
    coordinates: Coordinates = "speed",
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> Array:
    """Jacobian d(y', s')/d(y, s) of the closed-loop map by complex step, shape (..., 2, 2).

    ``s`` is xdot (``coordinates="speed"``) or E (``"energy"``). NaN on failed lanes.
    """
    y = np.asarray(y, dtype=float)
    second = np.asarray(second, dtype=float)
    y, second = np.broadcast_arrays(y, second)
    columns = []
    for direction in ((1.0, 0.0), (0.0, 1.0)):
        stride = closed_loop_map(
            params,
            y + 1j * COMPLEX_STEP * direction[0],
            second + 1j * COMPLEX_STEP * direction[1],
            policy,
            coordinates,
            corrections,
            liftoff,
        )
        out_second = stride.xdot if coordinates == "speed" else stride.energy
        column = np.stack([np.imag(stride.y), np.imag(out_second)], axis=-1) / COMPLEX_STEP
        columns.append(np.where(stride.ok[..., None], column, np.nan))
    return np.stack(columns, axis=-1)


def eigenvalues(jacobian: ArrayLike) -> Array:
    """Eigenvalues of (..., 2, 2) Jacobians, shape (..., 2), sorted by decreasing modulus."""
    values = np.linalg.eigvals(np.asarray(jacobian))
    order = np.argsort(-np.abs(values), axis=-1)
    return np.take_along_axis(values, order, axis=-1)
