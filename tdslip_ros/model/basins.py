"""Exact-plant studies with the batched engine: basins of attraction and fixed points reached (figs 7, 10).

Every lane of a grid of initial apex states hops on the exact plant
(:func:`~tdslip_ros.model.batch.batch_apex_return_map`, DOP853 at EXACT_TOLERANCE) under a stance policy
that the analytic map plans, stride by stride, until it fails or the strides run out. Outcomes:

* ``converged``: every apex change from some stride n on is below CONVERGENCE_TOLERANCE in the
  dimensionless apex coordinates (ybar, xdotbar); n is the convergence stride and the last apex the fixed
  point reached (the definition the recorded-run analysis uses too);
* ``sustained``: no failure, but not converged in the strides given;
* a failure of the exact plant by kind (:class:`~tdslip_ros.model.events.FailureKind`), the stride it
  happened in, or ``no_command`` where the policy found no command for the apex (its map predicts a
  failure, say); an apex too low to place the leg at the policy's angle (below the touchdown height, or
  within :data:`~tdslip_ros.model.dynamics.PLACEMENT_LEAD_TIME` of fall above it: the policy's
  ``leg_placement``) counts as ``toe_stubbing``, as the exact plant would report it;
* ``impossible``: an initial energy below m g y (no real forward speed).

The regulators are the paper's: open loop (section III, fixed beta and touchdown power alpha, eq. 26)
and, for the exact plant, energy regulation that takes the energy of the first stride as its goal
(section IV.B): each stride's torque aims the analytic map's next apex energy at that goal rather than at
the current apex energy, so that the map's errors do not accumulate from stride to stride.

A horizon says what happens within its strides: a slow but stable fixed point (|lambda| near 1) looks
``sustained``. Stability verdicts come from the fixed points and their eigenvalues
(:mod:`tdslip_ros.model.exact_stability`); the basins are figures and the cross-check.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.analytic import speed_from_energy
from tdslip_ros.model.arrays import Array, ArrayLike, CommandArrays, NoCommand, no_command_code
from tdslip_ros.model.batch import batch_apex_return_map
from tdslip_ros.model.controllers import energy_regulation, fixed_power
from tdslip_ros.model.events import FAILURE_KINDS, NO_FAILURE_CODE, FailureKind
from tdslip_ros.model.params import HopperParams

CONVERGENCE_TOLERANCE = 1e-4
"""Apex change (max of |d ybar|, |d xdotbar|) below which a lane counts as settled (the paper's 1e-4)."""
REGULATED_STRIDES = 50
OPEN_LOOP_STRIDES = 150
EXACT_TOLERANCE = 1e-10
"""rtol = atol of the exact plant's DOP853: apex errors ~1e-10, far below the tolerance judged."""

OUTCOMES: tuple[str, ...] = (
    "converged",
    "sustained",
    *(kind.value for kind in FAILURE_KINDS),
    "no_command",
    "impossible",
)
"""Outcome names; a lane's outcome is an index into this tuple."""
CONVERGED, SUSTAINED = 0, 1
NO_COMMAND, IMPOSSIBLE = OUTCOMES.index("no_command"), OUTCOMES.index("impossible")
_FAILURE_OFFSET = 2  # OUTCOMES index of FAILURE_KINDS[0]
_LEG_PLACEMENT = no_command_code(NoCommand.LEG_PLACEMENT)

StancePolicy = Callable[[int, Array, Array, Array], CommandArrays]
"""policy(stride, y, xdot, lanes) -> commands for the lanes still hopping (``lanes``: their flat indices
into the grid); NaN fields where the policy has no command."""
Progress = Callable[[int, int], None]
"""progress(strides done, strides in all), called after every stride."""


def failure_outcome(kind: FailureKind) -> int:
    """The OUTCOMES index of a failure kind of the exact plant."""
    return _FAILURE_OFFSET + FAILURE_KINDS.index(kind)


@dataclass(frozen=True)
class StrideHistory:
    """Apex states of every lane, row k the apex after k strides (NaN after a failure), shape (n + 1, *grid);
    outcome per lane (index into OUTCOMES; ``sustained`` for every lane that did not fail) and the stride
    a lane failed in (-1 for none)."""

    y: Array
    xdot: Array
    outcome: Array
    failure_stride: Array


def run_strides(
    params: HopperParams,
    y0: ArrayLike,
    xdot0: ArrayLike,
    policy: StancePolicy,
    strides: int,
    progress: Progress | None = None,
) -> StrideHistory:
    """Hop every lane of the (y0 [m], xdot0 [m/s]) grid on the exact plant for ``strides`` strides.

    Lanes with a NaN initial state start as ``impossible``.
    """
    y_start, xdot_start = np.broadcast_arrays(np.asarray(y0, dtype=float), np.asarray(xdot0, dtype=float))
    shape = y_start.shape
    y = np.full((strides + 1, y_start.size), np.nan)
    xdot = np.full_like(y, np.nan)
    y[0], xdot[0] = y_start.ravel(), xdot_start.ravel()
    outcome = np.where(np.isfinite(y[0]) & np.isfinite(xdot[0]), SUSTAINED, IMPOSSIBLE)
    failure_stride = np.full(y_start.size, -1)
    alive = np.flatnonzero(outcome == SUSTAINED)
    for stride in range(strides):
        if alive.size:
            command = policy(stride, y[stride, alive], xdot[stride, alive], alive)
            angle, tau0, t_f = (np.broadcast_to(field, alive.shape) for field in command)
            with np.errstate(invalid="ignore"):
                placed = ~(y[stride, alive] < dynamics.touchdown_height(params, np.cos(angle)))
            if command.no_command is not None:
                placed &= np.broadcast_to(command.no_command, alive.shape) != _LEG_PLACEMENT
            planned = placed & np.isfinite(angle) & np.isfinite(tau0) & np.isfinite(t_f)
            lanes = alive[planned]
            step = batch_apex_return_map(
                params,
                y[stride, lanes],
                xdot[stride, lanes],
                angle[planned],
                tau0[planned],
                t_f[planned],
                rtol=EXACT_TOLERANCE,
                atol=EXACT_TOLERANCE,
            )
            y[stride + 1, lanes], xdot[stride + 1, lanes] = step.y, step.xdot
            failed = np.full(alive.shape, NO_COMMAND)
            failed[~placed] = failure_outcome(FailureKind.TOE_STUBBING)
            failed[planned] = np.where(
                step.failure == NO_FAILURE_CODE, SUSTAINED, _FAILURE_OFFSET + step.failure
            )
            outcome[alive] = failed
            failure_stride[alive[failed != SUSTAINED]] = stride
            alive = alive[failed == SUSTAINED]
        if progress is not None:
            progress(stride + 1, strides)
    return StrideHistory(
        y=y.reshape(strides + 1, *shape),
        xdot=xdot.reshape(strides + 1, *shape),
        outcome=outcome.reshape(shape),
        failure_stride=failure_stride.reshape(shape),
    )


@dataclass(frozen=True)
class Basin:
    """Outcome of a grid of initial apex states (arrays of the grid's shape).

    y0 [m], energy0 [J]: the initial apexes; outcome: index into OUTCOMES; convergence_stride: the first
    stride n from which every apex change is below CONVERGENCE_TOLERANCE (-1 where not converged);
    y, xdot [m, m/s], energy [J]: the fixed point reached (the last apex) where converged, else NaN;
    history: every apex.
    """

    y0: Array
    energy0: Array
    outcome: Array
    convergence_stride: Array
    y: Array
    xdot: Array
    energy: Array
    history: StrideHistory


def settle(params: HopperParams, history: StrideHistory) -> tuple[Array, Array]:
    """Per lane: converged (bool) and the convergence stride (-1 where not converged).

    Changes are measured in (ybar, xdotbar); a lane that failed never converges.
    """
    y_bar = units.height_to_bar(params, history.y)
    xdot_bar = units.speed_to_bar(params, history.xdot)
    with np.errstate(invalid="ignore"):
        change = np.maximum(np.abs(np.diff(y_bar, axis=0)), np.abs(np.diff(xdot_bar, axis=0)))
        large = ~(change < CONVERGENCE_TOLERANCE)  # NaN (failed) counts as large
    strides = change.shape[0]
    # Index of the last large change + 1: the stride from which every change is small.
    last_large = strides - 1 - np.argmax(large[::-1], axis=0)
    start = np.where(large.any(axis=0), last_large + 1, 0)
    converged = (start < strides) & (history.outcome == SUSTAINED)
    return converged, np.where(converged, start, -1)


def basin(
    params: HopperParams,
    y0: ArrayLike,
    energy0: ArrayLike,
    policy: StancePolicy,
    strides: int,
    progress: Progress | None = None,
) -> Basin:
    """Hop a grid of initial (y0 [m], E0 [J]) under ``policy`` and classify every lane."""
    y_start, energy_start = np.broadcast_arrays(np.asarray(y0, dtype=float), np.asarray(energy0, dtype=float))
    history = run_strides(
        params, y_start, speed_from_energy(params, y_start, energy_start), policy, strides, progress
    )
    converged, start = settle(params, history)
    outcome = np.where(converged, CONVERGED, history.outcome)
    last_y, last_xdot = history.y[-1], history.xdot[-1]
    y = np.where(converged, last_y, np.nan)
    xdot = np.where(converged, last_xdot, np.nan)
    return Basin(
        y0=y_start,
        energy0=energy_start,
        outcome=outcome,
        convergence_stride=start,
        y=y,
        xdot=xdot,
        energy=params.m * (params.g * y + 0.5 * xdot**2),
        history=history,
    )


def goal_energy_regulator(params: HopperParams, beta: float, goal_energy: ArrayLike) -> StancePolicy:
    """The paper's exact-plant energy regulator: theta_td = beta [rad] and the torque that brings the
    analytic map's next apex energy to each lane's goal [J] (the energy of its first stride), t_f = t_lo.

    ``goal_energy`` holds one goal per lane of the grid (flat order) or a single goal for all lanes.
    """
    goal = np.ravel(np.asarray(goal_energy, dtype=float))

    def policy(stride: int, y: Array, xdot: Array, lanes: Array) -> CommandArrays:
        return energy_regulation(params, y, xdot, beta, target_energy=goal[lanes % goal.size])

    return policy


def open_loop_regulator(params: HopperParams, beta: float, alpha: ArrayLike) -> StancePolicy:
    """Section III's open loop: theta_td = beta [rad], touchdown power alpha (eq. 26), one alpha per lane of
    the grid (flat order) or a single one for all lanes."""
    alpha_ = np.ravel(np.asarray(alpha, dtype=float))

    def policy(stride: int, y: Array, xdot: Array, lanes: Array) -> CommandArrays:
        return fixed_power(params, y, xdot, beta, alpha_[lanes % alpha_.size])

    return policy


def regulated_basin(
    params: HopperParams,
    beta: float,
    y0: ArrayLike,
    energy0: ArrayLike,
    strides: int = REGULATED_STRIDES,
    progress: Progress | None = None,
) -> Basin:
    """Basin of the energy-regulated exact plant (fig. 10): each lane's goal is its initial energy."""
    y_start, energy_start = np.broadcast_arrays(np.asarray(y0, dtype=float), np.asarray(energy0, dtype=float))
    policy = goal_energy_regulator(params, beta, energy_start)
    return basin(params, y_start, energy_start, policy, strides, progress)


def open_loop_basin(
    params: HopperParams,
    beta: float,
    alpha: ArrayLike,
    y0: ArrayLike,
    energy0: ArrayLike,
    strides: int = OPEN_LOOP_STRIDES,
    progress: Progress | None = None,
) -> Basin:
    """Basin of the open-loop exact plant (fig. 7) for broadcast arrays of alpha and initial (y0, E0)."""
    alpha_, y_start, energy_start = np.broadcast_arrays(
        np.asarray(alpha, dtype=float), np.asarray(y0, dtype=float), np.asarray(energy0, dtype=float)
    )
    policy = open_loop_regulator(params, beta, alpha_)
    return basin(params, y_start, energy_start, policy, strides, progress)


def exact_regulated_fixed_points(
    params: HopperParams,
    beta: float,
    energies: ArrayLike,
    heights: ArrayLike,
    strides: int = REGULATED_STRIDES,
    progress: Progress | None = None,
) -> Basin:
    """The fixed points the energy-regulated exact plant reaches within ``strides``: a basin over the grid
    (energies [J]) x (heights [m]), whose converged lanes give, per goal energy, the fixed point(s) reached.
    A horizon verdict: the stability verdict itself comes from the fixed points and their eigenvalues
    (:mod:`tdslip_ros.model.exact_stability`)."""
    energy_grid, height_grid = np.meshgrid(
        np.asarray(energies, float), np.asarray(heights, float), indexing="ij"
    )
    return regulated_basin(params, beta, height_grid, energy_grid, strides, progress)
