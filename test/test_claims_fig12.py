"""fig12 (section IV.D): the paper's claims about ground reaction forces and virtual footfalls, checked on the
figure's JSON and on the model directly, with tolerances from the physics and the integration.

Sign convention (tdslip_ros/model/params.py): the body runs towards +x, the toe is at x = 0, theta decreases
through stance, forward thrust is tau < 0. A braking force is F_x < 0; a footfall behind the toe is x < 0.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.helpers import assert_png, strict_json

from tdslip_ros.analysis import paper_comparison
from tdslip_ros.analysis.figures import ground_reaction
from tdslip_ros.analysis.figures.catalogue import FIGURES
from tdslip_ros.analysis.figures.common import DEFAULT, Reporter
from tdslip_ros.commands import cli
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import StanceCommand
from tdslip_ros.model.policies.controllers import EXACT_STANCE_TOLERANCE, energy_regulation
from tdslip_ros.studies import engine

ROUNDING = 1e-12
"""m: x - y F_x/F_y against tau/F_y, or against 0 for a force along the leg, is rounding (~1e-16 m) in
lengths of 1 m and footfalls under 1 m."""
LOSSLESS_FOOTFALL = 1e-9
"""m: the lossless SLIP's footfall offset from its toe (its GRF lies along the leg exactly)."""
STATE_ERROR = 1e-10
"""m (or rad): what DOP853 at rtol = atol = 1e-12 leaves in a stance's state, interpolated by its dense
output: a hundred times its tolerance."""


@pytest.fixture(scope="module")
def data() -> dict[str, Any]:
    _, numbers = ground_reaction.fig12(DEFAULT, Reporter("test", interval=math.inf), "energy")
    return numbers


@pytest.fixture(scope="module")
def td_slip() -> ground_reaction.Stance:
    params, beta = ground_reaction.fig12_hopper(), math.radians(ground_reaction.BETA_DEG)
    apex, command = ground_reaction.regulated_gait(params, ground_reaction.SPEED, beta)
    return ground_reaction.sample_stance(params, apex, command)


def samples(data: dict[str, Any], model: str, key: str) -> np.ndarray:
    return np.array(data[model]["samples"][key], dtype=float)  # null (no footfall) as NaN


def test_the_hopper_is_the_papers_mass_and_leg_with_our_stiffness_and_damping(data: dict[str, Any]) -> None:
    params = data["params"]
    assert (
        (params["m"], params["r0"]) == (65.4, 1.0) == (data["paper_gave"]["m_kg"], data["paper_gave"]["r0_m"])
    )
    assert params["kbar"] == pytest.approx(36.0) and params["zeta0"] == pytest.approx(0.08)
    assert (data["our_choice"]["kbar"], data["our_choice"]["zeta0"]) == (36.0, 0.08)
    assert params["k_N_per_m"] == pytest.approx(36.0 * 65.4 * 9.81)
    assert "Kram" in data["note"] and "cannot be reproduced" in data["note"]


def test_td_slip_runs_at_an_energy_regulated_fixed_point_at_3_m_s(data: dict[str, Any]) -> None:
    """energy_exact keeps the energy, so the apex that maps onto itself in height does in speed too; its ramp
    ends at the exact liftoff (t_f = t_lo, section II.D)."""
    gait = data["td_slip"]
    assert gait["apex"]["xdot_m_per_s"] == 3.0 and gait["touchdown_angle_deg"] == ground_reaction.BETA_DEG
    assert gait["next_apex"]["y_m"] == pytest.approx(gait["apex"]["y_m"], abs=1e-9)
    assert gait["next_apex"]["xdot_m_per_s"] == pytest.approx(3.0, abs=1e-9)
    assert 0.9 < gait["apex"]["y_m"] < 1.2  # a running gait, not a high bounce
    assert gait["tau0_N_m"] < 0.0  # forward thrust
    params = data["params"]
    stance_scale = math.sqrt(params["m"] / params["k_N_per_m"])
    assert abs(gait["t_f_s"] - gait["stance_time_s"]) <= EXACT_STANCE_TOLERANCE * stance_scale
    assert gait["spectral_radius"] == pytest.approx(math.hypot(*gait["eigenvalue"]))
    assert gait["spectral_radius"] < 1.0  # stable: the regulated gait is a steady state


def test_the_sampled_stance_ends_in_the_exact_maps_liftoff_state(td_slip: ground_reaction.Stance) -> None:
    """The figure integrates the stance again (dense output); it must be the exact map's stance."""
    liftoff, toe = td_slip.liftoff, td_slip.touchdown.toe_x
    assert td_slip.x[-1] == pytest.approx(liftoff.x - toe, abs=STATE_ERROR)
    assert td_slip.y[-1] == pytest.approx(liftoff.y, abs=STATE_ERROR)
    assert td_slip.fx[-1] == pytest.approx(liftoff.grf_x, abs=td_slip.params.k * STATE_ERROR)
    assert td_slip.fy[-1] == pytest.approx(liftoff.grf_y, abs=td_slip.params.k * STATE_ERROR)


def test_td_slip_brakes_hardest_early_in_stance(data: dict[str, Any]) -> None:
    """The paper: "large backward horizontal forces introduced in the beginning of the stance phase". The
    braking peak comes in the first half and exceeds the propulsive peak of the second half (for the SLIP
    the two are equal). At touchdown the force is forward: the leg holds only the damper's force, and the
    ramp starts at its largest forward push. It is not larger than the lossless SLIP's from the same apex."""
    gait, measured = data["td_slip"], data["measured"]
    fx, t = samples(data, "td_slip", "grf_x_N"), samples(data, "td_slip", "t_s")
    braking = gait["peak_braking"]
    assert braking["grf_x_N"] < 0.0 and braking["stance_ratio"] < 0.5
    assert measured["td_slip_braking_peak_in_first_half"]
    second_half = t >= 0.5 * gait["stance_time_s"]
    assert -braking["grf_x_N"] > np.max(fx[second_half]) > 0.0
    assert measured["td_slip_braking_over_propulsive_peak_ratio"] > 1.0
    assert fx[0] > 0.0
    assert 0.0 < measured["td_slip_over_slip_braking_peak_ratio"] < 1.0


def test_td_slip_footfalls_lie_behind_the_toe_and_close_in_towards_it_at_liftoff(
    data: dict[str, Any], td_slip: ground_reaction.Stance
) -> None:
    """The footfall is tau/F_y from the toe (the GRF's moment about the toe is the hip torque): behind it
    (< 0) throughout, as tau < 0 and F_y > 0. At liftoff tau and F_y both vanish, the footfall tends to
    tau'/F_y' (L'Hopital): close to the toe (under a tenth of its touchdown offset), not at it."""
    footfall = samples(data, "td_slip", "footfall_m")
    pushing = np.isfinite(footfall)
    assert pushing[:-1].all() and not pushing[-1]  # no footfall only at liftoff, where F_y = 0
    assert np.all(footfall[pushing] < 0.0) and data["measured"]["td_slip_footfalls_behind_toe"]
    tau, fy = samples(data, "td_slip", "hip_torque_N_m"), samples(data, "td_slip", "grf_y_N")
    np.testing.assert_allclose(footfall[pushing], tau[pushing] / fy[pushing], rtol=0.0, atol=ROUNDING)
    at_touchdown, at_liftoff = (
        data["td_slip"]["footfall_at_touchdown_m"],
        data["td_slip"]["footfall_at_liftoff_m"],
    )
    assert at_touchdown < at_liftoff < 0.0
    assert abs(at_liftoff) < 0.1 * abs(at_touchdown)
    assert at_liftoff < -0.01  # centimetres behind the toe: the limit is not the toe
    # The limit is where the samples go: linear extrapolation of the last two to liftoff leaves O((dt/T)^2).
    dt_ratio = 1.0 / (footfall.size - 1)
    extrapolated = 2.0 * footfall[-2] - footfall[-3]
    assert extrapolated == pytest.approx(at_liftoff, abs=dt_ratio**2 * abs(at_touchdown))
    assert td_slip.liftoff_footfall() == at_liftoff


def test_without_hip_torque_the_grf_points_along_the_leg_damping_or_not(
    td_slip: ground_reaction.Stance,
) -> None:
    """Spring and damper push along the leg: the footfall moves off the toe only through the torque."""
    params, apex = td_slip.params, td_slip.apex
    for hopper in (params, ground_reaction.lossless(params)):
        stance = ground_reaction.sample_stance(
            hopper, apex, StanceCommand(td_slip.command.touchdown_angle, 0.0, 1.0)
        )
        footfall = stance.footfall()
        assert np.isfinite(footfall).sum() > 0.9 * footfall.size
        assert np.nanmax(np.abs(footfall)) < LOSSLESS_FOOTFALL


def test_the_lossless_slip_footfall_is_the_toe_and_its_stance_symmetric(data: dict[str, Any]) -> None:
    """The SLIP (no damping, no torque) from the same apex at the touchdown angle that maps the apex onto
    itself: the GRF along the leg throughout, a symmetric stance (theta_lo = -theta_td), F_x antisymmetric and
    F_y symmetric in time."""
    slip, measured = data["slip"], data["measured"]
    assert slip["apex"] == data["td_slip"]["apex"] and slip["tau0_N_m"] == 0.0
    assert slip["next_apex"]["y_m"] == pytest.approx(slip["apex"]["y_m"], abs=1e-9)
    assert slip["next_apex"]["xdot_m_per_s"] == pytest.approx(3.0, abs=1e-9)
    footfall = samples(data, "slip", "footfall_m")
    assert np.isnan(footfall[0]) and np.isnan(footfall[-1])  # F_y = 0 at touchdown and liftoff (r = r0)
    assert np.nanmax(np.abs(footfall)) < LOSSLESS_FOOTFALL
    assert measured["slip_largest_footfall_offset_m"] < LOSSLESS_FOOTFALL
    assert slip["liftoff_angle_deg"] == pytest.approx(
        -slip["touchdown_angle_deg"], abs=math.degrees(STATE_ERROR)
    )
    force_error = data["params"]["k_N_per_m"] * STATE_ERROR
    fx, fy = samples(data, "slip", "grf_x_N"), samples(data, "slip", "grf_y_N")
    np.testing.assert_allclose(fx, -fx[::-1], rtol=0.0, atol=force_error)
    np.testing.assert_allclose(fy, fy[::-1], rtol=0.0, atol=force_error)
    assert measured["slip_grf_x_antisymmetry_N"] <= force_error
    assert slip["peak_braking"]["stance_ratio"] < 0.5 < slip["peak_propulsive"]["stance_ratio"]


def test_the_papers_regulator_ends_its_ramp_after_liftoff_so_the_footfall_runs_off(
    data: dict[str, Any], td_slip: ground_reaction.Stance
) -> None:
    """Planned on the analytic map, the ramp ends at the predicted liftoff, not the exact one: where the ramp
    outlasts the stance, the torque is still pushing when F_y reaches zero and tau/F_y has no finite limit."""
    planned = data["paper_regulator_at_this_apex"]
    assert planned["ramp_end_after_liftoff_s"] > 0.0 and planned["hip_torque_at_liftoff_N_m"] < -1.0
    beta = math.radians(ground_reaction.BETA_DEG)
    command = energy_regulation(td_slip.params, td_slip.apex.y, td_slip.apex.xdot, beta).command()
    stance = ground_reaction.sample_stance(td_slip.params, td_slip.apex, command)
    last = stance.footfall()[np.isfinite(stance.footfall())][-1]
    assert last < 2.0 * td_slip.liftoff_footfall()


def test_the_command_draws_fig12_in_the_process_without_the_engine(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert "fig12" in FIGURES

    def no_engine(*args: object, **kwargs: object) -> None:
        raise AssertionError("fig12 needs no Dask cluster")

    monkeypatch.setattr(engine, "connect", no_engine)
    assert cli.main(["figures", "--out", str(tmp_path), "--only", "fig12"]) == 0
    assert_png(tmp_path / "fig12.png")
    document = strict_json(tmp_path / "fig12.json")
    assert document["figure"] == "fig12" and document["params"]["m"] == 65.4


def test_the_claims_table_reads_fig12s_numbers(data: dict[str, Any]) -> None:
    (row,) = [
        row
        for row in paper_comparison.rows({"fig12": data}, PAPER_PARAMS, model_rows=False)
        if row.figures == ("fig12",)
    ]
    braking = data["td_slip"]["peak_braking"]["grf_x_N"]
    assert f"braking peak {braking:.0f} N" in row.exact and "docs/paper.md" not in row.exact
    assert f"{data['td_slip']['footfall_at_liftoff_m']:.3f} m at liftoff" in row.exact
    assert row.command == "tdslip figures --out DIR --only fig12" and row.explanation == "fig-12"
