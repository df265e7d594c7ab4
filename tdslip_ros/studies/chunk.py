"""One chunk of a study: its trajectories hop on the exact plant and are reduced to one row each.

A chunk is a pure function of (study, chunk index): the lanes' parameters come from the design
(:meth:`~tdslip_ros.studies.design.Study.lanes`), the lanes of each hopper and policy hop together on the
batched engine with per-stride policy calls (:func:`~tdslip_ros.model.basins.run_strides`, DOP853 at
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

import warnings

import numpy as np
import pyarrow as pa

from tdslip_ros.model import basins
from tdslip_ros.model.analytic import Array, CommandArrays
from tdslip_ros.model.controllers import PolicySpec
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import HopperParams
from tdslip_ros.studies import table
from tdslip_ros.studies.design import POLICY_PARAMETERS, Lanes, Study


def run_chunk(study: Study, index: int) -> pa.Table:
    """The rows of chunk ``index`` of ``study`` (its trajectories in order)."""
    start, stop = study.chunk_range(index)
    lanes = study.lanes(start, stop)
    return table.of(lanes, run_lanes(study, lanes), study.digest)


def run_lanes(study: Study, lanes: Lanes) -> dict[str, Array]:
    """Hop every lane for study.strides strides; the outcome columns of :data:`.table.OUTCOME_COLUMNS`."""
    count = lanes["trajectory"].size
    result = table.empty_outcomes(count)
    groups: dict[tuple[str, float, float], list[int]] = {}
    for lane, key in enumerate(zip(lanes["policy"], lanes["kbar"], lanes["zeta0"], strict=True)):
        groups.setdefault((str(key[0]), float(key[1]), float(key[2])), []).append(lane)
    for (policy, kbar, zeta0), members in groups.items():
        group = np.asarray(members)
        params = study.params(kbar, zeta0)
        settings = {name: lanes[name][group] for name in POLICY_PARAMETERS}
        y0, xdot0 = _startable(params, lanes["y0"][group], lanes["xdot0"][group])
        history = basins.run_strides(
            params, y0, xdot0, lane_policy(policy, params, settings, study.corrections, xdot0), study.strides
        )
        for name, values in reduce_history(params, history).items():
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
    name: str, params: HopperParams, settings: dict[str, Array], corrections: int, xdot0: Array
) -> basins.StancePolicy:
    """The named policy with per-lane settings (arrays over the group's lanes): PolicySpec's policies are
    vectorised, so its settings are the alive lanes' values at each stride. pd's previous apex speed is
    kept per lane (xdot0 before the first stride)."""
    previous = np.array(xdot0, dtype=float)

    def policy(stride: int, y: Array, xdot: Array, lanes: Array) -> CommandArrays:
        spec = PolicySpec(name=name, corrections=corrections, **{k: v[lanes] for k, v in settings.items()})
        command = spec.commands(params, y, xdot, previous[lanes])
        previous[lanes] = xdot
        return command

    return policy


def reduce_history(params: HopperParams, history: basins.StrideHistory) -> dict[str, Array]:
    """The outcome columns of a run of lanes from their apex histories."""
    strides = history.y.shape[0] - 1
    converged, convergence_stride = basins.settle(params, history)
    failed = (history.outcome != basins.SUSTAINED) & (history.outcome != basins.IMPOSSIBLE)
    survived = np.where(failed, history.failure_stride, strides)
    survived = np.where(history.outcome == basins.IMPOSSIBLE, 0, survived)
    lanes = np.arange(history.y.shape[1])
    y_end, xdot_end = history.y[survived, lanes], history.xdot[survived, lanes]
    # The spread over the apexes after the start (rows 1..survived); NaN where no stride was survived.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: impossible starts
        y_std = np.nanstd(history.y[1:], axis=0)
        xdot_std = np.nanstd(history.xdot[1:], axis=0)
    energy_end = params.m * (params.g * y_end + 0.5 * xdot_end**2)
    return {
        "outcome": np.where(converged, basins.CONVERGED, history.outcome),
        "failure_stride": history.failure_stride,
        "strides_survived": survived,
        "convergence_stride": convergence_stride,
        "y_end": y_end,
        "xdot_end": xdot_end,
        "y_fixed": np.where(converged, y_end, np.nan),
        "xdot_fixed": np.where(converged, xdot_end, np.nan),
        "energy_fixed": np.where(converged, energy_end, np.nan),
        "y_std": y_std,
        "xdot_std": xdot_std,
    }
