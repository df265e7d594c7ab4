"""Which of a recording's 1 kHz samples a read run keeps, so that the reading streams.

A recording of at most :data:`FULL_RATE_SAMPLES` state samples (10 minutes at 1 kHz) keeps every sample,
as it always did. A longer one keeps a bounded set, chosen as the chunks stream past:

- outside the windows below, the first sample of each time bucket, the buckets being as many as
  FULL_RATE_SAMPLES over the run's span: the path over the whole run, at most that many points;
- inside them, every sample: the stride the COM figure draws (the last complete one, or one asked for),
  the last stride to the end of the recording (where a failure happened), and the stances under stance
  feedback, whose recorded states the replay of the policy's law needs.

The windows of stance feedback are the one part that grows with the run: about 300 samples a stance at
the paper's hopper (docs/benchmarks.md, "Long runs and the soak"). State and force samples are kept by
the same rule on their own stamps, so a kept state sample keeps the force sample of its tick.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from tdslip_ros.analysis.records import FloatArray, StrideRecord

FULL_RATE_SAMPLES = 600_000
"""The most state samples a read run keeps outside its windows (10 minutes at 1 kHz): a recording of no
more keeps every sample."""


@dataclass(frozen=True)
class SampleKeeping:
    """The rule: one sample per ``bucket`` seconds (0: every sample), and every sample inside
    ``windows`` ((n, 2) start and end times [s], sorted and disjoint)."""

    bucket: float = 0.0
    windows: FloatArray = field(default_factory=lambda: np.empty((0, 2)))

    @classmethod
    def for_run(
        cls,
        samples: int,
        strides: tuple[StrideRecord, ...],
        full_rate_strides: Iterable[int] = (),
        limit: int | None = None,
    ) -> SampleKeeping:
        """The rule for a recording of ``samples`` state samples whose strides are ``strides``;
        ``full_rate_strides``: strides (apex k to apex k + 1) kept whole besides the module's windows;
        ``limit``: FULL_RATE_SAMPLES if not given."""
        limit = FULL_RATE_SAMPLES if limit is None else limit
        if samples <= limit or len(strides) < 2:
            return cls()
        span = strides[-1].t - strides[0].t
        by_stride = {s.stride: s for s in strides}
        windows = [(strides[-2].t, math.inf)]
        for k in full_rate_strides:
            if k in by_stride:
                end = by_stride[k + 1].t if k + 1 in by_stride else math.inf
                windows.append((by_stride[k].t, end))
        windows += [
            (s.touchdown_time, s.liftoff_time if math.isfinite(s.liftoff_time) else math.inf)
            for s in strides
            if s.stance_feedback is not None and math.isfinite(s.touchdown_time)
        ]
        return cls(bucket=span / limit, windows=_merged(windows))

    @property
    def keeps_all(self) -> bool:
        return self.bucket == 0.0

    def stream(self) -> SampleStream:
        """A filter for one stream of samples (state or force), fed its stamps in order."""
        return SampleStream(self)


class SampleStream:
    """The keeping rule applied to one stream, batch after batch: the first sample of each bucket
    is remembered across batches."""

    def __init__(self, keeping: SampleKeeping) -> None:
        self.keeping = keeping
        self.last_bucket = -math.inf

    def kept(self, t: FloatArray) -> npt.NDArray[np.bool_]:
        """Which of the samples stamped ``t`` [s] (the stream's next batch) are kept."""
        if self.keeping.keeps_all or len(t) == 0:
            return np.ones(len(t), dtype=bool)
        buckets = np.floor(t / self.keeping.bucket)
        first = np.empty(len(t), dtype=bool)
        first[0] = buckets[0] != self.last_bucket
        first[1:] = buckets[1:] != buckets[:-1]
        self.last_bucket = float(buckets[-1])
        windows = self.keeping.windows
        at = np.searchsorted(windows[:, 0], t, side="right") - 1
        inside = (at >= 0) & (t <= windows[np.maximum(at, 0), 1])
        return first | inside


def _merged(windows: list[tuple[float, float]]) -> FloatArray:
    merged: list[list[float]] = []
    for start, end in sorted(windows):
        if merged and start <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], end)
        else:
            merged.append([start, end])
    return np.array(merged, dtype=float).reshape(-1, 2)
