"""Fixed points of the analytic apex return map and their stability (paper sections III and IV).

Open loop (section III). theta_td = beta and tau0 = C/thetadot_td, alpha = C/(m g sqrt(g r0)) (eq. 26),
t_f = the predicted liftoff time (:func:`~tdslip_ros.model.policies.controllers.fixed_power`). The map is 2-D
in (y, E) (eq. 23). Following the paper, for each apex height y the energy fixed point E*(y) solves
E' (y, E*) = E* (eq. 27; the energy map is unimodal, so there is one sign change of E' - E along E); the
fixed points of the whole map are then the zeros of the 1-D section h(y) = y'(y, E*(y)) - y (eq. 28).
Zeros are bracketed on a grid of heights and polished by Newton's method on the 2-D map, whose Jacobian
(complex step, :func:`~tdslip_ros.model.analytic.apex_map.map_jacobian`) also gives the eigenvalues. Tracing
over alpha counts the fixed points; where the count changes by two, a saddle-node bifurcation is located by
bisection in alpha (one eigenvalue passes through 1 there).

Energy regulation (section IV). theta_td = beta and tau0 with E_tau = E_loss (eq. 32,
:func:`~tdslip_ros.model.policies.controllers.energy_regulation`), so the analytic map keeps the apex energy
exactly and reduces to the 1-D apex-height map y -> y'(y; E) for each energy. Its fixed points are zeros
of y' - y on a grid of heights in (r0 cos beta, E/(m g)), polished by bracketed Newton; the eigenvalue is
dy'/dy (complex step). Heights below r0 cos(beta) are kinematically infeasible: the leg cannot be placed.

Everything is SI; the dimensionless numbers of the paper come from :mod:`tdslip_ros.model.units`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.analytic.apex_map import LiftoffMethod, SpeedSource
from tdslip_ros.model.analytic.closed_loop import (
    COMPLEX_STEP,
    Policy,
    closed_loop_map,
    eigenvalues,
    map_jacobian,
)
from tdslip_ros.model.arrays import Array, ArrayLike
from tdslip_ros.model.dynamics import speed_from_energy
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.policies.controllers import energy_regulation, fixed_power

ENERGY_SCAN = np.geomspace(0.005, 14.0, 30)
"""Dimensionless kinetic apex energies Ebar - ybar scanned to bracket the energy fixed point E*(y)
(geometric: slow high hops have E* just above m g y)."""
ROOT_TOLERANCE = 1e-12
"""Relative tolerance of the polished fixed points (height and energy)."""
ROOT_ITERATIONS = 60
EDGE_BISECTIONS = 14
"""Bisections towards the edge of a section's domain from the grid height next to it (section_brackets)."""
SADDLE_NODE_BISECTIONS = 14
"""Bisection steps in alpha per saddle-node bifurcation (the bracket shrinks by 2^-14)."""


@dataclass(frozen=True)
class FixedPoints:
    """Fixed points for each value of a parameter, ordered by apex height and padded with NaN.

    parameter: (n,) the traced value (alpha, or the apex energy [J]); y [m], xdot [m/s], energy [J]:
    (n, k); eigenvalues: (n, k, d) of the return map at each fixed point (d = 2 for the open-loop (y, E)
    map, 1 for the energy-regulated height map), largest modulus first.
    """

    parameter: Array
    y: Array
    xdot: Array
    energy: Array
    eigenvalues: Array

    @property
    def spectral_radius(self) -> Array:
        """Largest eigenvalue modulus per fixed point (NaN where there is none)."""
        return np.asarray(np.abs(self.eigenvalues[..., 0]))

    @property
    def stable(self) -> Array:
        """Asymptotically stable: every eigenvalue inside the unit circle."""
        with np.errstate(invalid="ignore"):
            return np.asarray(self.spectral_radius < 1.0)

    @property
    def count(self) -> Array:
        """Number of fixed points per parameter value."""
        return np.asarray(np.sum(np.isfinite(self.y), axis=-1))


def open_loop_policy(params: HopperParams, beta: float, alpha: ArrayLike) -> Policy:
    """The open-loop stance policy of section III: fixed touchdown angle beta [rad] and power alpha."""
    alpha_ = np.asarray(alpha, dtype=float)
    return lambda arrays, y, xdot: fixed_power(params, y, xdot, beta, alpha_)


def regulated_policy(params: HopperParams, beta: float) -> Policy:
    """The energy-regulating stance policy of section IV.A at the fixed touchdown angle beta [rad]."""
    return lambda arrays, y, xdot: energy_regulation(arrays, y, xdot, beta)


def _bracketed_newton(
    function: Callable[[Array, Array], tuple[Array, Array]], lower: Array, upper: Array, lower_value: Array
) -> Array:
    """Root per lane (1-D arrays) of a function that changes sign on [lower, upper]; NaN lanes stay NaN.

    ``function(x, lanes)`` returns the value and the derivative at x for the lanes with those indices.
    Newton steps, replaced by bisection where a step would leave the shrinking bracket or the value is not
    finite (a failed evaluation shrinks the bracket from above); a lane stops at ROOT_TOLERANCE relative,
    and only the lanes still going are evaluated. Lanes not solved in ROOT_ITERATIONS steps get NaN.
    """
    lower, upper = np.array(lower, dtype=float), np.array(upper, dtype=float)
    lower_sign = np.sign(lower_value)
    x = 0.5 * (lower + upper)
    solved = np.zeros(x.shape, dtype=bool)
    active = np.flatnonzero(np.isfinite(x))
    with np.errstate(invalid="ignore", divide="ignore"):
        for _ in range(ROOT_ITERATIONS):
            if active.size == 0:
                break
            here = x[active]
            value, slope = function(here, active)
            below = np.sign(value) == lower_sign[active]
            lower[active] = np.where(below, here, lower[active])
            upper[active] = np.where(below, upper[active], here)
            newton = here - value / slope
            inside = np.isfinite(newton) & (newton > lower[active]) & (newton < upper[active])
            step = np.where(inside, newton, 0.5 * (lower[active] + upper[active])) - here
            done = (value == 0.0) | (np.abs(step) <= ROOT_TOLERANCE * np.abs(here))
            x[active] = np.where(done, here, here + step)
            solved[active[done]] = np.isfinite(value[done])
            active = active[~done]
    return np.where(solved, x, np.nan)


def _sign_changes(values: Array) -> Array:
    """Mask (..., n - 1) of grid intervals where finite values change sign."""
    finite = np.isfinite(values[..., :-1]) & np.isfinite(values[..., 1:])
    return np.asarray(finite & (np.sign(values[..., :-1]) != np.sign(values[..., 1:])))


def _complex_step(
    function: Callable[[Array, Array], Array],
) -> Callable[[Array, Array], tuple[Array, Array]]:
    """(value, derivative) of a complex-step safe function(x, lanes) of a real array."""

    def evaluate(x: Array, lanes: Array) -> tuple[Array, Array]:
        value = function(x + 1j * COMPLEX_STEP, lanes)
        return np.real(value), np.imag(value) / COMPLEX_STEP

    return evaluate


# --- Open loop (section III) -----------------------------------------------------------------------------


def open_loop_energy_map(
    params: HopperParams,
    beta: float,
    alpha: ArrayLike,
    y: ArrayLike,
    energy: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> tuple[Array, Array]:
    """The open-loop (y, E) map (eq. 23): next apex height [m] and energy [J], NaN where the stride fails."""
    with np.errstate(invalid="ignore", over="ignore"):  # failing lanes
        stride = closed_loop_map(
            params,
            y,
            energy,
            open_loop_policy(params, beta, alpha),
            "energy",
            corrections,
            liftoff,
            speed=speed,
        )
    return stride.y, stride.energy


def energy_fixed_point(
    params: HopperParams,
    beta: float,
    alpha: ArrayLike,
    y: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> Array:
    """E*(y) [J] of eq. 27 for broadcast arrays of alpha and apex heights y [m]; NaN where none exists.

    The sign change of E'(y, E) - E from + to - along E is bracketed on ENERGY_SCAN and polished by
    bracketed Newton (dE'/dE by complex step).
    """
    alpha_, y_ = (
        a.ravel() for a in np.broadcast_arrays(np.asarray(alpha, dtype=float), np.asarray(y, dtype=float))
    )
    shape = np.broadcast_shapes(np.shape(alpha), np.shape(y))
    scale = units.energy_scale(params)
    energies = (units.height_to_bar(params, y_)[..., None] + ENERGY_SCAN) * scale
    with np.errstate(invalid="ignore"):
        scanned = open_loop_energy_map(
            params, beta, alpha_[..., None], y_[..., None], energies, corrections, liftoff, speed=speed
        )
        gain = scanned[1] - energies
    falling = _sign_changes(gain) & (gain[..., :-1] > 0.0)
    index = np.argmax(falling, axis=-1)[..., None]
    found = np.any(falling, axis=-1)
    lower = np.where(found, np.take_along_axis(energies, index, axis=-1)[..., 0], np.nan)
    upper = np.take_along_axis(energies, index + 1, axis=-1)[..., 0]

    def residual(energy: Array, lanes: Array) -> Array:
        return (
            open_loop_energy_map(
                params, beta, alpha_[lanes], y_[lanes], energy, corrections, liftoff, speed=speed
            )[1]
            - energy
        )

    return _bracketed_newton(_complex_step(residual), lower, upper, np.ones_like(lower)).reshape(shape)


EQ27_SCAN = np.geomspace(1e-3, 30.0, 200)
"""Dimensionless kinetic apex energies Ebar - ybar on which :func:`energy_fixed_point_count` counts the
solutions of eq. 27 (denser and wider than ENERGY_SCAN)."""


def energy_fixed_point_count(
    params: HopperParams,
    beta: float,
    alpha: ArrayLike,
    y: ArrayLike,
    scan: ArrayLike = EQ27_SCAN,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> tuple[Array, Array]:
    """How many solutions E* eq. 27 has for broadcast arrays of alpha and apex heights y [m]: the sign changes
    of E'(y, E) - E, either way, between neighbours of the kinetic energies ``scan`` (Ebar - ybar) where the
    map has a stride (:func:`energy_fixed_point` polishes the first from + to -). Also returns, per (alpha,
    y), the sign of E' - E at the highest energy with a stride (+1: the map fails before E' falls to E)."""
    alpha_, y_ = np.broadcast_arrays(np.asarray(alpha, dtype=float), np.asarray(y, dtype=float))
    energies = (units.height_to_bar(params, y_)[..., None] + np.asarray(scan)) * units.energy_scale(params)
    with np.errstate(invalid="ignore"):
        _, next_energy = open_loop_energy_map(
            params, beta, alpha_[..., None], y_[..., None], energies, corrections, liftoff, speed=speed
        )
    gain = next_energy - energies
    finite = np.isfinite(gain)
    last = np.take_along_axis(
        gain, (finite.shape[-1] - 1 - np.argmax(finite[..., ::-1], axis=-1))[..., None], -1
    )
    return np.sum(_sign_changes(gain), axis=-1), np.where(finite.any(axis=-1), np.sign(last[..., 0]), np.nan)


def height_section(
    params: HopperParams,
    beta: float,
    alpha: ArrayLike,
    y: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> tuple[Array, Array]:
    """The 1-D section of eq. 28: (E*(y) [J], y'(y, E*(y)) [m]) for broadcast alpha and y [m]."""
    energy = energy_fixed_point(params, beta, alpha, y, corrections, liftoff, speed=speed)
    with np.errstate(invalid="ignore"):
        y_next, _ = open_loop_energy_map(params, beta, alpha, y, energy, corrections, liftoff, speed=speed)
    return energy, y_next


def height_grid(params: HopperParams, beta: float, top: float = 2.8, points: int = 120) -> Array:
    """Apex heights [m] from the lowest that places the leg at beta (:func:`lowest_height`) to ``top`` r0
    (the scans' default)."""
    return np.linspace(lowest_height(params, beta), units.height_from_bar(params, top), points)


def open_loop_fixed_points(
    params: HopperParams,
    beta: float,
    alpha: ArrayLike,
    heights: ArrayLike | None = None,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> FixedPoints:
    """All fixed points of the open-loop map for each alpha of a 1-D array (eq. 28), with eigenvalues.

    Zeros of h(y) on ``heights`` (default :func:`height_grid`) are polished by Newton on the 2-D map from
    the interpolated bracket and kept if they stay inside it; two zeros closer than the grid spacing are
    missed (only next to a saddle-node).
    """
    alpha_ = np.atleast_1d(np.asarray(alpha, dtype=float))
    heights_ = height_grid(params, beta) if heights is None else np.asarray(heights, dtype=float)
    energy, y_next = height_section(
        params, beta, alpha_[:, None], heights_[None, :], corrections, liftoff, speed=speed
    )
    section = y_next - heights_
    changes = _sign_changes(section)
    rows, columns = np.nonzero(changes)
    # Start each polish at the linear interpolation of the bracket (the zero of the secant of h).
    h0, h1 = section[rows, columns], section[rows, columns + 1]
    weight = h0 / (h0 - h1)
    y0 = heights_[columns] + weight * (heights_[columns + 1] - heights_[columns])
    e0 = energy[rows, columns] + weight * (energy[rows, columns + 1] - energy[rows, columns])
    policy = open_loop_policy(params, beta, alpha_[rows])
    y_star, e_star, jacobian = _newton_fixed_point(params, policy, y0, e0, corrections, liftoff, speed=speed)
    inside = (y_star >= heights_[columns]) & (y_star <= heights_[columns + 1])
    values = eigenvalues(jacobian[inside])
    return padded_fixed_points(params, alpha_, rows[inside], y_star[inside], e_star[inside], values)


def _newton_fixed_point(
    params: HopperParams,
    policy: Policy,
    y: Array,
    energy: Array,
    corrections: int,
    liftoff: LiftoffMethod,
    speed: SpeedSource,
) -> tuple[Array, Array, Array]:
    """Newton's method on P(y, E) - (y, E) = 0 per lane; returns y*, E* and the Jacobian of P there."""
    jacobian = np.full((*np.shape(y), 2, 2), np.nan)
    converged = np.zeros(np.shape(y), dtype=bool)
    with np.errstate(invalid="ignore"):
        for _ in range(ROOT_ITERATIONS):
            stride = closed_loop_map(params, y, energy, policy, "energy", corrections, liftoff, speed=speed)
            jacobian = map_jacobian(params, y, energy, policy, "energy", corrections, liftoff, speed=speed)
            residual = np.stack([stride.y - y, stride.energy - energy], axis=-1)
            step = np.linalg.solve(jacobian - np.eye(2), -residual[..., None])[..., 0]
            step = np.where(np.isfinite(step), step, np.nan)
            converged = (np.abs(step[..., 0]) <= ROOT_TOLERANCE * np.abs(y)) & (
                np.abs(step[..., 1]) <= ROOT_TOLERANCE * np.abs(energy)
            )
            y, energy = y + step[..., 0], energy + step[..., 1]
            if np.all(converged | ~np.isfinite(y)):
                break
    return np.where(converged, y, np.nan), np.where(converged, energy, np.nan), jacobian


def padded_fixed_points(
    params: HopperParams, parameter: Array, rows: Array, y: Array, energy: Array, values: Array
) -> FixedPoints:
    """FixedPoints from flat lists of (row, y, E, eigenvalues), padded to the largest count per row."""
    rows, y, energy, values = (np.asarray(v) for v in (rows, y, energy, values))
    order = np.lexsort((y, rows))
    rows, y, energy, values = rows[order], y[order], energy[order], values[order]
    counts = np.bincount(rows, minlength=parameter.size)
    width = max(int(counts.max(initial=0)), 1)
    slot = np.arange(rows.size) - np.repeat(np.cumsum(counts) - counts, counts)
    shape = (parameter.size, width)
    padded_y, padded_energy = np.full(shape, np.nan), np.full(shape, np.nan)
    padded_values = np.full((*shape, values.shape[-1]), np.nan + 0j)
    padded_y[rows, slot], padded_energy[rows, slot] = y, energy
    padded_values[rows, slot] = values
    return FixedPoints(
        parameter=parameter,
        y=padded_y,
        xdot=speed_from_energy(params, padded_y, padded_energy),
        energy=padded_energy,
        eigenvalues=padded_values,
    )


def saddle_nodes(
    params: HopperParams,
    beta: float,
    traced: FixedPoints,
    heights: ArrayLike | None = None,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> Array:
    """Alphas of the saddle-node bifurcations along a trace (where the fixed-point count changes by 2).

    Each bracket between neighbouring traced alphas is bisected SADDLE_NODE_BISECTIONS times on the count
    of zeros of the height section (eq. 28) on ``heights``; returns the midpoints of the final brackets,
    sorted.
    """
    heights_ = height_grid(params, beta) if heights is None else np.asarray(heights, dtype=float)
    counts = traced.count
    jumps = np.flatnonzero(np.abs(np.diff(counts)) == 2)
    lower, upper = traced.parameter[jumps], traced.parameter[jumps + 1]
    lower_count = counts[jumps]
    for _ in range(SADDLE_NODE_BISECTIONS):
        if lower.size == 0:
            break
        middle = 0.5 * (lower + upper)
        _, y_next = height_section(params, beta, middle[:, None], heights_, corrections, liftoff, speed=speed)
        count = np.sum(_sign_changes(y_next - heights_), axis=-1)
        same = count == lower_count
        lower, upper = np.where(same, middle, lower), np.where(same, upper, middle)
    return np.sort(0.5 * (lower + upper))


# --- Energy regulation (section IV) ----------------------------------------------------------------------


def regulated_height_map(
    params: HopperParams,
    beta: float,
    energy: ArrayLike,
    y: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> Array:
    """The energy-regulated 1-D map y -> y'(y; E) [m] for broadcast energies [J] and heights [m]; NaN on
    failure (including heights below r0 cos beta, where the leg cannot be placed)."""
    with np.errstate(invalid="ignore"):
        stride = closed_loop_map(
            params, y, energy, regulated_policy(params, beta), "energy", corrections, liftoff, speed=speed
        )
    return stride.y


def infeasible_height(params: HopperParams, beta: float) -> float:
    """Apex heights below this [m], r0 cos(beta), are kinematically infeasible: the leg cannot be placed."""
    return float(params.r0 * np.cos(beta))


def lowest_height(params: HopperParams, beta: float) -> float:
    """The lowest apex height [m] from which the policies place the leg at beta: r0 cos(beta) plus the fall
    of dynamics.PLACEMENT_LEAD_TIME (0.12 mm), and a rounding margin."""
    return (infeasible_height(params, beta) + dynamics.placement_clearance(params.g)) * (1.0 + 1e-12)


def regulated_fixed_points(
    params: HopperParams,
    beta: float,
    energy: ArrayLike,
    points: int = 160,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> FixedPoints:
    """Fixed points of the energy-regulated height map for each apex energy [J] of a 1-D array.

    Zeros of y' - y are bracketed on ``points`` heights spread over [r0 cos beta, E/(m g)) per energy and
    up to the edges of the map's domain (:func:`section_brackets`), and polished by bracketed Newton; the
    eigenvalue is dy'/dy there (complex step).
    """
    energy_ = np.atleast_1d(np.asarray(energy, dtype=float))
    bottom = lowest_height(params, beta)
    top = energy_ / (params.m * params.g)
    # Denser towards the bottom, where the fixed points of high energies crowd; E/(m g) itself has xdot = 0.
    heights = bottom + np.linspace(0.0, 1.0, points + 1)[:-1] ** 2 * (top - bottom)[:, None]
    gap = (
        regulated_height_map(params, beta, energy_[:, None], heights, corrections, liftoff, speed=speed)
        - heights
    )

    def section(y: Array, rows: Array) -> Array:
        return regulated_height_map(params, beta, energy_[rows], y, corrections, liftoff, speed=speed) - y

    rows, low, high = section_brackets(section, heights, gap)
    lanes_energy = energy_[rows]

    def residual(y: Array, lanes: Array) -> Array:
        return section(y, rows[lanes])

    evaluate = _complex_step(residual)
    y_star = _bracketed_newton(evaluate, low, high, section(low, rows))
    _, slope = evaluate(y_star, np.arange(y_star.size))
    keep = np.isfinite(y_star)
    return padded_fixed_points(
        params, energy_, rows[keep], y_star[keep], lanes_energy[keep], (slope[keep] + 1.0)[:, None] + 0j
    )


def section_brackets(
    section: Callable[[Array, Array], Array], heights: Array, values: Array
) -> tuple[Array, Array, Array]:
    """Brackets (row, low, high) of the zeros of a 1-D section h, evaluated as ``values`` (rows, k) on
    ``heights`` ((rows, k) or (k,)): every sign change between neighbours, and every one between a grid
    height and the edge of h's domain next to it (NaN beyond: the policy has no command or the map fails,
    e.g. above y_max(E), where the leg swings back), the edge found by EDGE_BISECTIONS bisections with
    ``section(y, rows)`` (vectorised). Without the edges, a fixed point between the last grid height and
    the edge is missed, and a stable range ends early by up to a grid step."""
    heights = np.broadcast_to(heights, values.shape)
    finite = np.isfinite(values)
    rows, columns = np.nonzero(_sign_changes(values))
    edge_rows, edge_columns = np.nonzero(finite[:, :-1] != finite[:, 1:])
    inner = np.where(finite[edge_rows, edge_columns], edge_columns, edge_columns + 1)  # the finite end
    outer = np.where(finite[edge_rows, edge_columns], edge_columns + 1, edge_columns)
    start, start_value = heights[edge_rows, inner], values[edge_rows, inner]
    near, far, near_value = start.copy(), heights[edge_rows, outer].copy(), start_value.copy()
    for _ in range(EDGE_BISECTIONS if edge_rows.size else 0):
        middle = 0.5 * (near + far)
        value = np.real(section(middle, edge_rows))
        inside = np.isfinite(value)
        near, near_value = np.where(inside, middle, near), np.where(inside, value, near_value)
        far = np.where(inside, far, middle)
    crossing = np.sign(near_value) != np.sign(start_value)
    ends = np.sort(np.stack([start, near]), axis=0)
    return (
        np.concatenate([rows, edge_rows[crossing]]),
        np.concatenate([heights[rows, columns], ends[0, crossing]]),
        np.concatenate([heights[rows, columns + 1], ends[1, crossing]]),
    )


def longest_run_range(
    grid: ArrayLike, holds: Callable[[Array], Array], bisections: int
) -> tuple[float, float]:
    """Ends of the longest run of a sorted grid where ``holds`` (vectorised: values -> bools) is true,
    each end bisected ``bisections`` times against its outer neighbour (both ends at once); (NaN, NaN)
    if it holds nowhere. An end at the edge of the grid stays there."""
    grid_ = np.sort(np.asarray(grid, dtype=float))
    true = np.asarray(holds(grid_), dtype=bool)
    if not true.any():
        return float("nan"), float("nan")
    edges = np.diff(np.concatenate([[0], true.astype(int), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    longest = int(np.argmax(stops - starts))
    first, last = int(starts[longest]), int(stops[longest])
    inside = np.array([grid_[first], grid_[last]])
    outside = np.array([grid_[max(first - 1, 0)], grid_[min(last + 1, grid_.size - 1)]])
    for _ in range(bisections):
        middle = 0.5 * (inside + outside)
        still = np.asarray(holds(middle), dtype=bool)
        inside, outside = np.where(still, middle, inside), np.where(still, outside, middle)
    return float(inside[0]), float(inside[1])


def stable_energy_range(
    params: HopperParams,
    beta: float,
    energies: ArrayLike,
    bisections: int = 12,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> tuple[float, float]:
    """The energy interval [J] with a stable fixed point of the regulated height map: the longest run of
    ``energies`` with one, its ends refined by bisection (:func:`longest_run_range`)."""

    def has_stable(energy: Array) -> Array:
        points = regulated_fixed_points(
            params, beta, energy, corrections=corrections, liftoff=liftoff, speed=speed
        )
        return np.asarray(np.any(points.stable, axis=-1))

    return longest_run_range(energies, has_stable, bisections)
