"""The policies' solvers as compiled kernels of one lane, and their loops over the lanes of a batch.

Each analytic policy of :mod:`tdslip_ros.model.policies.controllers` is a kernel of one lane (``lane_*``,
:mod:`tdslip_ros.model.compiled`) on the analytic map's own lane kernels (:mod:`.map_kernels`):
:func:`lane_plan` solves a rule's (tau0, t_f) = (rule(stance), t_lo) by Newton's method,
:func:`lane_regulated_plan` finds energy regulation's forward root and :func:`lane_checked` keeps only a
command that the map accepts; deadbeat's angle search is :mod:`.deadbeat_kernels`. The loops (``*_lanes``)
run a policy over the lanes :class:`~tdslip_ros.model.arrays.Lanes` packs and write a block of rows (angle,
tau0, t_f, reason), one column a lane (:func:`write_command`). A lane's command does not depend on the other
lanes of its batch.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from tdslip_ros.model import dynamics
from tdslip_ros.model.analytic.map_kernels import (
    LaneStance,
    LaneStride,
    StanceStart,
    Touchdown,
    converged,
    lane_ascent,
    lane_descent,
    lane_stance,
    lane_stance_start,
)
from tdslip_ros.model.arrays import HAS_COMMAND, REASON_OF_FAILURE, Array, NoCommand, no_command_code
from tdslip_ros.model.compiled import kernel, real
from tdslip_ros.model.dynamics import apex_energy
from tdslip_ros.model.events import NO_FAILURE_CODE

FIXED_POINT_TOLERANCE = 1e-13
"""Relative change of t_f and tau0 below which the policies' fixed-point iterations stop."""
FIXED_POINT_ITERATIONS = 30
"""Bound on the Newton steps of a policy's (tau0, t_f) solve (solvable lanes need 4-8, rarely up to 16)."""
JACOBIAN_STEP = 1e-7
"""Forward-difference step of the Newton iterations' Jacobians, in the scaled variables (rad for angles)."""
ANGLE_MARGIN = 1e-6
"""rad kept inside the ends of the admissible touchdown interval, so that rounding cannot take an angle
at its end out of it (the physical margin is dynamics.PLACEMENT_LEAD_TIME)."""

# The plant's leg-placement rule, compiled as it stands: one rule for the plant and the planners.
register_jitable(dynamics.placement_clearance)
register_jitable(dynamics.can_place_leg)

# The no_command codes the kernels write (the index of the NoCommand in NO_COMMAND_KINDS).
NO_LIFTOFF_REASON = no_command_code(NoCommand.NO_LIFTOFF)
NO_SOLUTION_REASON = no_command_code(NoCommand.NO_SOLUTION)
LEG_PLACEMENT_REASON = no_command_code(NoCommand.LEG_PLACEMENT)
PREDICTED_REVERSAL_REASON = no_command_code(NoCommand.PREDICTED_REVERSAL)

# The rules that give tau0 from a planned stance (the policy's own equation; see lane_plan).
TORQUE_RULE = 0
"""tau0 = the given value (ramp_to_liftoff)."""
POWER_RULE = 1
"""tau0 = C/thetadot_td, C the given touchdown power (fixed_power, eq. 26)."""
ENERGY_RULE = 2
"""tau0 with E_tau = E_loss + dE, dE the given energy change (energy regulation, eq. 32)."""


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
    energy: complex = apex_energy(m, g, y, xdot)
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
    map_variant: int,
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
        reason = LEG_PLACEMENT_REASON
    elif touchdown.failure != NO_FAILURE_CODE:
        reason = PREDICTED_REVERSAL_REASON  # the touchdown's only other failure
    elif not start.liftoff_exists:
        reason = NO_LIFTOFF_REASON
    x0: complex = 0.0
    x1 = start.t_lo / scale_t
    if has_start:
        x0, x1 = start_tau0 / scale_tau, start_t_f / scale_t
    lifts_off, solved = True, False
    for _ in range(max_iterations if reason == HAS_COMMAND else 0):  # a lane with its reason has no plan
        tau0, t_f = x0 * scale_tau, x1 * scale_t
        stance = lane_stance(start, tau0, t_f, corrections, map_variant)
        g0, g1 = rule_torque(rule, value, stance, touchdown.thetadot, t_f) / scale_tau, stance.t_lo / scale_t
        lifts_off = lifts_off and stance.liftoff_exists
        solved = converged(g0, x0, FIXED_POINT_TOLERANCE) and converged(g1, x1, FIXED_POINT_TOLERANCE)
        if solved or not lifts_off:
            x0, x1 = g0, g1
            break
        # G at the two shifts of x, for its Jacobian.
        tau0 = (x0 + JACOBIAN_STEP) * scale_tau
        shifted = lane_stance(start, tau0, t_f, corrections, map_variant)
        g00 = rule_torque(rule, value, shifted, touchdown.thetadot, t_f) / scale_tau
        g01 = shifted.t_lo / scale_t
        tau0, t_f = x0 * scale_tau, (x1 + JACOBIAN_STEP) * scale_t
        shifted = lane_stance(start, tau0, t_f, corrections, map_variant)
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
        reason = NO_LIFTOFF_REASON
    elif reason == HAS_COMMAND and not solved:
        reason = NO_SOLUTION_REASON
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
    map_variant: int  # the map the policy plans on (map_kernels: liftoff method and next-apex speed)


@kernel
def lane_apex(
    m: float,
    k: float,
    r0: float,
    c: float,
    g: float,
    y: complex,
    xdot: complex,
    angle: complex,
    map_variant: int,
) -> Apex:
    touchdown = lane_descent(r0, g, y, xdot, angle)
    start = lane_stance_start(m, k, r0, c, g, angle, touchdown.rdot, touchdown.thetadot, map_variant)
    return Apex(m, k, r0, c, g, y, xdot, angle, touchdown, start, map_variant)


@kernel
def planned_energy_per_torque(
    apex: Apex, tau0: complex, t_f: complex, corrections: int, map_variant: int
) -> float:
    """Real part of e for the stance of (tau0, t_f) from the apex."""
    return real(lane_stance(apex.start, tau0, t_f, corrections, map_variant).energy_per_torque)


class Planned(NamedTuple):
    """A plan and the stance it produces (no stance of meaning where it has no command)."""

    plan: Plan
    stance: LaneStance


@kernel
def lane_regulated_plan(
    apex: Apex, change: complex, corrections: int, map_variant: int, max_iterations: int
) -> Planned:
    """Energy regulation's (tau0, t_f) on the forward root (e < 0, :mod:`.controllers`), dE = change.

    Newton from the unforced stance finds the forward root wherever the unforced stance swings forward
    under the corrections (e(0) < 0). Near the highest apex at which the leg still swings forward,
    gravity's correction makes e(0) >= 0 and Newton finds the backward root tau_b. There e is close to
    linear in tau0, e = e1 (tau0 - tau_e), so the two roots of tau0 e(tau0) = E_loss + dE sum to tau_e:
    Newton starts again from tau_e - tau_b, next to the forward root. A lane without a forward root gets
    no_solution.
    """
    y, angle, touchdown, start = apex.y, apex.angle, apex.touchdown, apex.start
    plan = lane_plan(
        y,
        angle,
        touchdown,
        start,
        ENERGY_RULE,
        change,
        corrections,
        map_variant,
        max_iterations,
        False,
        0.0,
        0.0,
    )
    tau0, t_f, reason = plan.tau0, plan.t_f, plan.reason
    stance = lane_stance(start, tau0, t_f, corrections, map_variant)
    rate = real(stance.energy_per_torque)
    if rate >= 0.0:  # the backward root
        backward = real(tau0)
        at_zero = planned_energy_per_torque(apex, 0.0, t_f, corrections, map_variant)
        root_sum = backward - rate * backward / (rate - at_zero)  # tau_e
        again = lane_plan(
            y,
            angle,
            touchdown,
            start,
            ENERGY_RULE,
            change,
            corrections,
            map_variant,
            max_iterations,
            True,
            root_sum - backward,
            t_f,
        )
        tau0, t_f, reason = again.tau0, again.t_f, again.reason
        stance = lane_stance(start, tau0, t_f, corrections, map_variant)
        forward = real(stance.energy_per_torque) < 0.0
        if reason == HAS_COMMAND and not forward:
            tau0, t_f, reason = np.nan, np.nan, NO_SOLUTION_REASON
    return Planned(Plan(tau0, t_f, reason), stance)


class Checked(NamedTuple):
    command: LaneCommand
    stride: LaneStride


@kernel
def reason_of_failure(failure: int) -> int:
    """The no_command code of one lane's failure code."""
    return HAS_COMMAND if failure == NO_FAILURE_CODE else int(REASON_OF_FAILURE[failure])


@kernel
def lane_checked(apex: Apex, planned: Planned) -> Checked:
    """The planned command, or no command with the reason the analytic map rejects it, and the map's
    stride with the planned command."""
    plan = planned.plan
    stride = lane_ascent(apex.m, apex.g, apex.y, apex.xdot, apex.touchdown, planned.stance, apex.map_variant)
    reason = plan.reason
    if reason == HAS_COMMAND:
        reason = reason_of_failure(stride.failure)
    angle, tau0, t_f = apex.angle, plan.tau0, plan.t_f
    if reason != HAS_COMMAND:
        angle, tau0, t_f = np.nan, np.nan, np.nan
    return Checked(LaneCommand(angle, tau0, t_f, reason), stride)


@kernel
def lane_energy_regulation(
    apex: Apex, change: complex, corrections: int, map_variant: int, max_iterations: int
) -> Checked:
    """Energy regulation's command (E_tau = E_loss + change) and the map's stride with it."""
    return lane_checked(apex, lane_regulated_plan(apex, change, corrections, map_variant, max_iterations))


@kernel
def lane_admissible_angles(r0: float, g: float, y: complex) -> tuple[float, float]:
    """Touchdown angles that place the leg from apex height y (see :func:`.controllers.admissible_angles`)."""
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
def neutral_angle_of(m: float, k: float, r0: float, xdot: complex) -> complex:
    """Raibert's neutral touchdown angle (:func:`.controllers.neutral_angle`)."""
    stance_time = np.pi * np.sqrt(m / k)
    angle: complex = np.arcsin(clip(xdot * stance_time / (2.0 * r0), 0.0, 1.0))
    return angle


COMMAND_ROWS = 4


@kernel
def write_command(out: Array, lane: int, command: LaneCommand) -> None:
    out[0, lane] = command.touchdown_angle
    out[1, lane] = command.tau0
    out[2, lane] = command.t_f
    out[3, lane] = command.reason


@kernel
def planned_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    angle: Array,
    value: Array,
    rule: int,
    check: bool,
    corrections: int,
    map_variant: int,
    out: Array,
) -> None:
    """A rule's plan per lane, checked in the map (fixed_power) or not (ramp_to_liftoff)."""
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        apex = lane_apex(m, k, r0, c, g, y[i], xdot[i], angle[i], map_variant)
        plan = lane_plan(
            y[i],
            angle[i],
            apex.touchdown,
            apex.start,
            rule,
            value[i],
            corrections,
            map_variant,
            FIXED_POINT_ITERATIONS,
            False,
            0.0,
            0.0,
        )
        if check:
            stance = lane_stance(apex.start, plan.tau0, plan.t_f, corrections, map_variant)
            write_command(out, i, lane_checked(apex, Planned(plan, stance)).command)
        else:
            planned = angle[i] if plan.reason == HAS_COMMAND else np.nan
            write_command(out, i, LaneCommand(planned, plan.tau0, plan.t_f, plan.reason))


@kernel
def regulated_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    angle: Array,
    target: Array,
    has_target: bool,
    corrections: int,
    map_variant: int,
    max_iterations: int,
    out: Array,
) -> None:
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        apex = lane_apex(m, k, r0, c, g, y[i], xdot[i], angle[i], map_variant)
        change = energy_change(m, g, y[i], xdot[i], has_target, target[i])
        write_command(
            out, i, lane_energy_regulation(apex, change, corrections, map_variant, max_iterations).command
        )


@kernel
def foot_placement_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    previous_xdot: Array,
    target_y: Array,
    target_xdot: Array,
    kp: Array,
    kd: Array,
    corrections: int,
    map_variant: int,
    out: Array,
) -> None:
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        angle = neutral_angle_of(m, k, r0, xdot[i])
        angle = angle + kp[i] * (xdot[i] - target_xdot[i]) + kd[i] * (xdot[i] - previous_xdot[i])
        lower, upper = lane_admissible_angles(r0, g, y[i])
        angle = clip(angle, lower, upper) if lower < upper else np.nan  # NaN: no angle places the leg
        apex = lane_apex(m, k, r0, c, g, y[i], xdot[i], angle, map_variant)
        target = apex_energy(m, g, target_y[i], target_xdot[i])
        change = energy_change(m, g, y[i], xdot[i], True, target)
        write_command(
            out,
            i,
            lane_energy_regulation(apex, change, corrections, map_variant, FIXED_POINT_ITERATIONS).command,
        )
