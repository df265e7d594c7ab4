"""The real ``ros2`` command line (ros2cli, ``ros2 launch``) in the tests.

It exists where ``../shared/ros2-tools`` sits beside the repository: ``./run.sh`` then installs its wheels
into the venv (with ``composition_interfaces`` and ``tf2_msgs``). Where that folder is absent, as in a user's
clone, a test that needs the tools skips with one line; where it is present but the tools are not installed,
the test fails, since that is a set-up defect. Nothing in the package itself needs these tools.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from tdslip_ros.nodes import isolation

REPO_ROOT = Path(__file__).resolve().parents[2]
SHARED_ROS2_TOOLS = REPO_ROOT.parent / "shared" / "ros2-tools"


def ros2_command() -> Path:
    """The venv's ``ros2`` executable; a one-line skip where ``../shared/ros2-tools`` is absent."""
    if not SHARED_ROS2_TOOLS.is_dir():
        pytest.skip(f"the real ros2 command line comes from {SHARED_ROS2_TOOLS}, which is absent")
    executable = Path(sys.executable).parent / "ros2"
    if not executable.is_file():
        pytest.fail(f"{SHARED_ROS2_TOOLS} exists but {executable} does not: run ./run.sh setup")
    return executable


def tf_message_type() -> type:
    """tf2_msgs' TFMessage, which ``./run.sh`` builds with the tools; a one-line skip where
    ``../shared/ros2-tools`` is absent (the plant then publishes no /tf, and says so)."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        if not SHARED_ROS2_TOOLS.is_dir():
            pytest.skip(f"tf2_msgs comes from {SHARED_ROS2_TOOLS}, which is absent")
        pytest.fail(f"{SHARED_ROS2_TOOLS} exists but tf2_msgs is not installed: run ./run.sh setup")
    return TFMessage  # type: ignore[no-any-return]


def ros2_environment(domain_id: int, log_dir: Path) -> dict[str, str]:
    """The environment of a ``ros2`` child on ``domain_id``, its logs in ``log_dir`` (never under HOME)."""
    environment = isolation.isolated_environment(domain_id)
    environment["AMENT_PREFIX_PATH"] = sys.prefix
    environment["ROS_LOG_DIR"] = str(log_dir)
    return environment
