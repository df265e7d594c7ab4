"""Recordings for the analysis and replay tests, made by the real node suite in lockstep.

Each named run is recorded once per test process (``tdslip run``'s :func:`~tdslip_ros.nodes.runner.run`,
a few seconds) under pytest's session temporary directory and shared by every test module: conftest.py
has a session fixture of each name (tests using one are in the ``nodes`` tier). The helpers
below derive damaged or reduced copies of a recording for the error tests, and copies as a
controller of the user's own would leave them.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import math
import os
import pickle
import re
import signal
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import pytest
from mcap.reader import make_reader
from mcap.records import Schema
from rclpy.serialization import deserialize_message, serialize_message
from tdslip_msgs.msg import StanceCommand

from tdslip_ros.bag import RosbagMcapWriter
from tdslip_ros.bag.reader import mcap_file, open_bag
from tdslip_ros.interfaces import custom_data_key, resolve
from tdslip_ros.model.paper import PAPER_PARAMS, UPRIGHT_TRUNK
from tdslip_ros.model.plant.perturbations import Mismatch, Perturbations, PlacementNoise, Pushes, SensingNoise
from tdslip_ros.model.plant.terrain import Blocks, Step
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.runner import RunOptions, RunReport, run

RUNS: dict[str, dict[str, Any]] = {
    # Energy regulation from the default apex (1 m, 5 m/s): converges in a few strides.
    "energy": {"strides": 12},
    # Deadbeat towards 0.95 m (below r0) at 1.5 m/s: the policies command only strides their map accepts, so
    # a failure needs the analytic map to be wrong. Here it is: the stride-1 command lifts off at ydot =
    # +0.05 m/s on the map and -0.97 m/s on the plant, a fall (docs/paper.md, the deadbeat edge).
    "fall": {"strides": 10, "policy": "deadbeat", "target_height": 0.95, "target_speed": 1.5},
    # The ideal regulator, planned on the exact map, holding the initial apex energy.
    "energy_exact": {"strides": 6, "policy": "energy_exact"},
    # Deadbeat to a target speed other than the controller's default (5 m/s).
    "deadbeat": {"strides": 4, "policy": "deadbeat", "target_speed": 4.0},
    # Every perturbation at once: random blocks, sensing noise, placement errors, a hip saturating at
    # 280 N m (energy regulation asks 273 N m on flat ground), a chosen and random pushes, a controller
    # that plans with 5 % more mass and 10 % less damping.
    "rough": {
        "strides": 12,
        "perturbations": Perturbations(
            terrain=Blocks(0.02, 0.5, seed=3),
            sensing=SensingNoise(0.005, 0.05, seed=1),
            placement=PlacementNoise(math.radians(0.5), seed=2),
            tau_max=280.0,
            pushes=Pushes(((5, -0.4),), size=0.2, rate=0.2, seed=4),
            mismatch=Mismatch(mass=1.05, damping=0.9),
        ),
    },
    # The baseline of ref. 36: stance_controller_node streams a hip torque per stance tick.
    "stance_pd": {"strides": 8, "policy": "stance_pd_speed_energy"},
    # A rigid body (the upright trunk) balanced by the posture policy, its hip starting at 1 m.
    "posture": {
        "strides": 8,
        "policy": "posture",
        "height": 1.2,
        "hopper": dataclasses.replace(PAPER_PARAMS, body=UPRIGHT_TRUNK),
    },
    # A 30 cm wall 8 m ahead: the toe cannot clear it.
    "wall": {"strides": 8, "perturbations": Perturbations(terrain=Step(0.3, 8.0))},
}
AGAIN = {"energy_again": "energy"}
"""Second runs with the options of another (test_nodes_recording_bytes compares the two bytewise)."""
_recorded: dict[str, RunReport] = {}


class IncompleteRecording(AssertionError):
    """A run's recording missed messages its nodes published."""


def record(name: str, directory: Path) -> RunReport:
    """Run ``name`` (see RUNS and AGAIN) into ``directory``/``name``: its report. IncompleteRecording if the
    recorder missed a message: the controller answers only once its publisher has matched the recorder
    (``min_subscribers``) and waits for the recorder's acknowledgement before it exits, so a gap is a defect
    of the recording (a return of the recorder race), which fails every test that uses the run."""
    report = run(RunOptions(out=directory / name, **RUNS[AGAIN.get(name, name)]))
    if not report.recording_complete:
        missed = {
            topic: (published, report.recorded.get(topic, 0))
            for topic, published in report.published.items()
            if report.recorded.get(topic, 0) != published
        }
        raise IncompleteRecording(
            f"run {name!r} recorded incompletely: (published, recorded) by topic {missed}; bag {report.bag}"
        )
    return report


@dataclass
class Background:
    """Figure documents drawn, runs recorded, then ``tdslip`` processes run, by a child process
    (``python support/analysis_runs.py DIRECTORY JOBS``), started when collection ended (conftest.py): what
    the tests need is made while the fast tests run, mostly on the core those leave idle. The child pickles
    each document and each run's report as it is done (one it could not make leaves the error) and each
    ``tdslip`` process's result (:meth:`command`)."""

    directory: Path
    names: tuple[str, ...]
    commands: dict[str, tuple[list[str], str]]
    """By key: the arguments of a ``tdslip`` process (the subcommand and its options, without ``--out``) and
    its output directory relative to the test's tmp_path."""
    drawings: list[tuple[str, str]]
    """(test module, name): the child's ``module.draw(name)``, a figure's document (test_claims_paper)."""
    process: subprocess.Popen[bytes]

    @classmethod
    def start(
        cls,
        directory: Path,
        names: tuple[str, ...],
        commands: dict[str, tuple[list[str], str]],
        drawings: list[tuple[str, str]],
    ) -> Background:
        """Draw ``drawings`` in the child first (the fast tests that read them run before any node test),
        then record the runs ``names`` (of RUNS), then run each of ``commands`` as a process of its own."""
        directory.mkdir(parents=True, exist_ok=True)
        # The work tree under test, as in the tests' own process (pyproject.toml: pythonpath), and test/,
        # whose modules draw the documents (a script's own folder, test/support/, is on its path instead).
        here = Path(__file__).resolve()
        path = os.pathsep.join([str(here.parents[2]), str(here.parents[1]), os.environ.get("PYTHONPATH", "")])
        with (directory / "background.log").open("wb") as log:
            process = subprocess.Popen(
                [sys.executable, __file__, str(directory), json.dumps([names, commands, drawings])],
                env={**os.environ, "PYTHONPATH": path.rstrip(os.pathsep)},
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,  # stop() ends its node processes with it
            )
        return cls(directory, names, commands, drawings, process)

    def _wait_for(self, result: Path, job: str) -> bytes:
        failed = result.with_suffix(".error")
        while not (result.exists() or failed.exists() or self.process.poll() is not None):
            time.sleep(0.05)
        if not result.exists():
            log = (self.directory / "background.log").read_text(errors="replace")
            error = failed.read_text() if failed.exists() else f"the child exited with {self.process.poll()}"
            pytest.fail(f"{job} did not finish in the background: {error}\n{log[-3000:]}", pytrace=False)
        return result.read_bytes()

    def report(self, name: str) -> RunReport:
        """The report of run ``name`` once the child has recorded it."""
        report = pickle.loads(self._wait_for(self.directory / f"{name}.pickle", f"run {name!r}"))
        return cast(RunReport, report)

    def drawn(self, module: str, name: str) -> Any:
        """``module.draw(name)`` as the child drew it, or None if it does not draw it."""
        if (module, name) not in self.drawings:
            return None
        return pickle.loads(
            self._wait_for(self.directory / f"{module}.{name}.pickle", f"{module}.draw({name!r})")
        )

    def command(self, arguments: list[str], out: Path) -> subprocess.CompletedProcess[str] | None:
        """The result of ``tdslip ARGUMENTS --out OUT`` if the child ran it (with its output moved to
        ``out``), else None. The child ran it into the same path below its directory as ``out`` is below
        the test's tmp_path (e.g. runs/hop: a parent that does not exist yet)."""
        for key, (background_arguments, relative) in self.commands.items():
            if (
                background_arguments == arguments
                and out.parts[-len(Path(relative).parts) :] == Path(relative).parts
            ):
                result = pickle.loads(self._wait_for(self.directory / f"{key}.result", f"tdslip {key}"))
                ran = self.directory / key / relative
                if ran.exists():
                    out.parent.mkdir(parents=True, exist_ok=True)
                    ran.rename(out)
                return cast(subprocess.CompletedProcess[str], result)
        return None

    def stop(self) -> None:
        """End the child and the processes it started, if it is still at work (a session cut short)."""
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGINT)  # a run stops its nodes on the way out
            try:
                self.process.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()


BACKGROUND: Background | None = None
"""Set by conftest.py when a selected test needs a job of the background child."""


def recorded_run(name: str, tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """The report of run ``name`` (see RUNS): from the background child if it records it, else recorded
    here on first use."""
    if name not in _recorded:
        if BACKGROUND is not None and name in BACKGROUND.names:
            _recorded[name] = BACKGROUND.report(name)
        else:
            _recorded[name] = record(name, tmp_path_factory.getbasetemp() / "analysis_runs")
    return _recorded[name]


def raw_messages(mcap_path: Path) -> Iterator[tuple[str, str, int, int, bytes]]:
    """(topic, type, log time, publish time, data) of every message, in file order."""
    with open(mcap_path, "rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            assert schema is not None
            yield channel.topic, schema.name, message.log_time, message.publish_time, message.data


def by_topic(mcap_path: Path) -> dict[str, list[bytes]]:
    """The data of every message by topic, in file order."""
    messages: dict[str, list[bytes]] = {}
    for topic, _, _, _, data in raw_messages(mcap_path):
        messages.setdefault(topic, []).append(data)
    return messages


def rewrite(
    source: Path,
    target: Path,
    keep: Callable[[str], bool] = lambda topic: True,
    retype: dict[str, str] | None = None,
    change: Callable[[str, int, bytes], bytes] = lambda topic, index, data: data,
    custom_data: dict[str, str] | None = None,
) -> Path:
    """A bare .mcap copy of ``source`` with only the topics ``keep`` accepts (channels of dropped topics
    are kept if listed in ``retype`` with a new type), their messages passed through ``change``, and
    ``custom_data`` (default: none)."""
    retype = retype or {}
    counts: dict[str, int] = {}
    with RosbagMcapWriter(target, bag_directory=False, custom_data=custom_data) as writer:
        for topic, type_name, log_time, publish_time, data in raw_messages(source):
            if topic in retype:
                writer.add_topic(topic, retype[topic])
                continue
            if not keep(topic):
                continue
            writer.add_topic(topic, type_name)
            index = counts.get(topic, 0)
            counts[topic] = index + 1
            writer.write(topic, change(topic, index, data), log_time, publish_time)
    return target


def as_if_from_ones_own_controller(report: RunReport, target: Path) -> Path:
    """A copy of a recording as a controller of the user's own leaves it: the commands carry a policy
    name the package does not know, and no controller parameters are stored."""

    def rename(topic: str, index: int, data: bytes) -> bytes:
        if topic != resolve(topics.COMMAND):
            return data
        command = deserialize_message(data, StanceCommand)
        command.policy = "my_controller"
        return bytes(serialize_message(command))

    stored = open_bag(report.bag).custom_data
    controller = custom_data_key("controller", "")
    kept = {key: value for key, value in stored.items() if not key.startswith(controller)}
    return rewrite(mcap_file(report.bag), target, change=rename, custom_data=kept)


def _write(path: Path, data: bytes) -> None:
    partial = path.with_name(path.name + ".partial")
    partial.write_bytes(data)
    partial.rename(path)  # whole or not at all for the waiting parent


def _background(
    directory: Path,
    names: list[str],
    commands: dict[str, tuple[list[str], str]],
    drawings: list[tuple[str, str]],
) -> None:
    """The child of :class:`Background`: each drawing pickled as it is done, then each run's report, then
    each ``tdslip`` process's result."""
    for module, name in drawings:
        result = directory / f"{module}.{name}.pickle"
        try:
            _write(result, pickle.dumps(importlib.import_module(module).draw(name)))
        except BaseException:
            result.with_suffix(".error").write_text(traceback.format_exc())
    for name in names:
        try:
            _write(directory / f"{name}.pickle", pickle.dumps(record(name, directory)))
        except BaseException:
            (directory / f"{name}.error").write_text(traceback.format_exc())
    for key, (arguments, relative) in commands.items():
        out = directory / key / relative
        try:
            result = subprocess.run(
                [sys.executable, "-m", "tdslip_ros.commands.cli", *arguments, "--out", str(out)],
                capture_output=True,
                text=True,
                timeout=180,
                check=False,
            )
        except BaseException:
            (directory / f"{key}.error").write_text(traceback.format_exc())
            continue
        _write(directory / f"{key}.result", pickle.dumps(result))


if __name__ == "__main__":
    _background(Path(sys.argv[1]), *json.loads(sys.argv[2]))


PITCH_LINE = re.compile(r"^float64 pitch(_rate)? .*\n", re.MULTILINE)
"""A field line of tdslip_msgs 0.2.0's pitch (HopperState, ApexEvent), with its comment."""


def as_recorded_before_pitch(mcap_path: Path, target: Path) -> Path:
    """The recording as tdslip_msgs 0.1.0 wrote it: every schema without the pitch fields, and each message
    with them without its last 16 bytes (both messages end with pitch, pitch_rate; so does ContactEvent, whose
    last field is a HopperState)."""
    with open(mcap_path, "rb") as stream, RosbagMcapWriter(target, bag_directory=False) as writer:
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            assert schema is not None
            text = schema.data.decode()
            old = PITCH_LINE.sub("", text)
            writer.add_topic(
                channel.topic,
                schema.name,
                schema=Schema(id=schema.id, name=schema.name, encoding=schema.encoding, data=old.encode()),
                type_hash=channel.metadata.get("topic_type_hash"),
            )
            data = message.data[:-16] if old != text else message.data
            writer.write(channel.topic, data, message.log_time, message.publish_time)
    return target
