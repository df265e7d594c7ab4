"""Uneven ground: the terrains, their text forms, where a falling toe lands, and a whole stride on a step
checked against an independent integration in Cartesian coordinates."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from tdslip_ros.model.events import FailureKind
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, ParameterError, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.perturbations import StrideConditions
from tdslip_ros.model.plant.terrain import (
    FLAT,
    Blocks,
    Profile,
    Step,
    Terrain,
    block_normals,
    parse_terrain,
    touchdown,
)

PARAMS = PAPER_PARAMS
COMMAND = StanceCommand(math.radians(20.0), -273.0, 0.13)
PROFILE = Profile((0.5, 0.9, 0.9, 1.4, 2.0, 2.0), (0.0, 0.03, -0.02, 0.04, -0.01, 0.05))


@pytest.mark.parametrize(
    "terrain",
    [FLAT, Step(-0.05, 0.8), Blocks(0.02, 0.5, 3), Blocks(0.01, 0.25, 7, start=-1.5), PROFILE],
    ids=lambda terrain: terrain.kind,
)
def test_text_form_reads_back_to_the_same_ground(terrain: Terrain) -> None:
    again = parse_terrain(terrain.spec())
    assert again.spec() == terrain.spec()
    x = np.linspace(-3.0, 6.0, 2001)
    assert np.array_equal(again.height(x), terrain.height(x))
    # One point at a time (the plant's 1 kHz path) gives the same heights, bit for bit.
    assert [terrain.height_at(value) for value in x] == terrain.height(x).tolist()


def test_heights_of_each_terrain() -> None:
    x = np.array([-1.0, 0.0, 0.79, 0.8, 3.0])
    assert np.array_equal(FLAT.height(x), np.zeros(5))
    assert Step(-0.05, 0.8).height(x).tolist() == [0.0, 0.0, 0.0, -0.05, -0.05]
    blocks = Blocks(0.02, 0.5, 3, start=0.0)
    assert blocks.height_at(-0.1) == 0.0  # flat before the start
    assert blocks.height_at(0.26) == 0.02 * float(block_normals(3, 0))
    assert blocks.height_at(1.0) == 0.02 * float(block_normals(3, 2))  # right-continuous at an edge
    # The profile: linear between points, a vertical edge at a repeated x, constant beyond the ends.
    assert PROFILE.height_at(0.0) == 0.0 and PROFILE.height_at(3.0) == 0.05
    assert PROFILE.height_at(0.7) == pytest.approx(0.015, abs=1e-15)
    assert PROFILE.height_at(0.9) == -0.02 and PROFILE.height_at(np.nextafter(0.9, 0.0)) == pytest.approx(
        0.03
    )
    assert PROFILE.height_at(1.15) == pytest.approx(0.01, abs=1e-15)


def test_block_heights_depend_on_seed_and_index_only() -> None:
    """Whatever the order, the lanes or the chunk a block falls in, block j of a seed has one height."""
    index = np.arange(0, 300)
    all_at_once = block_normals(5, index)
    one_by_one = np.array([float(block_normals(5, j)) for j in index[::-1]])[::-1]
    assert np.array_equal(all_at_once, one_by_one)
    mixed = block_normals(np.array([5, 6, 5, 6]), np.array([299, 0, 0, 299]))
    assert mixed.tolist() == [
        all_at_once[299],
        float(block_normals(6, 0)),
        all_at_once[0],
        float(block_normals(6, 299)),
    ]
    assert not np.array_equal(block_normals(6, index), all_at_once)
    assert abs(np.mean(all_at_once)) < 0.2 and 0.8 < np.std(all_at_once) < 1.2  # standard normals
    # Per-lane sigma scales one shape; per-lane seeds give each lane its own ground.
    lanes = Blocks(np.array([0.01, 0.03]), 0.5, 5)
    x = np.array([1.3, 1.3])
    assert lanes.height(x).tolist() == [0.01 * all_at_once[2], 0.03 * all_at_once[2]]


def test_profile_from_csv(tmp_path: Path) -> None:
    path = tmp_path / "ground.csv"
    path.write_text("x, height\n0.5, 0.0\n0.9, 0.03\n0.9, -0.02\n1.4, 0.04\n2.0, -0.01\n2.0, 0.05\n")
    read = parse_terrain(f"profile:file={path}")
    assert read.spec() == PROFILE.spec()
    for text, phrase in [
        ("x,height\n1.0,0\n0.5,0\n", "must not decrease"),
        ("1.0,0\n1.0,0.1\n1.0,0.2\n", "once"),
        ("1.0,0\n2.0,abc\n", "line 2"),
        ("x,height\n", "no 'x, height' rows"),
    ]:
        path.write_text(text)
        with pytest.raises(ParameterError, match=phrase):
            parse_terrain(f"profile:file={path}")
    with pytest.raises(ParameterError, match="No such file"):
        parse_terrain(f"profile:file={tmp_path / 'missing.csv'}")


@pytest.mark.parametrize(
    ("text", "phrase"),
    [
        ("hills", "is not one of: flat"),
        ("blocks:sigma=0.02,length=0.5", "missing seed=..."),
        ("blocks:sigma=0.02,length=0,seed=1", "length must be finite and > 0"),
        ("blocks:sigma=-1,length=0.5,seed=1", "sigma must be finite and >= 0"),
        ("blocks:sigma=0.02,length=0.5,seed=1.5", "seed='1.5' is not a valid int"),
        ("blocks:sigma=0.02,width=0.5,seed=1", "'width=0.5' is not one of sigma=..."),
        ("step:height=nan,x=1", "step height must be finite"),
        ("step:height=0.1,height=0.2,x=1", "height is given twice"),
        ("profile:points=0/0;x/1", "not 'x/height"),
    ],
)
def test_malformed_terrain_is_refused_in_one_line(text: str, phrase: str) -> None:
    with pytest.raises(ParameterError, match=phrase) as error:
        parse_terrain(text)
    assert "\n" not in str(error.value)


def _first_contact(terrain: Terrain, x0: float, y0: float, xdot: float, angle: float) -> float:
    """The first time the toe of a leg placed at an apex (x0, y0) is at or below the ground under it:
    sampled every 10 us along the path, then bisected to 1e-14 s (independent of the pieces)."""
    sin_td, cos_td = math.sin(angle), math.cos(angle)

    def below(t: np.ndarray) -> np.ndarray:
        toe_x = x0 + PARAMS.r0 * sin_td + xdot * t
        toe_y = y0 - 0.5 * PARAMS.g * t * t - PARAMS.r0 * cos_td
        return np.asarray(toe_y <= terrain.height(toe_x))

    t = np.arange(0.0, 1.0, 1e-5)
    first = int(np.argmax(below(t)))
    assert first > 0 and below(t[first : first + 1])[0]
    low, high = t[first - 1], t[first]
    while high - low > 1e-14:
        middle = 0.5 * (low + high)
        low, high = (low, middle) if below(np.array([middle]))[0] else (middle, high)
    return float(high)


@pytest.mark.parametrize(
    "terrain",
    [Step(0.05, 1.0), Step(-0.05, 1.0), Blocks(0.03, 0.2, 11), PROFILE],
    ids=lambda terrain: terrain.kind + ("-up" if getattr(terrain, "height_change", 0) > 0 else ""),
)
def test_touchdown_is_the_first_contact_of_the_falling_toe(terrain: Terrain) -> None:
    rng = np.random.default_rng(3)
    lanes = 60
    x0 = rng.uniform(-0.5, 1.5, lanes)
    y0 = rng.uniform(1.0, 1.15, lanes)
    xdot = rng.uniform(-1.0, 6.0, lanes)
    angle = np.radians(rng.uniform(10.0, 30.0, lanes))
    landing = touchdown(terrain, x0, y0, xdot, np.sin(angle), np.cos(angle), PARAMS.r0, PARAMS.g)
    edges = 0
    for lane in range(lanes):
        toe_x0 = x0[lane] + math.sin(angle[lane])
        below_at_placement = y0[lane] - math.cos(angle[lane]) < terrain.height_at(toe_x0)
        assert landing.stubbed[lane] == below_at_placement
        if below_at_placement:
            assert np.isnan(landing.t[lane])
            continue
        t = _first_contact(terrain, x0[lane], y0[lane], xdot[lane], angle[lane])
        assert landing.t[lane] == pytest.approx(t, abs=1e-12)
        toe_x = x0[lane] + math.sin(angle[lane]) + xdot[lane] * landing.t[lane]
        assert landing.toe_x[lane] == pytest.approx(toe_x, abs=1e-12)
        toe_y = y0[lane] - 0.5 * PARAMS.g * landing.t[lane] ** 2 - math.cos(angle[lane])
        assert landing.toe_y[lane] == pytest.approx(toe_y, abs=1e-12)  # where the toe is: on the ground
        if landing.edge[lane]:
            edges += 1  # on a face: between the levels either side of it
            sides = terrain.height(landing.toe_x[lane] + np.array([-1e-9, 1e-9]))
            assert min(sides) - 1e-12 <= landing.toe_y[lane] <= max(sides) + 1e-12
        else:
            assert landing.toe_y[lane] == pytest.approx(terrain.height_at(landing.toe_x[lane]), abs=1e-12)
    assert np.count_nonzero(landing.stubbed) < lanes // 4
    if isinstance(terrain, Step) and terrain.height_change < 0:
        assert edges == 0  # a step down has no face to meet
    elif not isinstance(terrain, Step):
        assert edges > 0  # these grounds have faces that some toes meet


def test_a_toe_placed_below_the_ground_stubs() -> None:
    """A step up just ahead of the body: the leg placed at the apex puts its toe inside the step."""
    step = Step(0.12, 0.2)
    result = apex_return_map(PARAMS, ApexState(1.0, 4.0), COMMAND, conditions=StrideConditions(terrain=step))
    assert result.failure is FailureKind.TOE_STUBBING and result.touchdown is None
    assert "below the ground" in result.reason and "x = 0.342" in result.reason
    # The same step farther ahead is met on its face.
    result = apex_return_map(
        PARAMS, ApexState(1.0, 4.0), COMMAND, conditions=StrideConditions(terrain=Step(0.12, 0.5))
    )
    assert result.failure is None and result.edge and result.ground is not None
    assert result.touchdown is not None and result.touchdown.toe_x == 0.5
    assert 0.0 < result.ground < 0.12


# --- a stride over a step, integrated independently ----------------------------------------------


def _cartesian_stride(
    terrain: Terrain, apex: tuple[float, float, float], command: StanceCommand, tau_max: float
) -> dict[str, float]:
    """One stride from an apex (x, y [world], xdot) in Cartesian body coordinates, by DOP853 at 1e-13:
    flight until the toe reaches the ground under it (an event on toe_y - h(toe_x), which also stops at a
    face it runs into), stance with the toe pinned and the leg's force and the hip torque written out as
    forces, liftoff where the leg force vanishes, flight to the apex. Returns the next apex, the ground
    height, and the hip work, damper loss and leftover spring energy."""
    m, k, c, r0, g = PARAMS.m, PARAMS.k, PARAMS.c, PARAMS.r0, PARAMS.g
    beta = command.touchdown_angle
    tolerance = {"rtol": 1e-13, "atol": 1e-13, "method": "DOP853"}

    def ballistic(t: float, s: np.ndarray) -> list[float]:
        return [s[2], s[3], 0.0, -g]

    def toe_meets_ground(t: float, s: np.ndarray) -> float:
        toe_x = s[0] + r0 * math.sin(beta)
        return float(s[1] - r0 * math.cos(beta) - terrain.height_at(toe_x))

    toe_meets_ground.terminal = True  # type: ignore[attr-defined]
    toe_meets_ground.direction = -1  # type: ignore[attr-defined]
    fall = solve_ivp(
        ballistic, (0.0, 5.0), [apex[0], apex[1], apex[2], 0.0], events=toe_meets_ground, **tolerance
    )
    x, y, vx, vy = fall.y_events[0][0]
    toe = (x + r0 * math.sin(beta), y - r0 * math.cos(beta))

    def torque(s: float) -> float:
        return min(
            max(command.tau0 * (1.0 - s / command.t_f) if s <= command.t_f else 0.0, -tau_max), tau_max
        )

    def stance(s: float, z: np.ndarray) -> list[float]:
        dx, dy = z[0] - toe[0], z[1] - toe[1]
        r = math.hypot(dx, dy)
        radial = (dx / r, dy / r)
        normal = (-dy / r, dx / r)  # the direction of increasing theta, theta = atan2(-dx, dy)
        rdot = radial[0] * z[2] + radial[1] * z[3]
        thetadot = (normal[0] * z[2] + normal[1] * z[3]) / r
        push = k * (r0 - r) - c * rdot
        tau = torque(s)
        fx, fy = push * radial[0] + tau / r * normal[0], push * radial[1] + tau / r * normal[1]
        return [z[2], z[3], fx / m, fy / m - g, tau * thetadot, c * rdot * rdot]

    def leg_force(s: float, z: np.ndarray) -> float:
        dx, dy = z[0] - toe[0], z[1] - toe[1]
        r = math.hypot(dx, dy)
        return k * (r0 - r) - c * (dx * z[2] + dy * z[3]) / r

    leg_force.terminal = True  # type: ignore[attr-defined]
    leg_force.direction = -1  # type: ignore[attr-defined]
    saturation_end = command.t_f * (1.0 - tau_max / abs(command.tau0)) if abs(command.tau0) > tau_max else 0.0
    kinks = sorted({s for s in (saturation_end, command.t_f) if s > 0.0})
    z = np.array([x, y, vx, vy, 0.0, 0.0])
    s0 = 0.0
    for s1 in [*kinks, 10.0]:
        piece = solve_ivp(stance, (s0, s1), z, events=leg_force, **tolerance)
        if piece.status == 1:
            z = piece.y_events[0][0]
            break
        z, s0 = piece.y[:, -1], s1
    r_lo = math.hypot(z[0] - toe[0], z[1] - toe[1])

    def rising(t: float, s: np.ndarray) -> float:
        return float(s[3])

    rising.terminal = True  # type: ignore[attr-defined]
    climb = solve_ivp(ballistic, (0.0, 5.0), z[:4], events=rising, **tolerance)
    x_a, y_a, xdot_a, _ = climb.y_events[0][0]
    return {
        "x": x_a,
        "y": y_a,
        "xdot": xdot_a,
        "ground": toe[1],
        "hip_work": z[4],
        "damping_loss": z[5],
        "spring_loss": 0.5 * k * (r_lo - r0) ** 2,
    }


@pytest.mark.parametrize(
    ("terrain", "tau_max"),
    [(Step(-0.05, 0.8), math.inf), (Step(-0.05, 0.8), 150.0), (Step(0.05, 0.85), math.inf)],
    ids=["step-down 5 cm", "step-down 5 cm, hip saturated at 150 N m", "step up met on its face"],
)
def test_stride_over_a_step_matches_an_independent_integration(terrain: Terrain, tau_max: float) -> None:
    """The stance that follows the step runs on the lower (or higher) ground: the next apex, the ground
    height and the energy flows agree with a Cartesian integration, and the energy balance holds per
    stride with the potential energy of the step, m g dh, to 1e-9 relative."""
    start = ApexState(1.0, 5.0)
    result = apex_return_map(
        PARAMS,
        start,
        COMMAND,
        rtol=1e-13,
        atol=1e-13,
        conditions=StrideConditions(terrain=terrain, tau_max=tau_max),
    )
    assert result.apex is not None and result.energy is not None and result.ground is not None
    assert result.apex_x is not None
    truth = _cartesian_stride(terrain, (0.0, start.y, start.xdot), COMMAND, tau_max)
    assert result.ground == pytest.approx(truth["ground"], abs=1e-11)
    levels = np.array([0.0, terrain.height_at(10.0)])
    assert result.edge == (np.min(np.abs(truth["ground"] - levels)) > 1e-9)
    assert result.apex_x == pytest.approx(truth["x"], abs=1e-9)
    assert result.ground + result.apex.y == pytest.approx(truth["y"], abs=1e-10)
    assert result.apex.xdot == pytest.approx(truth["xdot"], abs=1e-10)
    for flow in ("hip_work", "damping_loss", "spring_loss"):
        assert getattr(result.energy, flow) == pytest.approx(truth[flow], abs=1e-9 * start.energy(PARAMS))
    # Energy per stride, heights above the ground of the last stance: the step's m g dh enters.
    m_g_dh = PARAMS.m * PARAMS.g * (result.ground - 0.0)
    gain = result.apex.energy(PARAMS) - start.energy(PARAMS) + m_g_dh
    assert gain == pytest.approx(result.energy.net_gain, abs=1e-9 * start.energy(PARAMS))
    truth_energy = PARAMS.m * (PARAMS.g * truth["y"] + 0.5 * truth["xdot"] ** 2)
    truth_gain = truth_energy - start.energy(PARAMS)
    net = truth["hip_work"] - truth["damping_loss"] - truth["spring_loss"]
    assert truth_gain == pytest.approx(net, abs=1e-9 * start.energy(PARAMS))
    if tau_max < math.inf:  # the saturated hip did less work than the full ramp
        free = apex_return_map(PARAMS, start, COMMAND, conditions=StrideConditions(terrain=terrain))
        assert free.energy is not None and result.energy.hip_work < free.energy.hip_work
