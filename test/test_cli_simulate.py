"""``tdslip simulate``: its table is the stepper's run, its command replaces the first stride's losses."""

from __future__ import annotations

import math

import pytest
from support.helpers import apex_table

from tdslip_ros.analysis.simulate import energy_neutral_command
from tdslip_ros.commands.cli import main as tdslip
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, ParameterError, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map

PARAMS = PAPER_PARAMS


def test_energy_neutral_command_replaces_the_first_strides_losses() -> None:
    apex = ApexState(1.0, 5.5)
    command = energy_neutral_command(PARAMS, apex, math.radians(22.0))
    result = apex_return_map(PARAMS, apex, command)
    assert result.apex is not None and result.energy is not None
    assert result.energy.hip_work == pytest.approx(
        result.energy.damping_loss + result.energy.spring_loss, abs=1e-6 * apex.energy(PARAMS)
    )
    assert result.liftoff is not None and result.touchdown is not None
    assert command.t_f == pytest.approx(result.liftoff.t - result.touchdown.t, rel=1e-3)
    assert command.tau0 < 0.0
    with pytest.raises(ParameterError, match="give --tau0"):
        energy_neutral_command(PARAMS, ApexState(1.2, 0.3), math.radians(26.0))


def test_simulate_prints_the_steppers_apexes(capsys: pytest.CaptureFixture[str]) -> None:
    arguments = ["--strides", "3", "--tau0", "-335.5", "--t-f", "0.1227", "--touchdown-angle-deg", "22"]
    assert tdslip(["simulate", *arguments, "--speed", "5.5"]) == 0
    rows = apex_table(capsys.readouterr().out)
    assert [int(row[0]) for row in rows] == [0, 1, 2, 3]
    command = StanceCommand(math.radians(22.0), -335.5, 0.1227)
    apex, t = ApexState(1.0, 5.5), 0.0
    for row in rows[1:]:
        exact = apex_return_map(PARAMS, apex, command)
        assert exact.apex is not None and exact.energy is not None and exact.apex_time is not None
        t += exact.apex_time
        stride, time, y, xdot, energy, hip, damper, spring, ybar, xdotbar, ebar = row
        assert (time, y, xdot) == pytest.approx((t, exact.apex.y, exact.apex.xdot), abs=1e-4)
        assert (hip, damper, spring) == pytest.approx(
            (exact.energy.hip_work, exact.energy.damping_loss, exact.energy.spring_loss), abs=0.01
        )
        assert energy == pytest.approx(exact.apex.energy(PARAMS), abs=0.01)
        assert (ybar, xdotbar, ebar) == pytest.approx(
            (y, xdot / math.sqrt(PARAMS.g), energy / (PARAMS.m * PARAMS.g)), abs=2e-4
        )
        apex = exact.apex


def test_simulate_defaults_hop_and_failures_are_named(capsys: pytest.CaptureFixture[str]) -> None:
    assert tdslip(["simulate", "--strides", "5"]) == 0
    out = capsys.readouterr().out
    assert len(apex_table(out)) == 6 and "constant command" in out
    assert tdslip(["simulate", "--touchdown-angle-deg", "26", "--height", "1.2", "--speed", "3"]) == 1
    out = capsys.readouterr().out
    assert "reversal" in out and "failure at t" in out
    assert tdslip(["simulate", "--zeta0", "-1"]) == 2
    assert "zeta0" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--speed", "1e150"], "apex speed xdot = 1e+150 m/s exceeds max_apex_speed = 31.3209 m/s"),
        (["--speed", "1e200"], "apex speed xdot = 1e+200 m/s is out of the floating-point range"),
        (["--height", "1e9"], "apex height y = 1000000000.0 m exceeds max_apex_height = 10 m"),
        (["--tau0", "1e300"], "tau0 = 1e+300 N m exceeds the actuator limit |tau0| <= 15696 N m"),
        (["--tau0=-1e12"], "tau0 = -1000000000000.0 N m exceeds the actuator limit"),
        (["--tau0", "-300", "--t-f", "1e-9"], "t_f = 1e-09 s is outside [0.000334344, 3.34344] s"),
        (["--strides", "-5"], "--strides must be at least 1, got -5"),
        (["--strides", "0"], "--strides must be at least 1, got 0"),
        (["--zeta0", "2"], "zeta0 = c/(2 sqrt(m k)) = 2, but the model needs an underdamped leg"),
        (["--mass", "1e-300", "--kbar", "36"], "out of the floating-point range"),
        (["--stiffness", "3e4", "--kbar", "36"], "give --stiffness or --kbar, not both"),
        (["--dt", "0.5"], "cannot resolve this hopper"),
    ],
)
def test_simulate_refuses_implausible_input_in_one_line(
    arguments: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 9 items 14 and 15: --speed 1e200 and --tau0 1e300 gave tracebacks, --strides -5 exited 0."""
    assert tdslip(["simulate", *arguments]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("tdslip simulate: ") and captured.err.count("\n") == 1
    assert message in captured.err
