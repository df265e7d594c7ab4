"""The state and action spaces of viability (:mod:`.viability`), and their Q-maps on the batched exact
engine (:func:`tdslip_ros.model.plant.batch.batch_apex_return_map`, DOP853 at rtol = atol = QMAP_TOLERANCE).

* :class:`ApexSpace`: the damped hopper's apex (height y [m], speed xdot [m/s]) under ramp torques; the
  actions are the touchdown angle [rad] and tau0 [N m], t_f [s] given.
* :class:`EnergySpace`: one energy level E [J], the state the fraction of E in height,
  s = m g y / (m g y + m xdot^2 / 2) (vibly's normalisation); the action is the touchdown angle. Without
  regulation the hip is idle (tau0 = 0: with c = 0 the conservative SLIP); with it, the command is the
  paper's energy regulation towards E (:func:`~tdslip_ros.model.policies.controllers.energy_regulation`,
  the analytic map's prediction; the successor's fraction is taken of its own energy, as vibly does).

Angles are the paper's (shared/paper/NOTES.md): from the vertical, positive with the toe ahead of the body
when running forward; vibly's angle of attack is the same angle with the same sign. A pair whose angle the
plant does not take fails as :data:`.viability.ANGLE_REFUSED`. The pairs of a Q-map are in C order over
(*states, *actions): :func:`transitions` computes any contiguous range of them (a chunk), so that a Q-map
can be spread over workers and assembled bit for bit (each pair is one lane of its own: the engine's lanes
do not interact).

Perturbations: the conditions of :class:`~tdslip_ros.model.plant.perturbations.StrideConditions` that are
the same at every stride (tau_max, push, angle_error). Terrain is refused: where the toe lands depends on the
position x, which these states do not hold. An energy level refuses what changes the energy (a push, a
damped leg with an idle hip).

The cost per stride: bench/bench_viability.py (numbers in docs/benchmarks.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.plant.batch import batch_apex_return_map
from tdslip_ros.model.plant.perturbations import UNPERTURBED, StrideConditions
from tdslip_ros.model.policies.controllers import energy_regulation
from tdslip_ros.model.stability.viability import (
    ANGLE_REFUSED_CODE,
    NO_COMMAND_CODE,
    FloatArray,
    IntArray,
    QMap,
    check_grid,
)

QMAP_TOLERANCE = 1e-12
"""DOP853's rtol and atol of the Q-map's strides (the batched engine's default)."""
BYTES_PER_PAIR = 8 * 2 + 8 + 1 + 8 * 4 + 8
"""Memory a Q-map pair takes at its peak [bytes]: two successor coordinates, the failure code, the viable
flag, the conservative cells of two state axes and the fixed point's work array."""


def _check_conditions(conditions: StrideConditions) -> None:
    if not conditions.terrain.is_flat or conditions.ground is not None:
        raise ParameterError(
            "terrain cannot be taken by a viability space: where the toe lands depends on x, not in its state"
        )
    for name in ("tau_max", "push", "angle_error"):
        if np.ndim(getattr(conditions, name)) != 0:
            raise ParameterError(f"{name} must be one value for every stride of a viability space")


def _check_heights(params: HopperParams, name: str, heights: FloatArray) -> None:
    limit = PlausibilityLimits.for_hopper(params).max_apex_height
    if heights[0] <= 0.0 or heights[-1] > limit:
        raise ParameterError(
            f"the grid of {name} must lie in (0, {limit:.6g}] m (the plausibility limit), "
            f"got [{heights[0]:.6g}, {heights[-1]:.6g}] m"
        )


@dataclass(frozen=True)
class ApexSpace:
    """States (y [m], xdot [m/s]) and actions (touchdown_angle [rad], tau0 [N m]) with ramp_duration t_f [s];
    the grid axes strictly increasing (ParameterError otherwise)."""

    params: HopperParams
    heights: FloatArray
    speeds: FloatArray
    angles: FloatArray
    torques: FloatArray
    ramp_duration: float
    conditions: StrideConditions = field(default=UNPERTURBED)
    state_names: tuple[str, ...] = ("y", "xdot")
    action_names: tuple[str, ...] = ("touchdown_angle", "tau0")

    def __post_init__(self) -> None:
        for name, value in zip(("heights", "speeds", "angles", "torques"), self.axes, strict=True):
            object.__setattr__(self, name, check_grid(name, value))
        _check_heights(self.params, "heights", self.heights)
        if not (math.isfinite(self.ramp_duration) and self.ramp_duration > 0.0):
            raise ParameterError(
                f"ramp_duration must be a positive finite number, got {self.ramp_duration!r}"
            )
        _check_conditions(self.conditions)

    @property
    def axes(self) -> tuple[FloatArray, ...]:
        return (self.heights, self.speeds, self.angles, self.torques)

    @property
    def states(self) -> tuple[FloatArray, ...]:
        return (self.heights, self.speeds)

    @property
    def actions(self) -> tuple[FloatArray, ...]:
        return (self.angles, self.torques)

    def apexes(self, state: tuple[IntArray, ...], action: tuple[IntArray, ...]) -> tuple[FloatArray, ...]:
        """(y, xdot, touchdown_angle, tau0, t_f) of the pairs of these grid indices."""
        t_f = np.full(state[0].shape, self.ramp_duration)
        return (
            self.heights[state[0]],
            self.speeds[state[1]],
            self.angles[action[0]],
            self.torques[action[1]],
            t_f,
        )

    def coordinates(self, y: FloatArray, xdot: FloatArray) -> FloatArray:
        return np.stack((y, xdot), axis=-1)


@dataclass(frozen=True)
class EnergySpace:
    """One energy level ``energy`` [J]: states the height fractions (in (0, 1]), actions the touchdown angles
    [rad]; ``regulated``: the command is energy regulation towards ``energy`` (else tau0 = 0)."""

    params: HopperParams
    energy: float
    fractions: FloatArray
    angles: FloatArray
    regulated: bool = False
    conditions: StrideConditions = field(default=UNPERTURBED)
    state_names: tuple[str, ...] = ("height_fraction",)
    action_names: tuple[str, ...] = ("touchdown_angle",)

    def __post_init__(self) -> None:
        object.__setattr__(self, "fractions", check_grid("height fractions", self.fractions))
        object.__setattr__(self, "angles", check_grid("angles", self.angles))
        if not (math.isfinite(self.energy) and self.energy > 0.0):
            raise ParameterError(f"energy must be a positive finite number of J, got {self.energy!r}")
        if self.fractions[0] <= 0.0 or self.fractions[-1] > 1.0:
            raise ParameterError(
                f"the height fractions must lie in (0, 1], got [{self.fractions[0]!r}, "
                f"{self.fractions[-1]!r}]"
            )
        _check_heights(self.params, "heights (energy x fractions)", self.height(self.fractions))
        _check_conditions(self.conditions)
        # The state is a fraction of one energy: a stride that changes the energy leaves the space.
        if not self.regulated and self.params.c > 0.0:
            raise ParameterError(
                "a damped leg with an idle hip loses energy at every stride: one energy level is not its "
                "state space (take energy regulation, or the apex space)"
            )
        if self.conditions.push != 0.0:
            raise ParameterError(
                "a push changes the energy: one energy level cannot take it (take the apex space)"
            )

    @property
    def states(self) -> tuple[FloatArray, ...]:
        return (self.fractions,)

    @property
    def actions(self) -> tuple[FloatArray, ...]:
        return (self.angles,)

    def height(self, fraction: FloatArray) -> FloatArray:
        return np.asarray(fraction * self.energy / (self.params.m * self.params.g), dtype=np.float64)

    def apexes(self, state: tuple[IntArray, ...], action: tuple[IntArray, ...]) -> tuple[FloatArray, ...]:
        """(y, xdot, touchdown_angle, tau0, t_f) of the pairs of these grid indices (NaN tau0: no command)."""
        fraction, angle = self.fractions[state[0]], self.angles[action[0]]
        y = self.height(fraction)
        xdot = np.sqrt(2.0 * self.energy * (1.0 - fraction) / self.params.m)
        if not self.regulated:
            return (y, xdot, angle, np.zeros_like(y), np.ones_like(y))
        usable = (angle > 0.0) & (angle < 0.5 * math.pi)
        tau0, t_f = np.full_like(y, np.nan), np.full_like(y, np.nan)
        if usable.any():
            command = energy_regulation(
                self.params, y[usable], xdot[usable], angle[usable], target_energy=self.energy
            )
            tau0[usable], t_f[usable] = command.tau0, command.t_f
        return (y, xdot, angle, tau0, t_f)

    def coordinates(self, y: FloatArray, xdot: FloatArray) -> FloatArray:
        with np.errstate(invalid="ignore"):
            potential = self.params.g * y
            return (potential / (potential + 0.5 * xdot**2))[:, None]


ViabilitySpace = ApexSpace | EnergySpace


def pair_count(space: ViabilitySpace) -> int:
    return math.prod(axis.size for axis in (*space.states, *space.actions))


def transitions(
    space: ViabilitySpace, start: int = 0, stop: int | None = None
) -> tuple[FloatArray, IntArray]:
    """The successors (pairs, state dims) and failure codes of the pairs start..stop (flat C order over
    (*states, *actions)) of ``space``, each one stride of the batched engine."""
    stop = pair_count(space) if stop is None else stop
    shape = tuple(axis.size for axis in (*space.states, *space.actions))
    index = np.unravel_index(np.arange(start, stop), shape)
    dims = len(space.states)
    y, xdot, angle, tau0, t_f = space.apexes(index[:dims], index[dims:])
    failure = np.full(y.shape, -1, dtype=np.int64)
    failure[~((angle > 0.0) & (angle < 0.5 * math.pi))] = ANGLE_REFUSED_CODE
    failure[(failure == -1) & ~(np.isfinite(tau0) & np.isfinite(t_f))] = NO_COMMAND_CODE
    next_y, next_xdot = np.full(y.shape, np.nan), np.full(y.shape, np.nan)
    run = failure == -1
    if run.any():
        step = batch_apex_return_map(
            space.params,
            y[run],
            xdot[run],
            angle[run],
            tau0[run],
            t_f[run],
            rtol=QMAP_TOLERANCE,
            atol=QMAP_TOLERANCE,
            conditions=space.conditions,
        )
        next_y[run], next_xdot[run], failure[run] = step.y, step.xdot, step.failure
    return space.coordinates(next_y, next_xdot), failure


def assemble(space: ViabilitySpace, successor: FloatArray, failure: IntArray) -> QMap:
    """The Q-map of ``space`` from the transitions of all its pairs in order."""
    shape = tuple(axis.size for axis in (*space.states, *space.actions))
    return QMap(
        states=space.states,
        actions=space.actions,
        state_names=space.state_names,
        action_names=space.action_names,
        successor=successor.reshape(*shape, len(space.states)),
        failure=failure.reshape(shape),
    )


def q_map(space: ViabilitySpace) -> QMap:
    """The Q-map of ``space`` in one process (:mod:`tdslip_ros.studies.viability` spreads it over Dask)."""
    return assemble(space, *transitions(space))
