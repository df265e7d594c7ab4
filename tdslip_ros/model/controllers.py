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

from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

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
FIXED_POINT_ITERATIONS = 30
"""Bound on the Newton steps of a policy's (tau0, t_f) solve (solvable lanes need 4-8, rarely up to 16)."""
JACOBIAN_STEP = 1e-7
"""Forward-difference step of the Newton iterations' Jacobians, in the scaled variables (rad for angles)."""
DEADBEAT_SCAN_ITERATIONS = 10
"""Newton steps of the deadbeat scan's solves (from a cold start most solvable angles need 5-8)."""
DEADBEAT_TORQUE_TRUST = 0.02
"""Largest Newton correction of (tau0, t_f), scaled, at which a deadbeat refinement point is trusted."""
DEADBEAT_ITERATIONS = 40
"""Bound on the deadbeat refinement's steps (about 5 where the target is reachable, 30 when bisecting)."""
ANGLE_MARGIN = 1e-6
"""rad kept from the ends of the admissible touchdown interval (leg placement, pi/2)."""


TauRule = Callable[[Stance, Array, Array], Array]
"""tau0 from a planned stance, the touchdown angular rate and the ramp duration t_f."""


def _lane_shape(params: ParamArrays, *arrays: Array) -> tuple[int, ...]:
    """The broadcast shape of the parameters' fields and the arrays."""
    return np.broadcast_shapes(*(np.shape(field) for field in vars(params).values()), *map(np.shape, arrays))


def _torque_scales(params: ParamArrays, shape: tuple[int, ...]) -> Array:
    """(m g r0, sqrt(m/k)) stacked, shape (2, *shape): the units of (tau0, t_f) in the Newton iterations."""
    return np.stack(
        [np.broadcast_to(v, shape) for v in (params.m * params.g * params.r0, np.sqrt(params.m / params.k))]
    )


def _probes(count: int, shape: tuple[int, ...]) -> Array:
    """A point and its JACOBIAN_STEP shifts along each of ``count`` coordinates: (count + 1, count, 1...)."""
    directions = np.vstack([np.zeros(count), np.eye(count)])
    return JACOBIAN_STEP * directions.reshape(count + 1, count, *(1,) * len(shape))


def _solve2(matrix: Array, vector: Array) -> Array:
    """matrix^-1 vector per lane for (2, 2, ...) matrices and (2, ...) vectors (Cramer's rule)."""
    determinant = matrix[0, 0] * matrix[1, 1] - matrix[0, 1] * matrix[1, 0]
    solution = [
        matrix[1, 1] * vector[0] - matrix[0, 1] * vector[1],
        matrix[0, 0] * vector[1] - matrix[1, 0] * vector[0],
    ]
    return np.asarray(np.stack(solution) / determinant)


def _planned_stance(
    params: ParamArrays,
    y: Array,
    xdot: Array,
    angle: Array,
    tau0_rule: TauRule,
    corrections: int,
    liftoff: LiftoffMethod,
    max_iterations: int = FIXED_POINT_ITERATIONS,
) -> tuple[Array, Array]:
    """Solve (tau0, t_f) = (tau0_rule(stance), t_lo) for the stance they produce; returns (tau0, t_f).

    Lanes without liftoff, or that do not converge in ``max_iterations``, get NaN.
    Starts from the unforced stance (tau0 = 0, corrections = 0, where t_lo does not depend on t_f; starting
    from the rule's tau0 for it instead loses about 2 % of the solvable lanes). The
    plain iteration x <- G(x) contracts only linearly (about -1/3 per step for energy regulation, where tau0
    moves t_lo and the losses through p_hat), so this is Newton's method on G(x) - x = 0 per lane,
    x = (tau0, t_f) scaled by :func:`_torque_scales`. G is evaluated at x and at x + JACOBIAN_STEP e_j in
    one vectorised call (the three points are a leading axis), which gives its Jacobian by forward
    differences; that Jacobian's error of ~JACOBIAN_STEP only slows the final convergence to a rate of about
    that size. Where the Newton step is not finite the plain step is taken. Under a complex step the
    Jacobian is that of the real parts; the (linear) imaginary parts then converge at the same rate.
    """
    touchdown = descent_map(params, y, xdot, angle)
    unforced = stance_map(params, angle, touchdown.rdot, touchdown.thetadot, 0.0, 1.0, 0, liftoff)
    with np.errstate(invalid="ignore", divide="ignore"):
        # The rule's own arrays (targets, powers) may add lanes: the lanes are those of its result too.
        lanes = np.zeros_like(tau0_rule(unforced, touchdown.thetadot, unforced.t_lo))
    shape = _lane_shape(params, touchdown.rdot, lanes)
    scales = _torque_scales(params, shape)
    valid = np.broadcast_to((touchdown.failure == NO_FAILURE_CODE) & unforced.liftoff_exists, shape)
    x = np.stack(np.broadcast_arrays(lanes, unforced.t_lo, np.zeros(shape))[:2]) / scales
    probes = _probes(2, shape)
    with np.errstate(invalid="ignore", divide="ignore"):  # failed lanes carry NaN
        for _ in range(max_iterations):
            tau0, t_f = (x + probes).swapaxes(0, 1) * scales[:, None]
            stance = stance_map(
                params, angle, touchdown.rdot, touchdown.thetadot, tau0, t_f, corrections, liftoff
            )
            mapped = (
                np.stack(  # G at the three points (without corrections t_lo depends on neither)
                    np.broadcast_arrays(tau0_rule(stance, touchdown.thetadot, t_f), stance.t_lo, t_f)[:2]
                ).swapaxes(0, 1)
                / scales
            )
            valid = valid & stance.liftoff_exists[0]
            converged = lanes_converged(mapped[0, 0], x[0], FIXED_POINT_TOLERANCE) & lanes_converged(
                mapped[0, 1], x[1], FIXED_POINT_TOLERANCE
            )
            if np.all(converged | ~valid):
                x = mapped[0]
                break
            residual = mapped[0] - x
            # d residual_i / d x_j = dG_i/dx_j - delta_ij
            slope = np.real(mapped[1:] - mapped[0]).swapaxes(0, 1) / JACOBIAN_STEP - np.eye(2).reshape(
                2, 2, *(1,) * len(shape)
            )
            newton = -_solve2(slope, residual)
            x = x + np.where(np.isfinite(newton), newton, residual)
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


def _energy_tau0_rule(params: ParamArrays, y: Array, xdot: Array, target_energy: ArrayLike | None) -> TauRule:
    """tau0 with E_tau = E_loss + (E* - E_a) for the planned stance (E* = E_a without a target)."""
    energy = _apex_energy(params, y, xdot)
    change = np.zeros_like(energy) if target_energy is None else np.asarray(target_energy) - energy

    def tau0_rule(stance: Stance, thetadot_td: Array, t_f: Array) -> Array:
        energy_per_torque = stance.approximation.hip_energy(1.0, t_f, stance.t_lo)
        return (change + stance.energy_loss) / energy_per_torque

    return tau0_rule


def energy_regulation(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    beta: ArrayLike,
    target_energy: ArrayLike | None = None,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    max_iterations: int = FIXED_POINT_ITERATIONS,
) -> CommandArrays:
    """Energy regulation of section IV.A: theta_td = beta and tau0 with E_tau = E_loss (eq. 32), t_f = t_lo.

    With ``target_energy`` E* [J], E_tau = E_loss + (E* - E_a): the energy of the next apex predicted by the
    analytic map is E* (this is the regulator the exact-plant studies use, with the first stride's energy as
    E*, so that prediction errors do not accumulate). Without it, E* = E_a (the paper's eq. 32).
    For a given stance E_tau is linear in tau0, so each fixed-point step solves that linear equation.
    Lanes not solved in ``max_iterations`` Newton steps get NaN.
    """
    params = ParamArrays.of(params)
    y_, xdot_, beta_ = _as_arrays(y, xdot, beta)
    tau0_rule = _energy_tau0_rule(params, y_, xdot_, target_energy)
    tau0, t_f = _planned_stance(params, y_, xdot_, beta_, tau0_rule, corrections, liftoff, max_iterations)
    return CommandArrays(np.broadcast_to(beta_, np.shape(tau0)), tau0, t_f)


def admissible_angles(params: HopperParams | ParamArrays, y: ArrayLike) -> tuple[Array, Array]:
    """Touchdown angles that place the leg from apex height y: (arccos(min(y/r0, 1)), pi/2) less ANGLE_MARGIN.

    This is eq. 34's interval (-pi/2, pi/2) cut to forward running (StanceCommand's (0, pi/2)) and to
    feasible leg placement (y > r0 cos(theta_td), no toe stubbing).
    """
    params = ParamArrays.of(params)
    lowest = np.arccos(np.minimum(np.real(np.asarray(y)) / params.r0, 1.0))
    return lowest + ANGLE_MARGIN, np.broadcast_to(np.pi / 2 - ANGLE_MARGIN, np.shape(lowest))


class _DeadbeatPoint(NamedTuple):
    """A deadbeat refinement point per lane and the linearisation of its equations there.

    z = (theta_td, tau0/(m g r0), t_f/sqrt(m/k)), shape (3, ...); c(z) = G(x) - x is the residual of the
    torque's fixed point (x = z[1:], as in :func:`_planned_stance`), r(z) = xdot_next - xdot*.
    """

    z: Array
    r: Array  # r - r_x u: r with the torque solved at this angle (to first order)
    slope: Array  # r_theta - r_x w: dr/dtheta along the torque solution
    u: Array  # c_x^-1 c: the Newton correction of x at this angle, shape (2, ...)
    w: Array  # c_x^-1 c_theta: minus the rate at which the torque solution moves with the angle
    converged: Array  # x solves the torque's fixed point to FIXED_POINT_TOLERANCE
    ok: Array  # the map succeeded and the linearisation is finite

    @property
    def angle(self) -> Array:
        return np.asarray(self.z[0])

    @property
    def trusted(self) -> Array:
        """Close enough to the torque's fixed point for the linearisation to guide the angle."""
        return np.asarray(np.all(np.abs(self.u) <= DEADBEAT_TORQUE_TRUST, axis=0))

    def pick(self, other: _DeadbeatPoint, mask: Array) -> _DeadbeatPoint:
        """Lanes of ``other`` where mask is set, of self elsewhere."""
        return _DeadbeatPoint(*(np.where(mask, o, s) for s, o in zip(self, other, strict=True)))


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
    angle. The touchdown angle minimises f = r^2, r(theta) = xdot_next(theta) - xdot* (eq. 34), over the
    admissible interval (:func:`admissible_angles`). Since the map's next energy is then E* exactly,
    reaching xdot* also means reaching y*. Angles where the map fails count as f = +inf.

    * Scan: the ``grid`` angles are lanes of one vectorised energy-regulation solve and map evaluation.
      It only ranks the angles, so its solve stops after DEADBEAT_SCAN_ITERATIONS Newton
      steps and angles not solved by then count as failed (the angles towards pi/2, which have no solution,
      would otherwise keep every lane iterating to FIXED_POINT_ITERATIONS).
    * Refinement, per lane, from the best scan angle in the bracket of its neighbours, down to
      ``angle_tolerance`` rad: Newton's method on (theta, tau0, t_f) at once, one vectorised map evaluation
      of the point and its three forward-difference shifts per step (:class:`_DeadbeatPoint`). The angle
      step is Newton's for f'/2 = r r' = 0, ``delta = -r r'/(r'^2 + r r'')`` with r' taken along the torque
      solution and r'' from a secant of r'. Where the target is reachable (r = 0) this is Newton's method on
      r (quadratic convergence); where it is not, the secant method on r' = 0 (the extremum of xdot_next).
      A step that would leave the bracket is replaced by bisection, and the sign of f' at each new angle (a
      failed angle counts as uphill) shrinks the bracket. The torque takes the Newton step of its fixed
      point for the new angle, so both converge together; the result solves that fixed point to
      FIXED_POINT_TOLERANCE, like :func:`energy_regulation` at the returned angle.

    Lanes where every scanned angle fails get NaN.
    """
    params = ParamArrays.of(params)
    y_, xdot_, target_y_, target_xdot_ = _as_arrays(y, xdot, target_y, target_xdot)
    target_energy = _apex_energy(params, target_y_, target_xdot_)
    lower, upper = admissible_angles(params, y_)
    shape = _lane_shape(params, lower, xdot_, target_energy, target_xdot_)
    lower, upper = np.broadcast_to(lower, shape), np.broadcast_to(upper, shape)
    scales = _torque_scales(params, shape)

    # Scan: the candidate angles as a trailing axis of lanes.
    scan_lanes = ParamArrays(*(np.asarray(field)[..., None] for field in vars(params).values()))
    angles = lower[..., None] + (upper - lower)[..., None] * np.linspace(0.0, 1.0, grid)
    command = energy_regulation(
        scan_lanes,
        y_[..., None],
        xdot_[..., None],
        angles,
        target_energy[..., None],
        corrections,
        liftoff,
        max_iterations=DEADBEAT_SCAN_ITERATIONS,
    )
    stride = approximate_map(scan_lanes, y_[..., None], xdot_[..., None], command, corrections, liftoff)
    cost = (stride.xdot - target_xdot_[..., None]) ** 2
    cost = np.where(stride.ok & np.isfinite(cost), cost, np.inf)
    best = np.argmin(cost, axis=-1)[..., None]
    found = np.isfinite(np.take_along_axis(cost, best, axis=-1)[..., 0])

    def scanned(values: Array, offset: int) -> Array:
        index = np.clip(best + offset, 0, grid - 1)
        return np.asarray(np.take_along_axis(values, index, axis=-1)[..., 0])

    probes = _probes(3, shape)
    tau0_rule = _energy_tau0_rule(params, y_, xdot_, target_energy)

    def linearise(z: Array) -> _DeadbeatPoint:
        points = z + probes
        angle, tau0, t_f = points[:, 0], points[:, 1] * scales[0], points[:, 2] * scales[1]
        t_f = np.where(t_f > 0.0, t_f, np.nan)  # a wild step fails its lane, not the call
        stride = approximate_map(params, y_, xdot_, CommandArrays(angle, tau0, t_f), corrections, liftoff)
        values = np.stack(
            [
                tau0_rule(stride.stance, stride.touchdown.thetadot, t_f) / scales[0] - points[:, 1],
                stride.stance.t_lo / scales[1] - points[:, 2],
                stride.xdot - target_xdot_,
            ]
        )  # (c, r) at the four points
        value = values[:, 0]
        jacobian = (values[:, 1:] - values[:, :1]) / JACOBIAN_STEP  # d(c, r)_i / dz_j
        u = _solve2(jacobian[:2, 1:], value[:2])
        w = _solve2(jacobian[:2, 1:], jacobian[:2, 0])
        r = value[2] - np.sum(jacobian[2, 1:] * u, axis=0)
        slope = jacobian[2, 0] - np.sum(jacobian[2, 1:] * w, axis=0)
        converged = lanes_converged(value[0] + z[1], z[1], FIXED_POINT_TOLERANCE) & lanes_converged(
            value[1] + z[2], z[2], FIXED_POINT_TOLERANCE
        )
        finite = np.isfinite(r) & np.isfinite(slope) & np.all(np.isfinite(u) & np.isfinite(w), axis=0)
        return _DeadbeatPoint(z, r, slope, u, w, converged, stride.ok[0] & finite)

    with np.errstate(invalid="ignore", divide="ignore"):  # lanes without a command carry NaN
        torque = np.stack([scanned(command.tau0, 0), scanned(command.t_f, 0)]) / scales
        here = linearise(np.concatenate([scanned(angles, 0)[None], torque]))
        found = found & here.ok
        # f' = 2 r r' < 0: f falls to the right of the best scan angle, so its minimum lies on that side.
        rightwards = here.r * here.slope < 0.0
        a = np.where(rightwards, here.angle, scanned(angles, -1))
        b = np.where(rightwards, scanned(angles, 1), here.angle)
        # No r'' yet: the first step is Newton's on r.
        previous_angle, previous_slope = here.angle, here.slope
        done = ~found
        for _ in range(DEADBEAT_ITERATIONS):
            curvature = (here.slope - previous_slope) / (here.angle - previous_angle)
            curvature = np.where(np.isfinite(curvature), curvature, 0.0)
            denominator = here.slope**2 + here.r * curvature
            trial = here.angle - here.r * here.slope / denominator
            newton = np.isfinite(trial) & (denominator > 0.0) & (trial > a) & (trial < b)
            step = np.where(newton, trial, 0.5 * (a + b)) - here.angle
            settled = np.abs(step) <= angle_tolerance
            done = done | (settled & here.converged)
            if np.all(done):
                break
            step = np.where(done, 0.0, step)
            z = np.concatenate([(here.angle + step)[None], here.z[1:] - (here.u + here.w * step)])
            new = linearise(np.where(done, here.z, z))
            # Far from the torque's fixed point (or where the map fails there) the joint step says little:
            # solve the torque at that angle from scratch, as energy_regulation does, and linearise there.
            unsure = ~(new.ok & new.trusted) & ~done
            if unsure.any():
                solved = energy_regulation(params, y_, xdot_, new.angle, target_energy, corrections, liftoff)
                torque = np.stack([solved.tau0, solved.t_f]) / scales
                new = new.pick(linearise(np.concatenate([new.angle[None], torque])), unsure)
            good = new.ok & new.trusted
            moved = ~done & ~settled
            upper_end = np.where(good, new.r * new.slope > 0.0, step > 0.0)
            b = np.where(moved & upper_end, new.angle, b)
            a = np.where(moved & ~upper_end, new.angle, a)
            accept = good & ~done
            previous_angle = np.where(accept & moved, here.angle, previous_angle)
            previous_slope = np.where(accept & moved, here.slope, previous_slope)
            here = here.pick(new, accept)
    angle, tau0, t_f = (np.where(found, field, np.nan) for field in (here.angle, *(here.z[1:] * scales)))
    if np.all(here.converged | ~found):
        return CommandArrays(angle, tau0, t_f)
    # Out of steps with the torque not yet solved (an optimum at the edge of the failures): solve it there.
    return energy_regulation(params, y_, xdot_, angle, target_energy, corrections, liftoff)


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


POLICIES = ("open_loop", "energy", "deadbeat", "pd")


class PolicyError(ValueError):
    """The policy settings are incomplete or unknown."""


@dataclass(frozen=True)
class PolicySpec:
    """A named policy with its settings (SI; the controller node's parameters), in one place for the
    controller node and the offline analysis. ``source`` says where the settings came from."""

    name: str
    touchdown_angle: float
    touchdown_power: float
    target_energy: float
    target_height: float
    target_speed: float
    pd_kp: float
    pd_kd: float
    corrections: int
    source: str = ""

    def commands(
        self, params: HopperParams, y: npt.ArrayLike, xdot: npt.ArrayLike, previous_xdot: npt.ArrayLike
    ) -> CommandArrays:
        """The policy's commands at apexes (y, xdot), vectorised; previous_xdot is used by ``pd`` only."""
        if self.name == "open_loop":
            alpha = units.power_to_alpha(params, self.touchdown_power)
            return fixed_power(params, y, xdot, self.touchdown_angle, alpha, self.corrections)
        if self.name == "energy":
            return energy_regulation(
                params, y, xdot, self.touchdown_angle, self.target_energy, self.corrections
            )
        if self.name == "deadbeat":
            return deadbeat(params, y, xdot, self.target_height, self.target_speed, self.corrections)
        if self.name == "pd":
            return pd_speed_energy_height(
                params,
                y,
                xdot,
                previous_xdot,
                self.target_height,
                self.target_speed,
                kp=self.pd_kp,
                kd=self.pd_kd,
                corrections=self.corrections,
            )
        raise PolicyError(f"unknown policy {self.name!r}; one of {', '.join(POLICIES)}")

    @classmethod
    def settings(cls) -> tuple[str, ...]:
        """The names of the settings: the controller node's parameters of the same names."""
        return tuple(field.name for field in fields(cls) if field.name not in ("name", "source"))

    @classmethod
    def of(cls, name: str, values: Mapping[str, str | float], source: str = "") -> PolicySpec:
        """A spec from setting values as parameters or text give them: ``corrections`` an int, the rest
        floats."""
        converted: dict[str, Any] = {key: float(values[key]) for key in cls.settings()}
        converted["corrections"] = int(values["corrections"])
        return cls(name=name, source=source, **converted)

    @property
    def target(self) -> tuple[float, float] | None:
        """The target apex (y, xdot) of a policy that has one."""
        if self.name in ("deadbeat", "pd"):
            return self.target_height, self.target_speed
        return None
