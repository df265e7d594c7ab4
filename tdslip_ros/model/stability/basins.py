"""Exact-plant studies with the batched engine: basins of attraction and fixed points reached (figs 7, 10).

Every lane of a grid of initial apex states hops on the exact plant
(:func:`~tdslip_ros.model.plant.batch.batch_apex_return_map`, DOP853 at EXACT_TOLERANCE) under a stance policy
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

Under stance feedback (:mod:`~tdslip_ros.model.plant.stance_laws`: a hip torque a sampled law decides during
stance, as ref. 36's baseline of fig. 13 does) the lanes hop on
:func:`~tdslip_ros.model.plant.batch.simulate_strides` at a fixed touchdown angle per lane
(:func:`feedback_basin`), classified alike; :func:`speed_matching_angle` is a rule for that angle.

A horizon says what happens within its strides: a slow but stable fixed point (|lambda| near 1) looks
``sustained``. Stability verdicts come from the fixed points and their eigenvalues
(:mod:`tdslip_ros.model.stability.exact_fixed_points`); the basins are figures and the cross-check.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tdslip_ros.model import dynamics, units
from tdslip_ros.model.arrays import Array, ArrayLike, CommandArrays, NoCommand, no_command_code
from tdslip_ros.model.dynamics import speed_from_energy
from tdslip_ros.model.events import FAILURE_KINDS, NO_FAILURE_CODE, FailureKind
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.plant.batch import batch_apex_return_map, batch_feedback_return_map, simulate_strides
from tdslip_ros.model.plant.stance_laws import DEFAULT_SAMPLE_PERIOD, StanceLaw
from tdslip_ros.model.policies.controllers import energy_regulation, fixed_power

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
LawOf = Callable[[npt.NDArray[np.int64]], StanceLaw]
"""law_of(index) -> the stance law of the lanes ``index`` (flat indices), its per-lane fields over them."""

SPEED_ANGLE_SCAN = np.radians(np.arange(1.0, 60.0, 1.0))
"""rad: the touchdown angles :func:`speed_matching_angle` brackets its angle with (1 to 59 deg by 1 deg)."""
SPEED_ANGLE_BISECTIONS = 12
"""Bisections of that 1 deg bracket: to 2.4e-4 deg, which moves the next speed by some 1e-6 relative."""
SPEED_MATCH_TOLERANCE = 1e-3
"""Relative error of the next speed at the angle found. The next speed jumps where the touchdown's phase in
the 1 ms tick moves with the angle (the law's apexes jitter by some 5e-5 m, :mod:`.stance_laws`), so the
bisection may end on such a jump rather than a root; a failure inside the bracket would leave it far off."""


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
    t: Array | None = None
    """Apex times [s] on the sample clock of stance feedback, like y (None for ramps, which need none)."""


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
    return _classified(params, y_start, energy_start, history)


def _classified(params: HopperParams, y_start: Array, energy_start: Array, history: StrideHistory) -> Basin:
    """The Basin of the runs ``history`` from (y_start [m], energy_start [J])."""
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


def speed_matching_angle(
    params: HopperParams,
    target_y: ArrayLike,
    target_xdot: ArrayLike,
    law_of: LawOf,
    sample_period: float = DEFAULT_SAMPLE_PERIOD,
) -> Array:
    """Per target apex (target_y [m], target_xdot [m/s], 1-D arrays): the touchdown angle [rad] at which one
    stride from the target apex itself, its hip under stance feedback by ``law_of``, ends at the target
    speed; NaN where there is none.

    A stance law that regulates energy and speed through the hip torque (ref. 36's baseline,
    :class:`~.stance_pd.StancePDSpeedEnergy`) leaves the touchdown angle to its designer, and the angle
    decides how the law's energy splits between height and speed. This one makes the target apex a fixed
    point of one stride in speed, a calibration from the target alone, not from the closed loop. The next
    speed falls as the angle grows (the leg brakes over a longer sweep), so each target's bracket is the first
    pair of neighbouring angles of SPEED_ANGLE_SCAN whose strides both lift off, one ending faster than the
    target and the next slower; it is bisected SPEED_ANGLE_BISECTIONS times. The angle is kept only where its
    own stride ends within SPEED_MATCH_TOLERANCE of the target speed, so a failure inside a bracket (counted
    there as too fast) cannot pass for an angle.
    """
    y, xdot = np.broadcast_arrays(np.asarray(target_y, dtype=float), np.asarray(target_xdot, dtype=float))
    targets = np.arange(y.size)

    def excess(index: Array, angle: Array) -> Array:
        """The next speed less the target's, one stride from targets ``index`` at ``angle``; NaN: failed."""
        step = batch_feedback_return_map(
            params,
            y[index],
            xdot[index],
            angle,
            law_of(index),
            sample_period=sample_period,
            rtol=EXACT_TOLERANCE,
            atol=EXACT_TOLERANCE,
        )
        return np.where(step.failure == NO_FAILURE_CODE, step.xdot - xdot[index], np.nan)

    scan = SPEED_ANGLE_SCAN
    grid = excess(np.repeat(targets, scan.size), np.tile(scan, y.size)).reshape(y.size, scan.size)
    with np.errstate(invalid="ignore"):
        crossing = (grid[:, :-1] > 0.0) & (grid[:, 1:] <= 0.0)
    bracketed = np.flatnonzero(crossing.any(axis=1))
    first = np.argmax(crossing[bracketed], axis=1)
    low, high = scan[first], scan[first + 1]
    for _ in range(SPEED_ANGLE_BISECTIONS):
        middle = 0.5 * (low + high)
        slow = excess(bracketed, middle) <= 0.0  # NaN (failed): too fast
        low, high = np.where(slow, low, middle), np.where(slow, middle, high)
    middle = 0.5 * (low + high)
    matched = np.abs(excess(bracketed, middle)) <= SPEED_MATCH_TOLERANCE * np.abs(xdot[bracketed])
    angle = np.full(y.size, np.nan)
    angle[bracketed[matched]] = middle[matched]
    return angle


def feedback_basin(
    params: HopperParams,
    y0: ArrayLike,
    xdot0: ArrayLike,
    touchdown_angle: ArrayLike,
    law_of: LawOf,
    strides: int,
    sample_period: float = DEFAULT_SAMPLE_PERIOD,
) -> Basin:
    """Hop lanes from (y0 [m], xdot0 [m/s], 1-D arrays) for ``strides`` strides under stance feedback, and
    classify them as :func:`basin` does: each lane lands at its fixed touchdown_angle [rad] (NaN: it has
    none and is ``no_command``) and its hip follows ``law_of``, sampled every sample_period [s] on the clock
    where the first apexes are at t = 0 (:func:`~.batch.simulate_strides` at EXACT_TOLERANCE). The history
    keeps the apex times."""
    y_start, xdot_start, angle = np.broadcast_arrays(
        np.asarray(y0, dtype=float), np.asarray(xdot0, dtype=float), np.asarray(touchdown_angle, dtype=float)
    )
    planned = np.flatnonzero(np.isfinite(angle))

    def policy(stride: int, y: Array, xdot: Array, lanes: Array) -> tuple[Array, StanceLaw]:
        return angle[planned[lanes]], law_of(planned[lanes])

    run = simulate_strides(
        params,
        y_start[planned],
        xdot_start[planned],
        policy,
        strides,
        pass_lanes=True,
        rtol=EXACT_TOLERANCE,
        atol=EXACT_TOLERANCE,
        sample_period=sample_period,
    )
    y, xdot, t = (np.full((strides + 1, y_start.size), np.nan) for _ in range(3))
    y[0], xdot[0] = y_start, xdot_start
    y[:, planned], xdot[:, planned], t[:, planned] = run.y, run.xdot, run.t
    outcome = np.full(y_start.size, NO_COMMAND)
    outcome[planned] = np.where(run.failure == NO_FAILURE_CODE, SUSTAINED, _FAILURE_OFFSET + run.failure)
    failure_stride = np.zeros(y_start.size, dtype=np.int64)  # no command: fails at its first stride
    failure_stride[planned] = run.failure_stride
    history = StrideHistory(y=y, xdot=xdot, outcome=outcome, failure_stride=failure_stride, t=t)
    return _classified(params, y_start, params.m * (params.g * y_start + 0.5 * xdot_start**2), history)


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
    (:mod:`tdslip_ros.model.stability.exact_fixed_points`)."""
    energy_grid, height_grid = np.meshgrid(
        np.asarray(energies, float), np.asarray(heights, float), indexing="ij"
    )
    return regulated_basin(params, beta, height_grid, energy_grid, strides, progress)
