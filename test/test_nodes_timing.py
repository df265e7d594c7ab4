"""TickTiming's statistics on firing sequences whose errors and catch-ups are known by construction."""

from __future__ import annotations

import math

import pytest

from tdslip_ros.nodes.realtime import TickTiming

PERIOD = 1_000_000  # ns


def test_period_errors_and_missed_ticks_of_a_known_sequence() -> None:
    timing = TickTiming(PERIOD)
    # 101 firings: the first, 98 with errors 0..97 us in turn, one 2.5 ms late that catches up
    # 3 ticks (2 missed), then one 1.5 ms early relative to it (the schedule resumes).
    now, errors = 0, []
    timing.record(now, 1)
    for k in range(98):
        now += PERIOD + k * 1_000
        errors.append(k * 1_000)
        timing.record(now, 1)
    now += PERIOD + 2_500_000
    timing.record(now, 3)
    now += PERIOD - 1_500_000
    timing.record(now, 1)
    errors += [2_500_000, 1_500_000]

    assert (timing.firings, timing.ticks, timing.missed) == (101, 103, 2)
    ranked = sorted(errors)
    for quantile in (0.5, 0.9, 0.99):
        exact = ranked[max(0, int(quantile * len(ranked) + 0.999999) - 1)] * 1e-9
        assert timing.period_error(quantile) == pytest.approx(exact, abs=TickTiming.BIN_NS * 1e-9)
    assert timing.period_error(1.0) == pytest.approx(2.5e-3, abs=1e-6)


def test_a_new_run_is_not_timed_against_the_previous_one() -> None:
    timing = TickTiming(PERIOD)
    timing.record(0, 1)
    timing.record(PERIOD, 1)
    timing.resume()
    timing.record(60 * PERIOD, 1)  # a minute-long gap (a reset) is no period error
    timing.record(61 * PERIOD, 1)
    assert timing.period_error(1.0) < TickTiming.BIN_NS * 1e-9
    assert (timing.firings, timing.missed) == (4, 0)


def test_no_firings_no_statistics() -> None:
    assert math.isnan(TickTiming(PERIOD).period_error(0.5))
