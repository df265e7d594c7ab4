"""A long recording is read streaming: the samples kept (analysis/sample_keeping.py) against the full read
of the same recording, made long by lowering FULL_RATE_SAMPLES below its sample count."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tdslip_ros.analysis import sample_keeping
from tdslip_ros.analysis.compare import command_deviation, compare_run, policy_for_run
from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.analysis.records import Run, Samples
from tdslip_ros.analysis.report import analyze, stride_table
from tdslip_ros.nodes.runner import RunReport
from tdslip_ros.reporting.output import to_json

pytestmark = pytest.mark.nodes  # the recordings are fixtures of the nodes tier, one of them asked for by name

LIMIT = 300
"""FULL_RATE_SAMPLES in these tests: a tenth of the recordings' samples, or less."""


def _thinned(monkeypatch: pytest.MonkeyPatch, bag: Path, full_rate_strides: tuple[int, ...] = ()) -> Run:
    monkeypatch.setattr(sample_keeping, "FULL_RATE_SAMPLES", LIMIT)
    return read_run(bag, full_rate_strides=full_rate_strides)


def _kept_rows(full: Samples, thinned: Samples) -> np.ndarray:
    """The full read's index of each kept sample, checking that every column is the full read's there."""
    at = np.searchsorted(full.t, thinned.t)
    assert np.all(full.t[at] == thinned.t)
    for name in ("stride", "phase", "x", "y", "xdot", "ydot", "r", "theta", "hip_torque", "ground_height"):
        assert np.array_equal(getattr(full, name)[at], getattr(thinned, name)), name
    force = np.searchsorted(full.grf_t, thinned.grf_t)
    assert np.array_equal(full.grf_x[force], thinned.grf_x) and np.array_equal(
        full.grf_y[force], thinned.grf_y
    )
    return at


def _inside(t: np.ndarray, start: float, end: float) -> np.ndarray:
    return (t >= start) & (t <= end)


@pytest.mark.parametrize("name", ["stance_pd", "rough"])
def test_a_long_recording_keeps_its_windows_whole_and_one_sample_per_bucket_elsewhere(
    name: str, request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch
) -> None:
    report: RunReport = request.getfixturevalue(name)
    full = read_run(report.bag)
    assert full.sample_bucket == 0.0 and len(full.samples) == full.samples_recorded > 10 * LIMIT
    thinned = _thinned(monkeypatch, report.bag)
    samples = thinned.samples
    assert thinned.samples_recorded == full.samples_recorded
    assert [s.t for s in thinned.strides] == [s.t for s in full.strides]
    at = _kept_rows(full.samples, samples)
    span = full.strides[-1].t - full.strides[0].t
    assert thinned.sample_bucket == pytest.approx(span / LIMIT)
    # Whole inside: the last two strides to the end, and every stance under stance feedback.
    windows = [(full.strides[-2].t, math.inf)] + [
        (s.touchdown_time, s.liftoff_time) for s in full.strides if s.stance_feedback is not None
    ]
    assert (name == "stance_pd") == (len(windows) > 1)
    inside = np.zeros(len(full.samples), dtype=bool)
    for start, end in windows:
        inside |= _inside(full.samples.t, start, end)
    kept = np.zeros(len(full.samples), dtype=bool)
    kept[at] = True
    assert np.all(kept[inside])
    # Elsewhere one sample per bucket: at most LIMIT + 1 of them, none two buckets apart from the next.
    outside = kept & ~inside
    assert 0.5 * LIMIT <= np.count_nonzero(outside) <= LIMIT + 1
    assert np.max(np.diff(samples.t)) <= 2 * thinned.sample_bucket
    buckets = np.floor(full.samples.t[outside] / thinned.sample_bucket)
    assert len(np.unique(buckets)) == len(buckets)
    # What the analysis reports of the run is the full read's.
    policy = policy_for_run(full)
    assert policy is not None
    assert command_deviation(thinned, policy) == command_deviation(full, policy)
    tables = [to_json(stride_table(compare_run(run))) for run in (full, thinned)]
    assert tables[0] == tables[1]


def test_a_stride_asked_for_is_kept_whole_and_the_summary_counts_what_was_recorded(
    energy: RunReport, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    full = read_run(energy.bag)
    thinned = _thinned(monkeypatch, energy.bag, full_rate_strides=(3,))
    at = _kept_rows(full.samples, thinned.samples)
    stride = _inside(full.samples.t, full.strides[3].t, full.strides[4].t)
    assert np.all(np.isin(np.flatnonzero(stride), at))
    summaries = [
        analyze(run, tmp_path / str(i), stride=3).summary["run"] for i, run in enumerate((full, thinned))
    ]
    assert summaries[0]["samples"] == summaries[1]["samples"] == full.samples_recorded
    assert summaries[0]["samples_kept"] == full.samples_recorded > summaries[1]["samples_kept"]
    for key in ("sim_time_s", "failure_location", "outcome"):
        assert summaries[0][key] == summaries[1][key]
