"""A recorded run against the paper's analytic apex return map.

* **Per-stride prediction.** From each recorded apex and the command the plant actually applied,
  the analytic map (:func:`tdslip_ros.model.analytic.apex_map.approximate_map`, 0 and 1 correction iterations;
  ours or the paper's, ``Comparison.analytic_map``) predicts the next apex; the exact map (batched DOP853,
  :func:`tdslip_ros.model.plant.batch.batch_apex_return_map`) predicts it too, which separates the analytic
  map's approximation error from the 1 kHz plant's own integration error. On a perturbed run both predict what
  the plant did: the exact map with the run's terrain, torque limit, push and placement error (reproduced from
  the stored seeds), so its error stays at the flat-ground level; the analytic map (flat ground by
  construction) from the apex's height above the recorded ground of the stance, with the push, the placed
  angle and the ramp's tau0 cut to tau_max (the saturated ramp's peak: an approximation of the saturated
  ramp). Predicted and recorded apexes are compared in the world frame.
* **Stance feedback.** A stride whose hip took torques streamed per tick has no ramp for the maps: the
  exact map replays its recorded torques instead (:mod:`.stance_feedback`), and reports the error.
* **Convergence** at the paper's tolerance: the run has converged at stride n when every apex-to-apex
  change from apex n on is below 1e-4 in the dimensionless apex coordinates (ybar, xdotbar).
* **Fixed point and dominant eigenvalue from the recording.** The apex changes D_k = s_{k+1} - s_k
  of a run near a fixed point obey D_{k+1} = A D_k, A the Jacobian of the closed-loop stride map. A is
  fitted by least squares (minimum norm, so a run whose changes all lie along the dominant direction
  still gives that eigenvalue) over the changes above CHANGE_FLOOR (rounding noise), and the fixed
  point extrapolated from the last apex: s* = s_N + A (I - A)^-1 D_{N-1}. Only changes from the stride
  on which all of them stay below the tolerance enter the fit: the linear regime.
* **The analytic fixed point** of the closed-loop analytic map for the same parameters and policy, by
  Newton's method from the recorded estimate, and the eigenvalues of its Jacobian. The policy may
  remember the previous apex speed (the PD baseline's derivative term), so the stride map acts on
  (y, xdot, xdot_prev) and the Jacobian is 3x3; it is taken by central differences because the
  deadbeat policy's inner minimisation is not complex-step safe (``analytic.map_jacobian``).

The policy is replayed on the apexes the controller was given (measured, above the ground of the last
stance) with the hopper it planned with (the controller's stored parameters: model mismatch), and the
closed-loop analytic map pairs that planner with the plant's map.

The analytic map of the predictions and the closed loop (``analytic_map``: ours, the next apex speed from
the energy balance, or the paper's, from eq. 7's liftoff velocity) is the caller's, else the policy's own
setting (so a run planned on the paper's map is predicted on it), else ours.

Policy settings (:func:`policy_for_run`) come from the caller, else from the controller parameters
``tdslip run`` stores in the bag's custom_data, else from the recorded commands (policy name, fixed
touchdown angle) and the installed controller defaults (``config/controller.yaml``; energy
regulation's target, for ``energy`` and ``energy_exact``, defaults to the initial apex energy, as
``tdslip run`` sets it).
:func:`compare_run` then replays the policy on the recorded apexes and reports how closely it
reproduces the recorded commands, so wrong settings are visible.

A run driven by a controller of the user's own (a policy name this package does not know, or several)
has no policy unless the caller names one: the per-stride predictions, the convergence and the recorded
fixed point need only the recorded apexes and applied commands and are computed all the same; the replay
and the analytic fixed point, which need the policy, are skipped (``Comparison.policy`` is None).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs

from tdslip_ros.analysis.records import Run
from tdslip_ros.analysis.stance_feedback import (
    FeedbackPredictions,
    feedback_summary,
    law_deviation,
    predict_stance_feedback,
)
from tdslip_ros.bag.schema import MessageDefinitionError
from tdslip_ros.interfaces import installed_parameters, stored_parameters
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import (
    ANALYTIC_MAPS,
    DEFAULT_ANALYTIC_MAP,
    SpeedSource,
    approximate_map,
)
from tdslip_ros.model.analytic.closed_loop import eigenvalues
from tdslip_ros.model.arrays import CommandArrays
from tdslip_ros.model.events import failure_from_code
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.plant.batch import batch_apex_return_map
from tdslip_ros.model.plant.perturbations import StrideConditions
from tdslip_ros.model.policies.registry import (
    FIXED_ANGLE_POLICIES,
    POLICIES,
    POLICY_SETTINGS,
    SETTING_DEFAULTS,
    STANCE_FEEDBACK_POLICIES,
    PolicyError,
    PolicySpec,
)
from tdslip_ros.reporting.output import unit_key

FloatArray = npt.NDArray[np.float64]

KNOWN_POLICIES = (*POLICIES, *STANCE_FEEDBACK_POLICIES)
"""Every policy of the suite, the ones that answer with a ramp and the stance-feedback ones: each is
replayed on a recording that names it."""

CONVERGENCE_TOLERANCE = 1e-4
"""Dimensionless apex change below which a run has converged (the paper's tolerance)."""
CHANGE_FLOOR = 1e-11
"""Dimensionless apex changes below this are rounding noise and are not fitted."""
CORRECTIONS = (0, 1)
REPRODUCTION_TOLERANCE = 1e-6
"""Relative command deviation up to which a policy replay counts as reproducing the recorded commands."""
_JACOBIAN_STEP = 1e-4  # dimensionless central-difference step (deadbeat's angle search resolves 1e-9 rad)
_NEWTON_TOLERANCE = 1e-12
_NEWTON_ITERATIONS = 30
_NEWTON_HALVINGS = 20
_FIXED_POINT_RESIDUAL = 1e-8  # dimensionless residual up to which a Newton result counts as a fixed point


def controller_defaults() -> dict[str, Any]:
    """The installed controller node's parameter file (config/controller.yaml), as a mapping, with the
    declared default of each policy setting it does not set (the node's own, then; an older install)."""
    try:
        return {**SETTING_DEFAULTS, **installed_parameters("controller.yaml")}
    except (
        MessageDefinitionError,
        OSError,
        yaml.YAMLError,
        AttributeError,
        KeyError,
        StopIteration,
    ) as error:
        raise PolicyError(f"the installed controller defaults are unreadable: {error!r}") from None


def policy_for_run(run: Run, **overrides: Any) -> PolicySpec | None:
    """The policy settings of ``run``, each from the first of: ``overrides`` (None values ignored); the
    controller parameters ``tdslip run`` stored in the bag's custom_data; what the recording shows (the
    applied policy, the fixed touchdown angle of open_loop and energy, the initial apex energy as
    energy regulation's target); the installed controller defaults. None if no policy is named and the
    recording shows none this package knows (a controller of the user's own; module docstring); a name
    given that it does not know is a PolicyError."""
    given = {name: value for name, value in overrides.items() if value is not None}
    controller = stored_parameters(run.custom_data, "controller")
    stored = {key: value for key, value in controller.items() if key in PolicySpec.settings()}
    if "name" in given:
        name = str(given["name"])
        if name not in KNOWN_POLICIES:
            raise PolicyError(f"unknown policy {name!r}; one of {', '.join(KNOWN_POLICIES)}")
    else:
        policies = run.policies
        name = str(controller.get("policy", policies[0] if len(policies) == 1 else ""))
        if name not in KNOWN_POLICIES:
            return None
    defaults = controller_defaults()
    values: dict[str, Any] = {key: defaults[key] for key in PolicySpec.settings()}
    first = run.strides[0]
    values["target_energy"] = first.energy - run.params.m * run.params.g * first.ground  # above its ground
    first_command = next((s.command for s in run.strides if s.command is not None), None)
    if name in FIXED_ANGLE_POLICIES and first_command is not None:
        values["touchdown_angle"] = first_command.touchdown_angle
    values |= stored
    values |= {key: value for key, value in given.items() if key != "name"}
    sources = sorted(given.keys() - {"name"})
    if sources:
        source = "given: " + ", ".join(sources)
    elif stored:
        source = "the controller parameters stored in the recording"
    else:
        source = "recording + installed controller defaults"
    return PolicySpec.of(name, values, source)


# --- results ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Predictions:
    """Next-apex predictions for the strides in ``stride``: those with an applied command and a recorded
    next apex, and the stride in which the hopper failed (its ``recorded`` row is NaN: did the maps
    foresee the failure?). Arrays (n, 2) of (y [m], xdot [m/s]); NaN where a map failed."""

    stride: npt.NDArray[np.int64]
    recorded: FloatArray
    analytic: dict[int, FloatArray]
    analytic_failures: dict[int, list[str | None]]
    """The failure the analytic map predicts, by name, per stride (None where it predicts an apex)."""
    analytic_energy: dict[int, FloatArray]
    """Analytic (hip energy, damping loss, spring loss) [J] of each stride, (n, 3)."""
    exact: FloatArray


@dataclass(frozen=True)
class ErrorStats:
    """Dimensionless absolute errors of predicted next apexes, mean and max over the strides with a
    recorded next apex; ``failures``: how many of those the map predicted to fail."""

    strides: int
    failures: int
    mean_height: float
    max_height: float
    mean_speed: float
    max_speed: float


@dataclass(frozen=True)
class FixedPoint:
    """A fixed point (y [m], xdot [m/s]) with its eigenvalues (descending modulus)."""

    y: float
    xdot: float
    eigenvalues: tuple[complex, ...]

    @property
    def dominant(self) -> complex:
        return self.eigenvalues[0]


@dataclass(frozen=True)
class Comparison:
    run: Run
    policy: PolicySpec | None
    """The policy replayed and closed-loop analysed (None: the run's is unknown here, both skipped)."""
    analytic_map: str
    """The analytic map of the predictions (analytic.ANALYTIC_MAPS; the policy's, where there is one)."""
    predictions: Predictions
    errors: dict[int, ErrorStats]
    exact_errors: ErrorStats
    command_deviation: float | None
    """Largest relative deviation of the replayed policy's commands from the applied ones (None without a
    policy, NaN without an applied command)."""
    converged_at: int | None
    recorded_fixed_point: FixedPoint | None
    analytic_fixed_point: FixedPoint | None
    """None without a policy, or where Newton finds no fixed point of the closed-loop analytic map."""
    energy_balance_residual: float
    """Largest |E_{k+1} - E_k - (W_hip - E_c - E_k)| over strides, relative to E_k."""
    stance_feedback: FeedbackPredictions
    """The strides under stance feedback, replayed on the exact map from their recorded torques."""

    @property
    def policy_name(self) -> str:
        """The policy compared with, else the ones the recording shows (a controller of the user's own)."""
        if self.policy is not None:
            return self.policy.name
        return ", ".join(self.run.policies) or "no applied command"

    @property
    def ramp_policy(self) -> PolicySpec | None:
        """The policy where it answers with a ramp, so that its closed loop runs on the analytic map; None
        for a stance-feedback policy (its torque is decided during stance) or without a policy."""
        return self.policy if self.policy is not None and self.policy.name in POLICIES else None

    @property
    def policy_reproduced(self) -> bool:
        return self.command_deviation is not None and self.command_deviation <= REPRODUCTION_TOLERANCE


def compare_run(run: Run, policy: PolicySpec | None = None, analytic_map: str | None = None) -> Comparison:
    """Compare ``run`` with the analytic map (see the module docstring). ``policy`` defaults to the run's
    own (:func:`policy_for_run`); where that is None, what needs a policy is skipped. ``analytic_map``
    (analytic.ANALYTIC_MAPS) defaults to the policy's, else ours; the policy's closed loop runs on its own."""
    policy = policy_for_run(run) if policy is None else policy
    if analytic_map is None:
        analytic_map = DEFAULT_ANALYTIC_MAP if policy is None else policy.analytic_map
    if analytic_map not in ANALYTIC_MAPS:
        raise PolicyError(f"unknown analytic map {analytic_map!r}; one of {', '.join(ANALYTIC_MAPS)}")
    params = run.params
    predictions = predict(run, ANALYTIC_MAPS[analytic_map])
    apexes = run.apex_array()
    failed = run.outcome is not None and run.outcome.kind != "run_complete"
    converged_at, recorded = convergence(params, apexes, failed)
    # Newton starts from the recorded fixed point, else from the last apex.
    guess = (
        (recorded.y, recorded.xdot) if recorded is not None else (float(apexes[-1, 0]), float(apexes[-1, 1]))
    )
    # a stance-feedback policy has no closed loop on the analytic map: its torque is decided during stance
    ramp = policy is not None and policy.name in POLICIES
    analytic = analytic_fixed_point(params, policy, guess, run.planner) if ramp and policy else None
    return Comparison(
        run=run,
        policy=policy,
        analytic_map=analytic_map,
        predictions=predictions,
        errors={c: error_stats(params, predictions.analytic[c], predictions.recorded) for c in CORRECTIONS},
        exact_errors=error_stats(params, predictions.exact, predictions.recorded),
        command_deviation=None if policy is None else command_deviation(run, policy),
        converged_at=converged_at,
        recorded_fixed_point=recorded,
        analytic_fixed_point=analytic,
        energy_balance_residual=energy_balance_residual(run),
        stance_feedback=predict_stance_feedback(run),
    )


def predict(run: Run, speed: SpeedSource = "energy") -> Predictions:
    """Analytic (0 and 1 corrections; ``speed``: the analytic map's next apex speed, analytic.SpeedSource)
    and exact next apexes from each recorded apex and applied command (module docstring), in the world
    frame."""
    params, perturbations = run.params, run.perturbations
    by_stride = {s.stride: s for s in run.strides}
    rows = [
        s
        for s in run.strides
        if s.command is not None and (s.stride + 1 in by_stride or s.failure is not None)
    ]
    stride = np.array([s.stride for s in rows], dtype=np.int64)

    def column(name: str) -> FloatArray:
        return np.array([getattr(s, name) for s in rows], dtype=float)

    after = [by_stride.get(k + 1) for k in stride]
    recorded = np.array([(math.nan, math.nan) if a is None else (a.y, a.xdot) for a in after]).reshape(-1, 2)
    command = CommandArrays(
        *(
            np.array([getattr(s.command, name) for s in rows], dtype=float)
            for name in ("touchdown_angle", "tau0", "t_f")
        )
    )
    # The analytic map stands on the recorded ground of the stance (the apex's, where it has none).
    stance_ground = np.where(np.isnan(column("stance_ground")), column("ground"), column("stance_ground"))
    tau_max = float(perturbations.tau_max)
    applied = CommandArrays(
        np.array([s.placed_angle for s in rows], dtype=float),
        np.clip(command.tau0, -tau_max, tau_max) if perturbations.saturates else command.tau0,
        command.t_f,
    )
    start_y = column("y") - stance_ground
    start_xdot = column("xdot") + column("push")
    analytic, failures, energy = {}, {}, {}
    for corrections in CORRECTIONS:
        if params.body is not None:  # the analytic map is the fixed body's: it predicts none of these
            analytic[corrections] = np.full((len(rows), 2), math.nan)
            failures[corrections] = [None] * len(rows)
            energy[corrections] = np.full((len(rows), 3), math.nan)
            continue
        result = approximate_map(params, start_y, start_xdot, applied, corrections, speed=speed)
        analytic[corrections] = np.stack([stance_ground + result.y, result.xdot], axis=-1).reshape(-1, 2)
        codes = np.atleast_1d(result.failure)
        failures[corrections] = [None if (f := failure_from_code(int(c))) is None else str(f) for c in codes]
        energy[corrections] = np.stack(
            [result.stance.hip_energy, result.stance.damping_loss, result.stance.spring_energy], axis=-1
        ).reshape(-1, 3)
    if len(rows):
        exact = batch_apex_return_map(
            params,
            column("y") - column("ground"),
            column("xdot"),
            *command,
            pitch=column("pitch"),
            pitch_rate=column("pitch_rate"),
            conditions=StrideConditions(
                x=column("x"),
                ground=column("ground"),
                terrain=perturbations.terrain,
                tau_max=tau_max,
                push=column("push"),
                angle_error=column("angle_error"),
            ),
        )
        exact_next = np.stack([exact.ground + exact.y, exact.xdot], axis=-1)
    else:
        exact_next = np.empty((0, 2))
    return Predictions(
        stride=stride,
        recorded=recorded,
        analytic=analytic,
        analytic_failures=failures,
        analytic_energy=energy,
        exact=exact_next,
    )


def dimensionless(params: HopperParams, apexes: npt.ArrayLike) -> FloatArray:
    """(..., 2) apex (y, xdot) in SI to (ybar, xdotbar)."""
    apexes = np.asarray(apexes, dtype=float)
    return np.stack(
        [units.height_to_bar(params, apexes[..., 0]), units.speed_to_bar(params, apexes[..., 1])], axis=-1
    )


def error_stats(params: HopperParams, predicted: FloatArray, recorded: FloatArray) -> ErrorStats:
    reached = np.all(np.isfinite(recorded), axis=-1)
    error = np.abs(dimensionless(params, predicted[reached]) - dimensionless(params, recorded[reached]))
    ok = np.all(np.isfinite(error), axis=-1)
    good = error[ok]

    def stat(function: Any, column: int) -> float:
        return float(function(good[:, column])) if len(good) else math.nan

    return ErrorStats(
        strides=int(len(error)),
        failures=int(np.count_nonzero(~ok)),
        mean_height=stat(np.mean, 0),
        max_height=stat(np.max, 0),
        mean_speed=stat(np.mean, 1),
        max_speed=stat(np.max, 1),
    )


def convergence_stride(params: HopperParams, apexes: FloatArray) -> int | None:
    """First apex n from which every apex change is below CONVERGENCE_TOLERANCE (dimensionless,
    either coordinate), or None (also with fewer than two apexes)."""
    if len(apexes) < 2:
        return None
    change = np.max(np.abs(np.diff(dimensionless(params, apexes), axis=0)), axis=-1)
    large = np.flatnonzero(change >= CONVERGENCE_TOLERANCE)
    first = 0 if len(large) == 0 else int(large[-1]) + 1
    return first if first < len(change) else None


def convergence(
    params: HopperParams, apexes: FloatArray, failed: bool = False
) -> tuple[int | None, FixedPoint | None]:
    """The stride from which a run has converged (None if it has not) and the fixed point and
    eigenvalues fitted to its recorded apexes (None for a failed run or one whose last apex change is
    not below the tolerance). Apex changes below the tolerance that still grow (fitted |lambda| >= 1)
    are a slow drift, not convergence."""
    recorded = None if failed else recorded_fixed_point(params, apexes)
    if recorded is None or abs(recorded.dominant) >= 1.0:
        return None, recorded
    return convergence_stride(params, apexes), recorded


def recorded_fixed_point(params: HopperParams, apexes: FloatArray) -> FixedPoint | None:
    """Fixed point and eigenvalues of the fitted change map D_{k+1} = A D_k (module docstring), fitted
    on the changes from the stride on which every change is below CONVERGENCE_TOLERANCE (the linear
    regime); None if the last change is not."""
    first = convergence_stride(params, apexes)
    if first is None:
        return None
    bar = dimensionless(params, apexes)
    change = np.diff(bar, axis=0)
    size = np.max(np.abs(change), axis=-1)
    usable = (np.arange(len(size) - 1) >= first) & (size[:-1] > CHANGE_FLOOR)
    before, after = change[:-1][usable], change[1:][usable]
    last = bar[-1]
    if len(before):
        # lstsq solves before @ A.T = after; rcond drops directions the changes do not excite.
        a_transposed, *_ = np.linalg.lstsq(before, after, rcond=1e-6)
        a = a_transposed.T
        values = eigenvalues(a)
        try:
            fixed = last + a @ np.linalg.solve(np.eye(2) - a, change[-1])
        except np.linalg.LinAlgError:  # an eigenvalue of exactly 1: no extrapolation
            fixed = last
    else:
        # From above the tolerance to rounding noise in one stride: the last apex is the fixed point.
        values, fixed = np.zeros(2), last
    si = (units.height_from_bar(params, fixed[0]), units.speed_from_bar(params, fixed[1]))
    return FixedPoint(float(si[0]), float(si[1]), tuple(complex(v) for v in values))


def closed_loop_step(
    params: HopperParams,
    policy: PolicySpec,
    y: npt.ArrayLike,
    xdot: npt.ArrayLike,
    previous: npt.ArrayLike,
    planner: HopperParams | None = None,
) -> FloatArray:
    """(..., 3) next (y, xdot, xdot_prev) of the analytic closed-loop stride map (the policy's own,
    ``analytic_map``), the policy planning with ``planner`` (default: the plant's ``params``); NaN where it
    fails."""
    command = policy.commands(params if planner is None else planner, y, xdot, previous)
    result = approximate_map(params, y, xdot, command, policy.corrections, speed=policy.speed)
    return np.stack(np.broadcast_arrays(result.y, result.xdot, np.asarray(xdot, dtype=float)), axis=-1)


def _state_scale(params: HopperParams) -> FloatArray:
    """SI per dimensionless unit of (y, xdot, xdot_prev)."""
    return np.array([units.length_scale(params), units.speed_scale(params), units.speed_scale(params)])


def _closed_loop_bar(
    params: HopperParams, policy: PolicySpec, state_bar: FloatArray, planner: HopperParams | None = None
) -> FloatArray:
    """closed_loop_step in dimensionless coordinates, on (..., 3) states."""
    scale = _state_scale(params)
    state = state_bar * scale
    step = closed_loop_step(params, policy, state[..., 0], state[..., 1], state[..., 2], planner)
    return np.asarray(step / scale)


def closed_loop_jacobian(
    params: HopperParams, policy: PolicySpec, y: float, xdot: float, planner: HopperParams | None = None
) -> FloatArray:
    """3x3 Jacobian of the dimensionless closed-loop map at (y, xdot, xdot_prev = xdot), by central
    differences."""
    centre = np.array([y, xdot, xdot]) / _state_scale(params)
    steps = _JACOBIAN_STEP * np.eye(3)
    mapped = _closed_loop_bar(params, policy, np.concatenate([centre + steps, centre - steps]), planner)
    return np.asarray((mapped[:3] - mapped[3:]).T / (2.0 * _JACOBIAN_STEP))


def analytic_fixed_point(
    params: HopperParams,
    policy: PolicySpec,
    guess: tuple[float, float],
    planner: HopperParams | None = None,
) -> FixedPoint | None:
    """Fixed point of the analytic closed-loop map near ``guess`` (Newton), with the Jacobian's
    eigenvalues; None if Newton does not converge (no fixed point nearby, or the map fails there)."""
    scale = _state_scale(params)[:2]
    state = np.asarray(guess, dtype=float) / scale
    steps = _JACOBIAN_STEP * np.eye(2)

    def reduced(points: FloatArray) -> FloatArray:
        # Fixed points have xdot_prev = xdot, so Newton runs on (ybar, xdotbar) alone.
        full = np.concatenate([points, points[..., 1:2]], axis=-1)
        return _closed_loop_bar(params, policy, full, planner)[..., :2]

    def residual_at(point: FloatArray) -> FloatArray:
        return np.asarray(reduced(point[None, :])[0] - point)

    residual = residual_at(state)
    for _ in range(_NEWTON_ITERATIONS):
        if not np.all(np.isfinite(residual)):
            return None
        mapped = reduced(np.vstack([state + steps, state - steps]))
        jacobian = (mapped[:2] - mapped[2:]).T / (2.0 * _JACOBIAN_STEP)
        try:
            step = np.linalg.solve(jacobian - np.eye(2), -residual)
        except np.linalg.LinAlgError:
            return None
        # Damped: halve the step while it leaves the region where the map exists or does not help.
        for _ in range(_NEWTON_HALVINGS):
            trial_residual = residual_at(state + step)
            if np.all(np.isfinite(trial_residual)) and np.max(np.abs(trial_residual)) < np.max(
                np.abs(residual)
            ):
                break
            step = 0.5 * step
        state, residual = state + step, trial_residual
        if np.max(np.abs(step)) <= _NEWTON_TOLERANCE or np.max(np.abs(residual)) <= _NEWTON_TOLERANCE:
            break
    if not np.all(np.abs(residual) <= _FIXED_POINT_RESIDUAL) or state[0] <= 0.0:
        return None
    y, xdot = (float(v) for v in state * scale)
    values = eigenvalues(closed_loop_jacobian(params, policy, y, xdot, planner))
    return FixedPoint(y, xdot, tuple(complex(v) for v in values))


def command_deviation(run: Run, policy: PolicySpec) -> float:
    """Largest relative deviation of the policy's commands, replayed on the recorded apexes as the
    controller was given them (measured, above the ground of the last stance) with the hopper it planned
    with, from the applied ones (angle, tau0 and t_f each relative to its own magnitude); NaN without
    commands. A stance-feedback policy's law is replayed on the recorded stance states instead
    (:func:`.stance_feedback.law_deviation`)."""
    if policy.name in STANCE_FEEDBACK_POLICIES:
        return law_deviation(run, policy)
    rows = [(i, s) for i, s in enumerate(run.strides) if s.command is not None]
    if not rows:
        return math.nan

    y = np.array([s.seen_apex.y for _, s in rows])
    xdot = np.array([s.seen_apex.xdot for _, s in rows])
    previous = np.array([run.strides[i - 1].seen_apex.xdot if i > 0 else s.seen_apex.xdot for i, s in rows])
    replayed = policy.commands(run.planner, y, xdot, previous)
    worst = 0.0
    for name, values in zip(("touchdown_angle", "tau0", "t_f"), replayed, strict=True):
        applied = np.array([getattr(s.command, name) for _, s in rows])
        deviation = np.abs(np.asarray(values) - applied) / np.maximum(np.abs(applied), 1e-300)
        worst = max(worst, float(np.max(np.where(np.isfinite(deviation), deviation, np.inf))))
    return worst


def energy_balance_residual(run: Run) -> float:
    """Largest relative residual of E_{k+1} - E_k = W_hip - E_c - E_k + W_push over the recorded strides,
    E the world-frame apex energy (the ground's height drops out) and W_push = m ((v + dv)^2 - v^2) / 2
    the work of the push after apex k."""
    worst = 0.0
    m = run.params.m
    for before, after in zip(run.strides, run.strides[1:], strict=False):
        push_work = 0.5 * m * ((before.xdot + before.push) ** 2 - before.xdot**2)
        flows = before.hip_work - before.damping_loss - before.spring_loss + push_work
        worst = max(worst, abs(after.energy - before.energy - flows) / abs(before.energy))
    return worst


def policy_summary(policy: PolicySpec) -> dict[str, Any]:
    """JSON-ready settings of ``policy``, each key with its unit (POLICY_SETTINGS)."""
    return {
        "name": policy.name,
        **{
            unit_key(setting.name, setting.unit): getattr(policy, setting.name) for setting in POLICY_SETTINGS
        },
        "source": policy.source,
    }


def error_summary(stats: ErrorStats) -> dict[str, Any]:
    """JSON-ready prediction errors: counts, and the errors in ybar and xdotbar."""
    return {
        "strides": stats.strides,
        "failures": stats.failures,
        "mean_error_ybar": stats.mean_height,
        "max_error_ybar": stats.max_height,
        "mean_error_xdotbar": stats.mean_speed,
        "max_error_xdotbar": stats.max_speed,
    }


def comparison_summary(comparison: Comparison) -> dict[str, Any]:
    """JSON-ready summary of a comparison (SI and dimensionless; each key says its unit)."""
    params = comparison.run.params

    def point(fixed: FixedPoint | None) -> dict[str, Any] | None:
        if fixed is None:
            return None
        bar = dimensionless(params, (fixed.y, fixed.xdot))
        return {
            "y_m": fixed.y,
            "xdot_m_per_s": fixed.xdot,
            "ybar": float(bar[0]),
            "xdotbar": float(bar[1]),
            "eigenvalues": [[v.real, v.imag] for v in fixed.eigenvalues],
            "dominant_modulus": abs(fixed.dominant),
        }

    return {
        "policy": None if comparison.policy is None else policy_summary(comparison.policy),
        "analytic_map": comparison.analytic_map,
        "policy_reproduced": None if comparison.policy is None else comparison.policy_reproduced,
        "command_deviation_ratio": comparison.command_deviation,
        "prediction_errors": {
            **{f"analytic_{c}_corrections": error_summary(stats) for c, stats in comparison.errors.items()},
            "exact_map": error_summary(comparison.exact_errors),
        },
        "converged_at_stride": comparison.converged_at,
        "convergence_tolerance_bar": CONVERGENCE_TOLERANCE,
        "recorded_fixed_point": point(comparison.recorded_fixed_point),
        "analytic_fixed_point": point(comparison.analytic_fixed_point),
        "energy_balance_residual_ratio": comparison.energy_balance_residual,
        "stance_feedback_replay": feedback_summary(comparison.stance_feedback),
    }
