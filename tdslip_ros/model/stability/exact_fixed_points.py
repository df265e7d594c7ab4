"""Fixed points of the exact plant's closed-loop apex return map and their eigenvalues (issue 10).

The analytic map's fixed points (:mod:`tdslip_ros.model.stability.analytic_fixed_points`) say what the paper's
approximation predicts; this module says what the exact plant does, by the same construction on the exact map
(the batched engine's DOP853 stride, compiled lane by lane:
:func:`~tdslip_ros.model.plant.stride_kernels.compiled_apex_return_map`), so that every stability verdict on
the exact plant comes from a fixed point and its eigenvalue, not from a stride horizon:

* the closed loop (:class:`ExactLoop`): a stance policy at the fixed touchdown angle beta answers each apex
  (y, E) and the exact plant hops the stride, P(y, E) = (y', E'). A loop is a family of such maps, one per
  member value: the touchdown power alpha (``open_loop``, section III, t_f the analytic map's predicted
  liftoff, as the paper; or ``open_loop_stance_tf``, t_f the stance duration the plant produces), or the goal
  energy [J] of an energy regulator (``energy``: the torque planned on the analytic map, section IV.B;
  ``energy_exact``: planned on the exact map,
  :func:`~tdslip_ros.model.policies.controllers.exact_energy_regulation`, which keeps E' = goal exactly, so
  that the loop is the exact counterpart of the analytic regulated map);
* for each height y the energy fixed point E*(y) of E'(y, E) = E (eq. 27), bracketed (for the open loop on
  the energies of stability.ENERGY_SCAN, for a regulator within ENERGY_BRACKET of its goal) and solved by
  the Illinois method; the section h(y) = y'(y, E*(y)) - y (eq. 28) on a grid of heights; its sign
  changes polished by the Illinois method to ROOT_TOLERANCE;
* at each fixed point the 2x2 Jacobian of P by central differences (steps JACOBIAN_STEP r0 and m g r0,
  the policy planning again at every shifted apex) and its eigenvalues; stable means every modulus < 1.

The exact map is deterministic and accurate to ~1e-12, so the differences resolve eigenvalues to ~1e-5.
Stride horizons (:mod:`tdslip_ros.model.stability.basins`) remain the figures' basins and a cross-check.
:func:`exists_on_exact_plant` pairs the analytic map's fixed points with the exact plant's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from tdslip_ros.model import units
from tdslip_ros.model.analytic.closed_loop import eigenvalues
from tdslip_ros.model.arrays import Array, ArrayLike, CommandArrays
from tdslip_ros.model.dynamics import speed_from_energy
from tdslip_ros.model.events import NO_FAILURE_CODE
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.plant.batch import BatchStrideResult
from tdslip_ros.model.plant.stride_kernels import compiled_apex_return_map
from tdslip_ros.model.policies.controllers import energy_regulation, exact_energy_regulation, fixed_power
from tdslip_ros.model.stability.analytic_fixed_points import (
    EDGE_BISECTIONS,
    ENERGY_SCAN,
    FixedPoints,
    height_grid,
    longest_run_range,
    padded_fixed_points,
    section_brackets,
)

Regulator = Literal["open_loop", "open_loop_stance_tf", "energy", "energy_exact"]
EXACT_TOLERANCE = 1e-12
"""rtol = atol of the exact plant's DOP853 in these studies."""
ENERGY_BRACKET = 0.1
"""A regulator's energy fixed point is bracketed within +-10 % of its goal (its error on the exact plant is
below 1 %; energy_exact's is zero)."""
ROOT_TOLERANCE = 1e-11
"""Relative tolerance of the Illinois solves (energy, height)."""
ROOT_ITERATIONS = 60
JACOBIAN_STEP = 1e-6
"""Central-difference step of the Jacobian, in r0 (height) and m g r0 (energy)."""
STANCE_TF_ITERATIONS = 10
"""Bound on the secant steps of ``open_loop_stance_tf``'s t_f = stance duration(t_f) (4-5 suffice)."""


@dataclass(frozen=True)
class ExactLoop:
    """The closed-loop exact plant of one regulator at touchdown angle beta [rad], one member per value
    (alpha, or the goal energy [J]); ``members`` index ``values`` per lane in every method."""

    params: HopperParams
    beta: float
    regulator: Regulator
    values: Array

    @classmethod
    def of(cls, params: HopperParams, beta: float, regulator: Regulator, values: ArrayLike) -> ExactLoop:
        return cls(params, beta, regulator, np.atleast_1d(np.asarray(values, dtype=float)))

    def commands(self, y: Array, xdot: Array, members: Array) -> CommandArrays:
        """The policy's commands at apexes (y, xdot) for the given members (NaN where it has none)."""
        value = self.values[members]
        if self.regulator == "energy":
            return energy_regulation(self.params, y, xdot, self.beta, value)
        if self.regulator == "energy_exact":
            return exact_energy_regulation(self.params, y, xdot, self.beta, value)
        command = fixed_power(self.params, y, xdot, self.beta, value)
        if self.regulator == "open_loop":
            return command
        return CommandArrays(command.touchdown_angle, command.tau0, self._stance_duration(y, xdot, command))

    def _stance_duration(self, y: Array, xdot: Array, command: CommandArrays) -> Array:
        """t_f = the stance duration the exact plant produces with the ramp (tau0, t_f): the secant method on
        stance(t_f) - t_f from the analytic t_f and one plain step (the ramp's end barely moves the liftoff:
        the plain iteration alone contracts by only 0.02-0.05); NaN where the stance fails or does not
        settle to ROOT_TOLERANCE in STANCE_TF_ITERATIONS."""
        t_f = np.array(command.t_f)
        previous, previous_gap = np.full(t_f.shape, np.nan), np.full(t_f.shape, np.nan)
        moving = np.isfinite(t_f)
        for _ in range(STANCE_TF_ITERATIONS):
            if not moving.any():
                break
            angle, tau0 = command.touchdown_angle[moving], command.tau0[moving]
            gap = self._exact(y[moving], xdot[moving], angle, tau0, t_f[moving]).stance_time - t_f[moving]
            settled = np.abs(gap) <= ROOT_TOLERANCE * t_f[moving]
            with np.errstate(invalid="ignore", divide="ignore"):
                secant = t_f[moving] - gap * (t_f[moving] - previous[moving]) / (gap - previous_gap[moving])
            step = np.where(np.isfinite(secant), secant, t_f[moving] + gap)
            previous[moving], previous_gap[moving] = t_f[moving], gap
            t_f[moving] = np.where(settled, t_f[moving], step)
            moving[moving] = ~settled & np.isfinite(gap)
        return np.where(moving | ~np.isfinite(previous_gap), np.nan, t_f)

    def _exact(self, y: Array, xdot: Array, angle: Array, tau0: Array, t_f: Array) -> BatchStrideResult:
        return compiled_apex_return_map(
            self.params, y, xdot, angle, tau0, t_f, rtol=EXACT_TOLERANCE, atol=EXACT_TOLERANCE
        )

    def step(self, y: ArrayLike, energy: ArrayLike, members: ArrayLike) -> tuple[Array, Array]:
        """Next apex (y' [m], E' [J]) on the exact plant from apexes (y, E) of the members (1-d arrays,
        broadcast); NaN where the policy has no command or the plant fails."""
        y_, energy_, members_ = (np.ravel(a) for a in np.broadcast_arrays(y, energy, members))
        xdot = speed_from_energy(self.params, y_, energy_)
        y_next, energy_next = np.full(y_.shape, np.nan), np.full(y_.shape, np.nan)
        lanes = np.flatnonzero(np.isfinite(xdot) & (xdot > 0.0))
        if lanes.size == 0:
            return y_next, energy_next
        command = self.commands(y_[lanes], xdot[lanes], members_[lanes])
        planned = np.all(np.isfinite(np.stack(list(command))), axis=0)
        hop = lanes[planned]
        if hop.size:
            stride = self._exact(y_[hop], xdot[hop], *(np.asarray(field)[planned] for field in command))
            ok = stride.failure == NO_FAILURE_CODE
            y_next[hop[ok]] = stride.y[ok]
            energy_next[hop[ok]] = self.params.m * (self.params.g * stride.y[ok] + 0.5 * stride.xdot[ok] ** 2)
        return y_next, energy_next

    def forward_energy(self, y: Array) -> Array:
        """The lowest apex energy [J] at height y from which the leg placed at beta swings forward: at it the
        touchdown has thetadot = 0 (xdot cos(beta) = |ydot| sin(beta)), E = m g (y + (y - r0 cos beta)
        tan^2 beta); at height y it is the energy whose y_max(E) is y."""
        params = self.params
        drop = y - params.r0 * np.cos(self.beta)
        return np.asarray(params.m * params.g * (y + drop * np.tan(self.beta) ** 2))

    def energy_bracket(self, y: Array, members: Array) -> tuple[Array, Array]:
        """Energies [J] that bracket E*(y): for a regulator, the goal +-ENERGY_BRACKET, but not below the
        lowest energy from which the leg swings forward at this height (:meth:`forward_energy`); for the open
        loop, the first fall of E' - E from + to - over stability.ENERGY_SCAN (NaN where there is none)."""
        if self.regulator in ("energy", "energy_exact"):
            goal = self.values[members]
            low = np.maximum(goal * (1.0 - ENERGY_BRACKET), self.forward_energy(y) * (1.0 + ROOT_TOLERANCE))
            return low, goal * (1.0 + ENERGY_BRACKET)
        scale = units.energy_scale(self.params)
        energies = (units.height_to_bar(self.params, y)[:, None] + ENERGY_SCAN) * scale
        rows = np.broadcast_to(np.arange(y.size)[:, None], energies.shape)
        _, mapped = self.step(np.broadcast_to(y[:, None], energies.shape), energies, members[rows])
        gain = mapped.reshape(energies.shape) - energies
        falling = (
            np.isfinite(gain[:, :-1]) & np.isfinite(gain[:, 1:]) & (gain[:, :-1] > 0.0) & (gain[:, 1:] <= 0.0)
        )
        index = np.argmax(falling, axis=1)[:, None]
        found = np.any(falling, axis=1)
        low = np.where(found, np.take_along_axis(energies, index, axis=1)[:, 0], np.nan)
        return low, np.take_along_axis(energies, index + 1, axis=1)[:, 0]


def _illinois(
    function: Callable[[Array, Array], Array], low: Array, high: Array, tolerance: float = ROOT_TOLERANCE
) -> Array:
    """Roots per lane of ``function(x, lanes)`` (evaluated for the lanes still open) that changes sign on
    [low, high] (1-d arrays); the Illinois variant of regula falsi. An end where the function fails (outside
    its domain, such as an apex above y_max(E)) is first moved towards the other by up to EDGE_BISECTIONS
    bisections. NaN where there is no sign change, the function fails inside, or ROOT_ITERATIONS do not
    reach ``tolerance`` (relative)."""
    low, high = np.array(low, dtype=float), np.array(high, dtype=float)
    lanes = np.arange(low.size)
    f_low = np.full(low.size, np.nan)
    f_high = np.full(low.size, np.nan)
    ends = np.flatnonzero(np.isfinite(low) & np.isfinite(high))
    if ends.size:
        f_low[ends] = function(low[ends], lanes[ends])
        f_high[ends] = function(high[ends], lanes[ends])
    # Where one end fails and the other does not, move the failing end to the edge of the domain: bisect
    # between the last failing point and the finite point nearest to it.
    for end, value, other, other_value in ((low, f_low, high, f_high), (high, f_high, low, f_low)):
        failing = np.flatnonzero(np.isfinite(end) & ~np.isfinite(value) & np.isfinite(other_value))
        far, near, near_value = end[failing], other[failing], other_value[failing]
        for _ in range(EDGE_BISECTIONS if failing.size else 0):
            middle = 0.5 * (far + near)
            middle_value = function(middle, lanes[failing])
            inside = np.isfinite(middle_value)
            near, near_value = np.where(inside, middle, near), np.where(inside, middle_value, near_value)
            far = np.where(inside, far, middle)
        end[failing], value[failing] = near, near_value
    root = np.full(low.size, np.nan)
    active = np.flatnonzero(np.isfinite(f_low) & np.isfinite(f_high) & (np.sign(f_low) != np.sign(f_high)))
    exact_end = np.flatnonzero(f_low == 0.0)
    root[exact_end] = low[exact_end]
    active = np.setdiff1d(active, exact_end)
    side = np.zeros(low.size)  # +1: the last two steps kept the low end, -1: the high end
    previous = np.full(low.size, np.nan)
    for _ in range(ROOT_ITERATIONS):
        if active.size == 0:
            break
        a, b, fa, fb = low[active], high[active], f_low[active], f_high[active]
        x = b - fb * (b - a) / (fb - fa)
        fx = function(x, lanes[active])
        failed = ~np.isfinite(fx)
        settled = np.abs(x - previous[active]) <= tolerance * np.abs(x)
        done = ~failed & ((fx == 0.0) | settled | (np.abs(b - a) <= tolerance * np.abs(x)))
        root[active[done]] = x[done]
        previous[active] = x
        towards_low = np.sign(fx) == np.sign(fa)  # the root lies in [x, b]
        new_low, new_high = np.where(towards_low, x, a), np.where(towards_low, b, x)
        new_fa, new_fb = np.where(towards_low, fx, fa), np.where(towards_low, fb, fx)
        # Illinois: an end kept twice in a row has its value halved (superlinear, never stalls).
        kept = np.where(towards_low, -1.0, 1.0)
        repeat = kept == side[active]
        new_fb = np.where(repeat & towards_low, 0.5 * new_fb, new_fb)
        new_fa = np.where(repeat & ~towards_low, 0.5 * new_fa, new_fa)
        side[active] = kept
        low[active], high[active], f_low[active], f_high[active] = new_low, new_high, new_fa, new_fb
        active = active[~done & ~failed]
    return root


def energy_fixed_points(loop: ExactLoop, y: ArrayLike, members: ArrayLike) -> Array:
    """E*(y) [J] of eq. 27 on the exact plant, per lane of broadcast heights [m] and members."""
    y_, members_ = (np.ravel(a) for a in np.broadcast_arrays(np.asarray(y, dtype=float), members))
    if loop.regulator == "energy_exact":  # E' = goal by construction (controllers.EXACT_ENERGY_TOLERANCE)
        return np.where(
            np.isfinite(loop.step(y_, loop.values[members_], members_)[1]), loop.values[members_], np.nan
        )
    low, high = loop.energy_bracket(y_, members_)

    def gain(energy: Array, lanes: Array) -> Array:
        return loop.step(y_[lanes], energy, members_[lanes])[1] - energy

    return _illinois(gain, low, high)


def height_section(loop: ExactLoop, y: ArrayLike, members: ArrayLike) -> tuple[Array, Array]:
    """(E*(y) [J], h(y) = y'(y, E*(y)) - y [m]) of eq. 28 on the exact plant, flat over broadcast lanes."""
    y_, members_ = (np.ravel(a) for a in np.broadcast_arrays(np.asarray(y, dtype=float), members))
    energy = energy_fixed_points(loop, y_, members_)
    y_next, _ = loop.step(y_, energy, members_)
    return energy, y_next - y_


def jacobian(loop: ExactLoop, y: ArrayLike, energy: ArrayLike, members: ArrayLike) -> Array:
    """Jacobians d(y', E')/d(y, E) of the exact closed loop, shape (n, 2, 2), by central differences."""
    y_, energy_, members_ = (np.ravel(a) for a in np.broadcast_arrays(y, energy, members))
    steps = JACOBIAN_STEP * np.array([units.length_scale(loop.params), units.energy_scale(loop.params)])
    shifts = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]]) * steps  # (4, 2)
    points_y = (y_[None, :] + shifts[:, :1]).ravel()
    points_energy = (energy_[None, :] + shifts[:, 1:]).ravel()
    y_next, energy_next = loop.step(points_y, points_energy, np.tile(members_, 4))
    mapped = np.stack([y_next, energy_next], axis=-1).reshape(4, y_.size, 2)
    columns = [(mapped[0] - mapped[1]) / (2 * steps[0]), (mapped[2] - mapped[3]) / (2 * steps[1])]
    return np.stack(columns, axis=-1)


def fixed_points(loop: ExactLoop, heights: ArrayLike | None = None) -> FixedPoints:
    """All fixed points of the exact closed loop per member (zeros of h on ``heights``, default
    stability.height_grid, and up to the edges of h's domain; two closer than the grid spacing are
    missed), with the eigenvalues of P."""
    heights_ = (
        height_grid(loop.params, loop.beta, points=60) if heights is None else np.asarray(heights, float)
    )
    count = loop.values.size
    _, section = height_section(loop, np.tile(heights_, count), np.repeat(np.arange(count), heights_.size))
    section = section.reshape(count, heights_.size)

    def h(y: Array, members: Array) -> Array:
        return height_section(loop, y, members)[1]

    rows, low, high = section_brackets(h, heights_, section)

    y_star = _illinois(lambda y, lanes: h(y, rows[lanes]), low, high)
    energy_star, _ = height_section(loop, y_star, rows)
    keep = np.isfinite(y_star) & np.isfinite(energy_star)
    values = eigenvalues(jacobian(loop, y_star[keep], energy_star[keep], rows[keep]))
    return padded_fixed_points(loop.params, loop.values, rows[keep], y_star[keep], energy_star[keep], values)


def stable_energy_range(
    params: HopperParams,
    beta: float,
    regulator: Regulator,
    energies: ArrayLike,
    bisections: int = 8,
    heights: ArrayLike | None = None,
) -> tuple[float, float]:
    """Goal energies [J] with a stable fixed point of the regulated exact plant: the longest run of
    ``energies`` with one, its ends bisected (stability.longest_run_range)."""

    def has_stable(goals: Array) -> Array:
        return np.asarray(
            np.any(fixed_points(ExactLoop.of(params, beta, regulator, goals), heights).stable, axis=1)
        )

    return longest_run_range(energies, has_stable, bisections)


def exists_on_exact_plant(analytic: FixedPoints, exact: FixedPoints) -> Array:
    """Per analytic fixed point (the shape of analytic.y): whether the exact plant has it. It does where
    it and an exact fixed point of the same member are each other's nearest in height: the two maps have
    as many fixed points as such pairs, and an analytic fixed point left without a partner is an artifact
    of the approximation (how far a partner lies shows the map's error in locating it). False where there
    is no analytic fixed point."""
    exists = np.zeros(analytic.y.shape, dtype=bool)
    for row in range(analytic.y.shape[0]):
        present = np.flatnonzero(np.isfinite(analytic.y[row]))
        found = exact.y[row][np.isfinite(exact.y[row])]
        if present.size == 0 or found.size == 0:
            continue
        distance = np.abs(analytic.y[row, present][:, None] - found[None, :])
        nearest_exact = np.argmin(distance, axis=1)
        exists[row, present] = np.argmin(distance, axis=0)[nearest_exact] == np.arange(present.size)
    return exists
