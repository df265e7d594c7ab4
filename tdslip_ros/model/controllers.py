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

Implementation. Each policy is a compiled kernel of one lane (``lane_*``, :mod:`tdslip_ros.model.compiled`)
on the analytic map's own lane kernels; the functions below broadcast their inputs and run it in a compiled
loop over the lanes, so one apex costs a call into compiled code and a batch costs one loop. A lane's
command does not depend on the other lanes of its batch.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from numba.extending import register_jitable

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.analytic import (
    LiftoffMethod,
    approximate_map,
    check_corrections,
    liftoff_code,
    validate_angle,
)
from tdslip_ros.model.arrays import (
    HAS_COMMAND,
    REASON_OF_FAILURE,
    Array,
    ArrayLike,
    CommandArrays,
    Lanes,
    NoCommand,
    ParamArrays,
    elementwise,
    no_command_code,
    no_command_of_failure,
)
from tdslip_ros.model.closed_loop import fixed_command, map_jacobian
from tdslip_ros.model.compiled import kernel, real
from tdslip_ros.model.events import NO_FAILURE_CODE
from tdslip_ros.model.map_kernels import (
    LaneStance,
    LaneStride,
    StanceStart,
    Touchdown,
    apex_energy,
    converged,
    lane_ascent,
    lane_descent,
    lane_stance,
    lane_stance_start,
)
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import HopperParams, ParameterError, StanceCommand

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

# The plant's leg-placement rule, compiled as it stands: one rule for the plant and the planners.
register_jitable(dynamics.placement_clearance)
register_jitable(dynamics.can_place_leg)

_NO_LIFTOFF = no_command_code(NoCommand.NO_LIFTOFF)
_NO_SOLUTION = no_command_code(NoCommand.NO_SOLUTION)
_LEG_PLACEMENT = no_command_code(NoCommand.LEG_PLACEMENT)
_PREDICTED_REVERSAL = no_command_code(NoCommand.PREDICTED_REVERSAL)

# The rules that give tau0 from a planned stance (the policy's own equation; see _planned_stance).
TORQUE_RULE = 0
"""tau0 = the given value (ramp_to_liftoff)."""
POWER_RULE = 1
"""tau0 = C/thetadot_td, C the given touchdown power (fixed_power, eq. 26)."""
ENERGY_RULE = 2
"""tau0 with E_tau = E_loss + dE, dE the given energy change (energy regulation, eq. 32)."""


# --- compiled kernels of one lane ------------------------------------------------------------------------


class Plan(NamedTuple):
    """A planned (tau0, t_f) and the no_command code (HAS_COMMAND where planned; NaN fields else)."""

    tau0: complex
    t_f: complex
    reason: int


class LaneCommand(NamedTuple):
    """A policy's command for one lane: the fields of CommandArrays and the no_command code."""

    touchdown_angle: complex
    tau0: complex
    t_f: complex
    reason: int


@kernel
def solve2(
    a00: complex, a01: complex, a10: complex, a11: complex, b0: complex, b1: complex
) -> tuple[complex, complex]:
    """The solution of [[a00, a01], [a10, a11]] x = (b0, b1) (Cramer's rule)."""
    determinant = a00 * a11 - a01 * a10
    return (a11 * b0 - a01 * b1) / determinant, (a00 * b1 - a10 * b0) / determinant


@kernel
def torque_scales(m: float, k: float, r0: float, g: float) -> tuple[float, float]:
    """(m g r0, sqrt(m/k)): the units of (tau0, t_f) in the Newton iterations."""
    return m * g * r0, np.sqrt(m / k)


@kernel
def rule_torque(rule: int, value: complex, stance: LaneStance, thetadot_td: complex, t_f: complex) -> complex:
    """tau0 by the policy's rule (TORQUE_RULE, POWER_RULE, ENERGY_RULE) for a planned stance."""
    if rule == POWER_RULE:
        return value / thetadot_td
    if rule == ENERGY_RULE:
        return (value + (stance.damping_loss + stance.spring_energy)) / stance.energy_per_torque
    return value


@kernel
def energy_change(
    m: float, g: float, y: complex, xdot: complex, has_target: bool, target: complex
) -> complex:
    """E* - E_a for a target E*; zero without one (E* = E_a)."""
    energy = apex_energy(m, g, y, xdot)
    return target - energy if has_target else 0.0 * energy


@kernel
def lane_plan(
    y: complex,
    angle: complex,
    touchdown: Touchdown,
    start: StanceStart,
    rule: int,
    value: complex,
    corrections: int,
    liftoff: int,
    max_iterations: int,
    has_start: bool,
    start_tau0: complex,
    start_t_f: complex,
) -> Plan:
    """Solve (tau0, t_f) = (rule(stance), t_lo) for the stance they produce, from the touchdown and its
    unforced stance.

    Where the leg cannot be placed, without liftoff, or not converged in ``max_iterations`` the plan is NaN
    with its reason. The iteration starts from the unforced stance (tau0 = 0, corrections = 0, where t_lo
    does not depend on t_f; starting from the rule's tau0 for it instead loses about 2 % of the solvable
    lanes), or from (start_tau0, start_t_f) if has_start. The plain iteration x <- G(x) contracts only
    linearly (about -1/3 per step for energy regulation, where tau0 moves t_lo and the losses through
    p_hat), so this is Newton's method on G(x) - x = 0, x = (tau0, t_f) scaled by :func:`torque_scales`.
    G is evaluated at x and at x + JACOBIAN_STEP e_j, which gives its Jacobian by forward differences; that
    Jacobian's error of ~JACOBIAN_STEP only slows the final convergence to a rate of about that size. Where
    a component of the Newton step is not finite the plain step is taken. Under a complex step the
    Jacobian is that of the real parts; the (linear) imaginary parts then converge at the same rate.
    """
    s = start.approximation
    scale_tau, scale_t = torque_scales(s.m, s.k, s.r0, s.g)
    reason = HAS_COMMAND
    if not dynamics.can_place_leg(s.r0, s.g, real(y), np.cos(real(angle))):
        reason = _LEG_PLACEMENT
    elif touchdown.failure != NO_FAILURE_CODE:
        reason = _PREDICTED_REVERSAL  # the touchdown's only other failure
    elif not start.liftoff_exists:
        reason = _NO_LIFTOFF
    x0: complex = 0.0
    x1 = start.t_lo / scale_t
    if has_start:
        x0, x1 = start_tau0 / scale_tau, start_t_f / scale_t
    lifts_off, solved = True, False
    for _ in range(max_iterations if reason == HAS_COMMAND else 0):  # a lane with its reason has no plan
        tau0, t_f = x0 * scale_tau, x1 * scale_t
        stance = lane_stance(start, tau0, t_f, corrections, liftoff)
        g0, g1 = rule_torque(rule, value, stance, touchdown.thetadot, t_f) / scale_tau, stance.t_lo / scale_t
        lifts_off = lifts_off and stance.liftoff_exists
        solved = converged(g0, x0, FIXED_POINT_TOLERANCE) and converged(g1, x1, FIXED_POINT_TOLERANCE)
        if solved or not lifts_off:
            x0, x1 = g0, g1
            break
        # G at the two shifts of x, for its Jacobian.
        tau0 = (x0 + JACOBIAN_STEP) * scale_tau
        shifted = lane_stance(start, tau0, t_f, corrections, liftoff)
        g00 = rule_torque(rule, value, shifted, touchdown.thetadot, t_f) / scale_tau
        g01 = shifted.t_lo / scale_t
        tau0, t_f = x0 * scale_tau, (x1 + JACOBIAN_STEP) * scale_t
        shifted = lane_stance(start, tau0, t_f, corrections, liftoff)
        g10 = rule_torque(rule, value, shifted, touchdown.thetadot, t_f) / scale_tau
        g11 = shifted.t_lo / scale_t
        residual0, residual1 = g0 - x0, g1 - x1
        # d residual_i / d x_j = dG_i/dx_j - delta_ij
        step0, step1 = solve2(
            real(g00 - g0) / JACOBIAN_STEP - 1.0,
            real(g10 - g0) / JACOBIAN_STEP,
            real(g01 - g1) / JACOBIAN_STEP,
            real(g11 - g1) / JACOBIAN_STEP - 1.0,
            residual0,
            residual1,
        )
        x0 = x0 + (-step0 if np.isfinite(step0) else residual0)
        x1 = x1 + (-step1 if np.isfinite(step1) else residual1)
    if reason == HAS_COMMAND and not lifts_off:
        reason = _NO_LIFTOFF
    elif reason == HAS_COMMAND and not solved:
        reason = _NO_SOLUTION
    if reason != HAS_COMMAND:
        x0, x1 = np.nan, np.nan
    return Plan(x0 * scale_tau, x1 * scale_t, reason)


class Apex(NamedTuple):
    """One lane's apex, parameters and what the policies plan from: its touchdown and unforced stance."""

    m: float
    k: float
    r0: float
    c: float
    g: float
    y: complex
    xdot: complex
    angle: complex
    touchdown: Touchdown
    start: StanceStart


@kernel
def lane_apex(
    m: float, k: float, r0: float, c: float, g: float, y: complex, xdot: complex, angle: complex, liftoff: int
) -> Apex:
    touchdown = lane_descent(r0, g, y, xdot, angle)
    start = lane_stance_start(m, k, r0, c, g, angle, touchdown.rdot, touchdown.thetadot, liftoff)
    return Apex(m, k, r0, c, g, y, xdot, angle, touchdown, start)


@kernel
def planned_energy_per_torque(
    apex: Apex, tau0: complex, t_f: complex, corrections: int, liftoff: int
) -> float:
    """Real part of e for the stance of (tau0, t_f) from the apex."""
    return real(lane_stance(apex.start, tau0, t_f, corrections, liftoff).energy_per_torque)


class Planned(NamedTuple):
    """A plan and the stance it produces (no stance of meaning where it has no command)."""

    plan: Plan
    stance: LaneStance


@kernel
def lane_regulated_plan(
    apex: Apex, change: complex, corrections: int, liftoff: int, max_iterations: int
) -> Planned:
    """Energy regulation's (tau0, t_f) on the forward root (e < 0, module docstring), dE = change.

    Newton from the unforced stance finds the forward root wherever the unforced stance swings forward
    under the corrections (e(0) < 0). Near the highest apex at which the leg still swings forward,
    gravity's correction makes e(0) >= 0 and Newton finds the backward root tau_b. There e is close to
    linear in tau0, e = e1 (tau0 - tau_e), so the two roots of tau0 e(tau0) = E_loss + dE sum to tau_e:
    Newton starts again from tau_e - tau_b, next to the forward root. A lane without a forward root gets
    no_solution.
    """
    y, angle, touchdown, start = apex.y, apex.angle, apex.touchdown, apex.start
    plan = lane_plan(
        y, angle, touchdown, start, ENERGY_RULE, change, corrections, liftoff, max_iterations, False, 0.0, 0.0
    )
    tau0, t_f, reason = plan.tau0, plan.t_f, plan.reason
    stance = lane_stance(start, tau0, t_f, corrections, liftoff)
    rate = real(stance.energy_per_torque)
    if rate >= 0.0:  # the backward root
        backward = real(tau0)
        at_zero = planned_energy_per_torque(apex, 0.0, t_f, corrections, liftoff)
        root_sum = backward - rate * backward / (rate - at_zero)  # tau_e
        again = lane_plan(
            y,
            angle,
            touchdown,
            start,
            ENERGY_RULE,
            change,
            corrections,
            liftoff,
            max_iterations,
            True,
            root_sum - backward,
            t_f,
        )
        tau0, t_f, reason = again.tau0, again.t_f, again.reason
        stance = lane_stance(start, tau0, t_f, corrections, liftoff)
        forward = real(stance.energy_per_torque) < 0.0
        if reason == HAS_COMMAND and not forward:
            tau0, t_f, reason = np.nan, np.nan, _NO_SOLUTION
    return Planned(Plan(tau0, t_f, reason), stance)


@kernel
def reason_of_failure(failure: int) -> int:
    """The no_command code of one lane's failure code."""
    return HAS_COMMAND if failure == NO_FAILURE_CODE else int(REASON_OF_FAILURE[failure])


class Checked(NamedTuple):
    command: LaneCommand
    stride: LaneStride


@kernel
def lane_checked(apex: Apex, planned: Planned) -> Checked:
    """The planned command, or no command with the reason the analytic map rejects it, and the map's
    stride with the planned command."""
    plan = planned.plan
    stride = lane_ascent(apex.m, apex.g, apex.y, apex.xdot, apex.touchdown, planned.stance)
    reason = plan.reason
    if reason == HAS_COMMAND:
        reason = reason_of_failure(stride.failure)
    angle, tau0, t_f = apex.angle, plan.tau0, plan.t_f
    if reason != HAS_COMMAND:
        angle, tau0, t_f = np.nan, np.nan, np.nan
    return Checked(LaneCommand(angle, tau0, t_f, reason), stride)


@kernel
def lane_energy_regulation(
    apex: Apex, change: complex, corrections: int, liftoff: int, max_iterations: int
) -> Checked:
    """Energy regulation's command (E_tau = E_loss + change) and the map's stride with it."""
    return lane_checked(apex, lane_regulated_plan(apex, change, corrections, liftoff, max_iterations))


@kernel
def lane_admissible_angles(r0: float, g: float, y: complex) -> tuple[float, float]:
    """Touchdown angles that place the leg from apex height y (see :func:`admissible_angles`)."""
    placeable_top = real(y) - dynamics.placement_clearance(g)
    lowest = np.arccos(clip(placeable_top / r0, -1.0, 1.0))
    return lowest + ANGLE_MARGIN, np.pi / 2 - ANGLE_MARGIN


@kernel
def clip(x: float, lower: float, upper: float) -> float:
    """x clipped into [lower, upper]; NaN stays NaN (as np.clip)."""
    if x < lower:
        return lower
    if x > upper:
        return upper
    return x


@kernel
def rises_clear(g: float, stride: LaneStride) -> bool:
    """Whether the map's stride succeeds and its next flight climbs at least dynamics.placement_clearance
    from liftoff to apex (rises for at least PLACEMENT_LEAD_TIME): deadbeat's margin from a fall.

    Deadbeat's best angle often lies where the predicted liftoff speed reaches zero, the edge of the map's
    fall region (to come down to a low target apex); the exact plant's edge is a few mrad away, so an
    angle on the map's edge makes the plant fall (docs/paper.md, the deadbeat edge).
    """
    liftoff_height = stride.stance.r_lo * np.cos(stride.stance.theta_lo)
    climb = real(stride.y - liftoff_height)
    return stride.failure == NO_FAILURE_CODE and climb >= dynamics.placement_clearance(g)


class DeadbeatPoint(NamedTuple):
    """A deadbeat refinement point and the linearisation of its equations there.

    z = (theta_td, tau0/(m g r0), t_f/sqrt(m/k)); c(z) = G(x) - x is the residual of the torque's fixed point
    (x = (z1, z2), as in :func:`lane_plan`), r(z) = xdot_next - xdot*.
    """

    angle: float  # z0
    z1: float
    z2: float
    r: float  # r - r_x u: r with the torque solved at this angle (to first order)
    slope: float  # r_theta - r_x w: dr/dtheta along the torque solution
    u0: float  # u = c_x^-1 c: the Newton correction of x at this angle
    u1: float
    w0: float  # w = c_x^-1 c_theta: minus the rate at which the torque solution moves with the angle
    w1: float
    converged: bool  # x solves the torque's fixed point to FIXED_POINT_TOLERANCE
    ok: bool  # the map succeeded and the linearisation is finite

    @property
    def trusted(self) -> bool:
        """Close enough to the torque's fixed point for the linearisation to guide the angle (in kernels:
        :func:`trusted`)."""
        return trusted(self)


@kernel
def trusted(point: DeadbeatPoint) -> bool:
    return abs(point.u0) <= DEADBEAT_TORQUE_TRUST and abs(point.u1) <= DEADBEAT_TORQUE_TRUST


class DeadbeatGoal(NamedTuple):
    """What deadbeat solves for at one apex: the parameters, the apex and the target apex."""

    m: float
    k: float
    r0: float
    c: float
    g: float
    y: float
    xdot: float
    target_xdot: float
    change: float  # E* - E_a
    corrections: int
    liftoff: int


@kernel
def deadbeat_values(goal: DeadbeatGoal, apex: Apex, z1: float, z2: float) -> tuple[float, float, float, bool]:
    """(c, r) at z = (apex.angle, z1, z2) (:class:`DeadbeatPoint`) and whether the stride rises clear."""
    scale_tau, scale_t = torque_scales(goal.m, goal.k, goal.r0, goal.g)
    tau0, t_f = z1 * scale_tau, z2 * scale_t
    t_f = t_f if t_f > 0.0 else np.nan  # a wild step fails its point, not the lane
    stance = lane_stance(apex.start, tau0, t_f, goal.corrections, goal.liftoff)
    stride = lane_ascent(goal.m, goal.g, goal.y, goal.xdot, apex.touchdown, stance)
    torque = rule_torque(ENERGY_RULE, goal.change, stride.stance, stride.touchdown.thetadot, t_f)
    return (
        real(torque / scale_tau - z1),
        real(stride.stance.t_lo / scale_t - z2),
        real(stride.xdot - goal.target_xdot),
        rises_clear(goal.g, stride),
    )


@kernel
def linearise(goal: DeadbeatGoal, angle: float, z1: float, z2: float) -> DeadbeatPoint:
    """The point z and its linearisation, from the values at z and at its three forward shifts."""
    m, k, r0, c, g, y, xdot = goal.m, goal.k, goal.r0, goal.c, goal.g, goal.y, goal.xdot
    apex = lane_apex(m, k, r0, c, g, y, xdot, angle, goal.liftoff)
    shifted = lane_apex(m, k, r0, c, g, y, xdot, angle + JACOBIAN_STEP, goal.liftoff)
    c0, c1, r, clear = deadbeat_values(goal, apex, z1, z2)
    a0, a1, ar, _ = deadbeat_values(goal, shifted, z1, z2)
    b0, b1, br, _ = deadbeat_values(goal, apex, z1 + JACOBIAN_STEP, z2)
    d0, d1, dr, _ = deadbeat_values(goal, apex, z1, z2 + JACOBIAN_STEP)
    # d(c, r)_i / dz_j by forward differences
    c0_angle, c0_z1, c0_z2 = (a0 - c0) / JACOBIAN_STEP, (b0 - c0) / JACOBIAN_STEP, (d0 - c0) / JACOBIAN_STEP
    c1_angle, c1_z1, c1_z2 = (a1 - c1) / JACOBIAN_STEP, (b1 - c1) / JACOBIAN_STEP, (d1 - c1) / JACOBIAN_STEP
    r_angle, r_z1, r_z2 = (ar - r) / JACOBIAN_STEP, (br - r) / JACOBIAN_STEP, (dr - r) / JACOBIAN_STEP
    u = solve2(c0_z1, c0_z2, c1_z1, c1_z2, c0, c1)
    w = solve2(c0_z1, c0_z2, c1_z1, c1_z2, c0_angle, c1_angle)
    u0, u1, w0, w1 = real(u[0]), real(u[1]), real(w[0]), real(w[1])
    r_solved = r - (r_z1 * u0 + r_z2 * u1)
    slope = r_angle - (r_z1 * w0 + r_z2 * w1)
    done = converged(c0 + z1, z1, FIXED_POINT_TOLERANCE) and converged(c1 + z2, z2, FIXED_POINT_TOLERANCE)
    finite = np.isfinite(r_solved) and np.isfinite(slope)
    finite = finite and np.isfinite(u0) and np.isfinite(u1) and np.isfinite(w0) and np.isfinite(w1)
    return DeadbeatPoint(angle, z1, z2, r_solved, slope, u0, u1, w0, w1, done, clear and finite)


@kernel
def lane_deadbeat(goal: DeadbeatGoal, fractions: Array, angle_tolerance: float) -> LaneCommand:
    """Deadbeat's command for one apex (:func:`deadbeat`); ``fractions`` are the scan's angles as fractions
    of the admissible interval."""
    m, k, r0, c, g, y, xdot = goal.m, goal.k, goal.r0, goal.c, goal.g, goal.y, goal.xdot
    corrections, liftoff = goal.corrections, goal.liftoff
    scale_tau, scale_t = torque_scales(m, k, r0, g)
    lower, upper = lane_admissible_angles(r0, g, y)
    placeable = lower < upper

    # Scan: energy regulation at each candidate angle, ranked by the squared speed error.
    grid = fractions.size
    angles, tau0s, t_fs, costs = np.empty(grid), np.empty(grid), np.empty(grid), np.empty(grid)
    best = 0
    for j in range(grid):
        angle = lower + (upper - lower) * fractions[j] if placeable else np.nan
        apex = lane_apex(m, k, r0, c, g, y, xdot, angle, liftoff)
        checked = lane_energy_regulation(apex, goal.change, corrections, liftoff, DEADBEAT_SCAN_ITERATIONS)
        cost = (checked.stride.xdot - goal.target_xdot) ** 2
        if not (rises_clear(g, checked.stride) and np.isfinite(cost)):
            cost = np.inf
        angles[j], tau0s[j], t_fs[j], costs[j] = angle, checked.command.tau0, checked.command.t_f, cost
        if cost < costs[best]:
            best = j
    scan_found = np.isfinite(costs[best])
    before, after = max(best - 1, 0), min(best + 1, grid - 1)

    # Refinement: Newton on (theta, tau0, t_f) at once, bracketed (see deadbeat).
    here = linearise(goal, angles[best], tau0s[best] / scale_tau, t_fs[best] / scale_t)
    found = scan_found and here.ok
    # f' = 2 r r' < 0: f falls to the right of the best scan angle, so its minimum lies on that side.
    rightwards = here.r * here.slope < 0.0
    a = here.angle if rightwards else angles[before]
    b = angles[after] if rightwards else here.angle
    # No r'' yet: the first step is Newton's on r.
    previous_angle, previous_slope = here.angle, here.slope
    done = not found
    for _ in range(DEADBEAT_ITERATIONS):
        if done:
            break
        curvature = (here.slope - previous_slope) / (here.angle - previous_angle)
        curvature = curvature if np.isfinite(curvature) else 0.0
        denominator = here.slope**2 + here.r * curvature
        trial = here.angle - here.r * here.slope / denominator
        newton = np.isfinite(trial) and denominator > 0.0 and trial > a and trial < b
        step = (trial if newton else 0.5 * (a + b)) - here.angle
        settled = abs(step) <= angle_tolerance
        if settled and here.converged:
            break
        new = linearise(
            goal,
            here.angle + step,
            here.z1 - (here.u0 + here.w0 * step),
            here.z2 - (here.u1 + here.w1 * step),
        )
        if not (new.ok and trusted(new)):
            # Far from the torque's fixed point (or where the map fails there) the joint step says little:
            # solve the torque at that angle from scratch, as energy_regulation does, and linearise there.
            apex = lane_apex(m, k, r0, c, g, y, xdot, new.angle, liftoff)
            solved = lane_regulated_plan(apex, goal.change, corrections, liftoff, FIXED_POINT_ITERATIONS).plan
            new = linearise(goal, new.angle, real(solved.tau0) / scale_tau, real(solved.t_f) / scale_t)
        good = new.ok and trusted(new)
        if not settled:
            upper_end = new.r * new.slope > 0.0 if good else step > 0.0
            if upper_end:
                b = new.angle
            else:
                a = new.angle
        if good:
            if not settled:
                previous_angle, previous_slope = here.angle, here.slope
            here = new
    angle, tau0, t_f = here.angle, here.z1 * scale_tau, here.z2 * scale_t
    reason = HAS_COMMAND if found else (_NO_SOLUTION if placeable else _LEG_PLACEMENT)
    if not found:
        angle, tau0, t_f = np.nan, np.nan, np.nan
    apex = lane_apex(m, k, r0, c, g, y, xdot, angle, liftoff)
    if found and not here.converged:
        # Out of steps with the torque not yet solved (an optimum at the edge of the failures): solve it.
        planned = lane_regulated_plan(apex, goal.change, corrections, liftoff, FIXED_POINT_ITERATIONS)
    else:
        planned = Planned(Plan(tau0, t_f, reason), lane_stance(apex.start, tau0, t_f, corrections, liftoff))
    refined = lane_checked(apex, planned)
    if scan_found and not rises_clear(g, refined.stride):
        # The map rejects the refined command (or it leaves no margin from a fall): the best scanned one (its
        # cost was finite) stands.
        return LaneCommand(angles[best], tau0s[best], t_fs[best], HAS_COMMAND)
    return refined.command


@kernel
def neutral_angle_of(m: float, k: float, r0: float, xdot: complex) -> complex:
    """Raibert's neutral touchdown angle (:func:`neutral_angle`)."""
    stance_time = np.pi * np.sqrt(m / k)
    angle: complex = np.arcsin(clip(xdot * stance_time / (2.0 * r0), 0.0, 1.0))
    return angle


# --- compiled loops over the lanes of a batch: a block of rows (angle, tau0, t_f, reason), one column a lane


COMMAND_ROWS = 4


@kernel
def write_command(out: Array, lane: int, command: LaneCommand) -> None:
    out[0, lane] = command.touchdown_angle
    out[1, lane] = command.tau0
    out[2, lane] = command.t_f
    out[3, lane] = command.reason


@kernel
def _planned_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    angle: Array,
    value: Array,
    rule: int,
    check: bool,
    corrections: int,
    liftoff: int,
    out: Array,
) -> None:
    """A rule's plan per lane, checked in the map (fixed_power) or not (ramp_to_liftoff)."""
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        apex = lane_apex(m, k, r0, c, g, y[i], xdot[i], angle[i], liftoff)
        plan = lane_plan(
            y[i],
            angle[i],
            apex.touchdown,
            apex.start,
            rule,
            value[i],
            corrections,
            liftoff,
            FIXED_POINT_ITERATIONS,
            False,
            0.0,
            0.0,
        )
        if check:
            stance = lane_stance(apex.start, plan.tau0, plan.t_f, corrections, liftoff)
            write_command(out, i, lane_checked(apex, Planned(plan, stance)).command)
        else:
            planned = angle[i] if plan.reason == HAS_COMMAND else np.nan
            write_command(out, i, LaneCommand(planned, plan.tau0, plan.t_f, plan.reason))


@kernel
def _regulated_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    angle: Array,
    target: Array,
    has_target: bool,
    corrections: int,
    liftoff: int,
    max_iterations: int,
    out: Array,
) -> None:
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        apex = lane_apex(m, k, r0, c, g, y[i], xdot[i], angle[i], liftoff)
        change = energy_change(m, g, y[i], xdot[i], has_target, target[i])
        write_command(
            out, i, lane_energy_regulation(apex, change, corrections, liftoff, max_iterations).command
        )


@kernel
def _pd_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    previous_xdot: Array,
    target_y: Array,
    target_xdot: Array,
    kp: Array,
    kd: Array,
    corrections: int,
    liftoff: int,
    out: Array,
) -> None:
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        angle = neutral_angle_of(m, k, r0, xdot[i])
        angle = angle + kp[i] * (xdot[i] - target_xdot[i]) + kd[i] * (xdot[i] - previous_xdot[i])
        lower, upper = lane_admissible_angles(r0, g, y[i])
        angle = clip(angle, lower, upper) if lower < upper else np.nan  # NaN: no angle places the leg
        apex = lane_apex(m, k, r0, c, g, y[i], xdot[i], angle, liftoff)
        target = apex_energy(m, g, target_y[i], target_xdot[i])
        change = energy_change(m, g, y[i], xdot[i], True, target)
        write_command(
            out, i, lane_energy_regulation(apex, change, corrections, liftoff, FIXED_POINT_ITERATIONS).command
        )


@kernel
def _deadbeat_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    target_y: Array,
    target_xdot: Array,
    fractions: Array,
    angle_tolerance: float,
    corrections: int,
    liftoff: int,
    out: Array,
) -> None:
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        change = real(apex_energy(m, g, target_y[i], target_xdot[i]) - apex_energy(m, g, y[i], xdot[i]))
        goal = DeadbeatGoal(m, k, r0, c, g, y[i], xdot[i], target_xdot[i], change, corrections, liftoff)
        write_command(out, i, lane_deadbeat(goal, fractions, angle_tolerance))


# --- the policies' API -----------------------------------------------------------------------------------


def _require_at_least(name: str, value: int, least: int) -> None:
    if value < least:
        raise ParameterError(f"{name} must be at least {least}, got {value!r}")


def _commands(lanes: Lanes, block: Array) -> CommandArrays:
    angle, tau0, t_f = (lanes.shaped(row) for row in block[:3])
    return CommandArrays(angle, tau0, t_f, no_command=lanes.codes(block[3]))


def _apex_energy(params: ParamArrays, y: ArrayLike, xdot: ArrayLike) -> Array:
    return np.asarray(params.m * (params.g * np.asarray(y) + 0.5 * np.asarray(xdot) ** 2))


def _planned(
    params: ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    angle: ArrayLike,
    value: ArrayLike,
    rule: int,
    check: bool,
    corrections: int,
    liftoff: LiftoffMethod,
) -> CommandArrays:
    check_corrections(corrections)
    code = liftoff_code(liftoff)
    lanes = Lanes.of(params, y, xdot, angle, value)
    block = lanes.rows(COMMAND_ROWS)
    lanes.run(_planned_lanes, rule, check, corrections, code, block)
    return _commands(lanes, block)


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
    return _planned(ParamArrays.of(params), y, xdot, angle, tau0, TORQUE_RULE, False, corrections, liftoff)


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
    validate_angle(beta)
    power = units.power_from_alpha(params, np.asarray(alpha, dtype=float))
    return _planned(ParamArrays.of(params), y, xdot, beta, power, POWER_RULE, True, corrections, liftoff)


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
    the two roots the forward one is returned (:func:`lane_regulated_plan`). Lanes not solved in
    ``max_iterations`` (at least 1) Newton steps get no_solution.
    """
    _require_at_least("max_iterations", max_iterations, 1)
    validate_angle(beta)
    check_corrections(corrections)
    code = liftoff_code(liftoff)
    params = ParamArrays.of(params)
    target = 0.0 if target_energy is None else target_energy
    lanes = Lanes.of(params, y, xdot, beta, target)
    block = lanes.rows(COMMAND_ROWS)
    has_target = target_energy is not None
    lanes.run(_regulated_lanes, has_target, corrections, code, max_iterations, block)
    return _commands(lanes, block)


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
    y_, xdot_, beta_ = (np.asarray(value) for value in (y, xdot, beta))
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
    probes = _probes(2, EXACT_JACOBIAN_STEP)  # (3, 2, 1)
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


def _probes(count: int, step: float) -> Array:
    """A point and its ``step`` shifts along each of ``count`` coordinates: (count + 1, count, 1)."""
    directions = np.vstack([np.zeros(count), np.eye(count)])
    return step * directions.reshape(count + 1, count, 1)


def _solve2(matrix: Array, vector: Array) -> Array:
    """matrix^-1 vector per lane for (2, 2, n) matrices and (2, n) vectors (:func:`solve2`)."""
    return np.stack(elementwise(solve2, [complex, complex], *matrix.reshape(4, -1), *vector))


def admissible_angles(params: HopperParams | ParamArrays, y: ArrayLike) -> tuple[Array, Array]:
    """Touchdown angles that place the leg from apex height y: (arccos(min((y - d)/r0, 1)), pi/2) less
    ANGLE_MARGIN, d = dynamics.placement_clearance (the angles dynamics.can_place_leg accepts).

    This is eq. 34's interval (-pi/2, pi/2) cut to forward running (StanceCommand's (0, pi/2)) and to
    feasible leg placement (y - d >= r0 cos(theta_td)). The interval is empty (lower > upper) for an apex
    below d.
    """
    params = ParamArrays.of(params)
    lower, upper = elementwise(lane_admissible_angles, [float, float], params.r0, params.g, np.real(y))
    return lower, upper


@lru_cache(maxsize=8)
def _scan_fractions(grid: int) -> Array:
    """Deadbeat's scan angles as fractions of the admissible interval (read-only, being shared)."""
    fractions = np.linspace(0.0, 1.0, grid)
    fractions.flags.writeable = False
    return fractions


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

    * Scan: energy regulation and the map at ``grid`` angles across the interval. It only ranks the angles,
      so its solve stops after DEADBEAT_SCAN_ITERATIONS Newton steps and angles not solved by then count as
      failed (the angles towards pi/2, which have no solution, would otherwise iterate to
      FIXED_POINT_ITERATIONS).
    * Refinement, from the best scan angle in the bracket of its neighbours, down to ``angle_tolerance``
      rad: Newton's method on (theta, tau0, t_f) at once, the map evaluated at the point and its three
      forward-difference shifts per step (:func:`linearise`). The angle step is Newton's for
      f'/2 = r r' = 0, ``delta = -r r'/(r'^2 + r r'')`` with r' taken along the torque solution and r'' from
      a secant of r'. Where the target is reachable (r = 0) this is Newton's method on r (quadratic
      convergence); where it is not, the secant method on r' = 0 (the extremum of xdot_next). A step that
      would leave the bracket is replaced by bisection, and the sign of f' at each new angle (a failed
      angle counts as uphill) shrinks the bracket. The torque takes the Newton step of its fixed point for
      the new angle, so both converge together; the result solves that fixed point to
      FIXED_POINT_TOLERANCE, like :func:`energy_regulation` at the returned angle.

    The returned command is the refined one where the map accepts it, else the best scanned one (which
    it accepts). Lanes where every scanned angle fails get no_solution (leg_placement where no angle can
    place the leg). ``grid`` must be at least 2. Not complex-step safe (real parts are used).
    """
    _require_at_least("grid", grid, 2)
    check_corrections(corrections)
    code = liftoff_code(liftoff)
    params = ParamArrays.of(params)
    lanes = Lanes.of(params, *(np.real(v) for v in (y, xdot, target_y, target_xdot)))
    block = lanes.rows(COMMAND_ROWS)
    lanes.run(_deadbeat_lanes, _scan_fractions(grid), angle_tolerance, corrections, code, block)
    return _commands(lanes, block)


def neutral_angle(params: HopperParams | ParamArrays, xdot: ArrayLike) -> Array:
    """Raibert's neutral touchdown angle, toe half a stance's travel ahead: sin(theta_n) = xdot T_s/(2 r0).

    T_s = pi sqrt(m/k) is the half period of the leg spring, the usual estimate of the stance time.
    """
    params = ParamArrays.of(params)
    return elementwise(neutral_angle_of, [complex], params.m, params.k, params.r0, xdot)[0]


def pd_speed_energy_height(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    previous_xdot: ArrayLike,
    target_y: ArrayLike,
    target_xdot: ArrayLike,
    kp: ArrayLike = 0.06,
    kd: ArrayLike = 0.03,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
) -> CommandArrays:
    """PD baseline in the spirit of the paper's ref. 36 (energy control of height, PD control of speed).

    * Speed, through the touchdown angle (Raibert-style foot placement, discrete PD over strides)::

          theta_td = theta_n(xdot) + kp (xdot - xdot*) + kd (xdot - xdot_prev)

      with theta_n from :func:`neutral_angle`, gains in rad/(m/s) (scalars, or one per lane), clipped into
      :func:`admissible_angles`.
      Running too fast places the foot further ahead, which brakes. ``previous_xdot`` is the speed at the
      previous apex (pass ``xdot`` on the first stride).
    * Height, through the energy: tau0 from the analytic map so that the next apex has the energy of the
      target apex, E* = m g y* + m xdot*^2/2 (:func:`energy_regulation` with that target).

    Unlike :func:`deadbeat`, the angle ignores the map, so height and speed converge only over strides.
    """
    check_corrections(corrections)
    code = liftoff_code(liftoff)
    params = ParamArrays.of(params)
    lanes = Lanes.of(params, y, xdot, previous_xdot, target_y, target_xdot, kp, kd)
    block = lanes.rows(COMMAND_ROWS)
    lanes.run(_pd_lanes, corrections, code, block)
    return _commands(lanes, block)


def warm_up(params: HopperParams | None = None, complex_step: bool = True) -> None:
    """Load the compiled kernels of the analytic map and of every analytic policy, for one apex at a time
    as the controller node plans (and with ``complex_step`` for the complex step of map_jacobian too),
    compiling those not yet in the cache (:mod:`tdslip_ros.model.compiled`; about a minute for all of
    them, once). The controller node calls it before it subscribes to the apex, so that its first answer
    is not late; ``./run.sh setup`` calls it so that the first node or test does not compile."""
    params = PAPER_PARAMS if params is None else params
    y, xdot, beta = 1.1, 4.5, np.radians(26.0)
    for liftoff in ("paper", "force_root"):
        approximate_map(params, y, xdot, StanceCommand(beta, -500.0, 0.15), liftoff=liftoff)
    energy = float(params.m * (params.g * y + 0.5 * xdot**2))
    energy_regulation(params, y, xdot, beta)
    energy_regulation(params, y, xdot, beta, energy)
    fixed_power(params, y, xdot, beta, 1.5)
    ramp_to_liftoff(params, y, xdot, beta, -500.0)
    deadbeat(params, y, xdot, y, xdot)
    pd_speed_energy_height(params, y, xdot, xdot, y, xdot)
    if complex_step:
        for policy in (
            lambda p, y_, x_: energy_regulation(p, y_, x_, beta),
            lambda p, y_, x_: fixed_power(params, y_, x_, beta, 1.5),
            fixed_command(StanceCommand(beta, -500.0, 0.15)),
        ):
            map_jacobian(params, np.asarray(y), np.asarray(xdot), policy)


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
