"""Perturbed studies: the design's perturbation parameters, and the closed loop that holds its command.

The parameters (SI; each a field of :class:`~tdslip_ros.model.plant.perturbations.Perturbations`, per
trajectory):

* terrain, one per trajectory: random blocks (``terrain_sigma`` [m] the standard deviation of the block
  heights, ``terrain_block`` [m] their length, ``terrain_start`` [m] where they begin; each trajectory on
  its own ground, seed ``(seed * TERRAIN_SEED_FACTOR + trajectory) mod 2**31``: distinct for up to 2**31
  trajectories), or a single step (``step_height`` [m], negative:
  down, at ``step_x`` [m]), or flat (both 0). The hopper starts at x = 0 above flat ground;
* the sensor: ``noise_height`` [m] and ``noise_speed`` [m/s], the standard deviations of the apex the
  controller is given;
* the actuator: ``tau_max`` [N m] (inf: none), ``angle_noise`` [rad] the standard deviation of the leg's
  placement error;
* pushes: ``push_size`` [m/s] at each apex with probability ``push_rate``;
* the controller's model: ``mismatch_mass``, ``mismatch_stiffness``, ``mismatch_damping``,
  ``mismatch_rest_length``, factors on the plant's parameters (grid axes or fixed: one model per call).

Random draws come from the study's seed and the trajectory's index (the model's streams, see
:mod:`tdslip_ros.model.plant.perturbations`), never from the chunking.

:func:`run_held` is the closed loop of a study with ``hold_commands``: the batched engine
(:func:`~tdslip_ros.model.plant.batch.simulate_strides`, DOP853 at basins.EXACT_TOLERANCE) with the
perturbations, the policy planning on the measured apex with the controller's model, and, as the plant node
does, the command in force kept for a stride the policy has no command for (counted). The first command in
force is the policy's at the true initial apex; a trajectory without one is ``no_command`` at stride 0.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from tdslip_ros.model.arrays import Array
from tdslip_ros.model.events import FAILURE_KINDS, NO_FAILURE_CODE
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.plant.batch import simulate_strides
from tdslip_ros.model.plant.perturbations import Mismatch, Perturbations, PlacementNoise, Pushes, SensingNoise
from tdslip_ros.model.plant.terrain import FLAT, Blocks, Step, Terrain
from tdslip_ros.model.policies.registry import PolicySpec
from tdslip_ros.model.stability import basins
from tdslip_ros.studies.outcomes import reduce_history

MISMATCH_PARAMETERS = ("mismatch_mass", "mismatch_stiffness", "mismatch_damping", "mismatch_rest_length")
PERTURBATION_PARAMETERS = (
    "terrain_sigma",
    "terrain_block",
    "terrain_start",
    "step_height",
    "step_x",
    "noise_height",
    "noise_speed",
    "angle_noise",
    "tau_max",
    "push_size",
    "push_rate",
    *MISMATCH_PARAMETERS,
)
UNITS = {
    "terrain_sigma": "m",
    "terrain_block": "m",
    "terrain_start": "m",
    "step_height": "m",
    "step_x": "m",
    "noise_height": "m",
    "noise_speed": "m/s",
    "angle_noise": "rad",
    "tau_max": "N m",
    "push_size": "m/s",
    "push_rate": "",
    **dict.fromkeys(MISMATCH_PARAMETERS, ""),
}
DEFAULTS: dict[str, float] = {
    "terrain_sigma": 0.0,
    "terrain_block": 0.5,
    "terrain_start": 1.0,
    "step_height": 0.0,
    "step_x": 1.0,
    "noise_height": 0.0,
    "noise_speed": 0.0,
    "angle_noise": 0.0,
    "tau_max": math.inf,
    "push_size": 0.0,
    "push_rate": 0.0,
    **dict.fromkeys(MISMATCH_PARAMETERS, 1.0),
}
"""No perturbation: flat ground, a perfect sensor and model, an unlimited hip, no pushes."""
DOMAINS: dict[str, tuple[float, float, bool, str]] = {
    "terrain_sigma": (0.0, math.inf, True, "non-negative"),
    "terrain_block": (0.0, math.inf, False, "positive"),
    "noise_height": (0.0, math.inf, True, "non-negative"),
    "noise_speed": (0.0, math.inf, True, "non-negative"),
    "angle_noise": (0.0, math.inf, True, "non-negative"),
    "tau_max": (0.0, math.inf, False, "positive (inf: no limit)"),
    "push_size": (0.0, math.inf, True, "non-negative"),
    "push_rate": (0.0, 1.0, True, "in [0, 1]"),
    **dict.fromkeys(MISMATCH_PARAMETERS, (0.0, math.inf, False, "positive")),
}
"""(low, high, low included, what): the range of each bounded parameter (high is always included)."""
TERRAIN_SEED_FACTOR = 1_000_003
"""A prime: trajectory i's blocks have seed (seed * TERRAIN_SEED_FACTOR + i) mod 2**31 (the model's terrain
seeds are below 2**31), so the trajectories of a study hop on distinct grounds, another seed on others."""


def check_value(name: str, value: float) -> str | None:
    """Why ``value`` is outside the range of the perturbation parameter ``name`` (None: inside)."""
    if name not in DOMAINS:
        return None if math.isfinite(value) else "a finite number"
    low, high, low_included, what = DOMAINS[name]
    inside = (value >= low if low_included else value > low) and value <= high
    if name != "tau_max":
        inside = inside and math.isfinite(value)
    return None if inside else what


def terrain_kind(sigma: float, step: float) -> str:
    return "blocks" if sigma != 0.0 else "step" if step != 0.0 else "flat"


def perturbations_of(columns: dict[str, Array], seed: int, kind: str) -> Perturbations:
    """The perturbations of some lanes (their columns; one terrain kind and one controller model)."""
    trajectory = columns["trajectory"]
    terrain: Terrain = FLAT
    if kind == "blocks":
        terrain = Blocks(
            sigma=columns["terrain_sigma"],
            length=columns["terrain_block"],
            seed=(seed * TERRAIN_SEED_FACTOR + trajectory) % 2**31,
            start=columns["terrain_start"],
        )
    elif kind == "step":
        terrain = Step(height_change=columns["step_height"], x=columns["step_x"])
    mismatch = Mismatch(*(float(columns[name][0]) for name in MISMATCH_PARAMETERS))
    return Perturbations(
        terrain=terrain,
        sensing=SensingNoise(columns["noise_height"], columns["noise_speed"], seed),
        placement=PlacementNoise(columns["angle_noise"], seed),
        tau_max=columns["tau_max"],
        pushes=Pushes(size=columns["push_size"], rate=columns["push_rate"], seed=seed),
        mismatch=mismatch,
    )


def run_held(
    params: HopperParams,
    policy: str,
    settings: dict[str, Array],
    shared: Mapping[str, Any],
    y0: Array,
    xdot0: Array,
    perturbations: Perturbations,
    trajectories: Array,
    strides: int,
) -> dict[str, Array]:
    """The closed loop of the module docstring for lanes that start at (y0, xdot0) (NaN: impossible), the
    policy with per-lane ``settings`` and ``shared`` ones (chunk.lane_policy); the outcome columns of
    :mod:`.table` (``outcome`` as a basins.OUTCOMES index)."""
    count = y0.size
    controller = perturbations.mismatch.controller_params(params)
    first = PolicySpec(name=policy, **shared, **settings).commands(controller, y0, xdot0, xdot0)
    in_force = np.stack([np.array(np.broadcast_to(field, y0.shape), dtype=float) for field in first])
    start = np.flatnonzero(np.all(np.isfinite(in_force), axis=0))
    held = np.zeros(count, dtype=np.int64)
    previous = np.array(xdot0, dtype=float)
    lanes_of = {name: values[start] for name, values in settings.items()}

    def planned(stride: int, y: Array, xdot: Array, alive: Array) -> tuple[Array, Array, Array]:
        lanes = start[alive]
        spec = PolicySpec(name=policy, **shared, **{k: v[alive] for k, v in lanes_of.items()})
        command = np.stack(
            [np.broadcast_to(f, y.shape) for f in spec.commands(controller, y, xdot, previous[lanes])]
        )
        previous[lanes] = xdot
        answered = np.all(np.isfinite(command), axis=0)
        held[lanes[~answered]] += 1
        in_force[:, lanes[answered]] = command[:, answered]
        angle, tau0, t_f = in_force[:, lanes]
        return angle, tau0, t_f

    run = simulate_strides(
        params,
        y0[start],
        xdot0[start],
        planned,
        strides,
        pass_lanes=True,
        rtol=basins.EXACT_TOLERANCE,
        atol=basins.EXACT_TOLERANCE,
        perturbations=perturbations.take(start),
        trajectories=trajectories[start],
    )
    outcome = np.full(count, basins.NO_COMMAND)
    outcome[~np.isfinite(y0) | ~np.isfinite(xdot0)] = basins.IMPOSSIBLE
    failed = run.failure != NO_FAILURE_CODE
    kinds = np.array([basins.failure_outcome(kind) for kind in FAILURE_KINDS])
    outcome[start] = np.where(failed, kinds[np.maximum(run.failure, 0)], basins.SUSTAINED)
    failure_stride = np.where(outcome == basins.NO_COMMAND, 0, -1)
    failure_stride[start] = run.failure_stride
    y = np.full((strides + 1, count), np.nan)
    xdot = np.full_like(y, np.nan)
    y[0], xdot[0] = y0, xdot0
    y[:, start], xdot[:, start] = run.y, run.xdot
    history = basins.StrideHistory(y=y, xdot=xdot, outcome=outcome, failure_stride=failure_stride)
    x = np.full((strides + 1, count), np.nan)
    x[:, start] = run.x
    saturated = np.zeros(count, dtype=np.int64)
    saturated[start] = np.sum(run.saturated, axis=0)
    return reduce_history(params, history, x) | {"strides_held": held, "strides_saturated": saturated}
