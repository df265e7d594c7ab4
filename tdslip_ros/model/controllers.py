"""The paper's stance policies as pure functions: apex state(s), parameters, targets -> stance command arrays.

Every policy returns :class:`~tdslip_ros.model.analytic.CommandArrays` (touchdown angle [rad], ramp torque
tau0 [N m], ramp duration t_f [s]) broadcast over the inputs; ``.command()`` turns one lane into a validated
:class:`~tdslip_ros.model.params.StanceCommand`. A returned command always maps, in the map the policy
planned with, to a valid stride: where no such command exists the lane's fields are NaN and its
``no_command`` code names the reason (:class:`~tdslip_ros.model.analytic.NoCommand`: the leg cannot be
placed, no liftoff, a predicted fall or reversal, no forward torque solution), and ``.command()`` raises
:class:`~tdslip_ros.model.analytic.NoCommandError` with it. Touchdown angles are planned only where
:func:`~tdslip_ros.model.dynamics.can_place_leg` holds, the test the plant applies to every command.

``t_f`` is the liftoff time that the map predicts *for the returned command itself* (a fixed point
t_f = t_lo(t_f), since the torque correction of p_hat depends on t_f), so the map evaluated with the command
is exactly the map the policy planned with. The ideal regulator :func:`exact_energy_regulation`
(``energy_exact``) plans on the exact plant's map instead, with t_f the stance duration the plant produces.

Energy regulation has two torque roots. The hip energy E_tau = tau0 e(tau0), e the ramp-weighted mean
angular rate, is close to quadratic in tau0 because the torque's own momentum correction moves e; the
root the policies return is the *forward* one, where the body swings forward on average (e < 0, so forward
thrust tau0 < 0 does positive work). The other root drives the body backward and the map rejects it.

The torque-based policies are complex-step safe (for :func:`~tdslip_ros.model.analytic.map_jacobian`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.analytic import (
    HAS_COMMAND,
    Array,
    ArrayLike,
    CommandArrays,
    LiftoffMethod,
    NoCommand,
    ParamArrays,
    Stance,
    Stride,
    approximate_map,
    descent_map,
    lanes_converged,
    no_command_code,
    no_command_of_failure,
    stance_map,
)
from tdslip_ros.model.events import NO_FAILURE_CODE
from tdslip_ros.model.params import HopperParams, ParameterError

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
"""rad kept inside the ends of the admissible touchdown interval, so that rounding cannot take an angle
at its end out of it (the physical margin is dynamics.PLACEMENT_LEAD_TIME)."""
EXACT_ENERGY_TOLERANCE = 1e-11
"""Dimensionless energy E/(m g r0) to which energy_exact meets its target on the exact map."""
EXACT_STANCE_TOLERANCE = 1e-10
"""|t_f - stance duration| in units of sqrt(m/k) to which energy_exact ends the ramp at liftoff."""
EXACT_ITERATIONS = 12
"""Bound on energy_exact's Newton steps (3-4 from the analytic plan)."""
EXACT_JACOBIAN_STEP = 1e-6
"""Forward-difference step of energy_exact's Jacobian in the scaled (tau0, t_f): large against the exact
map's integration error (~1e-12), small against the curvature."""
EXACT_MAP_TOLERANCE = 1e-12
"""rtol = atol of the exact map energy_exact plans on (the batched engine's default)."""

_NO_LIFTOFF = no_command_code(NoCommand.NO_LIFTOFF)
_NO_SOLUTION = no_command_code(NoCommand.NO_SOLUTION)
_LEG_PLACEMENT = no_command_code(NoCommand.LEG_PLACEMENT)
_PREDICTED_REVERSAL = no_command_code(NoCommand.PREDICTED_REVERSAL)


TauRule = Callable[[Stance, Array, Array], Array]
"""tau0 from a planned stance, the touchdown angular rate and the ramp duration t_f."""


class _Plan(NamedTuple):
    """A planned (tau0, t_f) per lane and the no_command code (HAS_COMMAND where planned; NaN fields else)."""

    tau0: Array
    t_f: Array
    reason: Array

    def pick(self, other: _Plan, mask: Array) -> _Plan:
        """Lanes of ``other`` where mask is set, of self elsewhere."""
        return _Plan(*(np.where(mask, o, s) for s, o in zip(self, other, strict=True)))


def _lane_shape(params: ParamArrays, *arrays: Array) -> tuple[int, ...]:
    """The broadcast shape of the parameters' fields and the arrays."""
    return np.broadcast_shapes(*(np.shape(field) for field in vars(params).values()), *map(np.shape, arrays))


def _torque_scales(params: ParamArrays, shape: tuple[int, ...]) -> Array:
    """(m g r0, sqrt(m/k)) stacked, shape (2, *shape): the units of (tau0, t_f) in the Newton iterations."""
    return np.stack(
        [np.broadcast_to(v, shape) for v in (params.m * params.g * params.r0, np.sqrt(params.m / params.k))]
    )


def _probes(count: int, shape: tuple[int, ...], step: float = JACOBIAN_STEP) -> Array:
    """A point and its ``step`` shifts along each of ``count`` coordinates: (count + 1, count, 1...)."""
    directions = np.vstack([np.zeros(count), np.eye(count)])
    return step * directions.reshape(count + 1, count, *(1,) * len(shape))


def _solve2(matrix: Array, vector: Array) -> Array:
    """matrix^-1 vector per lane for (2, 2, ...) matrices and (2, ...) vectors (Cramer's rule)."""
    determinant = matrix[0, 0] * matrix[1, 1] - matrix[0, 1] * matrix[1, 0]
    solution = [
        matrix[1, 1] * vector[0] - matrix[0, 1] * vector[1],
        matrix[0, 0] * vector[1] - matrix[1, 0] * vector[0],
    ]
    return np.asarray(np.stack(solution) / determinant)


def _placeable(params: ParamArrays, y: Array, angle: Array) -> Array:
    """Where the leg can be placed at ``angle`` from the apex height y (dynamics.can_place_leg)."""
    return np.asarray(
        dynamics.can_place_leg(params.r0, params.g, np.real(y), np.cos(np.real(angle))), dtype=bool
    )


def _require_at_least(name: str, value: int, least: int) -> None:
    if value < least:
        raise ParameterError(f"{name} must be at least {least}, got {value!r}")


def _planned_stance(
    params: ParamArrays,
    y: Array,
    xdot: Array,
    angle: Array,
    tau0_rule: TauRule,
    corrections: int,
    liftoff: LiftoffMethod,
    max_iterations: int = FIXED_POINT_ITERATIONS,
    start: tuple[Array, Array] | None = None,
) -> _Plan:
    """Solve (tau0, t_f) = (tau0_rule(stance), t_lo) for the stance they produce.

    Lanes where the leg cannot be placed, without liftoff, or that do not converge in ``max_iterations``
    get NaN and their reason. By default the iteration starts from the unforced stance (tau0 = 0,
    corrections = 0, where t_lo does not depend on t_f; starting from the rule's tau0 for it instead loses
    about 2 % of the solvable lanes); ``start`` gives another (tau0, t_f). The plain iteration x <- G(x)
    contracts only linearly (about -1/3 per step for energy regulation, where tau0 moves t_lo and the losses
    through p_hat), so this is Newton's method on G(x) - x = 0 per lane, x = (tau0, t_f) scaled by
    :func:`_torque_scales`. G is evaluated at x and at x + JACOBIAN_STEP e_j in one vectorised call (the
    three points are a leading axis), which gives its Jacobian by forward differences; that Jacobian's error
    of ~JACOBIAN_STEP only slows the final convergence to a rate of about that size. Where the Newton step
    is not finite the plain step is taken. Under a complex step the Jacobian is that of the real parts; the
    (linear) imaginary parts then converge at the same rate.
    """
    touchdown = descent_map(params, y, xdot, angle)
    placeable = _placeable(params, y, angle)
    unforced = stance_map(params, angle, touchdown.rdot, touchdown.thetadot, 0.0, 1.0, 0, liftoff)
    with np.errstate(invalid="ignore", divide="ignore"):
        # The rule's own arrays (targets, powers) may add lanes: the lanes are those of its result too.
        lanes = np.zeros_like(tau0_rule(unforced, touchdown.thetadot, unforced.t_lo))
    shape = _lane_shape(params, touchdown.rdot, lanes, placeable)
    scales = _torque_scales(params, shape)
    reason = np.select(
        [~placeable, touchdown.failure != NO_FAILURE_CODE, ~unforced.liftoff_exists],
        [_LEG_PLACEMENT, _PREDICTED_REVERSAL, _NO_LIFTOFF],  # the touchdown's only other failure
        HAS_COMMAND,
    )
    reason = np.broadcast_to(reason, shape)
    x = np.stack(np.broadcast_arrays(lanes, unforced.t_lo, np.zeros(shape))[:2]) / scales
    if start is not None:
        x = np.stack(np.broadcast_arrays(*start, np.zeros(shape))[:2]) / scales
    lifts_off = np.ones(shape, dtype=bool)
    converged = np.zeros(shape, dtype=bool)
    probes = _probes(2, shape)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # failed or wild lanes: NaN, inf
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
            # Without corrections the stance does not depend on (tau0, t_f): no leading axis of points.
            lifts_off = lifts_off & np.broadcast_to(stance.liftoff_exists, (3, *shape))[0]
            converged = lanes_converged(mapped[0, 0], x[0], FIXED_POINT_TOLERANCE) & lanes_converged(
                mapped[0, 1], x[1], FIXED_POINT_TOLERANCE
            )
            if np.all(converged | ~lifts_off | (reason != HAS_COMMAND)):
                x = mapped[0]
                break
            residual = mapped[0] - x
            # d residual_i / d x_j = dG_i/dx_j - delta_ij
            slope = np.real(mapped[1:] - mapped[0]).swapaxes(0, 1) / JACOBIAN_STEP - np.eye(2).reshape(
                2, 2, *(1,) * len(shape)
            )
            newton = -_solve2(slope, residual)
            x = x + np.where(np.isfinite(newton), newton, residual)
    reason = np.select(
        [reason != HAS_COMMAND, ~lifts_off, ~converged], [reason, _NO_LIFTOFF, _NO_SOLUTION], HAS_COMMAND
    )
    solved = reason == HAS_COMMAND
    return _Plan(
        np.where(solved, x[0] * scales[0], np.nan), np.where(solved, x[1] * scales[1], np.nan), reason
    )


def _checked(
    params: ParamArrays,
    y: Array,
    xdot: Array,
    angle: Array,
    plan: _Plan,
    corrections: int,
    liftoff: LiftoffMethod,
) -> tuple[CommandArrays, Stride]:
    """The planned commands with every lane the analytic map rejects turned into a named no-command, and
    the map's stride with them."""
    planned = CommandArrays(*np.broadcast_arrays(angle, plan.tau0, plan.t_f))
    stride = approximate_map(params, y, xdot, planned, corrections, liftoff)
    reason = np.broadcast_to(plan.reason, stride.failure.shape)
    reason = np.where(reason == HAS_COMMAND, no_command_of_failure(stride.failure), reason)
    keep = reason == HAS_COMMAND
    angle_, tau0, t_f = (np.where(keep, field, np.nan) for field in planned)
    return CommandArrays(angle_, tau0, t_f, no_command=reason), stride


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
    """A given touchdown angle and ramp torque tau0, with t_f the liftoff time the map predicts for them.

    Not a policy but the paper's ramp for studies of the map itself (analytic_accuracy): the command is
    returned wherever t_f exists, also where the map then predicts a fall or a reversal, so that the
    failures of the analytic and the exact map can be compared.
    """
    params = ParamArrays.of(params)
    y_, xdot_, angle_, tau0_ = _as_arrays(y, xdot, angle, tau0)

    def tau0_rule(stance: Stance, thetadot_td: Array, t_f: Array) -> Array:
        return tau0_ + np.zeros_like(t_f)

    plan = _planned_stance(params, y_, xdot_, angle_, tau0_rule, corrections, liftoff)
    angle_out = np.where(plan.reason == HAS_COMMAND, angle_, np.nan)
    return CommandArrays(angle_out, plan.tau0, plan.t_f, no_command=plan.reason)


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
    power at touchdown (thetadot_td < 0, so tau0 < 0: forward thrust). t_f is the paper's choice, the
    liftoff time the analytic map predicts, not the stance duration the plant will produce (on the exact
    plant the ramp then ends a little before or after liftoff; docs/paper.md quantifies the difference).
    """
    arrays = ParamArrays.of(params)
    y_, xdot_, beta_ = _as_arrays(y, xdot, beta)
    power = np.asarray(units.power_from_alpha(params, np.asarray(alpha, dtype=float)))

    def tau0_rule(stance: Stance, thetadot_td: Array, t_f: Array) -> Array:
        return power / thetadot_td

    plan = _planned_stance(arrays, y_, xdot_, beta_, tau0_rule, corrections, liftoff)
    return _checked(arrays, y_, xdot_, beta_, plan, corrections, liftoff)[0]


def _energy_tau0_rule(params: ParamArrays, y: Array, xdot: Array, target_energy: ArrayLike | None) -> TauRule:
    """tau0 with E_tau = E_loss + (E* - E_a) for the planned stance (E* = E_a without a target)."""
    energy = _apex_energy(params, y, xdot)
    change = np.zeros_like(energy) if target_energy is None else np.asarray(target_energy) - energy

    def tau0_rule(stance: Stance, thetadot_td: Array, t_f: Array) -> Array:
        return (change + stance.energy_loss) / _energy_per_torque(stance, t_f)

    return tau0_rule


def _energy_per_torque(stance: Stance, t_f: Array) -> Array:
    """e = E_tau/tau0 of a stance: negative while the body swings forward over the ramp."""
    return stance.approximation.hip_energy(1.0, t_f, stance.t_lo)


def _planned_energy_per_torque(
    params: ParamArrays,
    y: Array,
    xdot: Array,
    angle: Array,
    tau0: Array,
    t_f: Array,
    corrections: int,
    liftoff: LiftoffMethod,
) -> Array:
    """Real part of e for the stance of (tau0, t_f) from the apex."""
    touchdown = descent_map(params, y, xdot, angle)
    stance = stance_map(params, angle, touchdown.rdot, touchdown.thetadot, tau0, t_f, corrections, liftoff)
    return np.real(_energy_per_torque(stance, np.asarray(t_f)))


def _regulated_plan(
    params: ParamArrays,
    y: Array,
    xdot: Array,
    angle: Array,
    target_energy: ArrayLike | None,
    corrections: int,
    liftoff: LiftoffMethod,
    max_iterations: int,
) -> _Plan:
    """Energy regulation's (tau0, t_f) on the forward root (e < 0, module docstring).

    Newton from the unforced stance finds the forward root wherever the unforced stance swings forward
    under the corrections (e(0) < 0). Near the highest apex at which the leg still swings forward,
    gravity's correction makes e(0) >= 0 and Newton finds the backward root tau_b. There e is close to
    linear in tau0, e = e1 (tau0 - tau_e), so the two roots of tau0 e(tau0) = E_loss + dE sum to tau_e:
    Newton starts again from tau_e - tau_b, next to the forward root. A lane without a forward root gets
    no_solution.
    """
    rule = _energy_tau0_rule(params, y, xdot, target_energy)
    plan = _planned_stance(params, y, xdot, angle, rule, corrections, liftoff, max_iterations)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        rate = _planned_energy_per_torque(params, y, xdot, angle, plan.tau0, plan.t_f, corrections, liftoff)
        backward = rate >= 0.0
        if not np.any(backward):
            return plan
        tau0 = np.real(plan.tau0)
        at_zero = _planned_energy_per_torque(
            params, y, xdot, angle, np.zeros_like(tau0), plan.t_f, corrections, liftoff
        )
        root_sum = tau0 - rate * tau0 / (rate - at_zero)  # tau_e
        # Only the backward lanes start again, as a flat batch of their own.
        shape = backward.shape
        lanes = ParamArrays(*(np.broadcast_to(field, shape)[backward] for field in vars(params).values()))
        y_, xdot_, angle_, start, t_f = (
            np.broadcast_to(value, shape)[backward] for value in (y, xdot, angle, root_sum - tau0, plan.t_f)
        )
        goal = None if target_energy is None else np.broadcast_to(target_energy, shape)[backward]
        again = _planned_stance(
            lanes,
            y_,
            xdot_,
            angle_,
            _energy_tau0_rule(lanes, y_, xdot_, goal),
            corrections,
            liftoff,
            max_iterations,
            (start, t_f),
        )
        forward = (
            _planned_energy_per_torque(lanes, y_, xdot_, angle_, again.tau0, again.t_f, corrections, liftoff)
            < 0.0
        )
    unsolved = _Plan(*(np.asarray(value) for value in (np.nan, np.nan, _NO_SOLUTION)))
    again = again.pick(unsolved, ~forward & (again.reason == HAS_COMMAND))
    fields_ = [np.array(np.broadcast_to(field, shape)) for field in plan]
    for field, value in zip(fields_, again, strict=True):
        field[backward] = value
    return _Plan(*fields_)


def _regulated(
    params: ParamArrays,
    y: Array,
    xdot: Array,
    angle: Array,
    target_energy: ArrayLike | None,
    corrections: int,
    liftoff: LiftoffMethod,
    max_iterations: int = FIXED_POINT_ITERATIONS,
) -> tuple[CommandArrays, Stride]:
    """Energy regulation's commands and the map's stride with them."""
    _require_at_least("max_iterations", max_iterations, 1)
    plan = _regulated_plan(params, y, xdot, angle, target_energy, corrections, liftoff, max_iterations)
    return _checked(params, y, xdot, angle, plan, corrections, liftoff)


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
    For a given stance E_tau is linear in tau0, so each fixed-point step solves that linear equation; of
    the two roots the forward one is returned (:func:`_regulated_plan`). Lanes not solved in
    ``max_iterations`` (at least 1) Newton steps get no_solution.
    """
    params = ParamArrays.of(params)
    y_, xdot_, beta_ = _as_arrays(y, xdot, beta)
    return _regulated(params, y_, xdot_, beta_, target_energy, corrections, liftoff, max_iterations)[0]


def exact_energy_regulation(
    params: HopperParams,
    y: ArrayLike,
    xdot: ArrayLike,
    beta: ArrayLike,
    target_energy: ArrayLike | None = None,
    corrections: int = 1,
) -> CommandArrays:
    """The ideal regulator ``energy_exact``: theta_td = beta and the (tau0, t_f) with which the exact plant's
    next apex has the energy E* [J] (E* = E_a without a target) to EXACT_ENERGY_TOLERANCE, t_f being the
    stance duration the plant itself produces with that command (the ramp ends at the exact liftoff).

    Newton's method on the exact map (the batched engine, DOP853 at EXACT_MAP_TOLERANCE) for
    x = (tau0, t_f) scaled as in :func:`_planned_stance` and the residuals ((E' - E*)/(m g r0),
    T_stance/sqrt(m/k) - x_1); its Jacobian by forward differences, the three points being lanes of one
    batched call. It starts from :func:`energy_regulation`'s forward root (``corrections`` of its map) and
    returns a command only where the exact map, evaluated with that very command, succeeds and meets both
    tolerances. Lanes where the analytic plan has no command keep its reason, lanes where the exact map
    fails at an iterate get that failure's, and lanes not converged in EXACT_ITERATIONS get no_solution.
    A plan costs about 3 x 4 exact strides: fine in lockstep and in studies. The gap between ``energy``
    and ``energy_exact`` is what the analytic approximation costs.
    """
    # Imported here: the batched engine imports scipy.integrate (0.6 s), which only this policy needs; a
    # controller node of the others starts as fast as before (its DDS discovery races the recorder's).
    from tdslip_ros.model.batch import batch_apex_return_map

    arrays = ParamArrays.of(params)
    y_, xdot_, beta_ = _as_arrays(y, xdot, beta)
    start = energy_regulation(arrays, y_, xdot_, beta_, target_energy, corrections)
    shape = np.shape(start.tau0)
    energy_scale = units.energy_scale(params)
    goal = (
        _apex_energy(arrays, y_, xdot_) if target_energy is None else np.asarray(target_energy, dtype=float)
    )
    goal_bar = np.broadcast_to(goal / energy_scale, shape).ravel()
    y_l, xdot_l, angle = (np.broadcast_to(np.real(v), shape).ravel() for v in (y_, xdot_, beta_))
    scales = np.array([units.torque_from_bar(params, 1.0), np.sqrt(params.m / params.k)])[:, None]
    x = np.stack([np.ravel(np.real(start.tau0)), np.ravel(np.real(start.t_f))]) / scales
    assert start.no_command is not None
    reason = np.array(np.broadcast_to(start.no_command, shape)).ravel()
    active = np.flatnonzero(reason == HAS_COMMAND)
    solved = np.zeros(reason.shape, dtype=bool)
    probes = _probes(2, (1,), EXACT_JACOBIAN_STEP)  # (3, 2, 1)
    for _ in range(EXACT_ITERATIONS):
        wild = ~np.all(np.isfinite(x[:, active]) & (x[1, active] > 0.0), axis=0)
        reason[active[wild]] = _NO_SOLUTION
        active = active[~wild]
        if active.size == 0:
            break
        points = x[:, active] + probes  # (3, 2, n): the point and its two shifts
        stride = batch_apex_return_map(
            params,
            y_l[active],
            xdot_l[active],
            angle[active],
            points[:, 0] * scales[0],
            points[:, 1] * scales[1],
            rtol=EXACT_MAP_TOLERANCE,
            atol=EXACT_MAP_TOLERANCE,
        )
        energy_bar = units.energy_to_bar(params, params.m * (params.g * stride.y + 0.5 * stride.xdot**2))
        residual = np.stack(
            [energy_bar - goal_bar[active], stride.stance_time / scales[1] - points[:, 1]]
        )  # (2, 3, n)
        failed = stride.failure[0] != NO_FAILURE_CODE
        reason[active[failed]] = no_command_of_failure(stride.failure[0][failed])
        done = ~failed & (np.abs(residual[0, 0]) <= EXACT_ENERGY_TOLERANCE)
        done &= np.abs(residual[1, 0]) <= EXACT_STANCE_TOLERANCE
        solved[active[done]] = True
        with np.errstate(invalid="ignore", divide="ignore"):
            step = -_solve2((residual[:, 1:] - residual[:, :1]) / EXACT_JACOBIAN_STEP, residual[:, 0])
        moving = ~failed & ~done
        x[:, active[moving]] += step[:, moving]
        active = active[moving]
    reason[active] = _NO_SOLUTION  # still iterating: not converged
    reason[~solved & (reason == HAS_COMMAND)] = _NO_SOLUTION
    tau0, t_f = (
        np.where(reason == HAS_COMMAND, row * scale, np.nan).reshape(shape)
        for row, scale in zip(x, scales, strict=True)
    )
    angle_out = np.where(reason == HAS_COMMAND, angle, np.nan).reshape(shape)
    return CommandArrays(angle_out, tau0, t_f, no_command=reason.reshape(shape))


def admissible_angles(params: HopperParams | ParamArrays, y: ArrayLike) -> tuple[Array, Array]:
    """Touchdown angles that place the leg from apex height y: (arccos(min((y - d)/r0, 1)), pi/2) less
    ANGLE_MARGIN, d = dynamics.placement_clearance (the angles dynamics.can_place_leg accepts).

    This is eq. 34's interval (-pi/2, pi/2) cut to forward running (StanceCommand's (0, pi/2)) and to
    feasible leg placement (y - d >= r0 cos(theta_td)). The interval is empty (lower > upper) for an apex
    below d.
    """
    params = ParamArrays.of(params)
    placeable_top = np.real(np.asarray(y)) - dynamics.placement_clearance(params.g)
    lowest = np.arccos(np.clip(placeable_top / params.r0, -1.0, 1.0))
    return lowest + ANGLE_MARGIN, np.broadcast_to(np.pi / 2 - ANGLE_MARGIN, np.shape(lowest))


def _rises_clear(params: ParamArrays, stride: Stride) -> Array:
    """Where the map's stride succeeds and its next flight climbs at least dynamics.placement_clearance from
    liftoff to apex (rises for at least PLACEMENT_LEAD_TIME): deadbeat's margin from a fall.

    Deadbeat's best angle often lies where the predicted liftoff speed reaches zero, the edge of the map's
    fall region (to come down to a low target apex); the exact plant's edge is a few mrad away, so an
    angle on the map's edge makes the plant fall (docs/paper.md, the deadbeat edge).
    """
    liftoff_height = stride.stance.r_lo * np.cos(stride.stance.theta_lo)
    with np.errstate(invalid="ignore"):
        climb = np.real(stride.y - liftoff_height)
        return np.asarray(stride.ok & (climb >= dynamics.placement_clearance(params.g)))


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

    The returned command is the refined one where the map accepts it, else the best scanned one (which
    it accepts). Lanes where every scanned angle fails get no_solution (leg_placement where no angle can
    place the leg). ``grid`` must be at least 2.
    """
    _require_at_least("grid", grid, 2)
    params = ParamArrays.of(params)
    y_, xdot_, target_y_, target_xdot_ = _as_arrays(y, xdot, target_y, target_xdot)
    target_energy = _apex_energy(params, target_y_, target_xdot_)
    lower, upper = admissible_angles(params, y_)
    shape = _lane_shape(params, lower, xdot_, target_energy, target_xdot_)
    lower, upper = np.broadcast_to(lower, shape), np.broadcast_to(upper, shape)
    placeable = lower < upper
    scales = _torque_scales(params, shape)

    # Scan: the candidate angles as a trailing axis of lanes.
    scan_lanes = ParamArrays(*(np.asarray(field)[..., None] for field in vars(params).values()))
    angles = lower[..., None] + (upper - lower)[..., None] * np.linspace(0.0, 1.0, grid)
    angles = np.where(placeable[..., None], angles, np.nan)
    command, stride = _regulated(
        scan_lanes,
        y_[..., None],
        xdot_[..., None],
        angles,
        target_energy[..., None],
        corrections,
        liftoff,
        DEADBEAT_SCAN_ITERATIONS,
    )
    cost = (stride.xdot - target_xdot_[..., None]) ** 2
    cost = np.where(_rises_clear(scan_lanes, stride) & np.isfinite(cost), cost, np.inf)
    best = np.argmin(cost, axis=-1)[..., None]
    scan_found = np.isfinite(np.take_along_axis(cost, best, axis=-1)[..., 0])

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
        return _DeadbeatPoint(z, r, slope, u, w, converged, _rises_clear(params, stride)[0] & finite)

    with np.errstate(invalid="ignore", divide="ignore"):  # lanes without a command carry NaN
        torque = np.stack([scanned(command.tau0, 0), scanned(command.t_f, 0)]) / scales
        here = linearise(np.concatenate([scanned(angles, 0)[None], torque]))
        found = scan_found & here.ok
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
                solved = _regulated_plan(
                    params, y_, xdot_, new.angle, target_energy, corrections, liftoff, FIXED_POINT_ITERATIONS
                )
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
    plan = _Plan(tau0, t_f, np.where(found, HAS_COMMAND, np.where(placeable, _NO_SOLUTION, _LEG_PLACEMENT)))
    if not np.all(here.converged | ~found):
        # Out of steps with the torque not yet solved (an optimum at the edge of the failures): solve it.
        solved = _regulated_plan(
            params, y_, xdot_, angle, target_energy, corrections, liftoff, FIXED_POINT_ITERATIONS
        )
        plan = plan.pick(solved, found & ~here.converged)
    refined, refined_stride = _checked(params, y_, xdot_, angle, plan, corrections, liftoff)
    # Where the map rejects the refined command (or it leaves no margin from a fall), the best scanned one
    # (its cost was finite) stands.
    assert refined.no_command is not None
    fallback = scan_found & ~_rises_clear(params, refined_stride)
    best_scanned = (scanned(np.asarray(field), 0) for field in (angles, command.tau0, command.t_f))
    angle, tau0, t_f = (
        np.where(fallback, scan, field) for scan, field in zip(best_scanned, refined, strict=True)
    )
    return CommandArrays(angle, tau0, t_f, no_command=np.where(fallback, HAS_COMMAND, refined.no_command))


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
    angle = np.where(lower < upper, np.clip(angle, lower, upper), np.nan)  # NaN: no angle places the leg
    target_energy = _apex_energy(params, target_y_, target_xdot_)
    return energy_regulation(params, y_, xdot_, angle, target_energy, corrections, liftoff)


POLICIES = ("open_loop", "energy", "energy_exact", "deadbeat", "pd")
FIXED_ANGLE_POLICIES = ("open_loop", "energy", "energy_exact")
"""Policies that touch down at the fixed ``touchdown_angle``."""
TARGET_APEX_POLICIES = ("deadbeat", "pd")
"""Policies that steer towards the target apex (``target_height``, ``target_speed``)."""


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
        if self.name == "energy_exact":
            return exact_energy_regulation(
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
        if self.name in TARGET_APEX_POLICIES:
            return self.target_height, self.target_speed
        return None
