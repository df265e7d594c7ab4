"""The README's ``colcon build``, started in the background as soon as a test that needs it is collected.

Compiling ``tdslip_msgs`` (the C and C++ type supports of seven interfaces) takes about a minute of both
cores. Started at the end of collection with the lowest CPU priority (nice 19), it uses what the tests
before it leave idle (most node tests wait on discovery, timeouts and child processes) instead of making
the suite wait a minute; the test that needs it waits for it. The build is the one the README gives, in a
plain workspace (this repository linked as ``src/tdslip_ros``), with the venv as underlay as an activated
venv presents it.
"""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

PACKAGE = "tdslip_ros"
BUILD_TIMEOUT = 900  # s


def readme_colcon_command(repo_root: Path) -> list[str]:
    """The ``colcon build`` line of the README's colcon section, as a user copies it."""
    lines = [line.strip() for line in (repo_root / "README.md").read_text().splitlines()]
    (command,) = [line for line in lines if line.startswith("colcon build")]
    return shlex.split(command)


def underlay_environment() -> dict[str, str]:
    """This process's environment with the venv as the only ROS prefix, as an activated venv presents it."""
    venv = Path(sys.prefix)
    environment = {
        key: value
        for key, value in os.environ.items()
        if key not in ("PYTHONPATH", "AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH", "COLCON_PREFIX_PATH")
    }
    return environment | {
        "AMENT_PREFIX_PATH": str(venv),
        "CMAKE_PREFIX_PATH": str(venv),
        "VIRTUAL_ENV": str(venv),
        "PATH": f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}",
    }


@dataclass
class ColconBuild:
    """A running (then finished) build of the README's command in ``workspace``."""

    workspace: Path
    environment: dict[str, str]
    process: subprocess.Popen[bytes]

    @classmethod
    def start(cls, repo_root: Path) -> ColconBuild:
        workspace = Path(tempfile.mkdtemp(prefix="tdslip_colcon_")) / "tdslip_ws"
        (workspace / "src").mkdir(parents=True)
        (workspace / "src" / PACKAGE).symlink_to(repo_root)
        environment = underlay_environment()
        logs = workspace.parent
        with (logs / "stdout").open("wb") as stdout, (logs / "stderr").open("wb") as stderr:
            process = subprocess.Popen(
                ["nice", "-n", "19", *readme_colcon_command(repo_root)],
                cwd=workspace,
                env=environment,
                stdout=stdout,
                stderr=stderr,
                start_new_session=True,  # remove() ends cmake and the compilers with it
            )
        return cls(workspace, environment, process)

    def wait(self) -> subprocess.CompletedProcess[str]:
        """The finished build: its exit status, stdout and stderr."""
        try:
            returncode = self.process.wait(BUILD_TIMEOUT)
        except subprocess.TimeoutExpired:
            os.killpg(self.process.pid, signal.SIGKILL)
            raise
        logs = self.workspace.parent
        return subprocess.CompletedProcess(
            self.process.args,
            returncode,
            (logs / "stdout").read_text(errors="replace"),
            (logs / "stderr").read_text(errors="replace"),
        )

    def remove(self) -> None:
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait()
        shutil.rmtree(self.workspace.parent, ignore_errors=True)
