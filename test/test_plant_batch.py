"""The batched engine against the single-trajectory exact map, lane by lane."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from support.failure_cases import FAILURE_CASES

from tdslip_ros.model import units
from tdslip_ros.model.events import NO_FAILURE_CODE, FailureKind, failure_code, failure_from_code
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.batch import BatchStrideResult, batch_apex_return_map, simulate_strides
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.stride_kernels import compiled_apex_return_map

PARAMS = PAPER_PARAMS
ENERGY_SCALE = units.energy_scale(PARAMS)


def _grid() -> tuple[np.ndarray, ...]:
    """12 x 12 apex states with commands varying per lane; some lanes fail (stubbing, reversal)."""
    y, xdot = np.meshgrid(np.linspace(0.9, 1.4, 12), np.linspace(0.5, 6.0, 12))
    rng = np.random.default_rng(11)
    angle = np.radians(rng.uniform(15.0, 28.0, y.shape))
    tau0 = rng.uniform(-900.0, 100.0, y.shape)
    t_f = rng.uniform(0.05, 0.3, y.shape)
    return y, xdot, angle, tau0, t_f


def test_batch_map_agrees_with_the_exact_map_on_a_grid() -> None:
    y, xdot, angle, tau0, t_f = _grid()
    batch = batch_apex_return_map(PARAMS, y, xdot, angle, tau0, t_f)
    assert batch.y.shape == y.shape
    kinds = set()
    for lane in np.ndindex(y.shape):
        exact = apex_return_map(
            PARAMS, ApexState(y[lane], xdot[lane]), StanceCommand(angle[lane], tau0[lane], t_f[lane])
        )
        assert batch.failure[lane] == failure_code(exact.failure), lane
        kinds.add(exact.failure)
        if exact.energy is not None:
            assert batch.hip_work[lane] == pytest.approx(exact.energy.hip_work, abs=1e-9 * ENERGY_SCALE)
            assert batch.damping_loss[lane] == pytest.approx(
                exact.energy.damping_loss, abs=1e-9 * ENERGY_SCALE
            )
            assert batch.spring_loss[lane] == pytest.approx(exact.energy.spring_loss, abs=1e-9 * ENERGY_SCALE)
        if exact.apex is None:
            assert np.isnan(batch.y[lane]) and np.isnan(batch.xdot[lane])
            continue
        assert units.height_to_bar(PARAMS, batch.y[lane] - exact.apex.y) == pytest.approx(0.0, abs=1e-9)
        assert units.speed_to_bar(PARAMS, batch.xdot[lane] - exact.apex.xdot) == pytest.approx(0.0, abs=1e-9)
        assert batch.stride_time[lane] == pytest.approx(exact.apex_time, abs=1e-9)
    # The grid exercises success and several failure kinds.
    assert {None, FailureKind.TOE_STUBBING, FailureKind.REVERSAL} <= kinds


@pytest.mark.parametrize(
    ("engine", "tolerance"),
    [(batch_apex_return_map, 1e-9), (compiled_apex_return_map, 1e-11)],
    ids=["batch", "compiled"],
)
@pytest.mark.parametrize(
    ("params", "apex", "command", "kind"),
    [case[1:5] for case in FAILURE_CASES],
    ids=[case.name for case in FAILURE_CASES],
)
def test_each_failure_per_lane(
    params: HopperParams,
    apex: ApexState,
    command: StanceCommand,
    kind: FailureKind,
    engine: Callable[..., BatchStrideResult],
    tolerance: float,
) -> None:
    """Each failure in a lane of its own, next to a lane that hops on, in the batched engine and in the
    compiled one-lane stride (its apex within its own accuracy, 1e-11 m, of the exact map's)."""
    assert apex_return_map(params, apex, command).failure is kind
    good_apex = ApexState(1.2, 4.0)
    good_command = StanceCommand(math.radians(20.0), -600.0, 0.15)
    lanes = engine(
        params,
        [apex.y, good_apex.y],
        [apex.xdot, good_apex.xdot],
        [command.touchdown_angle, good_command.touchdown_angle],
        [command.tau0, good_command.tau0],
        [command.t_f, good_command.t_f],
    )
    assert failure_from_code(int(lanes.failure[0])) is kind
    good = apex_return_map(params, good_apex, good_command)
    assert failure_from_code(int(lanes.failure[1])) is good.failure
    if good.apex is not None:
        assert abs(lanes.y[1] - good.apex.y) <= tolerance * params.r0


def test_simulate_strides_follows_the_exact_map_through_failures() -> None:
    """A constant open-loop command: lanes drift and fail at different strides (as in the paper)."""
    y0, xdot0 = np.meshgrid(np.linspace(1.05, 1.3, 4), np.linspace(3.0, 5.0, 3))
    command = StanceCommand(math.radians(20.0), -708.0, 0.161)
    calls: list[int] = []

    def policy(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[float, float, float]:
        calls.append(y.size)
        return command.touchdown_angle, command.tau0, command.t_f

    strides = 10
    run = simulate_strides(PARAMS, y0, xdot0, policy, strides)
    assert run.y.shape == (strides + 1, *y0.shape) and run.hip_work.shape == (strides, *y0.shape)
    for lane in np.ndindex(y0.shape):
        apex = ApexState(y0[lane], xdot0[lane])
        failed_at = -1
        for k in range(strides):
            exact = apex_return_map(PARAMS, apex, command)
            if exact.apex is None:
                failed_at = k
                assert run.failure[lane] == failure_code(exact.failure)
                assert np.all(np.isnan(run.y[k + 1 :, lane[0], lane[1]]))
                break
            assert run.y[(k + 1, *lane)] == pytest.approx(exact.apex.y, abs=1e-9)
            assert run.xdot[(k + 1, *lane)] == pytest.approx(exact.apex.xdot, abs=1e-9 * math.sqrt(PARAMS.g))
            assert exact.energy is not None
            assert run.hip_work[(k, *lane)] == pytest.approx(exact.energy.hip_work, abs=1e-9 * ENERGY_SCALE)
            apex = exact.apex
        assert run.failure_stride[lane] == failed_at
        if failed_at == -1:
            assert run.failure[lane] == NO_FAILURE_CODE
    assert 0 < np.count_nonzero(run.failure_stride >= 0) < y0.size  # some lanes fail, some do not
    assert calls[0] == y0.size and calls == sorted(calls, reverse=True)  # only alive lanes are asked


def test_policy_with_lane_memory_gets_the_alive_lanes() -> None:
    """A per-lane energy goal (the paper's regulator keeps the first stride's energy)."""
    y0 = np.array([0.9, 1.1, 1.2, 1.25])  # lane 0 stubs its toe at once
    xdot0 = np.array([4.0, 4.2, 3.9, 3.8])
    goal = PARAMS.m * (PARAMS.g * y0 + 0.5 * xdot0**2)
    seen: list[np.ndarray] = []

    def policy(
        stride: int, y: np.ndarray, xdot: np.ndarray, lanes: np.ndarray
    ) -> tuple[float, np.ndarray, float]:
        seen.append(lanes.copy())
        energy = PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)
        return math.radians(20.0), -610.8 + 3.0 * (energy - goal[lanes]), 0.15

    run = simulate_strides(PARAMS, y0, xdot0, policy, 4, pass_lanes=True)
    assert run.failure.tolist() == [failure_code(FailureKind.TOE_STUBBING), -1, -1, -1]
    assert seen[0].tolist() == [0, 1, 2, 3] and all(s.tolist() == [1, 2, 3] for s in seen[1:])
    for lane in (1, 2, 3):
        apex = ApexState(y0[lane], xdot0[lane])
        for k in range(4):
            tau0 = -610.8 + 3.0 * (apex.energy(PARAMS) - goal[lane])
            exact = apex_return_map(PARAMS, apex, StanceCommand(math.radians(20.0), tau0, 0.15))
            assert exact.apex is not None
            assert run.y[k + 1, lane] == pytest.approx(exact.apex.y, abs=1e-9)
            apex = exact.apex


def test_bad_lanes_are_refused_by_field_and_lane() -> None:
    with pytest.raises(ParameterError, match=r"touchdown_angle .* lane 2"):
        batch_apex_return_map(PARAMS, 1.2, 4.0, [0.3, 0.3, 2.0], -600.0, 0.15)
    with pytest.raises(ParameterError, match=r"t_f .* lane 0"):
        batch_apex_return_map(PARAMS, [1.2, 1.1], 4.0, 0.3, -600.0, [0.0, 0.1])
    with pytest.raises(ParameterError, match="apex height y"):
        batch_apex_return_map(PARAMS, [1.2, np.nan], 4.0, 0.3, -600.0, 0.1)
    with pytest.raises(ParameterError, match="tau0"):
        simulate_strides(PARAMS, [1.2], [4.0], lambda k, y, xdot: (0.3, np.inf, 0.1), 2)
