"""The batched engine with a rigid body (issue 36): its strides against the exact map, the fixed-body limit,
the energy balance with the rotation, the body's frame, tipping and the other failures, and its refusals.

Independent truth: the exact map (scipy's DOP853 at rtol = atol = 1e-13, its own flight, touchdown and event
location) from each apex the batched engine reached; the point mass's batched strides, which a hip at the
centre of mass leaves unchanged whatever the inertia, while the hip's torque spins the body by
-int(tau) / J; the energy balance of the stride, J phidot^2 / 2 included; and the body's frame, which only
R(phi) d sees (turning d by alpha in the body and the pitch by -alpha changes nothing but the pitch).

Mirror symmetry (x, theta, phi, tau and hip_x reversed) does not apply to whole strides here: the engines
hop forwards only (a touchdown angle in (0, pi/2), a backward liftoff fails as reversal); the equations'
symmetry is test_plant_rigid_body.py's.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from support.rigid_bodies import (
    BETA,
    PIVOT_BODIES,
    RAMP_BODIES,
    TIPPING,
    hip_regulator,
    ramp_start,
    with_body,
)

from tdslip_ros.model.events import FailureKind, failure_code, failure_from_code
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody, StanceCommand
from tdslip_ros.model.plant.batch import (
    BatchStrideResult,
    batch_apex_return_map,
    batch_feedback_return_map,
    simulate_strides,
)
from tdslip_ros.model.plant.exact_map import StrideResult, apex_return_map
from tdslip_ros.model.plant.perturbations import StrideConditions
from tdslip_ros.model.plant.stance_laws import StanceFeedback
from tdslip_ros.model.plant.stride_kernels import apex_stride, compiled_apex_return_map
from tdslip_ros.model.plant.terrain import Step
from tdslip_ros.model.policies.virtual_pivot import VirtualPivot

TOLERANCE = 1e-9
"""m, m/s, rad, rad/s, s and J: the batched engine's strides against the exact map's, as the point mass's."""


def lane_apex(result: BatchStrideResult, lane: int) -> ApexState:
    return ApexState(result.y[lane], result.xdot[lane], result.pitch[lane], result.pitch_rate[lane])


def assert_lane_is_the_exact_maps(result: BatchStrideResult, lane: int, exact: StrideResult) -> None:
    """The lane's failure, next apex (its position and time too), stance time and energy flows are the exact
    map's (NaN where it has none: a failure before liftoff)."""
    assert failure_from_code(int(result.failure[lane])) is exact.failure, exact.reason
    if exact.liftoff is None:
        assert np.isnan([result.stance_time[lane], result.hip_work[lane]]).all()
    else:
        assert exact.touchdown is not None
        stance_time = exact.liftoff.t - exact.touchdown.t
        assert result.stance_time[lane] == pytest.approx(stance_time, abs=TOLERANCE)
    if exact.energy is None:
        assert np.isnan(result.hip_work[lane])
    else:
        flows = (result.hip_work[lane], result.damping_loss[lane], result.spring_loss[lane])
        expected = (exact.energy.hip_work, exact.energy.damping_loss, exact.energy.spring_loss)
        assert flows == pytest.approx(expected, abs=TOLERANCE)
    if exact.apex is None:
        assert np.isnan([result.y[lane], result.pitch[lane], result.pitch_rate[lane]]).all()
        return
    assert exact.apex_time is not None and exact.apex_x is not None
    reached = (*dataclasses.astuple(lane_apex(result, lane)), result.stride_time[lane], result.x[lane])
    expected_apex = (*dataclasses.astuple(exact.apex), exact.apex_time, exact.apex_x)
    assert reached == pytest.approx(expected_apex, abs=TOLERANCE)


def regulated_lanes(params: HopperParams, apexes: list[ApexState]) -> tuple[list[StanceCommand], dict]:
    """hip_regulator's command per lane and the batched engine's arguments for them."""
    policy = hip_regulator(params)
    commands = [policy(apex) for apex in apexes]
    columns = {
        name: np.array([getattr(apex, name) for apex in apexes])
        for name in ("y", "xdot", "pitch", "pitch_rate")
    }
    ramps = {
        name: np.array([getattr(c, name) for c in commands]) for name in ("touchdown_angle", "tau0", "t_f")
    }
    return commands, {**columns, **ramps}


def test_ramp_strides_are_the_exact_maps() -> None:
    """Every body of RAMP_BODIES from two apexes, stride after stride from the apexes the engine reached: 24
    strides of ramp_start (the stepper's), and those of a start turning the other way until it fails."""
    hopped, turned = 0, 0.0
    for body, count in RAMP_BODIES.values():
        params = with_body(body)
        start = ramp_start(body)
        apexes = [start, dataclasses.replace(start, pitch=-0.05, pitch_rate=0.3)]
        alive = [0, 1]
        for _ in range(count):
            commands, lanes = regulated_lanes(params, apexes)
            result = batch_apex_return_map(
                params,
                lanes["y"],
                lanes["xdot"],
                lanes["touchdown_angle"],
                lanes["tau0"],
                lanes["t_f"],
                pitch=lanes["pitch"],
                pitch_rate=lanes["pitch_rate"],
            )
            for lane, (apex, command) in enumerate(zip(apexes, commands, strict=True)):
                exact = apex_return_map(params, apex, command, rtol=1e-13, atol=1e-13)
                assert_lane_is_the_exact_maps(result, lane, exact)
            hopped += alive.count(0)
            turned = max(turned, abs(result.pitch_rate[0] - start.pitch_rate))
            keep = [lane for lane in range(len(apexes)) if result.failure[lane] == -1]
            alive = [alive[lane] for lane in keep]
            apexes = [lane_apex(result, lane) for lane in keep]
        assert 0 in alive  # ramp_start's lane hopped all its strides
    assert hopped == 24
    assert turned > 0.1  # the bodies turn: the strides test the pitch, not a body held still


@pytest.mark.parametrize("name", PIVOT_BODIES)
def test_strides_under_the_virtual_pivot_are_the_exact_maps(name: str) -> None:
    """Stance feedback: the law sees each lane's pitch and rate at its sample instants; three lanes at
    different apex times on the sample clock, each stride against the exact map at that apex time."""
    body = PIVOT_BODIES[name]
    params = with_body(body)
    law = VirtualPivot(params, above=0.3, forward=0.03)
    apexes = [ApexState(1.0 - body.hip_y, 5.0, pitch, -0.2) for pitch in (0.05, 0.0, -0.03)]
    t = np.array([0.0, 0.0004, 0.0123])
    for _ in range(3):
        result = batch_feedback_return_map(
            params,
            [a.y for a in apexes],
            [a.xdot for a in apexes],
            BETA,
            law,
            pitch=[a.pitch for a in apexes],
            pitch_rate=[a.pitch_rate for a in apexes],
            apex_time=t,
        )
        for lane, apex in enumerate(apexes):
            exact = apex_return_map(
                params, apex, StanceFeedback(BETA, law), rtol=1e-13, atol=1e-13, apex_time=float(t[lane])
            )
            assert exact.failure is None
            assert_lane_is_the_exact_maps(result, lane, exact)
            torques = np.array([tau for _, tau in exact.stance_torques])
            assert np.ptp(torques) > 10.0  # the law acts
        apexes = [lane_apex(result, lane) for lane in range(len(apexes))]
        t = t + result.stride_time


@pytest.mark.parametrize("inertia", [50.0, 200.0, 1e6])
def test_a_hip_at_the_centre_of_mass_hops_the_point_masss_batched_strides(inertia: float) -> None:
    """d = 0: the centre of mass moves as the point mass does for any inertia, lane by lane over 4 strides of
    a grid of apexes and ramps; the body only spins, J dphidot = -int(tau) = -I per stance (I = tau0 t_f / 2),
    and the hip's work int(tau (thetadot - phidot)) is the point mass's less int(tau phidot) =
    w I - I^2 / (2 J), w the pitch rate at touchdown. Each lane starts spinning backwards at 1.5 I / J, to
    turn back and forth within its tip_limit."""
    y, xdot = (a.ravel() for a in np.meshgrid(np.linspace(1.1, 1.35, 4), np.linspace(3.0, 5.0, 4)))
    rng = np.random.default_rng(5)
    angle = np.radians(rng.uniform(18.0, 24.0, y.size))
    tau0, t_f = rng.uniform(-700.0, -100.0, y.size), rng.uniform(0.05, 0.12, y.size)  # ramps end in stance
    params = with_body(RigidBody(inertia, tip_limit=math.pi))
    pitch, pitch_rate = np.full(y.size, 0.1), 1.5 * tau0 * t_f / 2.0 / inertia
    lanes = np.arange(y.size)
    hopped = 0
    for _ in range(4):
        point = batch_apex_return_map(PAPER_PARAMS, y, xdot, angle, tau0, t_f)
        rigid = batch_apex_return_map(params, y, xdot, angle, tau0, t_f, pitch=pitch, pitch_rate=pitch_rate)
        np.testing.assert_array_equal(rigid.failure, point.failure)
        for field in ("y", "xdot", "stride_time", "x", "damping_loss", "spring_loss"):
            np.testing.assert_allclose(getattr(rigid, field), getattr(point, field), rtol=0.0, atol=TOLERANCE)
        ok = rigid.failure == -1
        assert np.all(rigid.stance_time[ok] > t_f[ok])
        impulse = tau0 * t_f / 2.0
        spun = pitch_rate - impulse / inertia
        np.testing.assert_allclose(rigid.pitch_rate[ok], spun[ok], rtol=0.0, atol=TOLERANCE)
        body_work = pitch_rate * impulse - impulse**2 / (2.0 * inertia)
        np.testing.assert_allclose(
            rigid.hip_work[ok], (point.hip_work - body_work)[ok], rtol=0.0, atol=TOLERANCE
        )
        hopped += int(ok.sum())
        y, xdot, pitch, pitch_rate = rigid.y[ok], rigid.xdot[ok], rigid.pitch[ok], rigid.pitch_rate[ok]
        angle, tau0, t_f, lanes = angle[ok], tau0[ok], t_f[ok], lanes[ok]
    assert hopped >= 30 and y.size >= 5


# Bodies standing on and hanging from their hips, behind and ahead, light and heavy.
BALANCE_BODIES = [
    RigidBody.from_gyration(80.0, 0.3, hip_y=-0.3, tip_limit=math.pi),
    RigidBody(10.0, hip_x=-0.1, hip_y=-0.2, tip_limit=math.pi),
    RigidBody(40.0, hip_x=0.05, hip_y=0.1, tip_limit=math.pi),
    RigidBody(7.2, hip_x=-0.15, hip_y=-0.1, tip_limit=math.pi),
]


@pytest.mark.parametrize("body", BALANCE_BODIES, ids=["trunk", "behind", "above", "light"])
def test_the_energy_balance_closes_with_the_rotation(body: RigidBody) -> None:
    """The apexes' total energy (J pitch_rate^2 / 2 included) changes by hip work - damper loss - spring
    loss, on a grid of lanes (apexes, pitches, rates, ramps); the rotation's share is not negligible."""
    params = with_body(body)
    y, xdot, pitch = (a.ravel() for a in np.meshgrid(np.linspace(1.15, 1.35, 3), [3.5, 4.5], [-0.05, 0.05]))
    y = y - body.hip_y
    pitch_rate, tau0 = -3.0 * pitch, np.linspace(-700.0, -200.0, y.size)
    result = batch_apex_return_map(params, y, xdot, BETA, tau0, 0.15, pitch=pitch, pitch_rate=pitch_rate)
    ok = result.failure == -1
    assert ok.sum() >= 8
    before = params.m * (params.g * y + 0.5 * xdot**2) + 0.5 * body.inertia * pitch_rate**2
    after = (
        params.m * (params.g * result.y + 0.5 * result.xdot**2) + 0.5 * body.inertia * result.pitch_rate**2
    )
    net = result.hip_work - result.damping_loss - result.spring_loss
    np.testing.assert_allclose((after - before)[ok], net[ok], rtol=0.0, atol=1e-10 * np.max(before))
    rotation = 0.5 * body.inertia * (result.pitch_rate**2 - pitch_rate**2)
    assert np.max(np.abs(rotation[ok])) > 1e-3 * np.max(np.abs(net[ok]))


def test_turning_the_bodys_frame_turns_only_the_pitch() -> None:
    """Only R(phi) d enters the motion: the hip's offset turned by alpha in the body, with the pitch turned by
    -alpha, gives the same strides, the pitch alpha lower."""
    body = RigidBody(20.0, hip_x=-0.15, hip_y=-0.1, tip_limit=math.pi)
    start = ramp_start(body)
    commands, lanes = regulated_lanes(with_body(body), [start, dataclasses.replace(start, pitch_rate=0.4)])
    args = (lanes["y"], lanes["xdot"], lanes["touchdown_angle"], lanes["tau0"], lanes["t_f"])
    reference = batch_apex_return_map(
        with_body(body), *args, pitch=lanes["pitch"], pitch_rate=lanes["pitch_rate"]
    )
    assert np.all(reference.failure == -1)
    for alpha in (0.7, -2.0):
        cos_a, sin_a = math.cos(alpha), math.sin(alpha)
        turned = dataclasses.replace(
            body, hip_x=cos_a * body.hip_x - sin_a * body.hip_y, hip_y=sin_a * body.hip_x + cos_a * body.hip_y
        )
        result = batch_apex_return_map(
            with_body(turned), *args, pitch=lanes["pitch"] - alpha, pitch_rate=lanes["pitch_rate"]
        )
        for field in ("y", "xdot", "pitch_rate", "x", "stride_time", "hip_work", "damping_loss"):
            np.testing.assert_allclose(getattr(result, field), getattr(reference, field), atol=TOLERANCE)
        np.testing.assert_allclose(result.pitch, reference.pitch - alpha, atol=TOLERANCE)


@pytest.mark.parametrize("name", TIPPING)
def test_tipping_is_the_exact_maps_failure(name: str) -> None:
    """Each way to tip in a lane of its own, next to a lane of the same body under a twentieth of the torque,
    not turning at its apex."""
    body, apex, tau0, phrase, max_apex_height = TIPPING[name]
    params = with_body(body)
    limits = PlausibilityLimits.for_hopper(params)
    if max_apex_height is not None:
        limits = dataclasses.replace(limits, max_apex_height=max_apex_height)
    command = StanceCommand(math.radians(22.0), tau0, 0.15)
    exact = apex_return_map(params, apex, command, rtol=1e-13, atol=1e-13, limits=limits)
    assert exact.failure is FailureKind.TIPPED and phrase in exact.reason
    result = batch_apex_return_map(
        params,
        apex.y,
        apex.xdot,
        command.touchdown_angle,
        [tau0, 0.02 * tau0],
        0.15,
        pitch=apex.pitch,
        pitch_rate=[apex.pitch_rate, 0.0],
        limits=limits,
    )
    assert result.failure[0] == failure_code(FailureKind.TIPPED)
    assert_lane_is_the_exact_maps(result, 0, exact)
    calm = apex_return_map(
        params,
        dataclasses.replace(apex, pitch_rate=0.0),
        dataclasses.replace(command, tau0=0.02 * tau0),
        rtol=1e-13,
        atol=1e-13,
        limits=limits,
    )
    assert_lane_is_the_exact_maps(result, 1, calm)


def test_each_lane_fails_as_the_exact_map_says() -> None:
    """A grid of apexes and commands whose lanes fail in several ways (the hip too low for the leg, the
    torque beyond the limits, reversal, tipping) beside lanes that hop, under saturation, a push and a
    placement error: lane by lane the exact map's failure and apex."""
    body = RigidBody(5.0, hip_x=-0.1, hip_y=-0.2, tip_limit=0.6)
    params = with_body(body)
    rng = np.random.default_rng(3)
    lanes = 60
    y = rng.uniform(1.0, 1.5, lanes)
    xdot = rng.uniform(0.3, 6.0, lanes)
    angle = np.radians(rng.uniform(10.0, 30.0, lanes))
    tau0 = rng.uniform(-1500.0, 200.0, lanes)
    tau0[:3] = [5e4, -5e4, 3e4]  # beyond the actuator's limit
    t_f = rng.uniform(0.05, 0.25, lanes)
    pitch, pitch_rate = rng.uniform(-0.5, 0.5, lanes), rng.uniform(-3.0, 3.0, lanes)
    tau_max, push, angle_error = 700.0, rng.uniform(-0.5, 0.5, lanes), rng.uniform(-0.02, 0.02, lanes)
    conditions = StrideConditions(tau_max=tau_max, push=push, angle_error=angle_error)
    result = batch_apex_return_map(
        params, y, xdot, angle, tau0, t_f, pitch=pitch, pitch_rate=pitch_rate, conditions=conditions
    )
    kinds = set()
    for lane in range(lanes):
        exact = apex_return_map(
            params,
            ApexState(y[lane], xdot[lane], pitch[lane], pitch_rate[lane]),
            StanceCommand(angle[lane], tau0[lane], t_f[lane]),
            rtol=1e-13,
            atol=1e-13,
            conditions=StrideConditions(tau_max=tau_max, push=push[lane], angle_error=angle_error[lane]),
        )
        assert_lane_is_the_exact_maps(result, lane, exact)
        assert result.saturated[lane] == (abs(tau0[lane]) > tau_max)
        kinds.add(exact.failure)
    assert {None, FailureKind.TOE_STUBBING, FailureKind.STATE_LIMIT, FailureKind.TIPPED} <= kinds


def test_the_fixed_bodys_pitch_is_zero_where_it_hops() -> None:
    for engine in (batch_apex_return_map, compiled_apex_return_map):
        result = engine(PAPER_PARAMS, [1.2, 0.5], 4.0, BETA, -600.0, 0.15)
        assert result.failure[1] == failure_code(FailureKind.TOE_STUBBING)
        np.testing.assert_array_equal(result.pitch, [0.0, np.nan])
        np.testing.assert_array_equal(result.pitch_rate, [0.0, np.nan])


def test_what_the_batched_engine_does_not_run_for_a_body_is_refused_by_name() -> None:
    params = with_body(RigidBody(20.0, hip_y=-0.2, tip_limit=1.0))
    lanes = ([1.3, 1.3], [4.0, 4.0], BETA, -150.0, 0.15)
    with pytest.raises(ParameterError, match="flat ground at height 0.*step terrain"):
        batch_apex_return_map(params, *lanes, conditions=StrideConditions(terrain=Step(0.5, 0.05)))
    with pytest.raises(ParameterError, match="flat ground at height 0"):
        batch_apex_return_map(params, *lanes, conditions=StrideConditions(ground=[0.0, 0.1]))
    with pytest.raises(ParameterError, match="simulate_strides runs the paper's fixed body only"):
        simulate_strides(params, 1.3, 4.0, lambda k, y, xdot: (BETA, -150.0, 0.15), 2)
    with pytest.raises(ParameterError, match="the compiled lane stride .*fixed body only"):
        compiled_apex_return_map(params, *lanes)
    with pytest.raises(ParameterError, match="the compiled lane stride .*fixed body only"):
        apex_stride(params, ApexState(1.3, 4.0), StanceCommand(BETA, -150.0, 0.15))
    with pytest.raises(
        ParameterError, match=r"apex pitch must be inside the body's tip_limit 1.0 rad.*lane 1"
    ):
        batch_apex_return_map(params, *lanes, pitch=[0.0, -1.0])
    with pytest.raises(ParameterError, match=r"apex pitch_rate must be finite, got .*nan.* in lane 0"):
        batch_feedback_return_map(
            params, *lanes[:3], VirtualPivot(params, above=0.3), pitch_rate=[math.nan, 0.0]
        )
    for name in ("pitch", "pitch_rate"):
        with pytest.raises(ParameterError, match=f"apex {name} must be 0 on the fixed body.*lane 1"):
            batch_apex_return_map(PAPER_PARAMS, *lanes, **{name: [0.0, 0.1]})
