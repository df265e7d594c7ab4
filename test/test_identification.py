"""tdslip_ros.analysis.identification against recordings made in the test by a separate integration of the
stance equations (support/synthetic_hopping.py: scipy solve_ivp on the equations written out there, not the
package's engines), with a ramp torque per stride. About 23 s in all on the loaded 2-core VM, half of it the
two exact-stance fits of three stances each."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from support.helpers import assert_png, strict_json
from support.synthetic_hopping import UNLIKE_DEFAULT, hopping, kinematics_only, with_sensor_noise

from tdslip_ros.analysis.identification import (
    EXACT_STANCE,
    FORCE_BALANCE,
    ILL_CONDITIONED,
    ILL_CONDITIONED_STATUS,
    TOO_NOISY,
    TOO_SHORT,
    fit_ramp,
    identify,
)
from tdslip_ros.commands import cli
from tdslip_ros.commands import identify as identify_command
from tdslip_ros.interfaces import read_hopper_file
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.nodes.runner import RunReport

PARAMETERS = ("k", "c", "r0")


@pytest.fixture(scope="module")
def recording():  # type: ignore[no-untyped-def]
    return hopping(UNLIKE_DEFAULT, 8)


def test_force_balance_recovers_the_hopper_and_each_ramp_noise_free(recording) -> None:  # type: ignore[no-untyped-def]
    run, strides, truth = recording
    result = identify(run, strides, PAPER_PARAMS)
    assert result.success and result.method == FORCE_BALANCE, result.message
    for name in (*PARAMETERS, "m"):
        # the bound is 0.5 %; the force balance is exact in (k r0, k, c), so rounding remains
        assert result.estimates[name].value == pytest.approx(getattr(truth, name), rel=1e-5), name
    assert result.params is not None and result.params.m == pytest.approx(truth.m, rel=1e-5)
    assert not any(drift.drifts for drift in result.drift.values())
    # the per-stance ramp, from the recorded torque and from the force across the leg, where it is not zero
    from_force = identify(replace(run, hip_torque=None), strides, PAPER_PARAMS)
    for recorded, derived, (tau0, t_f) in zip(result.stances, from_force.stances, truth.ramps, strict=True):
        if tau0 != 0.0:
            assert (recorded.ramp.tau0, recorded.ramp.t_f) == pytest.approx((tau0, t_f), rel=1e-5)
            assert (derived.ramp.tau0, derived.ramp.t_f) == pytest.approx((tau0, t_f), rel=1e-5)


def test_intervals_cover_the_truth_under_the_suites_sensor_noise(recording) -> None:  # type: ignore[no-untyped-def]
    """A few seeds here; bench/bench_identification.py --coverage runs 40 and docs/identify.md gives the
    coverage."""
    run, strides, truth = recording
    for seed in (0, 1, 2):
        result = identify(with_sensor_noise(run, 5e-4, 10.0, seed), strides, PAPER_PARAMS)
        assert result.success, result.message
        for name in (*PARAMETERS, "m"):
            estimate = result.estimates[name]
            assert estimate.low < estimate.high
            assert estimate.covers(getattr(truth, name)), (seed, name, estimate)


def test_exact_stance_fit_recovers_the_hopper_from_kinematics_alone(recording) -> None:  # type: ignore[no-untyped-def]
    """Kinematics fix k/m, c/m and tau/m: the true mass is given, the rest is the default hopper's guess."""
    run, strides, truth = recording
    given = replace(PAPER_PARAMS, m=truth.m)
    result = identify(kinematics_only(run), strides[1:4], given)
    assert result.success and result.method == EXACT_STANCE, result.message
    for name in PARAMETERS:
        assert result.estimates[name].value == pytest.approx(getattr(truth, name), rel=5e-3), name
    for fit, (tau0, t_f) in zip(result.stances, truth.ramps[1:4], strict=True):
        assert (fit.ramp.tau0, fit.ramp.t_f) == pytest.approx((tau0, t_f), rel=5e-3)


def test_a_stiff_leg_barely_compressed_is_ill_conditioned_and_says_which() -> None:
    """A leg 400 times stiffer (force at 10 kHz for its 7 ms stance) compresses by about a millimetre: under
    the sensor's noise the force along it, k (r0 - r) - c rdot with r nearly r0, does not pin k and c down."""
    stiff = replace(UNLIKE_DEFAULT, k=400.0 * UNLIKE_DEFAULT.k, c=20.0 * UNLIKE_DEFAULT.c)
    run, strides, _ = hopping(stiff, 5, dt=1e-4, angle_deg=18.0)
    result = identify(with_sensor_noise(run, 5e-4, 10.0, 0), strides, PAPER_PARAMS)
    assert not result.success and result.status == ILL_CONDITIONED_STATUS, result.message
    assert result.params is None
    assert result.condition_number > ILL_CONDITIONED
    assert set(result.unidentified) == {"k", "c"}, result.message
    assert result.message.startswith("k and c cannot be identified") and "\n" not in result.message


def test_too_short_and_too_noisy_say_so_in_one_line(recording) -> None:  # type: ignore[no-untyped-def]
    run, strides, _ = recording
    short = identify(run, strides[:2], PAPER_PARAMS)
    assert (short.success, short.status, short.params) == (False, TOO_SHORT, None)
    assert "2 usable stance(s)" in short.message
    noisy = identify(with_sensor_noise(run, 2e-2, 500.0, 0), strides[:4], PAPER_PARAMS)
    assert (noisy.success, noisy.status, noisy.params) == (False, TOO_NOISY, None), noisy.message
    assert "\n" not in noisy.message


def test_fit_ramp_finds_a_ramp_that_ends_inside_the_stance() -> None:
    s = np.arange(1, 250) * 1e-3
    torque = np.where(s <= 0.13, -400.0 * (1.0 - s / 0.13), 0.0)
    ramp = fit_ramp(s, torque)
    assert (ramp.tau0, ramp.t_f) == pytest.approx((-400.0, 0.13), rel=1e-6)
    assert ramp.rms < 1e-6
    assert math.isnan(fit_ramp(s, np.zeros_like(s)).t_f)


def test_the_command_writes_a_hopper_file_that_round_trips_and_a_report(
    recording,  # type: ignore[no-untyped-def]
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    run, strides, truth = recording
    out = tmp_path / "identified"
    args = identify_command.parser().parse_args(["robot.mcap", "--out", str(out)])
    assert identify_command.identify_recording(args, run, strides) == 0
    identified = read_hopper_file(out / "hopper.yaml")
    assert (identified.k, identified.c, identified.r0, identified.m) == pytest.approx(
        (truth.k, truth.c, truth.r0, truth.m), rel=1e-5
    )
    summary = strict_json(out / "summary.json")
    assert summary["status"] == "identified" and len(summary["stances"]) == len(strides)
    low, high = summary["estimates"]["k_N_per_m"]["interval"]
    assert low <= truth.k <= high
    for figure in ("stance_fit.png", "estimates.png"):
        assert_png(out / figure)
    assert "k   = 32490.7 N/m" in capsys.readouterr().out


def test_the_command_writes_nothing_for_data_that_cannot_serve(
    recording,  # type: ignore[no-untyped-def]
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    run, strides, _ = recording
    out = tmp_path / "identified"
    args = identify_command.parser().parse_args(["robot.mcap", "--out", str(out)])
    assert identify_command.identify_recording(args, run, strides[:2]) == 1
    error = capsys.readouterr().err
    assert error.startswith("tdslip identify: robot.mcap: too short") and error.count("\n") == 1
    assert not out.exists()
    bad = identify_command.parser().parse_args(
        ["robot.mcap", "--out", str(out), "--hopper", str(tmp_path / "x")]
    )
    assert identify_command.identify_recording(bad, run, strides) == 2
    assert "cannot be read" in capsys.readouterr().err and not out.exists()


def test_a_leg_that_stiffens_over_the_run_is_flagged_as_drift() -> None:
    """k grows by 5 % over 8 strides (the generator's stiffness_drift); c and r0 stay, and are not flagged."""
    run, strides, truth = hopping(UNLIKE_DEFAULT, 8, stiffness_drift=0.05)
    result = identify(run, strides, PAPER_PARAMS)
    per_stance = [fit.values["k"] for fit in result.stances]
    assert per_stance[0] == pytest.approx(truth.k, rel=1e-5) and per_stance[-1] == pytest.approx(
        1.05 * truth.k, rel=1e-5
    )
    assert result.drift["k"].drifts and result.drift["k"].change == pytest.approx(0.05 * truth.k, rel=0.05)
    assert not result.drift["c"].drifts and not result.drift["r0"].drifts


def test_kinematics_alone_of_a_barely_compressed_leg_is_ill_conditioned() -> None:
    """The issue's example: no force, and a leg 40 times stiffer compressing by about a centimetre, under
    0.5 mm of position noise: the exact stance cannot tell k and c (about 10 s, the costliest test here)."""
    stiff = replace(UNLIKE_DEFAULT, k=40.0 * UNLIKE_DEFAULT.k, c=6.0 * UNLIKE_DEFAULT.c)
    run, strides, _ = hopping(stiff, 4, angle_deg=18.0)
    guess = replace(PAPER_PARAMS, m=stiff.m, k=stiff.k, c=stiff.c)  # the truth as the start: still not enough
    result = identify(kinematics_only(with_sensor_noise(run, 5e-4, 10.0, 0)), strides[1:4], guess)
    assert (result.success, result.status, result.method) == (False, ILL_CONDITIONED_STATUS, EXACT_STANCE)
    assert result.condition_number > ILL_CONDITIONED and set(result.unidentified) >= {"k", "c"}
    assert result.message.startswith("k and c cannot be identified"), result.message


def test_tdslip_identify_of_a_suite_recording_finds_the_hopper_it_was_run_with(
    energy: RunReport, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The whole command on a bag of the node suite (energy regulation, 12 strides, the paper's hopper), read
    through the suite's own topic map and its strides found in the data (topic-map's reader)."""
    out = tmp_path / "identified"
    assert cli.main(["identify", str(energy.bag), "--out", str(out)]) == 0, capsys.readouterr().err
    identified = read_hopper_file(out / "hopper.yaml")
    assert (identified.k, identified.c, identified.r0, identified.m) == pytest.approx(
        (PAPER_PARAMS.k, PAPER_PARAMS.c, PAPER_PARAMS.r0, PAPER_PARAMS.m), rel=1e-6
    )
    assert cli.main(["identify", str(energy.bag), "--topic-map", str(tmp_path / "absent.yaml")]) == 2
    assert capsys.readouterr().err.count("\n") == 1
