"""The compiled exact stride (model.plant.stride_kernels) against the scalar exact map and the batched
engine: the
same failure kinds, the apex to the exact map's accuracy, the batch's numbers to rounding, the same
ParameterErrors; and energy_exact, which plans on it, over many lanes against the scalar exact map."""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pytest

from tdslip_ros.model import units
from tdslip_ros.model.arrays import HAS_COMMAND, NoCommand
from tdslip_ros.model.events import NO_FAILURE_CODE, FailureKind, failure_code
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, ParameterError, StanceCommand
from tdslip_ros.model.plant.batch import batch_apex_return_map
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.perturbations import StrideConditions
from tdslip_ros.model.plant.stance_kernel import LaneTorque, kink
from tdslip_ros.model.plant.stride_kernels import apex_stride, compiled_apex_return_map
from tdslip_ros.model.policies.controllers import exact_energy_regulation

PARAMS = PAPER_PARAMS
ENERGY_SCALE = units.energy_scale(PARAMS)
APEX_TOLERANCE = 1e-11
"""Dimensionless apex (y/r0, xdot/sqrt(g r0)): the exact map's accuracy at rtol = atol = 1e-12."""


def _random_lanes(count: int, seed: int) -> tuple[np.ndarray, ...]:
    """Apexes and ramps over the ranges the policies use and beyond: low apexes (toe stubbing), slow ones
    (reversal at touchdown), braking and long forward torques (reversal, fall), a third saturated."""
    rng = np.random.default_rng(seed)
    y = rng.uniform(0.85, 1.5, count)
    xdot = rng.uniform(0.3, 7.0, count)
    angle = np.radians(rng.uniform(8.0, 32.0, count))
    tau0 = rng.uniform(-1500.0, 400.0, count)
    t_f = rng.uniform(0.03, 0.4, count)
    tau_max = np.where(rng.uniform(size=count) < 0.3, rng.uniform(100.0, 800.0, count), math.inf)
    return y, xdot, angle, tau0, t_f, tau_max


def test_random_strides_match_the_exact_map_to_its_accuracy_with_the_same_failures() -> None:
    y, xdot, angle, tau0, t_f, tau_max = _random_lanes(300, 5)
    compiled = compiled_apex_return_map(
        PARAMS, y, xdot, angle, tau0, t_f, conditions=StrideConditions(tau_max=tau_max)
    )
    kinds = set()
    for lane in range(y.size):
        exact = apex_return_map(
            PARAMS,
            ApexState(y[lane], xdot[lane]),
            StanceCommand(angle[lane], tau0[lane], t_f[lane]),
            conditions=StrideConditions(tau_max=tau_max[lane]),
        )
        kinds.add(exact.failure)
        assert compiled.failure[lane] == failure_code(exact.failure), lane
        assert compiled.saturated[lane] == (abs(tau0[lane]) > tau_max[lane])
        if exact.energy is not None:
            assert compiled.hip_work[lane] == pytest.approx(exact.energy.hip_work, abs=1e-10 * ENERGY_SCALE)
            assert compiled.damping_loss[lane] == pytest.approx(
                exact.energy.damping_loss, abs=1e-10 * ENERGY_SCALE
            )
        if exact.apex is None:
            assert np.isnan(compiled.y[lane]) and np.isnan(compiled.xdot[lane])
            continue
        assert abs(units.height_to_bar(PARAMS, compiled.y[lane] - exact.apex.y)) <= APEX_TOLERANCE
        assert abs(units.speed_to_bar(PARAMS, compiled.xdot[lane] - exact.apex.xdot)) <= APEX_TOLERANCE
        assert compiled.stride_time[lane] == pytest.approx(exact.apex_time, abs=1e-11)
        assert exact.liftoff is not None
        assert compiled.stance_time[lane] == pytest.approx(exact.liftoff.t - exact.touchdown.t, abs=1e-11)
    assert {None, FailureKind.TOE_STUBBING, FailureKind.REVERSAL, FailureKind.FALL} <= kinds
    assert np.count_nonzero(compiled.saturated & (compiled.failure == NO_FAILURE_CODE)) > 20


def test_random_strides_are_the_batched_engine_s_to_rounding() -> None:
    """The same algorithm: every field within rounding (numpy's pow and libm's differ in the last bit,
    so the step sizes, and the states by ~1e-15 relative)."""
    lanes = _random_lanes(2000, 6)
    compiled = compiled_apex_return_map(PARAMS, *lanes[:5], conditions=StrideConditions(tau_max=lanes[5]))
    batch = batch_apex_return_map(PARAMS, *lanes[:5], conditions=StrideConditions(tau_max=lanes[5]))
    np.testing.assert_array_equal(compiled.failure, batch.failure)
    np.testing.assert_array_equal(compiled.saturated, batch.saturated)
    for field in fields(batch):
        if field.name not in ("failure", "saturated"):
            np.testing.assert_allclose(
                getattr(compiled, field.name),
                getattr(batch, field.name),
                rtol=1e-12,
                atol=1e-12,
                err_msg=field.name,
            )


def test_a_saturated_ramp_is_the_exact_map_s() -> None:
    apex, command = ApexState(1.1, 4.0), StanceCommand(math.radians(24.0), -900.0, 0.2)
    exact = apex_return_map(PARAMS, apex, command, conditions=StrideConditions(tau_max=300.0))
    ramp = (command.touchdown_angle, command.tau0, command.t_f)
    compiled = compiled_apex_return_map(
        PARAMS, apex.y, apex.xdot, *ramp, conditions=StrideConditions(tau_max=300.0)
    )
    assert exact.apex is not None and bool(compiled.saturated)
    assert abs(units.height_to_bar(PARAMS, float(compiled.y) - exact.apex.y)) <= APEX_TOLERANCE
    unsaturated = compiled_apex_return_map(PARAMS, apex.y, apex.xdot, *ramp)
    assert abs(float(unsaturated.y) - float(compiled.y)) > 1e-3  # the saturation is felt


@pytest.mark.parametrize(
    ("inputs", "tau_max", "message"),
    [
        ((-1.0, 4.0, 0.3, -500.0, 0.2), math.inf, "apex height y"),
        ((1.2, math.nan, 0.3, -500.0, 0.2), math.inf, "apex speed xdot"),
        ((1.2, 4.0, 2.0, -500.0, 0.2), math.inf, "touchdown_angle"),
        ((1.2, 4.0, 0.3, math.inf, 0.2), math.inf, "tau0"),
        ((1.2, 4.0, 0.3, -500.0, 0.0), math.inf, "t_f"),
        ((11.0, 4.0, 0.3, -500.0, 0.2), math.inf, "max_apex_height"),
        ((1.2, 4.0, 0.3, -500.0, 0.2), 0.0, "tau_max"),
    ],
)
def test_invalid_lanes_raise_the_batch_s_parameter_error(
    inputs: tuple[float, ...], tau_max: float, message: str
) -> None:
    with pytest.raises(ParameterError, match=message) as batch_error:
        batch_apex_return_map(PARAMS, *inputs, conditions=StrideConditions(tau_max=tau_max))
    with pytest.raises(ParameterError) as compiled_error:
        compiled_apex_return_map(PARAMS, *inputs, conditions=StrideConditions(tau_max=tau_max))
    assert str(compiled_error.value) == str(batch_error.value)


def test_one_apex_is_its_lane_of_the_lanes() -> None:
    """apex_stride, the one-apex API, is the lane of compiled_apex_return_map, bit for bit."""
    y, xdot, angle, tau0, t_f, tau_max = _random_lanes(60, 7)
    lanes = compiled_apex_return_map(
        PARAMS, y, xdot, angle, tau0, t_f, conditions=StrideConditions(tau_max=tau_max)
    )
    for lane in range(y.size):
        one = apex_stride(
            PARAMS,
            ApexState(y[lane], xdot[lane]),
            StanceCommand(angle[lane], tau0[lane], t_f[lane]),
            conditions=StrideConditions(tau_max=tau_max[lane]),
        )
        assert failure_code(one.failure) == lanes.failure[lane]
        assert (one.apex is None) == np.isnan(lanes.y[lane])
        if one.apex is not None:
            assert (one.apex.y, one.apex.xdot) == (lanes.y[lane], lanes.xdot[lane])
        for name in (
            "hip_work",
            "damping_loss",
            "spring_loss",
            "stance_time",
            "stride_time",
            "x",
            "saturated",
        ):
            np.testing.assert_array_equal(getattr(one, name), getattr(lanes, name)[lane], err_msg=name)


def test_one_apex_beyond_the_limits_raises_the_exact_map_s_parameter_error() -> None:
    apex, command = ApexState(11.0, 4.0), StanceCommand(0.3, -500.0, 0.2)
    with pytest.raises(ParameterError) as exact_error:
        apex_return_map(PARAMS, apex, command)
    with pytest.raises(ParameterError) as compiled_error:
        apex_stride(PARAMS, apex, command)
    assert str(compiled_error.value) == str(exact_error.value)
    with pytest.raises(ParameterError, match="tau_max"):
        apex_stride(PARAMS, ApexState(1.2, 4.0), command, conditions=StrideConditions(tau_max=0.0))


def test_energy_exact_over_many_lanes_meets_its_target_on_scipy_s_exact_map_or_says_why_not() -> None:
    """energy_exact's compiled Newton (policies.exact_regulation_kernels.exact_regulation_lanes), many lanes
    in one call, checked
    lane by lane on the scalar exact map (scipy's DOP853, not the kernel it plans on): every command it gives
    ends the stride at the target energy with the ramp ending at liftoff; the lanes it does not answer have a
    reason, both kinds among them: an iterate's failure on the exact plant and Newton finding no solution."""
    rng = np.random.default_rng(11)
    count = 80
    y = rng.uniform(0.93, 1.5, count)
    xdot = rng.uniform(2.0, 7.0, count)
    beta = np.radians(rng.uniform(14.0, 32.0, count))
    # targets within +-15 % of each apex's energy, and every tenth a fifth of it: too little to keep hopping
    energy = PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)
    target = energy * np.where(np.arange(count) % 10 == 0, 0.2, rng.uniform(0.85, 1.15, count))
    plan = exact_energy_regulation(PARAMS, y, xdot, beta, target)
    answered = np.flatnonzero(plan.no_command == HAS_COMMAND)
    assert 0.5 * count < answered.size < count  # most lanes answered, not all
    for lane in answered:
        command = plan.command(lane)
        result = apex_return_map(PARAMS, ApexState(y[lane], xdot[lane]), command)
        assert result.apex is not None and result.liftoff is not None and result.touchdown is not None
        assert abs(result.apex.energy(PARAMS) - target[lane]) < 1e-9 * ENERGY_SCALE
        assert command.t_f == pytest.approx(result.liftoff.t - result.touchdown.t, abs=1e-9)
    reasons = {plan.reason(lane) for lane in np.flatnonzero(plan.no_command != HAS_COMMAND)}
    assert NoCommand.NO_SOLUTION in reasons and reasons & {NoCommand.NO_LIFTOFF, NoCommand.PREDICTED_FALL}
    assert not np.isin(np.arange(0, count, 10), answered).any()


def test_the_next_kink_is_the_first_of_saturation_end_ramp_end_and_a_stop_still_ahead() -> None:
    """A stop instant the lane has reached is served: the ramp's own kinks count again after it."""
    ramp = LaneTorque(tau0=-500.0, t_f=0.15, tau_max=math.inf, stop=0.05)
    assert kink(ramp, 0.0) == 0.05  # the stop comes first
    assert kink(ramp, 0.05) == 0.15  # standing on it: the ramp's end is next
    assert kink(ramp._replace(stop=0.01), 0.1) == 0.15
    saturated = ramp._replace(tau_max=400.0, stop=math.inf)  # |tau| > 400 until 0.15 * (1 - 400/500)
    assert kink(saturated, 0.0) == pytest.approx(0.03, rel=1e-12)
    assert kink(saturated, 0.05) == 0.15
