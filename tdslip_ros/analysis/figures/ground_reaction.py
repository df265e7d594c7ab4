"""fig12 (section IV.D): the ground reaction force (GRF) over one stance of steady running at about 3 m/s and
its virtual footfalls, TD-SLIP under energy regulation beside the lossless SLIP from the same apex.

The paper's fig. 12 has three panels at m = 65.4 kg, r0 = 1 m and about 3 m/s: (a) human running (force-plate
data of Kram et al.), (b) TD-SLIP, (c) SLIP, whose parameters the paper "manually tuned" and does not give.
Panel (a) cannot be reproduced (the data are not in the paper). (b) and (c) come from the model here:

* the hopper: the paper's m = 65.4 kg and r0 = 1 m; kbar = 36 and zeta0 = 0.08 are our choice, the paper's
  hopper of sections III-IV (:mod:`tdslip_ros.model.paper`) at this mass;
* TD-SLIP (left): the exact plant under the ideal energy regulator ``energy_exact``
  (:func:`~tdslip_ros.model.policies.controllers.exact_energy_regulation`, whose ramp ends at the exact
  liftoff: t_f = t_lo, as section II.D assumes) at the touchdown angle BETA_DEG (our choice), at its fixed
  point with the apex speed SPEED: the apex height y* that the regulated stride maps onto itself
  (:func:`regulated_gait`);
* SLIP (right): the same hopper without damping (c = 0) and without hip torque, from the same apex, at the
  touchdown angle that maps that apex onto itself (:func:`symmetric_angle`; its stance is symmetric).

The virtual footfall is where the line through the centre of mass along the GRF meets the ground,
x - y F_x/F_y from the toe (as :func:`tdslip_ros.analysis.plots.com_trajectory` draws it from a recorded run).
The leg's spring and damper push along the leg and the hip torque tau acts across it with moment tau about the
toe, so the footfall lies exactly tau/F_y from the toe: at the toe wherever tau = 0 (the SLIP throughout),
behind it while the ramp pushes forward (tau < 0, the convention of :mod:`tdslip_ros.model.params`). At
liftoff tau and F_y both reach zero (the ramp ends there and the leg force crosses zero), and the footfall
tends to tau'/F_y' (:meth:`Stance.liftoff_footfall`): close to the toe, but not at it.

Everything is computed in the process (a few exact strides and two root searches, about a second).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from tdslip_ros.analysis.figures.common import FigureData, Reporter, Resolution
from tdslip_ros.model import dynamics
from tdslip_ros.model.analytic.apex_map import SpeedSource
from tdslip_ros.model.analytic.closed_loop import eigenvalues
from tdslip_ros.model.arrays import Array
from tdslip_ros.model.events import HopperState
from tdslip_ros.model.paper import PAPER_KBAR, PAPER_ZETA0
from tdslip_ros.model.params import ApexState, HopperParams, StanceCommand
from tdslip_ros.model.plant.batch import batch_apex_return_map
from tdslip_ros.model.plant.exact_map import StrideResult, apex_return_map
from tdslip_ros.model.policies.controllers import (
    admissible_angles,
    energy_regulation,
    exact_energy_regulation,
)
from tdslip_ros.model.stability import exact_fixed_points

MASS, LEG_LENGTH, SPEED = 65.4, 1.0, 3.0
"""The paper's fig. 12: m [kg], r0 [m], and its "approximately 3 m/s" as the apex speed [m/s] exactly."""
BETA_DEG = 17.0
"""TD-SLIP's touchdown angle [deg], our choice (the paper does not give its own). At 3 m/s the regulated fixed
point exists for beta in about [16, 20] deg, its apex rising from 0.98 to 1.23 m; at 17 deg it is 1.02 m."""
STANCE_SAMPLES = 401
"""Samples of a stance, touchdown and liftoff included."""
FLIGHT_SAMPLES = 60
"""Samples of each flight of the stride path (apex to touchdown, liftoff to apex)."""
TOLERANCE = 1e-12
"""rtol = atol of DOP853 for the sampled stance, as the exact map's (its liftoff state agrees to ~1e-11)."""
FORCE_FLOOR = 1e-6
"""F_y [m g] below which a sample has no footfall: F_y is zero at touchdown for the SLIP and at liftoff for
both, where x - y F_x/F_y is 0/0 in rounding (~k 1e-12 m = 2e-8 N); the nearest samples, 0.4 ms away, push
with some 10 N."""
HEIGHT_SCAN = 12
"""Apex heights scanned for the regulated fixed point's bracket, from just above the leg placement limit."""
HEIGHT_SPAN = 0.4
"""Height [r0] of that scan."""
ANGLE_SCAN = 40
"""Touchdown angles scanned for the SLIP's symmetric angle, across the admissible interval."""
LINE_STEP = 16
"""Draw the GRF line of every 16th stance sample (about every 6.5 ms)."""


def fig12_hopper() -> HopperParams:
    """The paper's m = 65.4 kg and r0 = 1 m with the package's kbar = 36 and zeta0 = 0.08."""
    return HopperParams.from_dimensionless(PAPER_KBAR, PAPER_ZETA0, m=MASS, r0=LEG_LENGTH)


def lossless(params: HopperParams) -> HopperParams:
    """The same hopper without damping: the SLIP (run with no hip torque)."""
    return dataclasses.replace(params, c=0.0)


@dataclass(frozen=True)
class Stance:
    """One stance on flat ground from ``apex`` under ``command``, sampled at STANCE_SAMPLES times s [s] from
    touchdown to liftoff: the body relative to the toe (x, y) [m], the hip torque tau [N m] and the GRF
    (fx, fy) [N] on the body (:func:`tdslip_ros.model.dynamics.ground_reaction_force`). ``stride`` is the
    exact map's stride, its event states in the world frame."""

    params: HopperParams
    apex: ApexState
    command: StanceCommand
    stride: StrideResult
    s: Array
    x: Array
    y: Array
    tau: Array
    fx: Array
    fy: Array

    @property
    def touchdown(self) -> HopperState:
        assert self.stride.touchdown is not None
        return self.stride.touchdown

    @property
    def liftoff(self) -> HopperState:
        assert self.stride.liftoff is not None
        return self.stride.liftoff

    @property
    def duration(self) -> float:
        """Touchdown to liftoff [s]."""
        return self.liftoff.t - self.touchdown.t

    def footfall(self) -> Array:
        """The virtual footfall relative to the toe [m], x - y F_x/F_y, where the leg pushes up
        (F_y > FORCE_FLOOR m g); NaN elsewhere."""
        pushing = self.fy > FORCE_FLOOR * self.params.m * self.params.g
        ratio = np.divide(self.fx, self.fy, out=np.full(self.fx.shape, np.nan), where=pushing)
        return np.asarray(self.x - self.y * ratio)

    def liftoff_footfall(self) -> float:
        """The footfall's limit at liftoff [m] when the ramp ends there (t_f = t_lo): tau and F_y both reach
        zero, and tau/F_y tends to tau'/F_y' (L'Hopital), tau' = -tau0/t_f and
        F_y' = f' cos(theta) - (tau'/r) sin(theta) with the leg force's rate f' = -k rdot - c rddot (the leg
        force itself is zero, so rddot = r thetadot^2 - g cos(theta)). 0 without torque."""
        if self.command.tau0 == 0.0:
            return 0.0
        params, state = self.params, self.liftoff
        tau_rate = -self.command.tau0 / self.command.t_f
        rddot = state.r * state.thetadot**2 - params.g * math.cos(state.theta)
        force_rate = -params.k * state.rdot - params.c * rddot
        fy_rate = force_rate * math.cos(state.theta) - tau_rate / state.r * math.sin(state.theta)
        return tau_rate / fy_rate

    def stride_path(self) -> tuple[Array, Array]:
        """The centre of mass relative to the toe [m] from the apex to the next one: the flights in closed
        form, the stance as sampled."""
        g, touchdown, liftoff = self.params.g, self.touchdown, self.liftoff
        toe = touchdown.toe_x
        fall = np.linspace(0.0, touchdown.t, FLIGHT_SAMPLES)[:-1]  # the apex is at x = 0, t = 0
        rise = np.linspace(0.0, liftoff.ydot / g, FLIGHT_SAMPLES)[1:]
        x = np.concatenate([self.apex.xdot * fall - toe, self.x, liftoff.x - toe + liftoff.xdot * rise])
        y = np.concatenate(
            [self.apex.y - 0.5 * g * fall**2, self.y, liftoff.y + liftoff.ydot * rise - 0.5 * g * rise**2]
        )
        return x, y


def sample_stance(params: HopperParams, apex: ApexState, command: StanceCommand) -> Stance:
    """The stance of the exact map's stride from ``apex`` under ``command`` (ValueError if the stride fails),
    integrated again from its touchdown state with dense output (eq. 2 as :mod:`.dynamics` states it, split at
    the ramp's end) up to the exact map's liftoff time."""
    stride = apex_return_map(params, apex, command, rtol=TOLERANCE, atol=TOLERANCE)
    if stride.apex is None or stride.touchdown is None or stride.liftoff is None:
        raise ValueError(f"the stride from {apex} under {command} fails: {stride.failure}: {stride.reason}")
    touchdown = stride.touchdown
    duration = stride.liftoff.t - touchdown.t
    s = np.linspace(0.0, duration, STANCE_SAMPLES)

    def rhs(time: float, state: Array) -> list[float]:
        r, theta, rdot, thetadot = (float(value) for value in state)
        tau = dynamics.ramp_torque(command.tau0, command.t_f, time)
        accelerations = dynamics.stance_accelerations(
            params, r, math.sin(theta), math.cos(theta), rdot, thetadot, tau
        )
        return [rdot, thetadot, *accelerations]

    # The ramp's end is a kink: integrate either side of it (not where it ends at liftoff, to rounding).
    kinks = [command.t_f] if command.t_f < duration * (1.0 - 1e-9) else []
    states = np.empty((4, s.size))
    start_state = np.array([touchdown.r, touchdown.theta, touchdown.rdot, touchdown.thetadot])
    for start, stop in pairwise([0.0, *kinks, duration]):
        solution = solve_ivp(
            rhs,
            (start, stop),
            start_state,
            method="DOP853",
            rtol=TOLERANCE,
            atol=TOLERANCE,
            dense_output=True,
        )
        inside = (s >= start) & (s <= stop)
        states[:, inside] = solution.sol(s[inside])
        start_state = solution.y[:, -1]
    r, theta, rdot, _ = states
    sin_t, cos_t = np.sin(theta), np.cos(theta)
    tau = np.asarray(dynamics.ramp_torque(command.tau0, command.t_f, s), dtype=float)
    fx, fy = dynamics.ground_reaction_force(params, r, sin_t, cos_t, rdot, tau)
    return Stance(params, apex, command, stride, s, -r * sin_t, r * cos_t, tau, fx, fy)


def regulated_gait(params: HopperParams, speed: float, beta: float) -> tuple[ApexState, StanceCommand]:
    """The apex (y*, speed) that the exact plant under energy_exact at touchdown angle beta [rad] maps onto
    itself, and its command. energy_exact keeps the apex energy (to 1e-11 m g r0), so y' = y means xdot' =
    xdot: a root of h(y) = y'(y) - y at the given speed, the first fall of h from + to - on HEIGHT_SCAN
    heights above the leg placement limit (a stable crossing, dy'/dy < 1), polished by Brent's method.
    ValueError where there is none."""
    low = params.r0 * math.cos(beta) + 2.0 * dynamics.placement_clearance(params.g)
    heights = np.linspace(low, low + HEIGHT_SPAN * params.r0, HEIGHT_SCAN)
    plan = exact_energy_regulation(params, heights, speed, beta)
    stride = batch_apex_return_map(
        params, heights, speed, plan.touchdown_angle, plan.tau0, plan.t_f, rtol=TOLERANCE, atol=TOLERANCE
    )
    h = stride.y - heights
    falls = np.flatnonzero((h[:-1] > 0.0) & (h[1:] <= 0.0))
    if falls.size == 0:
        raise ValueError(f"no regulated fixed point at {speed} m/s, beta = {math.degrees(beta):.4g} deg")

    def section(y: float) -> float:
        command = exact_energy_regulation(params, y, speed, beta).command()
        following = apex_return_map(params, ApexState(y, speed), command, rtol=TOLERANCE, atol=TOLERANCE)
        assert following.apex is not None, following.reason
        return following.apex.y - y

    y_star = float(brentq(section, heights[falls[0]], heights[falls[0] + 1], xtol=1e-13))
    return ApexState(y_star, speed), exact_energy_regulation(params, y_star, speed, beta).command()


def regulated_eigenvalue(params: HopperParams, apex: ApexState, beta: float) -> complex:
    """The largest eigenvalue of the energy_exact loop at its fixed point ``apex``
    (exact_fixed_points.jacobian; the other is 0, the regulator putting the goal energy back every stride)."""
    energy = apex.energy(params)
    loop = exact_fixed_points.ExactLoop.of(params, beta, "energy_exact", [energy])
    return complex(eigenvalues(exact_fixed_points.jacobian(loop, apex.y, energy, 0))[0, 0])


def symmetric_angle(params: HopperParams, apex: ApexState) -> float:
    """The touchdown angle [rad] at which the hopper ``params`` without hip torque maps ``apex`` onto itself:
    for the lossless SLIP the energy is kept, so y' = y means xdot' = xdot (and the stance is symmetric,
    theta_lo = -theta_td). The sign change of y' - y on ANGLE_SCAN admissible angles, polished by Brent's
    method; ValueError where there is none."""
    lower, upper = admissible_angles(params, apex.y)
    angles = np.linspace(max(float(lower), 1e-3), float(upper), ANGLE_SCAN)
    stride = batch_apex_return_map(
        params, apex.y, apex.xdot, angles, 0.0, 1.0, rtol=TOLERANCE, atol=TOLERANCE
    )
    h = stride.y - apex.y
    changes = np.flatnonzero(np.isfinite(h[:-1]) & np.isfinite(h[1:]) & (np.sign(h[:-1]) != np.sign(h[1:])))
    if changes.size == 0:
        raise ValueError(f"no touchdown angle maps {apex} onto itself")

    def section(angle: float) -> float:
        command = StanceCommand(angle, 0.0, 1.0)
        following = apex_return_map(params, apex, command, rtol=TOLERANCE, atol=TOLERANCE)
        assert following.apex is not None, following.reason
        return following.apex.y - apex.y

    return float(brentq(section, angles[changes[0]], angles[changes[0] + 1], xtol=1e-14))


def _peak(stance: Stance, index: int) -> dict[str, float]:
    return {
        "grf_x_N": float(stance.fx[index]),
        "t_s": float(stance.s[index]),
        "stance_ratio": float(stance.s[index] / stance.duration),
    }


def stance_json(stance: Stance) -> dict[str, Any]:
    """The numbers drawn of one stance, and what fig. 12's claims rest on."""
    footfall = stance.footfall()
    path_x, path_y = stance.stride_path()
    liftoff = stance.liftoff
    return {
        "apex": {"y_m": stance.apex.y, "xdot_m_per_s": stance.apex.xdot},
        "next_apex": (
            None
            if stance.stride.apex is None
            else {"y_m": stance.stride.apex.y, "xdot_m_per_s": stance.stride.apex.xdot}
        ),
        "touchdown_angle_deg": math.degrees(stance.command.touchdown_angle),
        "liftoff_angle_deg": math.degrees(liftoff.theta),
        "tau0_N_m": stance.command.tau0,
        "t_f_s": stance.command.t_f if stance.command.tau0 != 0.0 else None,  # no ramp: no t_f
        "stance_time_s": stance.duration,
        "peak_braking": _peak(stance, int(np.argmin(stance.fx))),
        "peak_propulsive": _peak(stance, int(np.argmax(stance.fx))),
        "peak_grf_y_N": float(np.max(stance.fy)),
        "footfall_at_touchdown_m": float(footfall[0]),
        "footfall_at_liftoff_m": stance.liftoff_footfall(),
        "largest_footfall_offset_m": float(np.nanmax(np.abs(footfall))),
        "samples": {
            "t_s": stance.s.tolist(),
            "x_m": stance.x.tolist(),
            "y_m": stance.y.tolist(),
            "hip_torque_N_m": stance.tau.tolist(),
            "grf_x_N": stance.fx.tolist(),
            "grf_y_N": stance.fy.tolist(),
            "footfall_m": footfall.tolist(),
        },
        "stride_path": {"x_m": path_x.tolist(), "y_m": path_y.tolist()},
    }


def _draw(axes: Array, stance: Stance, title: str) -> None:
    """One column: the stride path with the GRF lines down to the virtual footfalls, F_x, F_y and the
    footfall over stance time."""
    path, fx_axes, fy_axes, footfall_axes = axes
    footfall = stance.footfall()
    drawn = np.flatnonzero(np.isfinite(footfall))[::LINE_STEP]
    for i in drawn:
        path.plot([stance.x[i], footfall[i]], [stance.y[i], 0.0], color="tab:green", lw=0.8, alpha=0.8)
    path.plot(footfall[drawn], np.zeros(drawn.size), "|", color="tab:green", ms=8, label="virtual footfalls")
    path.plot(*stance.stride_path(), color="black", lw=1.5, label="centre of mass")
    path.plot([0.0], [0.0], "^", color="tab:red", ms=9, label="toe")
    path.axhline(0.0, color="grey", lw=1)
    path.set(xlabel="x - x_toe [m]", ylabel="y [m]", title=title, aspect="equal", ylim=(-0.05, 1.35))
    path.legend(fontsize=7, loc="upper center", ncol=3, handlelength=1.0, columnspacing=0.8)
    t_ms = 1e3 * stance.s
    braking = int(np.argmin(stance.fx))
    fx_axes.plot(t_ms, stance.fx, color="tab:blue")
    fx_axes.plot(t_ms[braking], stance.fx[braking], "o", color="tab:blue", mfc="none", label="peak braking")
    fx_axes.axhline(0.0, color="grey", lw=1)
    fx_axes.set(ylabel="F_x [N]")
    fx_axes.legend(fontsize=7)
    fy_axes.plot(t_ms, stance.fy, color="tab:blue")
    fy_axes.set(ylabel="F_y [N]")
    footfall_axes.plot(t_ms, footfall, color="tab:green", label="x_vf - x_toe")
    footfall_axes.plot(
        t_ms[-1], stance.liftoff_footfall(), "o", color="tab:green", mfc="none", label="limit at liftoff"
    )
    footfall_axes.axhline(0.0, color="tab:red", lw=1, label="toe")
    footfall_axes.set(xlabel="time since touchdown [ms]", ylabel="virtual footfall [m]")
    footfall_axes.legend(fontsize=7)


def fig12(resolution: Resolution, reporter: Reporter, speed: SpeedSource) -> FigureData:
    """TD-SLIP (energy_exact, BETA_DEG) and the lossless SLIP from the same apex at SPEED: GRF and virtual
    footfalls over one stance (the sampling does not depend on ``resolution``; the gait is the exact plant's
    and planned on the exact map, so the analytic map's ``speed`` does not enter)."""
    params, beta = fig12_hopper(), math.radians(BETA_DEG)
    reporter.stage(f"TD-SLIP: the energy_exact fixed point at {SPEED} m/s, beta = {BETA_DEG} deg")
    apex, command = regulated_gait(params, SPEED, beta)
    td_slip = sample_stance(params, apex, command)
    reporter.stage("SLIP: the symmetric touchdown angle from the same apex")
    slip_params = lossless(params)
    slip = sample_stance(slip_params, apex, StanceCommand(symmetric_angle(slip_params, apex), 0.0, 1.0))
    # The paper's regulator (planned on the analytic map) at the same apex: where its ramp ends.
    plan = energy_regulation(params, apex.y, apex.xdot, beta).command()
    planned = apex_return_map(params, apex, plan, rtol=TOLERANCE, atol=TOLERANCE)
    assert planned.liftoff is not None and planned.touchdown is not None, planned.reason
    planned_stance = planned.liftoff.t - planned.touchdown.t

    figure = Figure(figsize=(11, 14))
    columns = figure.subplots(4, 2, sharey="row", height_ratios=(1.8, 1, 1, 1)).T
    _draw(columns[0], td_slip, f"(b) TD-SLIP, energy_exact, beta = {BETA_DEG:g} deg")
    slip_angle = math.degrees(slip.command.touchdown_angle)
    _draw(columns[1], slip, f"(c) lossless SLIP, symmetric, beta = {slip_angle:.2f} deg")

    eigenvalue = regulated_eigenvalue(params, apex, beta)
    footfall = td_slip.footfall()
    pushing = np.isfinite(footfall)
    second_half = td_slip.s >= 0.5 * td_slip.duration
    data: dict[str, Any] = {
        # Replaces the catalogue's "params" (the 80 kg hopper of the other figures): fig. 12's hopper.
        "params": {
            "kbar": params.kbar,
            "zeta0": params.zeta0,
            "m": params.m,
            "r0": params.r0,
            "g": params.g,
            "k_N_per_m": params.k,
            "c_N_s_per_m": params.c,
        },
        "paper_gave": {"m_kg": MASS, "r0_m": LEG_LENGTH, "speed": "approximately 3 m/s"},
        "our_choice": {
            "kbar": PAPER_KBAR,
            "zeta0": PAPER_ZETA0,
            "apex_speed_m_per_s": SPEED,
            "td_slip_touchdown_angle_deg": BETA_DEG,
            "td_slip_regulator": "energy_exact (t_f = the exact liftoff)",
            "slip": "c = 0, no hip torque, the same apex, the touchdown angle that maps it onto itself",
        },
        "note": (
            "The paper's panel (a), human running from the force-plate data of Kram et al., cannot be "
            "reproduced: the data are not in the paper. The paper tuned the TD-SLIP and SLIP parameters by "
            "hand and does not give them; kbar, zeta0, beta and the exact speed here are ours. Lengths are "
            "relative to the toe; the virtual footfall is x - y F_x/F_y (where F_y > 1e-6 m g), which equals "
            "tau/F_y. With t_f = t_lo it tends to tau'/F_y' at liftoff (footfall_at_liftoff_m), not to 0."
        ),
        "td_slip": stance_json(td_slip)
        | {"eigenvalue": [eigenvalue.real, eigenvalue.imag], "spectral_radius": abs(eigenvalue)},
        "slip": stance_json(slip),
        "paper_regulator_at_this_apex": {
            "tau0_N_m": plan.tau0,
            "t_f_s": plan.t_f,
            "stance_time_s": planned_stance,
            "ramp_end_after_liftoff_s": plan.t_f - planned_stance,
            "hip_torque_at_liftoff_N_m": float(dynamics.ramp_torque(plan.tau0, plan.t_f, planned_stance)),
        },
        "measured": {
            "td_slip_footfalls_behind_toe": bool(np.all(footfall[pushing] < 0.0)),
            "td_slip_braking_peak_in_first_half": bool(np.argmin(td_slip.fx) < np.argmax(second_half)),
            "td_slip_braking_over_propulsive_peak_ratio": float(
                -np.min(td_slip.fx) / np.max(td_slip.fx[second_half])
            ),
            "td_slip_over_slip_braking_peak_ratio": float(np.min(td_slip.fx) / np.min(slip.fx)),
            "td_slip_footfall_liftoff_over_touchdown_ratio": td_slip.liftoff_footfall() / float(footfall[0]),
            "slip_largest_footfall_offset_m": float(np.nanmax(np.abs(slip.footfall()))),
            "slip_grf_x_antisymmetry_N": float(np.max(np.abs(slip.fx + slip.fx[::-1]))),
        },
    }
    return figure, data
