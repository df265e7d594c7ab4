"""A recorded lockstep run of the baseline of ref. 36 (stance_controller_node at 1 kHz), analysed: the exact
map replays each stance from its recorded torques and reproduces the recorded apexes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tdslip_ros.analysis.compare import compare_run
from tdslip_ros.analysis.reader import read_run
from tdslip_ros.analysis.report import analyze
from tdslip_ros.model.policies import STANCE_PD_SPEED_ENERGY
from tdslip_ros.model.stance_laws import RecordedTorques
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
