"""A run of lanes reduced to its outcome columns (see :mod:`.table`), whichever closed loop ran it."""

from __future__ import annotations

import warnings

import numpy as np

from tdslip_ros.model.arrays import Array
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.stability import basins


def reduce_history(
    params: HopperParams, history: basins.StrideHistory, x: Array | None = None
) -> dict[str, Array]:
    """The outcome columns of a run of lanes from their apex histories (and apex positions x [m], where
    the closed loop tracks them)."""
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
        "x_end": np.full(lanes.size, np.nan) if x is None else x[survived, lanes],
    }
