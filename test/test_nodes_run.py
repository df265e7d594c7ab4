"""``tdslip run`` end to end, as a user runs it: three processes, a bag, a table, an exit status."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml  # type: ignore[import-untyped]
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from support import analysis_runs
from support.helpers import apex_table
from support.ros_harness import stop_example

from tdslip_ros.analysis.decoding import read_run
from tdslip_ros.bag.recover import recover
from tdslip_ros.interfaces import resolve
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.nodes import topics

pytestmark = pytest.mark.nodes


IN_BACKGROUND = {
    # tdslip run ARGUMENTS --out <tmp_path>/RELATIVE of these tests, run by the background child of
    # conftest.py while the fast tests run (tdslip_run then hands over its result and output). Lockstep
    # only: a realtime run would compete with the fast tests for the CPU in its 1 kHz tick.
    "test_a_run_prints_its_apexes_and_leaves_a_complete_bag[lockstep]": (
        ("--strides", "3", "--policy", "energy", "--mode", "lockstep"),
        "runs/hop",
    ),
    "test_a_failed_run_names_the_failure_and_exits_non_zero[lockstep]": (
        ("--strides", "8", "--terrain", "step:height=0.3,x=8", "--mode", "lockstep"),
        "wall",
    ),
    "test_a_command_the_controller_finds_none_for_is_the_failure_it_names": (
        ("--speed", "0", "--strides", "3", "--timeout", "1"),
        "standing",
    ),
    "test_a_run_in_a_namespace_records_and_analyses_its_topics_there": (
        ("--strides", "3", "--namespace", "h1"),
        "ns",
    ),
}


def tdslip_run(*arguments: str) -> subprocess.CompletedProcess[str]:
    if arguments[-2] == "--out" and analysis_runs.BACKGROUND is not None:
        ran = analysis_runs.BACKGROUND.command(["run", *arguments[:-2]], Path(arguments[-1]))
        if ran is not None:
            return ran
    return subprocess.run(
        [sys.executable, "-m", "tdslip_ros.commands.cli", "run", *arguments],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )


def bag_apexes(bag: Path) -> list[tuple[int, float, float]]:
    with (bag / f"{bag.name}_0.mcap").open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [
            (message.stride, message.height, message.forward_speed)
            for _, _, _, message in reader.iter_decoded_messages(topics=[resolve(topics.APEX)])
        ]


def bag_counts(bag: Path) -> dict[str, int]:
    information = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {
        entry["topic_metadata"]["name"]: entry["message_count"]
        for entry in information["topics_with_message_count"]
    }


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_run_prints_its_apexes_and_leaves_a_complete_bag(tmp_path: Path, mode: str) -> None:
    """In realtime the run records /clock too (--record-clock), at every tick like the state."""
    bag = tmp_path / "runs" / "hop"
    clock = ("--record-clock",) if mode == "realtime" else ()
    result = tdslip_run("--strides", "3", "--policy", "energy", "--mode", mode, *clock, "--out", str(bag))
    assert result.returncode == 0, result.stdout + result.stderr
    rows = apex_table(result.stdout)
    assert [int(row[0]) for row in rows] == [0, 1, 2, 3]
    # The table is the bag's apex sequence, in SI and in the paper's units (r0 = 1 m, sqrt(g r0)).
    for row, (stride, height, speed) in zip(rows, bag_apexes(bag), strict=True):
        assert row[0] == stride
        assert row[2:4] == pytest.approx([height, speed], abs=1e-5)
        assert row[5:7] == pytest.approx(
            [height / PAPER_PARAMS.r0, speed / (PAPER_PARAMS.g * PAPER_PARAMS.r0) ** 0.5], abs=1e-5
        )
    counts = bag_counts(bag)
    # (A realtime run on a loaded machine may also report a command that came after its touchdown.)
    assert counts[resolve(topics.APEX)] == 4 and counts[resolve(topics.STATUS)] >= 1
    assert counts[resolve(topics.STATE)] > 700
    if clock:
        assert counts["/clock"] == counts[resolve(topics.STATE)]
    printed = {
        line.split()[0]: line.split()[1:] for line in result.stdout.splitlines() if line.startswith("/")
    }
    for topic, count in counts.items():  # the run's own check, printed per topic
        assert printed[topic] == [str(count), str(count)], topic
    assert "LOST" not in result.stdout and f"{mode} run, policy energy: 3 strides" in result.stdout


@pytest.mark.parametrize("mode", ["realtime", "lockstep"])
def test_a_failed_run_names_the_failure_and_exits_non_zero(tmp_path: Path, mode: str) -> None:
    bag = tmp_path / "wall"
    # A 30 cm wall 8 m ahead: the toe cannot clear it (analysis_runs.RUNS["wall"]).
    result = tdslip_run(
        "--strides", "8", "--terrain", "step:height=0.3,x=8", "--mode", mode, "--out", str(bag)
    )
    assert result.returncode == 1
    assert "run FAILED at stride " in result.stderr and ": toe_stubbing" in result.stderr
    assert bag_counts(bag)[resolve(topics.STATUS)] >= 1  # the failure is recorded too, nothing lost
    assert "LOST" not in result.stdout


def test_an_apex_the_leg_cannot_be_placed_from_is_refused_before_anything_starts(tmp_path: Path) -> None:
    """From a 0.9 m apex a leg at 20 degrees (r0 cos = 0.94 m) cannot be placed: refused at once (it used
    to wait out the command timeout), as a usage error, with nothing written."""
    bag = tmp_path / "low"
    result = tdslip_run("--strides", "3", "--height", "0.9", "--out", str(bag))
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.startswith("tdslip run: the leg cannot be placed from an apex at 0.9 m")
    assert result.stderr.count("\n") == 1
    assert not bag.exists()


@pytest.mark.parametrize(
    ("arguments", "reason"),
    [
        (
            ["--policy", "deadbeat", "--target-speed", "400"],
            "controller parameters: target_speed must lie in [0, 100], got 400.0",
        ),
        (
            ["--policy", "stance_pd_speed_energy", "--target-height", "-3"],
            "controller parameters: target_height must lie in [0.001",
        ),
        # The plant's own value is named, not the controller's target energy that derives from it.
        (["--height", "1e9"], "plant parameters: initial_height must lie in [0.001, 100], got 1000000000.0"),
        (
            ["--mode", "realtime", "--realtime-priority", "500"],
            "plant parameters: realtime_priority must lie",
        ),
        (["--mode", "realtime", "--realtime-cpu", "4096"], "realtime CPU 4096 is not one this run may use"),
        # A rigid body: what balances it, and what it cannot run on yet.
        (["--policy", "posture"], "the posture policy balances a rigid body: give --body rigid"),
        (["--hip", "0", "-0.3"], "--hip needs --body rigid"),
        (["--body", "rigid", "--height", "1.2", "--body-inertia", "-1"], "body inertia must be"),
        (
            ["--body", "rigid", "--height", "1.2", "--policy", "posture", "--terrain", "step:height=0.1,x=3"],
            "the 1 kHz stepper runs a rigid body on flat ground",
        ),
        (["--body", "rigid", "--policy", "posture"], "the leg cannot be placed from an apex at 0.8 m"),
        (["--body", "rigid", "--height", "1.2"], "the energy policy plans on the paper's fixed body"),
    ],
)
def test_a_setting_out_of_range_is_refused_before_anything_starts(
    tmp_path: Path, arguments: list[str], reason: str
) -> None:
    """As the plant's are: it used to start the recorder, let the controller exit and leave an empty bag."""
    bag = tmp_path / "far"
    result = tdslip_run("--strides", "3", *arguments, "--out", str(bag))
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.startswith(f"tdslip run: {reason}")
    assert result.stderr.count("\n") == 1
    assert not bag.exists()


def test_an_existing_output_is_refused(tmp_path: Path) -> None:
    result = tdslip_run("--strides", "1", "--out", str(tmp_path))
    assert result.returncode == 2 and "exists already" in result.stderr


def test_a_400_stride_lockstep_run_with_both_cores_busy_records_every_message(tmp_path: Path) -> None:
    """The plant paces itself on the recorder (flow control) instead of failing when the recorder
    falls behind on a loaded machine: the run completes and nothing is lost. (Measured: the recorder is
    FLOW_WINDOW messages behind within the first 3,000 ticks, and the plant waits for it 30 to 50 times in
    the 104,000 ticks of 400 strides.)"""
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        bag = tmp_path / "long"
        result = subprocess.run(
            [sys.executable, "-m", "tdslip_ros.commands.cli", "run", "--strides", "400", "--out", str(bag)],
            capture_output=True,
            text=True,
            timeout=1200,
            check=False,
        )
    finally:
        for process in busy:
            process.kill()
            process.wait()
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert "lockstep run, policy energy: 400 strides" in result.stdout
    counts = bag_counts(bag)
    assert counts[resolve(topics.APEX)] == 401 and counts[resolve(topics.STATE)] > 100_000
    printed = {
        line.split()[0]: line.split()[1:] for line in result.stdout.splitlines() if line.startswith("/")
    }
    assert {topic: int(values[1]) for topic, values in printed.items()} == counts
    assert all(values[0] == values[1] for values in printed.values())  # published = recorded, per topic


def test_a_run_in_a_namespace_records_and_analyses_its_topics_there(tmp_path: Path) -> None:
    bag = tmp_path / "ns"
    # Written as a user may, without the leading slash that rcl's __ns remapping needs (the run adds it).
    result = tdslip_run("--strides", "3", "--namespace", "h1", "--out", str(bag))
    assert result.returncode == 0, result.stdout + result.stderr
    counts = bag_counts(bag)
    assert counts["/h1/tdslip/apex"] == 4 and not any(topic.startswith("/tdslip/") for topic in counts)
    run = read_run(bag)
    assert len(run.strides) == 4 and run.params_source == "stored in the recording"


def child_pid(parent: int, module: str) -> int | None:
    """The pid of ``parent``'s child process running ``python -m <module>``, if there is one."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            command = (stat.parent / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if int(fields[1]) == parent and module.encode() in command:
            return int(stat.parent.name)
    return None


def hopping_run(tmp_path: Path, *arguments: str) -> tuple[subprocess.Popen[str], Path]:
    """``tdslip run`` hopping until stopped (up to a minute), once it has passed stride 3."""
    bag = tmp_path / "run"
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tdslip_ros.commands.cli",
            "run",
            "--strides",
            "0",
            "--duration",
            "60",
            "--out",
            str(bag),
        ]
        + list(arguments),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stderr is not None
    for line in process.stderr:  # the progress lines
        if line.startswith("stride ") and int(line.split()[1].split("/")[0]) >= 3:
            break
    return process, bag


def assert_finalised_and_analysable(bag: Path, stdout: str) -> dict[str, tuple[int, int]]:
    """The bag is finalised, the analysis reads it, and the printed table accounts for every topic:
    (published, recorded) per topic, as printed."""
    assert (bag / "metadata.yaml").is_file()
    run = read_run(bag)
    assert len(run.strides) >= 3
    printed = {line.split()[0]: line.split()[1:3] for line in stdout.splitlines() if line.startswith("/")}
    counts = {topic: (int(published), int(recorded)) for topic, (published, recorded) in printed.items()}
    assert {topic: recorded for topic, (_, recorded) in counts.items()} == {
        topic: count for topic, count in bag_counts(bag).items() if topic in counts
    }
    return counts


def test_a_controller_killed_mid_run_leaves_a_finalised_bag_and_a_count_of_what_was_lost(
    tmp_path: Path,
) -> None:
    process, bag = hopping_run(tmp_path)
    controller = child_pid(process.pid, "tdslip_ros.nodes.controller_node")
    assert controller is not None
    os.kill(controller, signal.SIGKILL)
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode == 1
    assert "controller_node exited early (-9)" in stderr and "(finalised: tdslip analyze" in stderr
    counts = assert_finalised_and_analysable(bag, stdout)
    lost = {topic: published - recorded for topic, (published, recorded) in counts.items()}
    print(f"messages lost after the controller's kill -9: {lost}")
    # The plant's own topics: nothing lost (the plant lives on). The controller's: at most the answer
    # it had just sent, if the kill came before the recorder acknowledged it.
    assert all(n == 0 for topic, n in lost.items() if topic != resolve(topics.COMMAND))
    assert lost[resolve(topics.COMMAND)] in (0, 1)


def test_a_recorder_killed_mid_run_is_named_with_what_tdslip_recover_gets_back(tmp_path: Path) -> None:
    """Issue 35: the table used to say LOST with 0 recorded on every topic, and recover then got
    thousands back. Now its column is what recover keeps, and the shortfall is put on the recorder."""
    process, bag = hopping_run(tmp_path)
    assert process.stderr is not None
    for line in process.stderr:  # past the first chunks (about 10 strides each)
        if line.startswith("stride ") and int(line.split()[1].split("/")[0]) >= 30:
            break
    recorder = child_pid(process.pid, "tdslip_ros.nodes.recorder_node")
    assert recorder is not None
    os.kill(recorder, signal.SIGKILL)
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode == 1
    assert "recorder_node exited early (-9)" in stderr and "LOST" not in stdout
    rows = [line.split(maxsplit=3) for line in stdout.splitlines() if line.startswith("/")]
    assert stdout.splitlines()[0].split() == ["topic", "published", "recoverable"]
    printed = {topic: int(recoverable) for topic, _, recoverable, *_ in rows}
    assert sum(printed.values()) > 0
    assert f"make it readable ({sum(printed.values())} messages) with: tdslip recover {bag}" in stderr
    assert {row[3] for row in rows if len(row) == 4} <= {"after the recorder stopped"}
    recovery = recover(bag)
    assert {topic: recovery.recovered.get(topic, 0) for topic in printed} == printed


def test_a_command_the_controller_finds_none_for_is_the_failure_it_names(tmp_path: Path) -> None:
    """From a standing start (0 m/s) energy regulation predicts a reversal: the failure line says that,
    not only the plant's command_timeout (issue 35)."""
    result = tdslip_run(
        "--speed", "0", "--strides", "3", "--timeout", "1", "--out", str(tmp_path / "standing")
    )
    assert result.returncode == 1
    (failure,) = [line for line in result.stderr.splitlines() if line.startswith("run FAILED")]
    assert failure.startswith(
        "run FAILED at stride 0, t = 0.000000 s: the controller found no command: no command "
        "(predicted_reversal): "
    )
    assert failure.endswith(
        "(command_timeout: no valid command for epoch 0, stride 0 within command_timeout = 1 s)"
    )


def test_a_double_ctrl_c_leaves_a_finalised_bag(tmp_path: Path) -> None:
    process, bag = hopping_run(tmp_path)
    process.send_signal(signal.SIGINT)
    process.send_signal(signal.SIGINT)  # impatient: the second one interrupts at once
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode in (0, 130), stderr
    assert "Traceback" not in stderr
    read_run(bag)  # finalised and readable
    assert (bag / "metadata.yaml").is_file()


def run_with_my_controller(bag: Path, *options: str) -> tuple[int, int, str, str, int]:
    """``tdslip run --controller none OPTIONS`` with examples/my_controller.py started beside it in a free
    domain of its own: (the run's exit status, the example's, the run's stdout and stderr, the domain)."""
    from tdslip_ros.nodes import isolation

    # A free domain from the pool; released at once, the run reserves it (its ROS_DOMAIN_ID), and the pool's
    # cool-down keeps other runs off it meanwhile.
    with isolation.reserved_domain() as domain_id:
        pass
    environment = isolation.isolated_environment(domain_id)
    command = [sys.executable, "-m", "tdslip_ros.commands.cli", "run", "--controller", "none"]
    run = subprocess.Popen(
        [*command, *options, "--wait-for-controller", "60", "--out", str(bag)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=environment,
    )
    controller = subprocess.Popen(
        [sys.executable, str(Path(__file__).parents[1] / "examples" / "my_controller.py")],
        env=environment,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        stdout, stderr = run.communicate(timeout=120)
        controller_status = controller.wait(30)  # the example ends with the plant's run
    finally:
        stop_example(controller)
    return run.returncode, controller_status, stdout, stderr, domain_id


def test_a_run_with_ones_own_controller_waits_for_it_and_ends_recorded_and_analysable(tmp_path: Path) -> None:
    """``tdslip run --controller none`` starts the plant and the recorder only and waits for the user's own
    controller (examples/my_controller.py, started a few seconds later in the same domain); the run ends by
    itself, and so does the example, everything is recorded, and tdslip analyze reads it as a controller of
    one's own."""
    bag = tmp_path / "mine"
    returncode, controller_status, stdout, stderr, domain_id = run_with_my_controller(bag, "--strides", "5")
    assert returncode == 0, stdout[-1500:] + stderr[-2000:]
    assert controller_status == 0
    assert stderr.startswith(f"tdslip run: waiting up to 60 s for your controller in ROS domain {domain_id}")
    assert "lockstep run, your own controller: 5 strides" in stdout and "LOST" not in stdout
    counts = bag_counts(bag)
    assert counts[resolve(topics.APEX)] == 6 and counts[resolve(topics.COMMAND)] >= 5
    analysed = subprocess.run(
        [sys.executable, "-m", "tdslip_ros.commands.cli", "analyze", str(bag)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert analysed.returncode == 0, analysed.stderr[-2000:]
    assert "skip" in analysed.stdout + analysed.stderr  # the replay of a known policy is skipped, and said


def test_ones_own_ramp_controller_on_a_rigid_body_is_predicted_by_the_batched_engine(tmp_path: Path) -> None:
    """A rigid body under a controller of one's own that answers with ramps (examples/my_controller.py):
    its recording reads, and the batched engine (the analysis' exact map for ramps) predicts each recorded
    next apex from the recorded apex, pitch included, and the command, to the plant's RK4 error."""
    from tdslip_ros.analysis.compare import compare_run

    bag = tmp_path / "rigid"
    returncode, _, stdout, stderr, _ = run_with_my_controller(
        bag, "--strides", "3", "--body", "rigid", "--body-inertia", "100", "--height", "1.2"
    )
    assert returncode == 0, stdout[-1500:] + stderr[-2000:]
    run = read_run(bag)
    assert run.params.body is not None and len(run.strides) == 4
    assert all(abs(s.pitch) > 1e-3 for s in run.strides[1:])  # the hip torque turns the body
    comparison = compare_run(run)
    assert comparison.exact_errors.strides == 3 and comparison.exact_errors.failures == 0
    assert max(comparison.exact_errors.max_height, comparison.exact_errors.max_speed) < 1e-9
    assert np.all(np.isnan(comparison.predictions.analytic[1]))  # the analytic map is the fixed body's
