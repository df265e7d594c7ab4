"""energy_exact's planner compiled: Newton's method on the exact stride of one lane
(:func:`tdslip_ros.model.plant.stride_kernels.lane_stride`) for the ramp (tau0, t_f) whose next apex has the
goal energy and whose ramp ends at liftoff (:func:`.controllers.exact_energy_regulation` says the method).

A policy, so it lives with the policies and calls the plant's compiled stride, not the other way round.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tdslip_ros.model.arrays import HAS_COMMAND, REASON_OF_FAILURE, Array
from tdslip_ros.model.compiled import kernel
from tdslip_ros.model.events import NO_FAILURE_CODE
from tdslip_ros.model.plant.stance_kernel import LaneHopper, LaneTorque
from tdslip_ros.model.plant.stride_kernels import (
    FAILURE_ROW,
    STANCE_TIME_ROW,
    STRIDE_ROWS,
    XDOT_ROW,
    Y_ROW,
    LaneLimits,
    lane_stride,
)
from tdslip_ros.model.policies.controller_kernels import NO_SOLUTION_REASON, solve2, torque_scales


class Newton(NamedTuple):
    """energy_exact's Newton settings (controllers.EXACT_*): the tolerances on the scaled energy and stance
    residuals, the bound on the steps and the forward-difference step."""

    energy_tolerance: float
    stance_tolerance: float
    iterations: int
    jacobian_step: float


@kernel
def exact_regulation_lanes(
    hopper: Array,
    limits: Array,
    y: Array,
    xdot: Array,
    angle: Array,
    goal_bar: Array,
    tau0: Array,
    t_f: Array,
    tolerance: float,
    newton: Newton,
    reason: Array,
) -> None:
    """energy_exact's Newton iteration (:func:`.controllers.exact_energy_regulation`) for every lane, from
    the start (tau0 [N m], t_f [s]) of the lanes whose ``reason`` is HAS_COMMAND: the command into tau0 and
    t_f where it converged, else NaN, and the reason into ``reason``. goal_bar: the goal energy / (m g r0);
    tolerance: the exact map's rtol = atol. The steps and their rounding are those of the numpy version."""
    lane_hopper = LaneHopper(hopper[0], hopper[1], hopper[2], hopper[3], hopper[4])
    lane_limits = LaneLimits(limits[0], limits[1], limits[2], limits[3])
    m, g = lane_hopper.m, lane_hopper.g
    energy_scale = m * g * lane_hopper.r0
    torque_scale, time_scale = torque_scales(m, lane_hopper.k, lane_hopper.r0, g)
    block = np.empty((STRIDE_ROWS, 3))  # the point and its shifts along tau0 and t_f
    energy_residual, stance_residual = np.empty(3), np.empty(3)
    for lane in range(y.size):
        x0, x1 = tau0[lane] / torque_scale, t_f[lane] / time_scale
        solved = False
        for _ in range(newton.iterations if reason[lane] == HAS_COMMAND else 0):
            if not (math.isfinite(x0) and math.isfinite(x1) and x1 > 0.0):
                break
            for point in range(3):
                p0 = x0 + (newton.jacobian_step if point == 1 else 0.0)
                p1 = x1 + (newton.jacobian_step if point == 2 else 0.0)
                ramp = LaneTorque(p0 * torque_scale, p1 * time_scale, math.inf, math.inf)
                lane_stride(
                    lane_hopper,
                    lane_limits,
                    y[lane],
                    xdot[lane],
                    angle[lane],
                    ramp,
                    tolerance,
                    tolerance,
                    block,
                    point,
                )
                energy = m * (g * block[Y_ROW, point] + 0.5 * block[XDOT_ROW, point] ** 2)
                energy_residual[point] = energy / energy_scale - goal_bar[lane]
                stance_residual[point] = block[STANCE_TIME_ROW, point] / time_scale - p1
            failure = int(block[FAILURE_ROW, 0])
            if failure != NO_FAILURE_CODE:
                reason[lane] = REASON_OF_FAILURE[failure]
                break
            if (
                abs(energy_residual[0]) <= newton.energy_tolerance
                and abs(stance_residual[0]) <= newton.stance_tolerance
            ):
                solved = True
                break
            step = newton.jacobian_step
            step0, step1 = solve2(
                (energy_residual[1] - energy_residual[0]) / step,
                (energy_residual[2] - energy_residual[0]) / step,
                (stance_residual[1] - stance_residual[0]) / step,
                (stance_residual[2] - stance_residual[0]) / step,
                energy_residual[0],
                stance_residual[0],
            )
            x0, x1 = x0 + -step0, x1 + -step1
        if not solved and reason[lane] == HAS_COMMAND:
            reason[lane] = NO_SOLUTION_REASON
        has_command = reason[lane] == HAS_COMMAND
        tau0[lane] = x0 * torque_scale if has_command else math.nan
        t_f[lane] = x1 * time_scale if has_command else math.nan
