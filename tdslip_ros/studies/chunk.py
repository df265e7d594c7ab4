"""One chunk of a study: its trajectories hop on the exact plant and are reduced to one row each.

A chunk is a pure function of (study, chunk index): the lanes' parameters come from the design
(:meth:`~tdslip_ros.studies.design.Study.lanes`), the lanes of each hopper and policy hop together on the
batched engine with per-stride policy calls (:func:`~tdslip_ros.model.stability.basins.run_strides`, DOP853 at
basins.EXACT_TOLERANCE), and the chunk's row order is the trajectory order. Lanes share a policy call, and
the policies' Newton iterations run until every lane of a call has converged, so a trajectory's last bits
depend on the chunk it is in: the chunking is part of the design (``chunk_size``), never of where or how
the chunks run.

Each row (see :mod:`.table`): the trajectory's parameters; ``outcome`` (basins.OUTCOMES: ``converged``,
``sustained``, a failure kind of the exact plant, ``no_command`` where the policy had none, ``impossible``
where the initial apex does not exist or lies beyond the plausibility limits); the stride of the failure;
the strides survived; the convergence stride (every apex change from it on below
basins.CONVERGENCE_TOLERANCE in ybar, xdotbar); the last apex reached; the fixed point reached (where
converged); and the spread of the apexes over the strides survived.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa

from tdslip_ros.model.arrays import Array, CommandArrays
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.policies.registry import PolicySpec
from tdslip_ros.model.stability import basins
from tdslip_ros.studies import perturbed, table
from tdslip_ros.studies.design import CHOICE_SETTINGS, GROUP_PARAMETERS, POLICY_PARAMETERS, Lanes, Study
from tdslip_ros.studies.outcomes import reduce_history


def run_chunk(study: Study, index: int) -> pa.Table:
    """The rows of chunk ``index`` of ``study`` (its trajectories in order)."""
    start, stop = study.chunk_range(index)
    lanes = study.lanes(start, stop)
    return table.of(lanes, run_lanes(study, lanes), study.digest)


def run_lanes(study: Study, lanes: Lanes) -> dict[str, Array]:
    """Hop every lane for study.strides strides; the outcome columns of :data:`.table.OUTCOME_COLUMNS`.

    Lanes of one policy, analytic map, hopper, controller model and terrain kind hop together: one call of
    the batched engine (basins.run_strides, or perturbed.run_held for a study that holds commands)."""
    count = lanes["trajectory"].size
    result = table.empty_outcomes(count)
    groups: dict[tuple[object, ...], list[int]] = {}
    keys = zip(*(lanes[name] for name in GROUP_PARAMETERS), lanes["terrain"], strict=True)
    for lane, key in enumerate(keys):
        groups.setdefault(tuple(key), []).append(lane)
    for key, members in groups.items():
        group = np.asarray(members)
        value = dict(zip(GROUP_PARAMETERS, key[:-1], strict=True))
        params = study.params(float(value["kbar"]), float(value["zeta0"]))
        settings = {name: lanes[name][group] for name in POLICY_PARAMETERS if name not in CHOICE_SETTINGS}
        shared = {"corrections": study.corrections, **{name: str(value[name]) for name in CHOICE_SETTINGS}}
        y0, xdot0 = _startable(params, lanes["y0"][group], lanes["xdot0"][group])
        if study.hold_commands:
            columns = {name: values[group] for name, values in lanes.items()}
            perturbations = perturbed.perturbations_of(columns, study.seed, str(key[-1]))
            outcomes = perturbed.run_held(
                params,
                str(value["policy"]),
                settings,
                shared,
                y0,
                xdot0,
                perturbations,
                columns["trajectory"],
                study.strides,
            )
        else:
            policy = lane_policy(str(value["policy"]), params, settings, shared, xdot0)
            outcomes = reduce_history(params, basins.run_strides(params, y0, xdot0, policy, study.strides))
        for name, values in outcomes.items():
            result[name][group] = values
    return result


def _startable(params: HopperParams, y0: Array, xdot0: Array) -> tuple[Array, Array]:
    """Initial apexes, NaN where none exists or it lies beyond the plausibility limits (impossible)."""
    with np.errstate(invalid="ignore"):
        bad = ~(np.isfinite(y0) & np.isfinite(xdot0) & (y0 > 0.0))
        bad |= PlausibilityLimits.for_hopper(params).apex_exceeded(
            np.where(bad, 1.0, y0), np.where(bad, 0.0, xdot0)
        )
    return np.where(bad, np.nan, y0), np.where(bad, np.nan, xdot0)


def lane_policy(
    name: str, params: HopperParams, settings: dict[str, Array], shared: Mapping[str, Any], xdot0: Array
) -> basins.StancePolicy:
    """The named policy with per-lane settings (arrays over the group's lanes) and ``shared`` ones (one
    value for all: ``corrections``, and the settings of text choices, ``analytic_map``): PolicySpec's
    policies are vectorised, so its settings are the alive lanes' values at each stride.
    apex_foot_placement's previous apex speed is kept per lane (xdot0 before the first stride)."""
    previous = np.array(xdot0, dtype=float)

    def policy(stride: int, y: Array, xdot: Array, lanes: Array) -> CommandArrays:
        spec = PolicySpec(name=name, **shared, **{k: v[lanes] for k, v in settings.items()})
        command = spec.commands(params, y, xdot, previous[lanes])
        previous[lanes] = xdot
        return command

    return policy
