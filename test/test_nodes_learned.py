"""The learned policy in the node suite: a lockstep ``tdslip run --policy learned`` of a residual file the
test writes, recorded and analysed; the analysis replays the learned policy from the file the bag names."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from support.learned_policy import learned_file, malformed_file

from tdslip_ros.analysis.compare import REPRODUCTION_TOLERANCE, command_deviation, policy_for_run
from tdslip_ros.analysis.decoding import read_run

pytestmark = pytest.mark.nodes


def tdslip(*arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tdslip_ros.commands.cli", *arguments],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )


def test_a_lockstep_run_of_the_learned_policy_is_recorded_and_replayed_by_the_analysis(
    tmp_path: Path,
) -> None:
    policy_file = learned_file(tmp_path / "policy.json")
    bag = tmp_path / "learned"
    ran = tdslip(
        "run", "--strides", "4", "--policy", "learned", "--policy-file", policy_file, "--out", str(bag)
    )
    assert ran.returncode == 0, ran.stdout + ran.stderr
    assert "lockstep run, policy learned: 4 strides" in ran.stdout
    run = read_run(bag)
    assert run.policies == ("learned",) and len(run.strides) == 5
    # The bag names the file; replayed on the recorded apexes, the policy gives the recorded commands.
    policy = policy_for_run(run)
    assert policy is not None and (policy.name, policy.policy_file) == ("learned", policy_file)
    assert command_deviation(run, policy) <= REPRODUCTION_TOLERANCE
    # Not energy regulation under another name: its base alone commands otherwise.
    assert command_deviation(run, replace(policy, name="energy")) > 1e-3
    analysed = tdslip("analyze", str(bag))
    assert analysed.returncode == 0, analysed.stdout + analysed.stderr
    assert "policy learned" in analysed.stdout and "reproduces the recorded commands" in analysed.stdout
    comparison = json.loads((bag / "report" / "summary.json").read_text())["comparison"]
    assert comparison["policy"]["policy_file"] == policy_file and comparison["policy_reproduced"]


def test_a_learned_run_without_a_readable_file_is_refused_before_anything_starts(tmp_path: Path) -> None:
    spaced = learned_file(tmp_path / "a policy.json")  # readable, but the bag's custom_data splits at spaces
    for file, reason in (
        ((), "needs its file (--policy-file)"),
        (("--policy-file", str(tmp_path / "missing.json")), "missing.json: [Errno 2] No such file"),
        (("--policy-file", str(malformed_file(tmp_path))), "its base policy must be one of"),
        (("--policy-file", spaced), "cannot name a file with spaces"),
    ):
        refused = tdslip(
            "run", "--strides", "1", "--policy", "learned", *file, "--out", str(tmp_path / "bag")
        )
        assert refused.returncode == 2 and reason in refused.stderr, refused.stderr
        assert not (tmp_path / "bag").exists()
