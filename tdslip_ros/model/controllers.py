"""The paper's stance policies as pure functions: apex state(s), parameters, targets -> stance command arrays.

Every policy returns :class:`~tdslip_ros.model.analytic.CommandArrays` (touchdown angle [rad], ramp torque
tau0 [N m], ramp duration t_f [s]) broadcast over the inputs; ``.command()`` turns one lane into a validated
:class:`~tdslip_ros.model.params.StanceCommand`. Lanes where no command exists (the apex is too low to place
the leg at the angle asked for, or the analytic map predicts no liftoff) get NaN fields; the analytic map
reports such lanes as failures. ``t_f`` is always the liftoff time that the analytic map predicts *for the
returned command itself* (a fixed point t_f = t_lo(t_f), since the torque correction of p_hat depends on
t_f), so the map evaluated with the command is exactly the map the policy planned with.

The torque-based policies are complex-step safe (for :func:`~tdslip_ros.model.analytic.map_jacobian`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from tdslip_ros.model import units
from tdslip_ros.model.analytic import (
    Array,
    ArrayLike,
    CommandArrays,
    LiftoffMethod,
    ParamArrays,
    Stance,
    approximate_map,
    descent_map,
    lanes_converged,
    stance_map,
)
from tdslip_ros.model.events import NO_FAILURE_CODE
from tdslip_ros.model.params import HopperParams

FIXED_POINT_TOLERANCE = 1e-13
"""Relative change of t_f and tau0 below which the policies' fixed-point iterations stop."""
FIXED_POINT_ITERATIONS = 60
ANGLE_MARGIN = 1e-6
"""rad kept from the ends of the admissible touchdown interval (leg placement, pi/2)."""


TauRule = Callable[[Stance, Array, Array], Array]
"""tau0 from a planned stance, the touchdown angular rate and the ramp duration t_f."""


def _planned_stance(
    params: ParamArrays,
    y: Array,
    xdot: Array,
    angle: Array,
    tau0_rule: TauRule,
    corrections: int,
    liftoff: LiftoffMethod,
    start: tuple[ArrayLike, ArrayLike] | None = None,
) -> tuple[Array, Array]:
    """Solve (tau0, t_f) = (tau0_rule(stance), t_lo) for the stance they produce; returns (tau0, t_f).

    Lanes without liftoff, or that do not converge in FIXED_POINT_ITERATIONS, get NaN.
    Starts from ``start`` = (tau0, t_f) where it is finite (a solution at a nearby angle or state), elsewhere
    from the unforced stance (tau0 = 0, corrections = 0, where t_lo does not depend on t_f). The
    plain iteration x <- G(x) contracts only linearly (about -1/3 per step for energy regulation, where
    tau0 moves t_lo and the losses through p_hat), so it is accelerated by Anderson mixing of depth one
    per lane, on (tau0, t_f) scaled by m g r0 and sqrt(m/k).
    """
    touchdown = descent_map(params, y, xdot, angle)
    shape = np.broadcast_shapes(np.shape(touchdown.rdot), np.shape(params.m))
    scales = (params.m * params.g * params.r0, np.sqrt(params.m / params.k))
    valid = touchdown.failure == NO_FAILURE_CODE
    start_tau0, start_t_f = (np.nan, np.nan) if start is None else start
    x: list[Array] = [
        np.asarray(start_tau0) / scales[0] + np.zeros(shape, dtype=touchdown.rdot.dtype),
        np.asarray(start_t_f) / scales[1] + np.zeros(shape),
    ]
    warm = np.isfinite(x[0]) & np.isfinite(x[1])
    if not np.all(warm):
        unforced = stance_map(params, angle, touchdown.rdot, touchdown.thetadot, 0.0, 1.0, 0, liftoff)
        x = [np.where(warm, x[0], 0.0), np.where(warm, x[1], unforced.t_lo / scales[1])]
        valid = valid & (warm | unforced.liftoff_exists)
    previous: tuple[list[Array], list[Array]] | None = None
    with np.errstate(invalid="ignore", divide="ignore"):  # failed lanes carry NaN
        for _ in range(FIXED_POINT_ITERATIONS):
            tau0, t_f = x[0] * scales[0], x[1] * scales[1]
            stance = stance_map(
                params, angle, touchdown.rdot, touchdown.thetadot, tau0, t_f, corrections, liftoff
            )
            mapped = [tau0_rule(stance, touchdown.thetadot, t_f) / scales[0], stance.t_lo / scales[1]]
            valid = valid & stance.liftoff_exists
            converged = lanes_converged(mapped[0], x[0], FIXED_POINT_TOLERANCE) & lanes_converged(
                mapped[1], x[1], FIXED_POINT_TOLERANCE
            )
            if np.all(converged | ~valid):
                x = mapped
                break
            residual = [new - old for new, old in zip(mapped, x, strict=True)]
            step = residual
            if previous is not None:
                dx = [a - b for a, b in zip(x, previous[0], strict=True)]
                dr = [a - b for a, b in zip(residual, previous[1], strict=True)]
                gamma = (dr[0] * residual[0] + dr[1] * residual[1]) / (dr[0] ** 2 + dr[1] ** 2)
                gamma = np.where(np.isfinite(gamma), gamma, 0.0)
                step = [r - gamma * (a + b) for r, a, b in zip(residual, dx, dr, strict=True)]
            previous = (x, residual)
            x = [a + b for a, b in zip(x, step, strict=True)]
    valid = valid & converged  # a lane that did not converge has no command
    return np.where(valid, x[0] * scales[0], np.nan), np.where(valid, x[1] * scales[1], np.nan)


def _as_arrays(*values: ArrayLike) -> list[Array]:
    return [np.asarray(value) for value in values]


def _apex_energy(params: ParamArrays, y: Array, xdot: Array) -> Array:
    return params.m * (params.g * y + 0.5 * xdot**2)


def ramp_to_liftoff(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    angle: ArrayLike,
    tau0: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> CommandArrays:
    """A given touchdown angle and ramp torque tau0, with t_f the liftoff time the map predicts for them."""
    y_, xdot_, angle_, tau0_ = _as_arrays(y, xdot, angle, tau0)

    def tau0_rule(stance: Stance, thetadot_td: Array, t_f: Array) -> Array:
        return tau0_ + np.zeros_like(t_f)

    tau0_out, t_f = _planned_stance(
        ParamArrays.of(params), y_, xdot_, angle_, tau0_rule, corrections, liftoff
    )
    return CommandArrays(np.broadcast_to(angle_, np.shape(t_f)), tau0_out, t_f)


def fixed_power(
    params: HopperParams,
    y: ArrayLike,
    xdot: ArrayLike,
    beta: ArrayLike,
    alpha: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> CommandArrays:
    """Open-loop regime of section III: theta_td = beta, tau0 = C/thetadot_td (eq. 26), t_f = predicted t_lo.

    ``alpha`` is the dimensionless touchdown power C/(m g sqrt(g r0)); C = tau0 thetadot_td > 0 is the hip
    power at touchdown (thetadot_td < 0, so tau0 < 0: forward thrust).
    """
    y_, xdot_, beta_ = _as_arrays(y, xdot, beta)
    power = np.asarray(units.power_from_alpha(params, np.asarray(alpha, dtype=float)))

    def tau0_rule(stance: Stance, thetadot_td: Array, t_f: Array) -> Array:
        return power / thetadot_td

    tau0, t_f = _planned_stance(ParamArrays.of(params), y_, xdot_, beta_, tau0_rule, corrections, liftoff)
    return CommandArrays(np.broadcast_to(beta_, np.shape(tau0)), tau0, t_f)


def energy_regulation(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    beta: ArrayLike,
    target_energy: ArrayLike | None = None,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> CommandArrays:
    """Energy regulation of section IV.A: theta_td = beta and tau0 with E_tau = E_loss (eq. 32), t_f = t_lo.

    With ``target_energy`` E* [J], E_tau = E_loss + (E* - E_a): the energy of the next apex predicted by the
    analytic map is E* (this is the regulator the exact-plant studies use, with the first stride's energy as
    E*, so that prediction errors do not accumulate). Without it, E* = E_a (the paper's eq. 32).
    For a given stance E_tau is linear in tau0, so each fixed-point step solves that linear equation.
    """
    params = ParamArrays.of(params)
    y_, xdot_, beta_ = _as_arrays(y, xdot, beta)
    energy = _apex_energy(params, y_, xdot_)
    change = np.zeros_like(energy) if target_energy is None else np.asarray(target_energy) - energy

    def tau0_rule(stance: Stance, thetadot_td: Array, t_f: Array) -> Array:
        energy_per_torque = stance.approximation.hip_energy(1.0, t_f, stance.t_lo)
        return (change + stance.energy_loss) / energy_per_torque

    tau0, t_f = _planned_stance(params, y_, xdot_, beta_, tau0_rule, corrections, liftoff)
    return CommandArrays(np.broadcast_to(beta_, np.shape(tau0)), tau0, t_f)


def admissible_angles(params: HopperParams | ParamArrays, y: ArrayLike) -> tuple[Array, Array]:
    """Touchdown angles that place the leg from apex height y: (arccos(min(y/r0, 1)), pi/2) less ANGLE_MARGIN.

    This is eq. 34's interval (-pi/2, pi/2) cut to forward running (StanceCommand's (0, pi/2)) and to
    feasible leg placement (y > r0 cos(theta_td), no toe stubbing).
    """
    params = ParamArrays.of(params)
    lowest = np.arccos(np.minimum(np.real(np.asarray(y)) / params.r0, 1.0))
    return lowest + ANGLE_MARGIN, np.broadcast_to(np.pi / 2 - ANGLE_MARGIN, np.shape(lowest))


def deadbeat(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    target_y: ArrayLike,
    target_xdot: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    grid: int = 32,
    angle_tolerance: float = 1e-9,
) -> CommandArrays:
    """Deadbeat control by inversion of the analytic map (section V.A, eqs. 33-34).

    The torque supplies the energy of the target apex in one stride, E_tau = dE + E_loss (eq. 33, the
    energy regulation with E* = m g y* + m xdot*^2/2), solved jointly with t_f = t_lo for every candidate
    angle. The touchdown angle minimises (xdot* - xdot_next(theta))^2 (eq. 34) over the admissible interval
    (:func:`admissible_angles`): a scan of ``grid`` angles, then golden-section search in the bracket
    around the best one down to ``angle_tolerance`` rad. Since the map's next energy is then E* exactly,
    reaching xdot* also means reaching y*. Angles where the map fails count as +inf.
    """
    params = ParamArrays.of(params)
    y_, xdot_, target_y_, target_xdot_ = _as_arrays(y, xdot, target_y, target_xdot)
    target_energy = _apex_energy(params, target_y_, target_xdot_)
    lower, upper = admissible_angles(params, y_)
    shape = np.broadcast_shapes(np.shape(lower), np.shape(xdot_), np.shape(target_energy), np.shape(params.m))
    lower, upper = np.broadcast_to(lower, shape), np.broadcast_to(upper, shape)

    lanes = ParamArrays(*(np.asarray(field)[..., None] for field in vars(params).values()))
    y_lanes, xdot_lanes = y_[..., None], xdot_[..., None]

    def objective(angle: Array) -> Array:
        command = energy_regulation(
            lanes,
            y_lanes,
            xdot_lanes,
            angle,
            target_energy[..., None],
            corrections,
            liftoff,
        )
        stride = approximate_map(lanes, y_lanes, xdot_lanes, command, corrections, liftoff)
        cost = (target_xdot_[..., None] - stride.xdot) ** 2
        return np.where(np.isfinite(cost), cost, np.inf)

    fractions = np.linspace(0.0, 1.0, grid)
    angles = lower[..., None] + (upper - lower)[..., None] * fractions
    best = np.argmin(objective(angles), axis=-1)[..., None]
    step = (upper - lower)[..., None] / (grid - 1)
    a = np.maximum(np.take_along_axis(angles, best, axis=-1) - step, lower[..., None])
    b = np.minimum(np.take_along_axis(angles, best, axis=-1) + step, upper[..., None])
    angle = _golden_section(objective, a, b, angle_tolerance)[..., 0]
    return energy_regulation(params, y_, xdot_, angle, target_energy, corrections, liftoff)


def _golden_section(objective: Callable[[Array], Array], a: Array, b: Array, tolerance: float) -> Array:
    """Vectorised golden-section minimisation on [a, b] per lane (the objective sees all lanes at once)."""
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    c, d = b - ratio * (b - a), a + ratio * (b - a)
    fc, fd = objective(c), objective(d)
    while np.max(b - a) > tolerance:
        left = fc <= fd
        a, b = np.where(left, a, c), np.where(left, d, b)
        c_new = np.where(left, b - ratio * (b - a), d)
        d_new = np.where(left, c, a + ratio * (b - a))
        fresh = np.where(left, c_new, d_new)
        f_fresh = objective(fresh)
        fc, fd = np.where(left, f_fresh, fd), np.where(left, fc, f_fresh)
        c, d = c_new, d_new
    return np.asarray(np.where(fc <= fd, c, d))


def neutral_angle(params: HopperParams | ParamArrays, xdot: ArrayLike) -> Array:
    """Raibert's neutral touchdown angle, toe half a stance's travel ahead: sin(theta_n) = xdot T_s/(2 r0).

    T_s = pi sqrt(m/k) is the half period of the leg spring, the usual estimate of the stance time.
    """
    params = ParamArrays.of(params)
    stance_time = np.pi * np.sqrt(params.m / params.k)
    return np.arcsin(np.clip(np.asarray(xdot) * stance_time / (2.0 * params.r0), 0.0, 1.0))


def pd_speed_energy_height(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    previous_xdot: ArrayLike,
    target_y: ArrayLike,
    target_xdot: ArrayLike,
    kp: float = 0.06,
    kd: float = 0.03,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> CommandArrays:
    """PD baseline in the spirit of the paper's ref. 36 (energy control of height, PD control of speed).

    * Speed, through the touchdown angle (Raibert-style foot placement, discrete PD over strides)::

          theta_td = theta_n(xdot) + kp (xdot - xdot*) + kd (xdot - xdot_prev)

      with theta_n from :func:`neutral_angle`, gains in rad/(m/s), clipped into :func:`admissible_angles`.
      Running too fast places the foot further ahead, which brakes. ``previous_xdot`` is the speed at the
      previous apex (pass ``xdot`` on the first stride).
    * Height, through the energy: tau0 from the analytic map so that the next apex has the energy of the
      target apex, E* = m g y* + m xdot*^2/2 (:func:`energy_regulation` with that target).

    Unlike :func:`deadbeat`, the angle ignores the map, so height and speed converge only over strides.
    """
    params = ParamArrays.of(params)
    y_, xdot_, previous_, target_y_, target_xdot_ = _as_arrays(y, xdot, previous_xdot, target_y, target_xdot)
    angle = neutral_angle(params, xdot_) + kp * (xdot_ - target_xdot_) + kd * (xdot_ - previous_)
    lower, upper = admissible_angles(params, y_)
    angle = np.clip(angle, lower, upper)
    target_energy = _apex_energy(params, target_y_, target_xdot_)
    return energy_regulation(params, y_, xdot_, angle, target_energy, corrections, liftoff)
