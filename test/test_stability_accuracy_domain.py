"""The accuracy domain of the analytic map (analytic_accuracy.domain_errors, domain_table, boundaries) over
the stance's maximum leg compression and the touchdown angle, the axes of the paper's claim (II.C).

The truth is the exact plant: the compression is its bottom state's (checked here against the plant and
against an integration of eq. 2 written in this file), the errors are against its next apex. The physics
says where the errors should grow: the stance approximation truncates a series in the compression (eqs. 8,
14) and holds the angular momentum constant up to a linear gravity correction (eq. 22). The boundaries that
docs/paper.md states are measured again on the fine grid at two of its angles.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from tdslip_ros.model.analytic.apex_map import SpeedSource, approximate_map
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.stability.analytic_accuracy import (
    DOMAIN_GRID,
    ERROR_LEVELS,
    FINE_DOMAIN_GRID,
    SPEED_SOURCES,
    Boundary,
    DomainErrors,
    ExactStrides,
    Quantity,
    StrideGrid,
    boundaries,
    domain_errors,
    domain_table,
    exact_strides,
    first_mismatches,
)

PARAMS = PAPER_PARAMS
PAPER_MD = Path(__file__).resolve().parents[1] / "docs" / "paper.md"


@pytest.fixture(scope="module")
def exact() -> ExactStrides:
    return exact_strides(PARAMS, DOMAIN_GRID)


@pytest.fixture(scope="module")
def domain(exact: ExactStrides) -> DomainErrors:
    return domain_errors(PARAMS, exact)


def _bottom_of_eq_2(y: float, xdot: float, command: StanceCommand) -> float:
    """r at the first maximum compression, from eq. 2 integrated here: polar coordinates about the toe,
    theta from the vertical, decreasing in stance (NOTES.md), the ramp tau0 (1 - t/t_f) until t_f."""
    m, k, c, r0, g = PARAMS.m, PARAMS.k, PARAMS.c, PARAMS.r0, PARAMS.g
    angle = command.touchdown_angle
    ydot = -math.sqrt(2.0 * g * (y - r0 * math.cos(angle)))
    rdot = -xdot * math.sin(angle) + ydot * math.cos(angle)
    thetadot = (-xdot * math.cos(angle) - ydot * math.sin(angle)) / r0

    def rhs(t: float, s: np.ndarray, ramp: bool) -> list[float]:
        r, theta, r_rate, theta_rate = s
        tau = command.tau0 * (1.0 - t / command.t_f) if ramp else 0.0
        radial = r * theta_rate**2 - g * math.cos(theta) + (k * (r0 - r) - c * r_rate) / m
        angular = (g * math.sin(theta) - 2.0 * r_rate * theta_rate) / r + tau / (m * r * r)
        return [r_rate, theta_rate, radial, angular]

    def bottom(t: float, s: np.ndarray, ramp: bool) -> float:
        return float(s[2])

    bottom.direction = 1.0  # type: ignore[attr-defined]
    state = np.array([r0, angle, rdot, thetadot])
    for span, ramp in (((0.0, command.t_f), True), ((command.t_f, command.t_f + 1.0), False)):
        solution = solve_ivp(rhs, span, state, "DOP853", events=bottom, args=(ramp,), rtol=1e-12, atol=1e-12)
        if solution.t_events[0].size:
            return float(solution.y_events[0][0][0])
        state = solution.y[:, -1]
    raise AssertionError("no bottom")


def test_the_compression_and_the_errors_are_the_exact_plants(
    exact: ExactStrides, domain: DomainErrors
) -> None:
    points = DOMAIN_GRID.points()
    no_bottom = set(range(len(points))) - set(domain.index.tolist())
    for i in no_bottom:  # left out: no ramp, or no bottom on the exact plant
        y, xdot = points[i][:2]
        if np.isfinite(exact.commands.t_f[i]):
            assert apex_return_map(PARAMS, ApexState(y, xdot), exact.commands.command(i)).bottom is None
    for lane, i in enumerate(domain.index):
        y, xdot = points[i][:2]
        command = exact.commands.command(int(i))
        result = apex_return_map(PARAMS, ApexState(y, xdot), command)
        assert result.bottom is not None
        assert domain.compression[lane] == pytest.approx(1.0 - result.bottom.r / PARAMS.r0, abs=1e-9)
        for speed in SPEED_SOURCES:
            stride = approximate_map(PARAMS, y, xdot, command, 1, speed=speed)
            if result.apex is None or not bool(stride.ok):
                assert all(math.isnan(domain.errors[speed, q][lane]) for q in ("height", "speed"))
                assert domain.mismatch[speed][lane] == ((result.apex is None) != (not bool(stride.ok)))
                continue
            height, speed_error = (
                abs(float(stride.y) / result.apex.y - 1.0),
                abs(float(stride.xdot) / result.apex.xdot - 1.0),
            )
            assert domain.errors[speed, "height"][lane] == pytest.approx(height, rel=1e-12)
            assert domain.errors[speed, "speed"][lane] == pytest.approx(speed_error, rel=1e-12)
    # r_min itself against eq. 2 integrated independently: the least and most compressed stride per angle.
    for angle in DOMAIN_GRID.angles:
        lanes = np.flatnonzero(domain.angle == angle)
        for lane in lanes[[np.argmin(domain.compression[lanes]), np.argmax(domain.compression[lanes])]]:
            i = int(domain.index[lane])
            r_min = _bottom_of_eq_2(*points[i][:2], exact.commands.command(i))
            assert domain.compression[lane] == pytest.approx(1.0 - r_min / PARAMS.r0, abs=1e-9)


def test_both_maps_share_the_height_error(domain: DomainErrors) -> None:
    """The next apex height is eq. 7 in both maps; only where our energy balance leaves no kinetic energy at
    the apex does ours fail alone (never the paper's alone)."""
    ours, papers = domain.errors["energy", "height"], domain.errors["liftoff", "height"]
    both = ~np.isnan(ours) & ~np.isnan(papers)
    assert both.sum() > 100
    np.testing.assert_array_equal(ours[both], papers[both])
    assert not np.any(~np.isnan(ours) & np.isnan(papers))
    for speed in SPEED_SOURCES:  # a map compares both quantities or neither
        heights, speeds = domain.errors[speed, "height"], domain.errors[speed, "speed"]
        np.testing.assert_array_equal(np.isnan(heights), np.isnan(speeds))


def _medians(
    domain: DomainErrors, speed: SpeedSource, quantity: Quantity, low: float, high: float
) -> list[float]:
    """Median error per touchdown angle of the strides compressed within [low, high) (NaN where none)."""
    error = domain.errors[speed, quantity]
    medians = []
    for angle in domain.grid.angles:
        here = (domain.angle == angle) & (domain.compression >= low) & (domain.compression < high)
        medians.append(
            float(np.median(error[here & ~np.isnan(error)])) if np.any(here & ~np.isnan(error)) else np.nan
        )
    return medians


@pytest.mark.parametrize("speed", SPEED_SOURCES)
def test_the_height_error_grows_with_the_compression(domain: DomainErrors, speed: SpeedSource) -> None:
    """The stance approximation truncates the series in (r0 - r)/r0 of r thetadot^2 and of 1/r^2 (eqs. 8, 14):
    at every angle the median height error rises from bin to bin of compression up to 0.35, and beyond 0.3
    some stride errs by more than 10 %."""
    table = domain_table(domain, speed, "height")
    for column in range(len(table.angles)):
        rows = [row for row in range(len(table.edges) - 1) if table.edges[row + 1] <= 0.35]
        medians = [table.median[row, column] for row in rows if table.count[row, column]]
        assert len(medians) >= 3
        assert np.all(np.diff(medians) > 0.0), (np.degrees(table.angles[column]), medians)
    error = domain.errors[speed, "height"]
    for angle in domain.grid.angles:
        assert np.nanmax(error[(domain.angle == angle) & (domain.compression >= 0.3)]) > 0.1


def test_our_speed_error_grows_with_the_angle(domain: DomainErrors) -> None:
    """At equal compression (0.10-0.20), the median error of our next speed grows with the touchdown angle:
    gravity's torque about the toe grows with the leg's angle from the vertical, and the approximation keeps
    the angular momentum constant up to the linear correction of eq. 22."""
    medians = [value for value in _medians(domain, "energy", "speed", 0.10, 0.20) if not np.isnan(value)]
    assert len(medians) >= 3
    assert np.all(np.diff(medians) > 0.0), medians


def test_the_map_is_accurate_where_its_assumptions_hold(domain: DomainErrors) -> None:
    """Near the vertical (10-20 deg) and compressed by less than 0.15, every stride's next apex height and our
    next speed err by less than 2 %; the paper's speed (eq. 7) does not get that close (median over 1 %)."""
    small = (np.degrees(domain.angle) < 20.5) & (domain.compression < 0.15)
    for quantity in ("height", "speed"):
        error = domain.errors["energy", quantity][small]
        assert np.count_nonzero(~np.isnan(error)) >= 10
        assert np.nanmax(error) < 0.02
    assert np.nanmedian(domain.errors["liftoff", "speed"][small]) > 0.01


def test_a_boundary_is_where_the_first_stride_reaches_the_level() -> None:
    """boundaries() on a hand-made domain: strides at one angle with errors 0.2 %, 0.5 %, 3 %, 0.8 %, 7 %."""
    grid = StrideGrid((1.0,), (5.0,), (0.3,), (0.0,))
    compression = np.array([0.10, 0.15, 0.20, 0.25, 0.30])
    error = np.array([0.002, 0.005, 0.03, 0.008, 0.07])
    errors = {(speed, quantity): error for speed in SPEED_SOURCES for quantity in ("height", "speed")}
    mismatch = {speed: np.zeros(5, dtype=bool) for speed in SPEED_SOURCES}
    domain = DomainErrors(grid, 1, np.arange(5), np.full(5, 0.3), compression, errors, mismatch)  # type: ignore[arg-type]
    assert boundaries(domain, "energy", "height", 0.01) == [Boundary(0.3, 0.01, 0.15, 0.20)]
    assert boundaries(domain, "energy", "height", 0.05) == [Boundary(0.3, 0.05, 0.25, 0.30)]
    assert boundaries(domain, "energy", "height", 0.1) == [Boundary(0.3, 0.1, 0.30, None)]
    assert boundaries(domain, "energy", "height", 0.001) == [Boundary(0.3, 0.001, None, 0.10)]


# The columns of docs/paper.md's boundary table: the map (speed source) and the quantity.
DOCUMENTED_COLUMNS: dict[str, tuple[SpeedSource, Quantity]] = {
    "height, ours": ("energy", "height"),
    "height, paper's": ("liftoff", "height"),
    "speed, ours": ("energy", "speed"),
    "speed, paper's": ("liftoff", "speed"),
}
MISMATCH_COLUMN = "first failure mismatch, ours / paper's"
COMPARED_COLUMN = "compared"  # the least and the largest compression compared (by the paper's map)
CHECKED_ANGLES_DEG = (10.0, 30.0)


def _documented_boundaries() -> dict[str, dict[str, list[str]]]:
    """docs/paper.md's boundary table of the section "Accuracy domain": cells by angle ("10 deg") and column,
    each split at " / "."""
    text = PAPER_MD.read_text()
    section = text.split("\n## Accuracy domain\n", 1)[1].split("\n## ", 1)[0]
    lines = [line for line in section.splitlines() if line.startswith("|")]
    header = next(index for index, line in enumerate(lines) if line.startswith("| angle |"))
    names = [cell.strip() for cell in lines[header].strip("|").split("|")]
    table = {}
    for line in lines[header + 2 :]:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        if not re.fullmatch(r"\d+ deg", cells[0]):
            break
        table[cells[0]] = {name: cell.split(" / ") for name, cell in zip(names[1:], cells[1:], strict=True)}
    return table


def _agrees(documented: str, below: float | None, censored: bool) -> bool:
    if below is None:
        return documented == "none"
    if censored != documented.startswith(">= "):
        return False
    return abs(float(documented.removeprefix(">= ")) - below) <= 0.005 + 1e-12


def test_the_documented_boundaries_are_the_measured_ones() -> None:
    """Each angle's boundaries depend on its strides alone, so the fine grid at two of its angles measures
    their rows of the table again."""
    angles = tuple(a for a in FINE_DOMAIN_GRID.angles if round(math.degrees(a), 6) in CHECKED_ANGLES_DEG)
    assert len(angles) == len(CHECKED_ANGLES_DEG)
    grid = StrideGrid(FINE_DOMAIN_GRID.heights, FINE_DOMAIN_GRID.speeds, angles, FINE_DOMAIN_GRID.torques)
    domain = domain_errors(PARAMS, exact_strides(PARAMS, grid))
    documented = _documented_boundaries()
    assert set(documented["10 deg"]) == {*DOCUMENTED_COLUMNS, MISMATCH_COLUMN, COMPARED_COLUMN}
    compared = ~np.isnan(domain.errors["liftoff", "height"])
    for index, degrees in enumerate(CHECKED_ANGLES_DEG):
        row = documented[f"{degrees:g} deg"]
        here = domain.compression[compared & (domain.angle == angles[index])]
        least, largest = (float(value) for value in row[COMPARED_COLUMN][0].split("-"))
        assert (least, largest) == pytest.approx((here.min(), here.max()), abs=0.005 + 1e-12)
        for name, (speed, quantity) in DOCUMENTED_COLUMNS.items():
            for level, cell in zip(ERROR_LEVELS, row[name], strict=True):
                found = boundaries(domain, speed, quantity, level)[index]
                assert _agrees(cell, found.below, found.leaves is None), (degrees, name, level, cell, found)
        for speed, cell in zip(SPEED_SOURCES, row[MISMATCH_COLUMN], strict=True):
            assert _agrees(cell, first_mismatches(domain, speed)[index], False), (degrees, speed, cell)
