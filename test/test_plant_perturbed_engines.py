"""Perturbations in the three engines: one description, the same trajectories and failures everywhere,
random draws that depend on (seed, trajectory, stride) only, and nothing changed when nothing perturbs."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import numpy.typing as npt
import pytest
from support.failure_cases import PERTURBED_FAILURE_CASES, PerturbedFailureCase

from tdslip_ros.interfaces import (
    PERTURBATION_PARAMETERS,
    perturbation_parameters,
    perturbations_from_parameters,
)
from tdslip_ros.model import units
from tdslip_ros.model.events import EventKind, FailureKind, failure_code, failure_from_code
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.batch import BatchRun, Policy, batch_apex_return_map, simulate_strides
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.perturbations import (
    Mismatch,
    Perturbations,
    PlacementNoise,
    Pushes,
    SensingNoise,
    StrideConditions,
)
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.model.plant.terrain import FLAT, Blocks, Step
from tdslip_ros.model.policies import controllers

PARAMS = PAPER_PARAMS
BETA = math.radians(20.0)
TARGET_ENERGY = ApexState(1.0, 5.0).energy(PARAMS)


def regulator(y: npt.ArrayLike, xdot: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A proportional energy regulator in closed form, at 20 deg cut to the angles the (measured) apex
    admits. Closed form: each lane's command depends on that lane alone (the analytic policies' Newton
    iterations run until every lane of a call has converged, so their last bits depend on the call's other
    lanes), and it is cheap enough to answer thousands of apexes one by one."""
    y, xdot = np.atleast_1d(np.asarray(y, dtype=float)), np.atleast_1d(np.asarray(xdot, dtype=float))
    low, high = controllers.admissible_angles(PARAMS, y)
    energy = PARAMS.m * (PARAMS.g * y + 0.5 * xdot**2)
    tau0 = -273.0 + 2.0 * (energy - TARGET_ENERGY)
    return np.clip(BETA, low, high), tau0, np.full(y.shape, 0.13)


def random_perturbations(lanes: int, seed: int) -> tuple[np.ndarray, np.ndarray, Perturbations]:
    """Initial apexes and per-lane perturbations of every kind. Lanes 0-9 are pushed beyond the speed limit
    (state_limit), lanes 10-29 by +-6 m/s (half of them backwards: reversal); the rest are rough."""
    rng = np.random.default_rng(seed)
    size = np.where(np.arange(lanes) < 10, 40.0, np.where(np.arange(lanes) < 30, 6.0, 0.4))
    perturbations = Perturbations(
        terrain=Blocks(rng.uniform(0.0, 0.05, lanes), 0.4, rng.integers(0, 4, lanes)),
        sensing=SensingNoise(0.01, 0.1, seed=7),
        placement=PlacementNoise(math.radians(1.5), seed=8),
        tau_max=rng.uniform(150.0, 600.0, lanes),
        pushes=Pushes(((1, -0.3),), size=size, rate=np.where(size > 1.0, 1.0, 0.3), seed=9),
    )
    return rng.uniform(0.95, 1.15, lanes), rng.uniform(4.0, 5.5, lanes), perturbations


def exact_trajectory(
    y0: float, xdot0: float, perturbations: Perturbations, trajectory: int, strides: int
) -> tuple[list[tuple[float, float, float, float]], FailureKind | None]:
    """(x, ground, y above ground, xdot) per apex by the exact map, the draws realised stride by stride."""
    apex, x, ground = ApexState(y0, xdot0), 0.0, perturbations.terrain.height_at(0.0)
    apexes = [(x, ground, apex.y, apex.xdot)]
    tau_max = float(perturbations.tau_max)
    for stride in range(strides):
        draws = perturbations.draws([trajectory], stride, 1)
        measured_y = apex.y + draws.height_error[0, 0]
        measured_xdot = apex.xdot + draws.speed_error[0, 0]
        angle, tau0, t_f = (float(v[0]) for v in regulator(measured_y, measured_xdot))
        result = apex_return_map(
            PARAMS,
            apex,
            StanceCommand(angle, tau0, t_f),
            conditions=StrideConditions(
                x=x,
                ground=ground,
                terrain=perturbations.terrain,
                tau_max=tau_max,
                push=float(draws.push[0, 0]),
                angle_error=float(draws.angle_error[0, 0]),
            ),
        )
        if result.apex is None:
            return apexes, result.failure
        assert result.ground is not None and result.apex_x is not None
        apex, x, ground = result.apex, result.apex_x, result.ground
        apexes.append((x, ground, apex.y, apex.xdot))
    return apexes, None


def stepper_trajectory(
    y0: float, xdot0: float, perturbations: Perturbations, trajectory: int, strides: int
) -> tuple[list[tuple[float, float, float, float]], FailureKind | None]:
    """The same on the 1 kHz stepper, each apex answered with the regulator on the measured apex."""
    stepper = FixedStepStepper(
        PARAMS,
        ApexState(y0, xdot0),
        StanceCommand(BETA, -273.0, 0.13),
        perturbations=perturbations,
        trajectory=trajectory,
    )

    def answer() -> None:
        measured_y, measured_xdot = stepper.measured_apex
        angle, tau0, t_f = (float(v[0]) for v in regulator(measured_y - stepper.ground, measured_xdot))
        stepper.set_command(StanceCommand(angle, tau0, t_f))

    def apex_row() -> tuple[float, float, float, float]:
        state = stepper.apex_state
        return state.x, stepper.ground, state.y - stepper.ground, state.xdot

    answer()
    apexes = [apex_row()]
    for _ in range(10_000):
        if stepper.failed is not None or stepper.stride >= strides:
            break
        for event in stepper.step():
            if event.kind is EventKind.APEX and stepper.failed is None:
                apexes.append(apex_row())
                if stepper.stride < strides:
                    answer()
    return apexes, stepper.failed


def batch_run(
    y0: np.ndarray,
    xdot0: np.ndarray,
    perturbations: Perturbations,
    strides: int,
    trajectories: np.ndarray,
    policy: Policy | None = None,
) -> BatchRun:
    return simulate_strides(
        PARAMS,
        y0,
        xdot0,
        policy or (lambda stride, y, xdot: regulator(y, xdot)),
        strides,
        perturbations=perturbations,
        trajectories=trajectories,
    )


def test_exact_map_stepper_and_batch_agree_on_200_random_perturbed_trajectories() -> None:
    """Rough blocks, sensing noise, placement errors, saturation and pushes at once, per lane: the three
    engines give the same apexes (batch against exact map to 1e-9, the 1 kHz stepper to its own
    tolerance, 1e-8) and the same failure, by name, on every lane."""
    lanes, strides = 200, 3
    y0, xdot0, perturbations = random_perturbations(lanes, seed=21)
    batch = batch_run(y0, xdot0, perturbations, strides, np.arange(lanes))
    kinds: set[FailureKind | None] = set()
    scale = np.array([units.length_scale(PARAMS), units.length_scale(PARAMS), 1.0, units.speed_scale(PARAMS)])
    for lane in range(lanes):
        mine = perturbations.take(lane)
        exact, exact_failure = exact_trajectory(y0[lane], xdot0[lane], mine, lane, strides)
        stepped, stepper_failure = stepper_trajectory(y0[lane], xdot0[lane], mine, lane, strides)
        batch_failure = failure_from_code(int(batch.failure[lane]))
        assert exact_failure is stepper_failure is batch_failure, lane
        kinds.add(exact_failure)
        assert len(exact) == len(stepped)
        batch_rows = np.stack(
            [batch.x[:, lane], batch.ground[:, lane], batch.y[:, lane], batch.xdot[:, lane]], axis=1
        )
        assert np.all(np.isnan(batch_rows[len(exact) :, [0, 2, 3]]))  # the ground of a failed stance stays
        np.testing.assert_allclose(
            batch_rows[: len(exact)] / scale, np.array(exact) / scale, rtol=0, atol=1e-9
        )
        np.testing.assert_allclose(np.array(stepped) / scale, np.array(exact) / scale, rtol=0, atol=1e-8)
    assert {None, FailureKind.STATE_LIMIT, FailureKind.REVERSAL, FailureKind.TOE_STUBBING} <= kinds
    assert np.count_nonzero(batch.saturated) > 0 and np.count_nonzero(batch.failure == -1) > lanes // 3


def test_splitting_1000_trajectories_into_7_calls_gives_identical_results() -> None:
    """Random draws come from (seed, trajectory, stride): seven uneven calls, the lanes shuffled, give
    the results of one call bit for bit."""
    lanes, strides = 1000, 4
    y0, xdot0, perturbations = random_perturbations(lanes, seed=5)
    whole = batch_run(y0, xdot0, perturbations, strides, np.arange(lanes))
    order = np.random.default_rng(2).permutation(lanes)
    parts = np.split(order, [50, 51, 230, 400, 620, 777])
    assert len(parts) == 7
    for part in parts:
        split = batch_run(y0[part], xdot0[part], perturbations.take(part), strides, part)
        for field in dataclasses.fields(whole):
            ours, theirs = getattr(split, field.name), getattr(whole, field.name)[..., part]
            assert np.array_equal(ours, theirs, equal_nan=ours.dtype.kind == "f"), field.name
    assert 0 < np.count_nonzero(whole.failure == -1) < lanes


def test_nothing_perturbs_bit_for_bit() -> None:
    """Every perturbation at zero (flat ground, no noise, no push, no saturation) is the flat-ground run
    bit for bit in every engine, and so are zero-sized perturbations that take the perturbed code path
    (blocks of height 0, a torque limit never reached) in the batched engine."""
    none = Perturbations(sensing=SensingNoise(0.0, 0.0, seed=3), pushes=Pushes(size=0.5, rate=0.0))
    assert not none.active
    y0, xdot0 = np.linspace(0.95, 1.2, 8), np.linspace(4.0, 5.5, 8)
    plain = batch_run(y0, xdot0, Perturbations(), 5, np.arange(8))
    unperturbed = simulate_strides(PARAMS, y0, xdot0, lambda k, y, xdot: regulator(y, xdot), 5)
    zero_sized = batch_run(
        y0, xdot0, Perturbations(terrain=Blocks(0.0, 0.3, 1), tau_max=1e6), 5, np.arange(8)
    )
    for run in (plain, zero_sized):
        for name in ("y", "xdot", "hip_work", "damping_loss", "spring_loss", "failure", "failure_stride"):
            assert np.array_equal(getattr(run, name), getattr(unperturbed, name), equal_nan=True), name
    assert np.all(zero_sized.ground[np.isfinite(zero_sized.y)] == 0.0)
    command = StanceCommand(BETA, -273.0, 0.13)
    for engine_result in (
        apex_return_map(
            PARAMS,
            ApexState(1.0, 5.0),
            command,
            conditions=StrideConditions(terrain=FLAT, push=0.0, angle_error=0.0),
        ),
        apex_return_map(PARAMS, ApexState(1.0, 5.0), command),
    ):
        assert engine_result.apex == apex_return_map(PARAMS, ApexState(1.0, 5.0), command).apex
    stepped = FixedStepStepper(PARAMS, ApexState(1.0, 5.0), command, perturbations=none)
    reference = FixedStepStepper(PARAMS, ApexState(1.0, 5.0), command)
    for _ in range(400):
        assert stepped.step() == reference.step()
        assert stepped.state == reference.state
    # Zero-sized blocks through the terrain walk: numpy's square root against the flat path's float power
    # may differ in the last bit, no more.
    flat = apex_return_map(PARAMS, ApexState(1.0, 5.0), command)
    level = apex_return_map(
        PARAMS,
        ApexState(1.0, 5.0),
        command,
        conditions=StrideConditions(terrain=Blocks(0.0, 0.3, 1), tau_max=1e6),
    )
    assert flat.apex is not None and level.apex is not None and level.ground == 0.0
    assert level.apex.y == pytest.approx(flat.apex.y, rel=1e-14)
    assert level.apex.xdot == pytest.approx(flat.apex.xdot, rel=1e-14)


def test_random_draws_depend_on_seed_trajectory_and_stride_only() -> None:
    perturbations = Perturbations(
        sensing=SensingNoise(0.01, 0.1, seed=4),
        placement=PlacementNoise(0.02, seed=4),
        pushes=Pushes(((3, 0.25),), size=0.5, rate=0.5, seed=4),
    )
    whole = perturbations.draws([0, 7, 3], 0, 150)
    for trajectory, lane in ((3, 2), (7, 1)):
        for first, count in ((0, 1), (63, 2), (100, 50)):
            part = perturbations.draws([trajectory], first, count)
            for name in ("height_error", "speed_error", "angle_error", "push"):
                assert np.array_equal(
                    getattr(part, name)[:, 0], getattr(whole, name)[first : first + count, lane]
                )
    # Equal seeds in different kinds are independent streams; turning one kind on leaves the others.
    assert not np.allclose(whole.height_error / 0.01, whole.angle_error / 0.02)
    alone = Perturbations(sensing=SensingNoise(0.01, 0.1, seed=4)).draws([0, 7, 3], 0, 150)
    assert np.array_equal(alone.height_error, whole.height_error) and not alone.angle_error.any()
    # Sizes: normal sensor and angle errors; pushes of +-size at about the rate, plus the chosen one.
    many = perturbations.draws(np.arange(200), 0, 50)
    assert np.std(many.height_error) == pytest.approx(0.01, rel=0.05)
    assert np.std(many.angle_error) == pytest.approx(0.02, rel=0.05)
    random_pushes = np.delete(many.push, 3, axis=0)
    assert set(np.unique(random_pushes)) == {-0.5, 0.0, 0.5}
    assert np.mean(random_pushes != 0.0) == pytest.approx(0.5, abs=0.02)
    assert set(np.unique(many.push[3])) == {-0.25, 0.25, 0.75}


def test_the_sensor_changes_what_the_controller_sees_not_the_plant() -> None:
    """Under a policy that ignores its input the hopper moves alike with and without sensing noise; the
    measured apex is the true one plus the drawn error."""
    y0, xdot0 = np.full(4, 1.0), np.full(4, 5.0)

    def constant(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[float, float, float]:
        return BETA, -273.0, 0.13

    noisy = Perturbations(sensing=SensingNoise(0.02, 0.2, seed=1))
    seen = simulate_strides(PARAMS, y0, xdot0, constant, 4, perturbations=noisy)
    clean = simulate_strides(PARAMS, y0, xdot0, constant, 4)
    assert np.array_equal(seen.y, clean.y) and np.array_equal(seen.xdot, clean.xdot)
    draws = noisy.draws(np.arange(4), 0, 4)
    assert np.array_equal(seen.measured_y, seen.y[:-1] + draws.height_error)
    assert np.array_equal(seen.measured_xdot, seen.xdot[:-1] + draws.speed_error)
    assert np.array_equal(clean.measured_y, clean.y[:-1])


def test_a_push_changes_the_energy_by_its_kinetic_energy() -> None:
    """Energy per stride with a push at the apex: E' - E = W_hip - E_c - E_k + m ((v + dv)^2 - v^2) / 2."""
    command = StanceCommand(BETA, -273.0, 0.13)
    for push in (-0.8, 0.5):
        start = ApexState(1.0, 5.0)
        result = apex_return_map(PARAMS, start, command, conditions=StrideConditions(push=push))
        assert result.apex is not None and result.energy is not None
        kick = 0.5 * PARAMS.m * ((start.xdot + push) ** 2 - start.xdot**2)
        gain = result.apex.energy(PARAMS) - start.energy(PARAMS)
        assert gain == pytest.approx(result.energy.net_gain + kick, abs=1e-9 * start.energy(PARAMS))
        batch = batch_apex_return_map(
            PARAMS, 1.0, 5.0, BETA, -273.0, 0.13, conditions=StrideConditions(push=push)
        )
        assert batch.y == pytest.approx(result.apex.y, abs=1e-9)


def test_saturated_strides_are_counted() -> None:
    y0, xdot0 = np.full(3, 1.0), np.full(3, 5.0)

    def ramp(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[float, np.ndarray, float]:
        return BETA, np.array([-200.0, -300.0, -400.0])[: y.size], 0.13

    run = simulate_strides(PARAMS, y0, xdot0, ramp, 2, perturbations=Perturbations(tau_max=250.0))
    assert run.saturated.tolist() == [[False, True, True], [False, True, True]]
    stepper = FixedStepStepper(
        PARAMS,
        ApexState(1.0, 5.0),
        StanceCommand(BETA, -300.0, 0.13),
        perturbations=Perturbations(tau_max=250.0),
    )
    torques = []
    while stepper.stride < 1:
        stepper.step()
        torques.append(stepper.state.hip_torque)
    assert stepper.saturated_strides == 1 and min(torques) == -250.0


@pytest.mark.parametrize("case", PERTURBED_FAILURE_CASES, ids=[case.name for case in PERTURBED_FAILURE_CASES])
def test_each_perturbed_failure_in_every_engine(case: PerturbedFailureCase) -> None:
    p = case.perturbations
    draws = p.draws([0], 0, 1)
    exact = apex_return_map(
        case.params,
        case.apex,
        case.command,
        conditions=StrideConditions(
            terrain=p.terrain,
            tau_max=float(p.tau_max),
            push=float(draws.push[0, 0]),
            angle_error=float(draws.angle_error[0, 0]),
        ),
    )
    assert exact.failure is case.kind and case.phrase in exact.reason, exact.reason
    stepper = FixedStepStepper(case.params, case.apex, case.command, perturbations=p)
    for _ in range(5000):
        events = stepper.step()
        if stepper.failed is not None:
            break
    failure = events[-1]
    assert failure.kind is EventKind.FAILURE and failure.failure is case.kind
    assert failure.reason.split(" ")[:2] == exact.reason.split(" ")[:2]
    assert exact.failure_state is not None and failure.t == pytest.approx(exact.failure_state.t, abs=1e-8)

    def command(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[float, float, float]:
        return case.command.touchdown_angle, case.command.tau0, case.command.t_f

    batch = simulate_strides(case.params, case.apex.y, case.apex.xdot, command, 1, perturbations=p)
    assert int(batch.failure) == failure_code(case.kind)


def test_text_forms_and_node_settings_read_back() -> None:
    perturbations = Perturbations(
        terrain=Blocks(0.02, 0.5, 3),
        sensing=SensingNoise(0.005, 0.05, seed=1),
        placement=PlacementNoise(0.01, seed=2),
        tau_max=400.0,
        pushes=Pushes(((5, 0.3), (2, -0.5)), size=0.2, rate=0.1, seed=4),
    )
    settings = perturbation_parameters(perturbations)
    assert tuple(settings) == tuple(PERTURBATION_PARAMETERS.values())
    assert settings["pushes"] == "2:-0.5;5:0.3;random:size=0.2,rate=0.1,seed=4"
    again = perturbations_from_parameters({name: str(value) for name, value in settings.items()})
    assert perturbation_parameters(again) == settings
    assert perturbations_from_parameters({}).active is False
    assert Pushes.parse(settings["pushes"]).spec() == settings["pushes"]
    assert SensingNoise.parse("height=0.005,speed=0.05,seed=1").spec() == perturbations.sensing.spec()
    mismatch = Mismatch.parse("mass=1.1,damping=0.5")
    assert mismatch.spec() == "mass=1.1,stiffness=1.0,damping=0.5,rest_length=1.0"
    planned = mismatch.controller_params(PARAMS)
    assert isinstance(planned, HopperParams)
    assert (planned.m, planned.k, planned.c, planned.r0) == (
        PARAMS.m * 1.1,
        PARAMS.k,
        PARAMS.c * 0.5,
        PARAMS.r0,
    )


@pytest.mark.parametrize(
    ("parse", "text", "phrase"),
    [
        (Pushes.parse, "5:fast", "neither STRIDE:DV"),
        (Pushes.parse, "-1:0.3", "stride must be a non-negative integer"),
        (Pushes.parse, "random:size=0.3", "missing rate=..."),
        (Pushes.parse, "random:size=0.3,rate=2", "rate must be in [0, 1]"),
        (SensingNoise.parse, "height=-0.1", "height noise must be finite and >= 0"),
        (SensingNoise.parse, "heigth=0.1", "is not one of height=..."),
        (Mismatch.parse, "mass=0", "mass mismatch factor must be finite and > 0"),
        (Mismatch.parse, "gravity=1.1", "is not one of mass=..."),
    ],
)
def test_malformed_perturbations_are_refused_in_one_line(parse: object, text: str, phrase: str) -> None:
    with pytest.raises(ParameterError, match=phrase.replace("[", r"\[").replace("]", r"\]")) as error:
        parse(text)  # type: ignore[operator]
    assert "\n" not in str(error.value)


def test_per_lane_perturbations_are_refused_by_the_single_trajectory_engines() -> None:
    lanes = Perturbations(terrain=Step(np.array([0.1, -0.1]), 1.0))
    with pytest.raises(ParameterError, match="per-lane"):
        FixedStepStepper(PARAMS, ApexState(1.0, 5.0), StanceCommand(BETA, -273.0, 0.13), perturbations=lanes)
    with pytest.raises(ParameterError, match="push must be finite"):
        batch_apex_return_map(
            PARAMS, 1.0, 5.0, BETA, -273.0, 0.13, conditions=StrideConditions(push=[0.0, np.nan])
        )
