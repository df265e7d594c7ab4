"""A recorded lockstep run of the baseline of ref. 36 (stance_controller_node at 1 kHz), analysed: the exact
map replays each stance from its recorded torques and reproduces the recorded apexes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tdslip_ros.analysis.compare import compare_run, policy_for_run
from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.analysis.records import STANCE_FEEDBACK, CommandRecord, ContactRecord
from tdslip_ros.analysis.report import analyze
from tdslip_ros.analysis.report_text import headline
from tdslip_ros.analysis.stance_feedback import FeedbackPredictions, feedback_summary
from tdslip_ros.analysis.strides import applied_commands
from tdslip_ros.model.events import HopperState, Phase
from tdslip_ros.model.paper import UPRIGHT_TRUNK
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.stance_laws import RecordedTorques
from tdslip_ros.model.policies.registry import STANCE_PD_SPEED_ENERGY
from tdslip_ros.nodes.runner import RunReport

REPRODUCED = 1e-9
"""m and m/s: the issue's bound on the replay's error (the plant's RK4 at 4 sub-steps: ~1e-11)."""


def test_the_exact_map_reproduces_the_recorded_apexes_from_the_recorded_torques(stance_pd: RunReport) -> None:
    assert stance_pd.ok, stance_pd.outcome
    run = read_run(stance_pd.bag)
    assert run.policies == (STANCE_PD_SPEED_ENERGY,)
    strides = [s for s in run.strides if s.stance_feedback is not None]
    assert len(strides) == len(run.strides) - 1 == 8  # every stance, but after the last apex
    for stride in strides:
        assert stride.command is None and stride.stance_feedback is not None
        law = stride.stance_feedback.law
        assert isinstance(law, RecordedTorques) and len(law.times) > 50
        assert stride.touchdown_time < law.times[0] < stride.liftoff_time
    replay = compare_run(run).stance_feedback
    assert list(replay.stride) == [s.stride for s in strides] and replay.failures == [None] * 8
    assert np.max(replay.error) < REPRODUCED, replay.error


def test_tdslip_analyze_reports_the_replay(stance_pd: RunReport, tmp_path: Path) -> None:
    analysis = analyze(read_run(stance_pd.bag), tmp_path / "report")
    summary = json.loads(analysis.files["summary"].read_text())["comparison"]["stance_feedback_replay"]
    assert summary["strides"] == 8 and summary["failures"] == 0
    assert summary["max_height_error_m"] < REPRODUCED and summary["max_speed_error_m_per_s"] < REPRODUCED
    assert (
        "its recorded torques replayed on the exact map over 8 strides"
        in analysis.files["report"].read_text()
    )


def test_a_rigid_bodys_pitch_is_recorded_and_replayed_per_stride(posture: RunReport, tmp_path: Path) -> None:
    """Issue 36: the posture policy on the upright trunk, recorded and analysed. The exact map, from each
    recorded apex (pitch included) and the stance's recorded torques, gives the next apex's pitch and rate as
    recorded; the policy replayed on the recorded states gives the torques held; the report says so, draws the
    pitch and draws no analytic return map, which is the fixed body's."""
    assert posture.ok, posture.outcome
    run = read_run(posture.bag)
    assert run.params.body == UPRIGHT_TRUNK and run.params_source == "stored in the recording"
    pitches = [s.pitch for s in run.strides]
    assert pitches[0] == 0.0 and all(-0.6 < pitch < -0.3 for pitch in pitches[1:])  # it leans forward
    assert np.array_equal(run.samples.pitch[:1], [0.0]) and np.ptp(run.samples.pitch) > 0.3
    comparison = compare_run(run)
    replay = comparison.stance_feedback
    assert replay.failures == [None] * 8
    assert np.max(replay.error) < REPRODUCED, replay.error
    assert np.max(np.abs(replay.exact_pitch - replay.recorded_pitch)) < REPRODUCED, replay.exact_pitch
    assert comparison.command_deviation is not None and comparison.command_deviation < 1e-9
    analysis = analyze(run, tmp_path / "report")
    summary = json.loads(analysis.files["summary"].read_text())
    replayed = summary["comparison"]["stance_feedback_replay"]
    assert replayed["max_pitch_error_rad"] < REPRODUCED and replayed["max_pitch_rate_error_rad_per_s"] < 1e-8
    assert summary["run"]["params"]["body"]["inertia_kg_m2"] == UPRIGHT_TRUNK.inertia
    assert "body_pitch" in summary["figures"] and "return_map" in summary["figures_omitted"]
    report = analysis.files["report"].read_text()
    assert "body: rigid, J = 7.2 kg m^2" in report and ", pitch " in report


def test_the_stance_feedback_policy_is_replayed_and_reproduces_every_torque(stance_pd: RunReport) -> None:
    """Issue 33: its law, with the stored settings and the controller's hopper, on each recorded stance state
    gives the torque the hip held, to rounding (the node computes on floats with math, the replay on arrays
    with numpy); other gains do not."""
    run = read_run(stance_pd.bag)
    comparison = compare_run(run)
    assert comparison.policy is not None and comparison.policy.name == STANCE_PD_SPEED_ENERGY
    assert comparison.command_deviation is not None and comparison.command_deviation < 1e-13
    assert comparison.policy_reproduced
    assert comparison.ramp_policy is None and comparison.analytic_fixed_point is None
    doubled = 2.0 * comparison.policy.stance_speed_gain
    other = compare_run(run, policy_for_run(run, stance_speed_gain=doubled))
    assert other.command_deviation is not None and other.command_deviation > 1e-3
    assert "policy stance_pd_speed_energy (" in headline(comparison) and "reproduces" in headline(comparison)


def test_a_stance_feedback_command_is_found_applied_with_and_without_a_torque_limit() -> None:
    """Before: with tau_max the reader evaluated the ramp of a command that has none (t_f = 0) and divided
    by zero, so that tdslip analyze crashed on every stance-feedback run recorded with --tau-max."""
    angle = math.radians(22.0)
    state = HopperState(
        t=0.5, stride=0, phase=Phase.STANCE, x=0.0, y=0.93, xdot=3.0, ydot=-1.0, toe_x=0.4, toe_y=0.0, r=1.0,
        theta=angle, rdot=-1.0, thetadot=-3.0, hip_torque=0.0, energy=0.0, grf_x=math.nan, grf_y=math.nan,
    )  # fmt: skip
    touchdown = ContactRecord("touchdown", 0, 0.5, state)
    command = CommandRecord(0, angle, 0.0, 0.0, STANCE_PD_SPEED_ENERGY, 1, STANCE_FEEDBACK)
    for perturbations in (Perturbations(), Perturbations(tau_max=500.0)):
        assert applied_commands([touchdown], [command], perturbations) == {0: command}


def test_a_replay_predicted_to_fail_does_not_hide_the_other_strides_errors() -> None:
    predictions = FeedbackPredictions(
        stride=np.array([3, 4]),
        recorded=np.array([[1.0, 4.0], [1.1, 4.2]]),
        exact=np.array([[1.0 + 2e-12, 4.0 - 3e-12], [np.nan, np.nan]]),
        failures=[None, "fall"],
        recorded_pitch=np.array([[0.1, 0.2], [0.3, 0.4]]),
        exact_pitch=np.array([[0.1 + 5e-12, 0.2], [np.nan, np.nan]]),
    )
    summary = feedback_summary(predictions)
    assert summary["max_pitch_error_rad"] == pytest.approx(5e-12, rel=1e-3)
    assert summary["failures"] == 1
    assert summary["max_height_error_m"] == pytest.approx(2e-12, rel=1e-3)
    assert summary["max_speed_error_m_per_s"] == pytest.approx(3e-12, rel=1e-3)
    json.dumps(summary, allow_nan=False)  # standard JSON: no NaN
