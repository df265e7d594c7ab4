"""The real ``ros2`` commands of a test as child processes: started on one domain, logged under the test's
folder, stopped like a Ctrl-C at a terminal, and always reaped.

Each child leads a process group of its own, and stopping it signals the whole group: ``ros2 run`` and
``ros2 launch`` start the node in a child of their own, and only a terminal's Ctrl-C (the group)
reaches both, as it would for a user.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from support.ros2_tools import ros2_command, ros2_environment
from tdslip_ros.bag import open_bag
from tdslip_ros.bag.cdr import decoder
from tdslip_ros.bag.reader import iter_messages

REAP_GRACE = 15.0  # s for a group to end after SIGINT before it is killed
README = Path(__file__).resolve().parents[2] / "README.md"
ROS2_IN_CODE = re.compile(r"(?:^|`)(ros2 [^`\n#]*?)\s*(?:`|#|$)", re.MULTILINE)


def readme_ros2_commands() -> list[str]:
    """Every ``ros2 ...`` command of README.md: in an inline code span or on a line of a code block."""
    return [match.group(1) for match in ROS2_IN_CODE.finditer(README.read_text())]


def readme_command(command: str) -> list[str]:
    """The words of a README ``ros2`` command, which must be there as written, with ``ros2`` the venv's."""
    assert command in readme_ros2_commands(), f"README.md no longer has `{command}`"
    return [str(ros2_command()), *shlex.split(command)[1:]]


def bag_messages(bag: Path) -> dict[str, list[tuple[int, Any]]]:
    """Every message of a finalised bag (its summary checked against its data) by topic: (log time [ns],
    decoded message), in log-time order."""
    opened = open_bag(bag)
    decoders = {name: decoder(info.schema) for name, info in opened.topics.items() if info.schema}
    messages: dict[str, list[tuple[int, Any]]] = {}
    for channel, message in iter_messages(opened, log_time_order=True):
        messages.setdefault(channel.topic, []).append(
            (message.log_time, decoders[channel.topic](message.data))
        )
    return messages


@dataclass
class Ros2Processes:
    """The children of one test on one domain, each logging to ``<folder>/<name>.log``."""

    domain_id: int
    folder: Path
    started: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)

    def start(self, name: str, arguments: list[str]) -> subprocess.Popen[bytes]:
        with (self.folder / f"{name}.log").open("wb") as log:
            process = subprocess.Popen(
                arguments,
                cwd=self.folder,
                env=ros2_environment(self.domain_id, self.folder / "ros_log"),
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        self.started[name] = process
        return process

    def run(self, name: str, arguments: list[str], timeout: float) -> int:
        """Start ``arguments`` and wait for their exit status (a test failure after ``timeout`` s)."""
        process = self.start(name, arguments)
        try:
            return process.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{name} did not end within {timeout} s:\n{self.output(name)}") from None

    def output(self, name: str) -> str:
        return (self.folder / f"{name}.log").read_text(errors="replace")

    def interrupt(self, name: str, timeout: float = REAP_GRACE) -> int:
        """Ctrl-C for ``name``'s group; its exit status."""
        process = self.started[name]
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGINT)
        try:
            return process.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{name} did not stop on SIGINT:\n{self.output(name)}") from None

    def reap(self) -> None:
        """SIGINT to every group still running, SIGKILL to any still there after REAP_GRACE s."""
        running = [process for process in self.started.values() if process.poll() is None]
        for process in running:
            os.killpg(process.pid, signal.SIGINT)
        for process in running:
            try:
                process.wait(REAP_GRACE)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()


@contextmanager
def ros2_processes(domain_id: int, folder: Path) -> Iterator[Ros2Processes]:
    processes = Ros2Processes(domain_id, folder)
    try:
        yield processes
    finally:
        processes.reap()
