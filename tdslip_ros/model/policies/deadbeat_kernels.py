"""Deadbeat's search for the touchdown angle, as compiled kernels of one lane, and its loop over the lanes.

The inversion of the analytic map of :func:`tdslip_ros.model.policies.controllers.deadbeat` (its docstring
gives the method): a scan of energy regulation at angles across the admissible interval, then Newton's method
on (theta, tau0, t_f) at once (:func:`linearise`, :func:`lane_deadbeat`), on the policies' kernels
(:mod:`.controller_kernels`). Not complex-step safe: the search works on real parts.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from tdslip_ros.model import dynamics
from tdslip_ros.model.analytic.map_kernels import LaneStride, converged, lane_ascent, lane_stance
from tdslip_ros.model.arrays import HAS_COMMAND, Array
from tdslip_ros.model.compiled import kernel, real
from tdslip_ros.model.dynamics import apex_energy
from tdslip_ros.model.events import NO_FAILURE_CODE
from tdslip_ros.model.policies.controller_kernels import (
    ENERGY_RULE,
    FIXED_POINT_ITERATIONS,
    FIXED_POINT_TOLERANCE,
    JACOBIAN_STEP,
    LEG_PLACEMENT_REASON,
    NO_SOLUTION_REASON,
    Apex,
    LaneCommand,
    Plan,
    Planned,
    lane_admissible_angles,
    lane_apex,
    lane_checked,
    lane_energy_regulation,
    lane_regulated_plan,
    rule_torque,
    solve2,
    torque_scales,
    write_command,
)

DEADBEAT_SCAN_ITERATIONS = 10
"""Newton steps of the deadbeat scan's solves (from a cold start most solvable angles need 5-8)."""
DEADBEAT_TORQUE_TRUST = 0.02
"""Largest Newton correction of (tau0, t_f), scaled, at which a deadbeat refinement point is trusted."""
DEADBEAT_ITERATIONS = 40
"""Bound on the deadbeat refinement's steps (about 5 where the target is reachable, 30 when bisecting)."""

# dynamics.placement_clearance compiles as controller_kernels registers it (one rule for plant and planners).


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
    (x = (z1, z2), as in :func:`~.controller_kernels.lane_plan`), r(z) = xdot_next - xdot*.
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
    map_variant: int


@kernel
def deadbeat_values(goal: DeadbeatGoal, apex: Apex, z1: float, z2: float) -> tuple[float, float, float, bool]:
    """(c, r) at z = (apex.angle, z1, z2) (:class:`DeadbeatPoint`) and whether the stride rises clear."""
    scale_tau, scale_t = torque_scales(goal.m, goal.k, goal.r0, goal.g)
    tau0, t_f = z1 * scale_tau, z2 * scale_t
    t_f = t_f if t_f > 0.0 else np.nan  # a wild step fails its point, not the lane
    stance = lane_stance(apex.start, tau0, t_f, goal.corrections, goal.map_variant)
    stride = lane_ascent(goal.m, goal.g, goal.y, goal.xdot, apex.touchdown, stance, goal.map_variant)
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
    apex = lane_apex(m, k, r0, c, g, y, xdot, angle, goal.map_variant)
    shifted = lane_apex(m, k, r0, c, g, y, xdot, angle + JACOBIAN_STEP, goal.map_variant)
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
    """Deadbeat's command for one apex (:func:`.controllers.deadbeat`); ``fractions`` are the scan's angles
    as fractions of the admissible interval."""
    m, k, r0, c, g, y, xdot = goal.m, goal.k, goal.r0, goal.c, goal.g, goal.y, goal.xdot
    corrections, map_variant = goal.corrections, goal.map_variant
    scale_tau, scale_t = torque_scales(m, k, r0, g)
    lower, upper = lane_admissible_angles(r0, g, y)
    placeable = lower < upper

    # Scan: energy regulation at each candidate angle, ranked by the squared speed error.
    grid = fractions.size
    angles, tau0s, t_fs, costs = np.empty(grid), np.empty(grid), np.empty(grid), np.empty(grid)
    best = 0
    for j in range(grid):
        angle = lower + (upper - lower) * fractions[j] if placeable else np.nan
        apex = lane_apex(m, k, r0, c, g, y, xdot, angle, map_variant)
        checked = lane_energy_regulation(
            apex, goal.change, corrections, map_variant, DEADBEAT_SCAN_ITERATIONS
        )
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
            apex = lane_apex(m, k, r0, c, g, y, xdot, new.angle, map_variant)
            solved = lane_regulated_plan(
                apex, goal.change, corrections, map_variant, FIXED_POINT_ITERATIONS
            ).plan
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
    reason = HAS_COMMAND if found else (NO_SOLUTION_REASON if placeable else LEG_PLACEMENT_REASON)
    if not found:
        angle, tau0, t_f = np.nan, np.nan, np.nan
    apex = lane_apex(m, k, r0, c, g, y, xdot, angle, map_variant)
    if found and not here.converged:
        # Out of steps with the torque not yet solved (an optimum at the edge of the failures): solve it.
        planned = lane_regulated_plan(apex, goal.change, corrections, map_variant, FIXED_POINT_ITERATIONS)
    else:
        planned = Planned(
            Plan(tau0, t_f, reason), lane_stance(apex.start, tau0, t_f, corrections, map_variant)
        )
    refined = lane_checked(apex, planned)
    if scan_found and not rises_clear(g, refined.stride):
        # The map rejects the refined command (or it leaves no margin from a fall): the best scanned one (its
        # cost was finite) stands.
        return LaneCommand(angles[best], tau0s[best], t_fs[best], HAS_COMMAND)
    return refined.command


@kernel
def deadbeat_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    target_y: Array,
    target_xdot: Array,
    fractions: Array,
    angle_tolerance: float,
    corrections: int,
    map_variant: int,
    out: Array,
) -> None:
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        change = real(apex_energy(m, g, target_y[i], target_xdot[i]) - apex_energy(m, g, y[i], xdot[i]))
        goal = DeadbeatGoal(m, k, r0, c, g, y[i], xdot[i], target_xdot[i], change, corrections, map_variant)
        write_command(out, i, lane_deadbeat(goal, fractions, angle_tolerance))
