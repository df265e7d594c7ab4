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
``bench/bench_analytic.py``, which prints the accuracy table). The paper's own map, which keeps the
horizontal liftoff velocity through the flight (``xdot' = xdot_lo``, ``E' = m (g y' + xdot_lo^2/2)``), is the
variant ``speed="liftoff"`` of :func:`approximate_map`; both are one kernel with a flag
(:func:`map_variant_code`).

Implementation. The equations are written once, as compiled scalar kernels of one lane
(:mod:`tdslip_ros.model.analytic.map_kernels`): the one-apex controller calls them directly and the vectorised
API here runs them in a compiled loop over the lanes of a batch. The public functions broadcast over arrays of
states, parameters and commands (:mod:`tdslip_ros.model.arrays`) and are complex-step safe (the imaginary
parts are treated as infinitesimal perturbations; a batch with any complex input runs the complex128
specialisation of the same kernels) so that :func:`~tdslip_ros.model.analytic.closed_loop.map_jacobian` can
differentiate them, including the controllers of :mod:`tdslip_ros.model.policies.controllers`. A lane's result
does not depend on the other lanes of its batch.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Literal

import numpy as np

from tdslip_ros.model import dynamics
from tdslip_ros.model.analytic.map_kernels import (
    ENERGY_SPEED,
    FORCE_ROOT_LIFTOFF,
    LANE_STANCE_VALUES,
    LIFTOFF_SPEED,
    PAPER_LIFTOFF,
    STRIDE_ROWS,
    Angle,
    LaneApproximation,
    StanceState,
    Touchdown,
    angle_of,
    lane_approximation,
    lane_damping_loss,
    lane_descent,
    lane_gravity_correction,
    lane_hip_energy,
    lane_leg_force,
    lane_leg_force_rate,
    lane_liftoff,
    lane_stance,
    lane_stance_start,
    lane_state,
    lane_torque_correction,
    lane_wave,
    stride_lanes,
)
from tdslip_ros.model.arrays import (
    Array,
    ArrayLike,
    CommandArrays,
    Lanes,
    ParamArrays,
    command_arrays,
    elementwise,
)
from tdslip_ros.model.events import NO_FAILURE_CODE, FailureKind, failure_from_code
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand

LiftoffMethod = Literal["paper", "force_root"]
SpeedSource = Literal["energy", "liftoff"]
"""Where the map takes the next apex speed from: the energy balance (``"energy"``, the default, ours) or
the horizontal liftoff velocity of eq. (7) (``"liftoff"``, the paper's map as printed)."""
ANALYTIC_MAPS: dict[str, SpeedSource] = {"ours": "energy", "paper": "liftoff"}
"""The analytic maps by name, each with its next apex speed (:data:`SpeedSource`): ours, from the energy
balance (the default), or the paper's, from the liftoff velocity of eq. 7 as printed. The policies'
``analytic_map`` setting (:mod:`tdslip_ros.model.policies.registry`) and ``tdslip ... --map`` name them so."""
DEFAULT_ANALYTIC_MAP = "ours"


def map_variant_code(liftoff: str, speed: str = "energy") -> int:
    """The kernels' code of a map variant (a liftoff method and a speed source, map_kernels); ValueError
    names the choices."""
    methods = {"paper": PAPER_LIFTOFF, "force_root": FORCE_ROOT_LIFTOFF}
    sources = {"energy": ENERGY_SPEED, "liftoff": LIFTOFF_SPEED}
    if liftoff not in methods:
        raise ValueError(f"unknown liftoff method {liftoff!r}; use 'paper' or 'force_root'")
    if speed not in sources:
        raise ValueError(f"unknown speed source {speed!r}; use 'energy' or 'liftoff'")
    return methods[liftoff] | sources[speed]


def check_corrections(corrections: int) -> None:
    if corrections < 0:
        raise ValueError(f"corrections must be >= 0, got {corrections}")


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
        code = map_variant_code(method)
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
    code = map_variant_code(liftoff)

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
    """One stride of the approximate map P = P_a o P_s o P_d, per lane. Failed lanes hold NaN."""

    y: Array
    xdot: Array
    energy: Array
    failure: Array  # NO_FAILURE_CODE or events.failure_code(FailureKind)
    touchdown: Touchdown
    stance: Stance

    @property
    def ok(self) -> Array:
        return np.asarray(self.failure == NO_FAILURE_CODE)


def strides_of_block(params: ParamArrays, lanes: Lanes, angle: Array, block: Array) -> Stride:
    """The Stride of a block of lanes written by write_stride (angle: the lanes' touchdown angles)."""
    row = [lanes.shaped(values) for values in block]
    done = int(np.real(block[17]).max(initial=0))
    stance = Stance.of_rows(params, lanes.shaped(angle), row[4], row[7:16], row[16].real != 0.0, done)
    touchdown = Touchdown(row[4], row[5], lanes.codes(block[6]))
    return Stride(row[0], row[1], row[2], lanes.codes(block[3]), touchdown, stance)


def approximate_map(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    command: CommandArrays | StanceCommand,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> Stride:
    """The approximate apex return map (eqs. 3-7) from apex (y, xdot), vectorised with broadcasting.

    ``speed`` is where the next apex speed comes from (:data:`SpeedSource`; the module docstring). NaN in a
    command field (a policy that found no command) propagates to a failed lane; other out-of-range command
    values raise ParameterError.
    """
    params = ParamArrays.of(params)
    angle, tau0, t_f = command_arrays(command)
    validate_command(angle, t_f)
    check_corrections(corrections)
    code = map_variant_code(liftoff, speed)
    lanes = Lanes.of(params, y, xdot, angle, tau0, t_f)
    block = lanes.rows(STRIDE_ROWS)
    lanes.run(stride_lanes, corrections, code, block)
    return strides_of_block(params, lanes, lanes.values[2], block)


def validate_angle(angle: ArrayLike) -> None:
    angle = np.real(angle)
    if np.any((angle <= 0.0) | (angle >= np.pi / 2)):
        raise ParameterError("touchdown_angle must lie in (0, pi/2) rad on every lane")


def validate_command(angle: Array, t_f: Array) -> None:
    validate_angle(angle)
    if np.any(np.real(t_f) <= 0.0):
        raise ParameterError("t_f (ramp duration) must be positive on every lane")


def approximate_map_energy(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    energy: ArrayLike,
    command: CommandArrays | StanceCommand,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> Stride:
    """The same map from apex (y, E) coordinates (eq. 23); read ``.y`` and ``.energy`` of the result."""
    xdot = dynamics.speed_from_energy(params, y, energy)
    return approximate_map(params, y, xdot, command, corrections, liftoff, speed=speed)


def approximate_return_map(
    params: HopperParams,
    apex: ApexState,
    command: StanceCommand,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
    limits: PlausibilityLimits | None = None,
) -> tuple[ApexState | None, FailureKind | None]:
    """Scalar convenience: the next apex and None, or None and the failure. An apex or command beyond
    ``limits`` (default: the hopper's, :mod:`.limits`) is refused with ParameterError, as the plant
    and the exact map refuse it."""
    checked = PlausibilityLimits.of(params, limits)
    checked.check_apex(apex)
    checked.check_command(command)
    stride = approximate_map(params, apex.y, apex.xdot, command, corrections, liftoff, speed=speed)
    failure = failure_from_code(int(stride.failure))
    if failure is not None:
        return None, failure
    return ApexState(float(stride.y), float(stride.xdot)), None
