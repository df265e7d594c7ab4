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

All functions broadcast over arrays of states, parameters and commands and are complex-step safe (the
imaginary parts are treated as infinitesimal perturbations) so that :func:`map_jacobian` can differentiate
them, including the controllers of :mod:`tdslip_ros.model.controllers`.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.events import (
    NO_FAILURE_CODE,
    FailureKind,
    failure_code,
    failure_from_code,
)
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
"""Relative change of p_hat below which further correction iterations stop (on every lane)."""
FORCE_ROOT_TOLERANCE = 1e-14
"""Relative step in t below which the safeguarded Newton search for the force root stops."""
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

    @classmethod
    def of(cls, params: HopperParams | ParamArrays | Sequence[HopperParams]) -> ParamArrays:
        """Arrays from one parameter set (0-d arrays), several (1-d arrays) or an existing ParamArrays."""
        if isinstance(params, ParamArrays):
            return params
        if isinstance(params, HopperParams):
            return cls(*(np.asarray(getattr(params, name)) for name in ("m", "k", "r0", "c", "g")))
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


def no_command_of_failure(failure: ArrayLike) -> Array:
    """no_command codes for map failure codes (events.failure_code); HAS_COMMAND where none."""
    codes = np.full(np.shape(failure), HAS_COMMAND)
    for kind, reason in _NO_COMMAND_OF_FAILURE.items():
        codes = np.where(np.asarray(failure) == failure_code(kind), no_command_code(reason), codes)
    return codes


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


def _real(x: Array) -> Array:
    return np.real(x)


def _atan2(y: Array, x: Array) -> Array:
    """atan2 carrying infinitesimal imaginary parts (complex step): d atan2 = (x dy - y dx)/(x^2 + y^2)."""
    if not (np.iscomplexobj(y) or np.iscomplexobj(x)):
        return np.arctan2(y, x)
    yr, xr = np.real(y), np.real(x)
    return np.asarray(np.arctan2(yr, xr) + 1j * (xr * np.imag(y) - yr * np.imag(x)) / (xr**2 + yr**2))


def _where_real_le(a: Array, b: Array) -> Array:
    """Elementwise min(a, b) chosen on the real parts (complex-step safe away from a tie)."""
    return np.where(_real(a) <= _real(b), a, b)


class _Angle(NamedTuple):
    """A constant phase held as its cosine and sine, so that cos(wd t + phase) needs no new trigonometry."""

    cos: Array
    sin: Array

    def __add__(self, other: object) -> _Angle:
        assert isinstance(other, _Angle)
        return _Angle(
            self.cos * other.cos - self.sin * other.sin, self.sin * other.cos + self.cos * other.sin
        )

    def __sub__(self, other: object) -> _Angle:
        assert isinstance(other, _Angle)
        return _Angle(
            self.cos * other.cos + self.sin * other.sin, self.sin * other.cos - self.cos * other.sin
        )

    def angle(self) -> Array:
        return _atan2(self.sin, self.cos)


class _Oscillation(NamedTuple):
    """e^{-a t}, cos(wd t) and sin(wd t) at the times t: the only transcendental functions of t needed."""

    envelope: Array
    cos: Array
    sin: Array

    def at(self, phase: _Angle) -> Array:
        """e^{-a t} cos(wd t + phase)."""
        return np.asarray(self.envelope * (self.cos * phase.cos - self.sin * phase.sin))


class StanceState(NamedTuple):
    r: Array
    rdot: Array
    theta: Array
    thetadot: Array


@dataclass(frozen=True)
class StanceApproximation:
    """Closed-form stance of section II.C for a constant angular momentum ``m r0^2 omega`` (module docstring).

    All fields are broadcast arrays; ``t`` arguments broadcast against them. The phases phi1, phi2, phi3 are
    kept as (cos, sin) pairs: cos phi1 = A/M, sin phi1 = -B/M, cos phi2 = zeta, sin phi2 = -sqrt(1 - zeta^2),
    cos phi3 = (k - c^2/(2m))/Mbar, sin phi3 = c wd/Mbar, which makes every evaluation cost one exp, one cos
    and one sin per time, whatever is evaluated.
    """

    params: ParamArrays
    theta_td: Array
    rdot_td: Array
    omega: Array
    omega_hat: Array
    zeta: Array
    omega_d: Array
    decay: Array  # a = zeta omega_hat = c/(2m)
    equilibrium: Array  # F/omega_hat^2
    amplitude_a: Array  # A
    amplitude: Array  # M
    force_amplitude: Array  # Mbar
    x_rate: Array  # X
    y_amplitude: Array  # Y
    bottom_time: Array
    phase1: _Angle
    phase2: _Angle
    phase3: _Angle

    @classmethod
    def build(cls, params: ParamArrays, theta_td: Array, rdot_td: Array, omega: Array) -> StanceApproximation:
        m, k, r0, c, g = params.m, params.k, params.r0, params.c, params.g
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
        phase1 = _Angle(amplitude_a / amplitude, -amplitude_b / amplitude)
        phase2 = _Angle(zeta, -damped_fraction)
        # Bottom: wd t_b + phi1 + phi2 = pi/2 (mod 2 pi), the first such t_b > 0.
        bottom_phase = np.pi / 2 - (phase1 + phase2).angle()
        bottom_phase = bottom_phase - 2.0 * np.pi * np.floor(_real(bottom_phase) / (2.0 * np.pi))
        equilibrium = r0 - amplitude_a
        return cls(
            params=params,
            theta_td=theta_td,
            rdot_td=rdot_td,
            omega=omega,
            omega_hat=omega_hat,
            zeta=zeta,
            omega_d=omega_d,
            decay=decay,
            equilibrium=equilibrium,
            amplitude_a=amplitude_a,
            amplitude=amplitude,
            force_amplitude=force_amplitude,
            x_rate=omega * (3.0 - 2.0 * equilibrium / r0),
            y_amplitude=2.0 * omega * amplitude / (r0 * omega_hat),
            bottom_time=bottom_phase / omega_d,
            phase1=phase1,
            phase2=phase2,
            phase3=_Angle(spring_term / force_amplitude, c * omega_d / force_amplitude),
        )

    @property
    def phi1(self) -> Array:
        return self.phase1.angle()

    @property
    def phi3(self) -> Array:
        """In [0, pi): the force phase lag of the damper."""
        return self.phase3.angle()

    def _oscillation(self, t: ArrayLike) -> _Oscillation:
        t = np.asarray(t)
        angle = self.omega_d * t
        return _Oscillation(np.exp(-self.decay * t), np.cos(angle), np.sin(angle))

    def state(self, t: ArrayLike) -> StanceState:
        """r, rdot, theta, thetadot at t (eqs. 12-15), sharing one exp, cos and sin."""
        return self._state(self._oscillation(t), t)

    def _state(self, wave: _Oscillation, t: ArrayLike) -> StanceState:
        radial = wave.at(self.phase1)
        lag = self.phase1 - self.phase2
        swing = wave.at(lag) - lag.cos
        return StanceState(
            r=self.amplitude * radial + self.equilibrium,
            rdot=-self.omega_hat * self.amplitude * wave.at(self.phase1 + self.phase2),
            theta=self.theta_td + self.x_rate * np.asarray(t) + self.y_amplitude * swing,
            thetadot=self.x_rate - 2.0 * self.omega * self.amplitude * radial / self.params.r0,
        )

    def length_and_angle(self, t: ArrayLike) -> tuple[Array, Array]:
        """r and theta at t (eqs. 12 and 15), all the momentum corrections need."""
        wave = self._oscillation(t)
        lag = self.phase1 - self.phase2
        swing = wave.at(lag) - lag.cos
        theta = self.theta_td + self.x_rate * np.asarray(t) + self.y_amplitude * swing
        return self.amplitude * wave.at(self.phase1) + self.equilibrium, theta

    def r(self, t: ArrayLike) -> Array:
        """Leg length (12)."""
        return self.state(t).r

    def rdot(self, t: ArrayLike) -> Array:
        """Leg length rate (13)."""
        return self.state(t).rdot

    def thetadot(self, t: ArrayLike) -> Array:
        """Leg angular rate (14), from the linearised 1/r^2."""
        return self.state(t).thetadot

    def theta(self, t: ArrayLike) -> Array:
        """Leg angle (15), the integral of (14)."""
        return self.state(t).theta

    def leg_force(self, t: ArrayLike) -> Array:
        """Spring-damper force along the leg, k (r0 - r) - c rdot, in the closed form of (16)."""
        oscillation = self._oscillation(t).at(self.phase1 + self.phase3)
        return np.asarray(
            self.params.k * self.amplitude_a - self.force_amplitude * self.amplitude * oscillation
        )

    def leg_force_rate(self, t: ArrayLike) -> Array:
        """Time derivative of :meth:`leg_force`."""
        oscillation = self._oscillation(t).at(self.phase1 + self.phase3 + self.phase2)
        return self.force_amplitude * self.omega_hat * self.amplitude * oscillation

    def liftoff_time(self, method: LiftoffMethod = "paper") -> tuple[Array, Array]:
        """Liftoff time and a mask of lanes where it exists (see the module docstring for both methods)."""
        if method == "paper":
            return self._paper_liftoff_time()
        if method == "force_root":
            return self._force_root_liftoff_time()
        raise ValueError(f"unknown liftoff method {method!r}; use 'paper' or 'force_root'")

    def _paper_liftoff_time(self) -> tuple[Array, Array]:
        q = (
            self.params.k
            * self.amplitude_a
            / (self.force_amplitude * self.amplitude * np.exp(-2.0 * self.decay * self.bottom_time))
        )
        with np.errstate(invalid="ignore"):
            after_bottom = (1.5 * np.pi + (self.phase2 - self.phase3).angle() - np.arccos(q)) / self.omega_d
        exists = (np.abs(_real(q)) <= 1.0) & (_real(after_bottom) > 0.0)
        return self.bottom_time + after_bottom, exists

    def _force_root_liftoff_time(self) -> tuple[Array, Array]:
        # The force decreases monotonically from the bottom to its minimum at phase 3 pi/2 - phi2.
        lower = _real(self.bottom_time) + np.zeros(np.shape(self.bottom_time))
        upper = lower + _real((np.pi - self.phi3) / self.omega_d)
        exists = _real(self.leg_force(upper)) <= 0.0
        paper_time, _ = self._paper_liftoff_time()
        start = _real(paper_time)
        t = np.clip(np.where(np.isfinite(start), start, 0.5 * (lower + upper)), lower, upper)
        real_self = self._real_part()
        for _ in range(100):
            force = real_self.leg_force(t)
            rate = real_self.leg_force_rate(t)
            lower = np.where(force > 0.0, t, lower)
            upper = np.where(force > 0.0, upper, t)
            newton = t - force / np.where(rate < 0.0, rate, -np.inf)
            inside = (newton > lower) & (newton < upper)
            t_new = np.where(inside, newton, 0.5 * (lower + upper))
            done = np.abs(t_new - t) <= FORCE_ROOT_TOLERANCE * np.abs(t_new)
            t = t_new
            if np.all(done | ~exists):
                break
        if np.iscomplexobj(self.omega) or np.iscomplexobj(self.rdot_td):
            # One complex Newton step from the real root carries the perturbation (implicit function theorem).
            t = t - self.leg_force(t) / self.leg_force_rate(t)
        return t, exists

    def _real_part(self) -> StanceApproximation:
        def real(value: object) -> object:
            if isinstance(value, _Angle):
                return _Angle(_real(value.cos), _real(value.sin))
            return value if isinstance(value, ParamArrays) else _real(np.asarray(value))

        return StanceApproximation(**{name: real(value) for name, value in vars(self).items()})  # type: ignore[arg-type]

    def damping_loss(self, t: ArrayLike) -> Array:
        """E_c = int_0^t c rdot^2 (closed form of eq. 31, re-derived)."""
        return self._damping_loss(self._oscillation(t))

    def _damping_loss(self, wave: _Oscillation) -> Array:
        double = _Oscillation(wave.envelope**2, wave.cos**2 - wave.sin**2, 2.0 * wave.sin * wave.cos)
        phase = self.phase1 + self.phase2 + self.phase1
        oscillation = phase.cos - double.at(phase)
        scale = 0.5 * self.params.m * (self.amplitude * self.omega_hat) ** 2
        return np.asarray(scale * (1.0 - double.envelope + self.zeta * oscillation))

    def hip_energy(self, tau0: ArrayLike, t_f: ArrayLike, t_end: ArrayLike) -> Array:
        """E_tau = int_0^T tau thetadot dt for the ramp tau0 (1 - t/t_f), T = min(t_f, t_end) (eq. 25)."""
        tau0, t_f, t_end = np.asarray(tau0), np.asarray(t_f), np.asarray(t_end)
        t = _where_real_le(t_f, t_end)
        wave = self._oscillation(t)
        lag1 = self.phase1 - self.phase2
        lag2 = lag1 - self.phase2
        i0 = -(wave.at(lag1) - lag1.cos) / self.omega_hat
        i1 = -t * wave.at(lag1) / self.omega_hat - (wave.at(lag2) - lag2.cos) / self.omega_hat**2
        mean_part = self.x_rate * (t - t**2 / (2.0 * t_f))
        oscillating_part = 2.0 * self.omega * self.amplitude / self.params.r0 * (i0 - i1 / t_f)
        return np.asarray(tau0 * (mean_part - oscillating_part))


def torque_momentum_correction(tau0: ArrayLike, t_f: ArrayLike, t_lo: ArrayLike) -> Array:
    """dp_tau: time average over [0, t_lo] of the integrated ramp torque (eq. 21 for general t_f)."""
    tau0, t_f, t_lo = np.asarray(tau0), np.asarray(t_f), np.asarray(t_lo)
    shorter = _where_real_le(t_lo, t_f)
    longer = t_lo + t_f - shorter
    return np.asarray(tau0 * (shorter / 2.0 - shorter**2 / (6.0 * longer)))


def gravity_momentum_correction(
    params: ParamArrays, theta_td: Array, t_lo: Array, r_lo: Array, theta_lo: Array
) -> Array:
    """dp_g of eq. 22: r sin(theta) interpolated linearly from touchdown to liftoff, then time-averaged."""
    return np.asarray(
        params.m * params.g * t_lo / 6.0 * (2.0 * params.r0 * np.sin(theta_td) + r_lo * np.sin(theta_lo))
    )


class Touchdown(NamedTuple):
    rdot: Array
    thetadot: Array
    failure: Array


def descent_map(params: ParamArrays, y: ArrayLike, xdot: ArrayLike, theta_td: ArrayLike) -> Touchdown:
    """P_d (eq. 6): apex (y, xdot) and touchdown angle to the polar touchdown velocities."""
    y, xdot, theta_td = np.asarray(y), np.asarray(xdot), np.asarray(theta_td)
    drop = y - params.r0 * np.cos(theta_td)
    with np.errstate(invalid="ignore"):
        ydot = -np.sqrt(2.0 * params.g * drop)
    sin, cos = np.sin(theta_td), np.cos(theta_td)
    rdot = -xdot * sin + ydot * cos
    thetadot = (-xdot * cos - ydot * sin) / params.r0
    failure = np.where(_real(drop) < 0.0, TOE_STUBBING, NO_FAILURE_CODE)
    failure = np.where((failure == NO_FAILURE_CODE) & (_real(thetadot) >= 0.0), REVERSAL, failure)
    return Touchdown(rdot, thetadot, failure)


@dataclass(frozen=True)
class Stance:
    """Outcome of the approximate stance map P_s with corrections, per lane."""

    approximation: StanceApproximation  # the last (most corrected) one
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
    corrections_done: int

    @property
    def energy_loss(self) -> Array:
        return self.damping_loss + self.spring_energy


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
    iterations stop early once p_hat changes by less than CORRECTION_TOLERANCE (relative) on every lane.
    """
    if corrections < 0:
        raise ValueError(f"corrections must be >= 0, got {corrections}")
    theta_td, rdot_td, thetadot_td = (
        np.asarray(theta_td),
        np.asarray(rdot_td),
        np.asarray(thetadot_td),
    )
    tau0, t_f = np.asarray(tau0), np.asarray(t_f)
    momentum_td = params.m * params.r0**2 * thetadot_td
    momentum = momentum_td
    done = 0
    with np.errstate(invalid="ignore", divide="ignore"):
        approximation = StanceApproximation.build(
            params, theta_td, rdot_td, momentum / (params.m * params.r0**2)
        )
        t_lo, exists = approximation.liftoff_time(liftoff)
        while done < corrections:
            r_lo, theta_lo = approximation.length_and_angle(t_lo)
            corrected = (
                momentum_td
                + torque_momentum_correction(tau0, t_f, t_lo)
                + gravity_momentum_correction(params, theta_td, t_lo, r_lo, theta_lo)
            )
            converged = _converged(corrected, momentum, CORRECTION_TOLERANCE, exists)
            momentum = corrected
            done += 1
            approximation = StanceApproximation.build(
                params, theta_td, rdot_td, momentum / (params.m * params.r0**2)
            )
            t_lo, exists = approximation.liftoff_time(liftoff)
            if converged:
                break
        wave = approximation._oscillation(t_lo)
        at_liftoff = approximation._state(wave, t_lo)
        return Stance(
            approximation=approximation,
            momentum=momentum,
            t_lo=t_lo,
            r_lo=at_liftoff.r,
            theta_lo=at_liftoff.theta,
            rdot_lo=at_liftoff.rdot,
            thetadot_lo=at_liftoff.thetadot,
            hip_energy=approximation.hip_energy(tau0, t_f, t_lo),
            damping_loss=approximation._damping_loss(wave),
            spring_energy=0.5 * params.k * (at_liftoff.r - params.r0) ** 2,
            liftoff_exists=exists,
            corrections_done=done,
        )


def lanes_converged(new: Array, old: Array, tolerance: float) -> Array:
    """Per lane: new and old agree to ``tolerance`` relative, real and imaginary parts separately."""
    ok = np.abs(_real(new) - _real(old)) <= tolerance * np.abs(_real(new))
    if np.iscomplexobj(new) or np.iscomplexobj(old):
        ok &= np.abs(np.imag(new) - np.imag(old)) <= tolerance * np.abs(np.imag(new))
    return np.asarray(ok)


def _converged(new: Array, old: Array, tolerance: float, mask: Array) -> bool:
    """:func:`lanes_converged` on every lane of mask."""
    return bool(np.all(lanes_converged(new, old, tolerance) | ~mask))


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


def _apex_energy(params: ParamArrays, y: Array, xdot: Array) -> Array:
    return params.m * (params.g * y + 0.5 * xdot**2)


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
    _validate_command(angle, t_f)
    y, xdot = np.asarray(y), np.asarray(xdot)
    touchdown = descent_map(params, y, xdot, angle)
    stance = stance_map(
        params,
        angle,
        touchdown.rdot,
        touchdown.thetadot,
        tau0,
        t_f,
        corrections,
        liftoff,
    )
    with np.errstate(invalid="ignore"):
        sin, cos = np.sin(stance.theta_lo), np.cos(stance.theta_lo)
        ydot_lo = stance.rdot_lo * cos - stance.r_lo * stance.thetadot_lo * sin
        xdot_lo = -stance.rdot_lo * sin - stance.r_lo * stance.thetadot_lo * cos
        y_next = stance.r_lo * cos + ydot_lo**2 / (2.0 * params.g)
        energy_next = _apex_energy(params, y, xdot) + stance.hip_energy - stance.energy_loss
        kinetic = energy_next / params.m - params.g * y_next
        xdot_next = np.sqrt(2.0 * kinetic)
    failure = touchdown.failure
    unset = failure == NO_FAILURE_CODE
    failure = np.where(unset & ~stance.liftoff_exists, NO_LIFTOFF, failure)
    unset = failure == NO_FAILURE_CODE
    failure = np.where(unset & ~(_real(ydot_lo) > 0.0), FALL, failure)
    unset = failure == NO_FAILURE_CODE
    failure = np.where(unset & ~((_real(kinetic) > 0.0) & (_real(xdot_lo) > 0.0)), REVERSAL, failure)
    failed = failure != NO_FAILURE_CODE
    return Stride(
        y=np.where(failed, np.nan, y_next),
        xdot=np.where(failed, np.nan, xdot_next),
        energy=np.where(failed, np.nan, energy_next),
        failure=failure,
        touchdown=touchdown,
        stance=stance,
        liftoff_xdot=np.where(failed, np.nan, xdot_lo),
    )


def _validate_command(angle: Array, t_f: Array) -> None:
    angle, t_f = _real(angle), _real(t_f)
    if np.any((angle <= 0.0) | (angle >= np.pi / 2)):
        raise ParameterError("touchdown_angle must lie in (0, pi/2) rad on every lane")
    if np.any(t_f <= 0.0):
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
) -> tuple[ApexState | None, FailureKind | None]:
    """Scalar convenience: the next apex and None, or None and the failure."""
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
