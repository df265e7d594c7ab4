"""Lint as tests, like ROS 2's ament_flake8 tests: ruff over the repo, strict mypy over the model core.

The configuration is in pyproject.toml; a failure shows the tool's own output.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


def run_tool(repo_root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", *args], cwd=repo_root, capture_output=True, text=True, check=False, timeout=300
    )


def require_success(result: subprocess.CompletedProcess[str]) -> None:
    if result.returncode != 0:
        pytest.fail(f"{' '.join(map(str, result.args[2:]))} failed:\n{result.stdout}{result.stderr}", False)


def test_ruff_check(repo_root: Path) -> None:
    require_success(run_tool(repo_root, "ruff", "check", "--no-cache", "."))


def test_ruff_format(repo_root: Path) -> None:
    require_success(run_tool(repo_root, "ruff", "format", "--check", "--diff", "--no-cache", "."))


def test_mypy_strict_on_model(repo_root: Path) -> None:
    require_success(run_tool(repo_root, "mypy", "tdslip_ros/model"))


def test_mypy_configuration_rejects_untyped_and_any_leaks(repo_root: Path, tmp_path: Path) -> None:
    """The model's mypy settings really are strict: an untyped def and an Any return are errors."""
    sloppy = tmp_path / "sloppy.py"
    sloppy.write_text(
        "import json\n\ndef untyped(a, b):\n    return a + b\n\n"
        "def leaks_any(text: str) -> int:\n    return json.loads(text)\n"
    )
    result = run_tool(
        repo_root, "mypy", "--config-file", str(repo_root / "pyproject.toml"), "--no-incremental", str(sloppy)
    )
    assert result.returncode == 1, result.stdout + result.stderr
    assert "[no-untyped-def]" in result.stdout
    assert "[no-any-return]" in result.stdout
