"""Shared fixtures of the test suite."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from ros_harness import RosGraph

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def repo_root() -> Path:
    """The work tree under test (the directory holding package.xml)."""
    return REPO_ROOT


@pytest.fixture
def ament_index(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make the ament index searchable the way ros2cli searches it: through AMENT_PREFIX_PATH.

    ./run.sh sets it to the venv; under a bare ``.venv/bin/python -m pytest`` it is set here to this
    interpreter's prefix, as sourcing a ROS setup file would.
    """
    if not os.environ.get("AMENT_PREFIX_PATH"):
        monkeypatch.setenv("AMENT_PREFIX_PATH", sys.prefix)


@pytest.fixture
def ros(monkeypatch: pytest.MonkeyPatch) -> Iterator[RosGraph]:
    """A private, in-process ROS graph (own context, domain and executor), torn down after the test."""
    from ros_harness import ros_graph

    from tdslip_ros.nodes.isolation import process_settings

    for name, value in process_settings().items():
        monkeypatch.setenv(name, value)  # read when this process creates its first participant
    with ros_graph() as graph:
        yield graph


@pytest.fixture
def tiny_disk(tmp_path: Path) -> Iterator[Path]:
    """A real 2 MiB tmpfs (root in a sandbox can mount one); skipped where mounting is not allowed,
    which leaves the simulated full disk of test_bag_writer.py."""
    mount_point = tmp_path / "disk"
    mount_point.mkdir()
    result = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount_point)],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    if result.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {result.stderr.strip()}")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", str(mount_point)], timeout=30, check=True)
