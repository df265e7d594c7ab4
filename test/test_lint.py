"""Lint as tests, like ROS 2's ament_flake8 tests: ruff over the repo, strict mypy over the model core, and
the import contracts of the package's layers (import-linter).

The configuration is in pyproject.toml; a failure shows the tool's own output.
"""

from __future__ import annotations

import os
import shutil
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


def lint_imports(tree: Path) -> subprocess.CompletedProcess[str]:
    """import-linter's ``lint-imports`` (the one installed beside this Python) on the package in ``tree``,
    with the contracts of ``tree/pyproject.toml``; it finds the package in its working directory."""
    environment = {name: value for name, value in os.environ.items() if name != "PYTHONPATH"}
    return subprocess.run(
        [str(Path(sys.executable).with_name("lint-imports")), "--no-cache"],
        cwd=tree,
        env=environment,
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )


def test_import_contracts(repo_root: Path) -> None:
    result = lint_imports(repo_root)
    if result.returncode != 0:
        pytest.fail(f"lint-imports failed:\n{result.stdout}{result.stderr}", False)
    assert "0 broken" in result.stdout


FORBIDDEN_IMPORTS = {
    "model/units.py": "import tdslip_ros.interfaces",  # the model imports upwards
    "studies/outcomes.py": "import tdslip_ros.analysis.decoding",  # studies and analysis are apart
    "analysis/plots.py": "import rclpy",  # ROS in the offline analysis
    "envs/tasks.py": "import tdslip_ros.studies.outcomes",  # the learning envs and the studies are apart
    "reporting/output.py": "import tdslip_ros.reporting.style",  # with the next: a cycle
    "reporting/style.py": "import tdslip_ros.reporting.output",
    "model/plant/stride_kernels.py": "import tdslip_ros.model.policies.controller_kernels",  # upwards
    "model/analytic/apex_map.py": "import tdslip_ros.model.plant.batch",  # map and plant apart
    "model/arrays.py": "import tdslip_ros.model.limits",  # the ground's own order
}


def test_the_import_contracts_refuse_what_they_forbid(repo_root: Path, tmp_path: Path) -> None:
    """A copy of the package with one forbidden import per contract (and more layer violations):
    lint-imports fails and names every one of them."""
    shutil.copytree(
        repo_root / "tdslip_ros", tmp_path / "tdslip_ros", ignore=shutil.ignore_patterns("__pycache__")
    )
    shutil.copy(repo_root / "pyproject.toml", tmp_path)
    for path, line in FORBIDDEN_IMPORTS.items():
        module = tmp_path / "tdslip_ros" / path
        module.write_text(module.read_text() + line + "\n")
    result = lint_imports(tmp_path)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "0 kept, 4 broken" in result.stdout, result.stdout
    report = " ".join(result.stdout.split())  # long lines are wrapped
    for importer, imported in (
        ("tdslip_ros.model.units", "tdslip_ros.interfaces"),
        ("tdslip_ros.studies.outcomes", "tdslip_ros.analysis.decoding"),
        ("tdslip_ros.analysis.plots", "rclpy"),
        ("tdslip_ros.envs.tasks", "tdslip_ros.studies.outcomes"),
        ("tdslip_ros.model.plant.stride_kernels", "tdslip_ros.model.policies.controller_kernels"),
        ("tdslip_ros.model.analytic.apex_map", "tdslip_ros.model.plant.batch"),
        ("tdslip_ros.model.arrays", "tdslip_ros.model.limits"),
    ):
        assert f"{importer} -> {imported}" in report, result.stdout
    assert "No cycles are allowed in tdslip_ros.reporting." in report, result.stdout
