"""The run reader: tidy records from a real lockstep recording, and clear errors for damaged input."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from support.analysis_runs import as_recorded_before_pitch, raw_messages, rewrite

from tdslip_ros import interfaces
from tdslip_ros.analysis.decoding import RunReadError, infer_params, read_run
from tdslip_ros.analysis.records import CommandRecord, ContactRecord
from tdslip_ros.analysis.strides import applied_commands
from tdslip_ros.bag import RosbagMcapWriter
from tdslip_ros.bag.reader import mcap_file, open_bag
from tdslip_ros.interfaces import resolve
from tdslip_ros.model.events import HopperState, Phase
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.runner import RunReport


@pytest.fixture(scope="module")
def mcap_path(energy: RunReport) -> Path:
    return mcap_file(energy.bag)


def test_the_offline_analysis_and_the_studies_do_not_load_rclpy(repo_root: Path) -> None:
    """Every module of tdslip_ros.analysis and tdslip_ros.studies imports without ROS (rclpy, the generated
    messages); the import contracts (test_lint.py) say the same of the imports as written."""
    packages = ("tdslip_ros.analysis", "tdslip_ros.studies")
    expected = sorted(
        ".".join(path.relative_to(repo_root).with_suffix("").parts).removesuffix(".__init__")
        for package in packages
        for path in repo_root.joinpath(*package.split(".")).rglob("*.py")
    )
    code = (
        "import importlib, pkgutil, sys\n"
        f"for name in {packages!r}:\n"
        "    package = importlib.import_module(name)\n"
        "    for module in pkgutil.walk_packages(package.__path__, name + '.'):\n"
        "        importlib.import_module(module.name)\n"
        f"print(sorted(m for m in sys.modules if m.startswith({packages!r})))\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'tdslip_msgs')))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=repo_root, capture_output=True, text=True, check=True, timeout=300
    )
    imported, ros = result.stdout.splitlines()
    assert imported == str(expected)
    assert ros == "[]"


def test_interface_type_names_are_those_of_the_generated_message_classes() -> None:
    expected = {
        topic: topics.type_name(topics.MESSAGE_TYPES[topic])
        for topic in topics.RECORDED_TOPICS
        if topic not in (topics.MARKERS, topics.HIP_TORQUE)  # the analysis replays the applied torques
    }
    assert interfaces.TOPIC_TYPES == expected


def test_records_match_what_the_plant_published(energy: RunReport) -> None:
    run = read_run(energy.bag)
    # A ramp controller streams no hip torque (no publisher, no channel); the plant applied none.
    assert (
        resolve(topics.HIP_TORQUE) not in energy.recorded
        and energy.recorded[resolve(topics.APPLIED_TORQUE)] == 0
    )
    assert run.message_counts == energy.recorded
    assert len(run.samples) == energy.published[resolve(topics.STATE)] == len(run.samples.grf_t)
    assert len(run.apexes) == energy.published[resolve(topics.APEX)] == len(run.strides)
    assert len(run.contacts) == energy.published[resolve(topics.CONTACT)]
    assert len(run.commands) == energy.published[resolve(topics.COMMAND)]
    # The runner's monitor received the apex events over DDS and rclpy: an independent decoding path.
    for stride, apex in zip(run.strides, energy.apexes, strict=True):
        assert (stride.stride, stride.t, stride.y, stride.xdot, stride.energy) == (
            apex.stride,
            apex.sim_time,
            apex.height,
            apex.forward_speed,
            apex.energy,
        )
    assert run.outcome is not None and run.outcome.kind == "run_complete" and run.outcome.fatal
    assert all(s.failure is None for s in run.strides)
    # Every stance that started had its command; the run ends at an apex, so the last stride has none.
    assert all(s.command is not None and s.policy == "energy" for s in run.strides[:-1])
    assert run.strides[-1].command is None and math.isnan(run.strides[-1].hip_work)
    # 1 kHz samples, sorted, one per tick from t = 0.
    assert np.array_equal(np.round(run.samples.t * 1000.0), np.arange(len(run.samples)))
    assert np.array_equal(run.samples.t, run.samples.grf_t)


def test_stride_energy_flows_are_the_next_apex_bookkeeping(energy: RunReport) -> None:
    run = read_run(energy.bag)
    for stride, after in zip(run.strides, energy.apexes[1:], strict=False):
        assert (stride.hip_work, stride.damping_loss, stride.spring_loss) == (
            after.hip_work,
            after.damping_loss,
            after.spring_loss,
        )
        assert stride.touchdown_time < stride.liftoff_time < after.sim_time


def test_vectorised_1khz_columns_equal_mcap_ros2_decoding(energy: RunReport, mcap_path: Path) -> None:
    run = read_run(energy.bag)
    fields = {
        "x": "x",
        "y": "y",
        "xdot": "xdot",
        "ydot": "ydot",
        "toe_x": "toe_x",
        "toe_y": "toe_y",
        "r": "leg_length",
        "theta": "leg_angle",
        "rdot": "leg_length_rate",
        "thetadot": "leg_angle_rate",
        "hip_torque": "hip_torque",
        "energy": "energy",
        "stride": "stride",
        "phase": "phase",
        "pitch": "pitch",
        "pitch_rate": "pitch_rate",
    }
    decoded: dict[str, list[object]] = {name: [] for name in (*fields, "t", "fx", "fy")}
    with open(mcap_path, "rb") as stream:
        messages = make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            topics=[resolve(topics.STATE), resolve(topics.GRF)]
        )
        for _, channel, _, msg in messages:
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            if channel.topic == resolve(topics.STATE):
                decoded["t"].append(stamp)
                for name, field in fields.items():
                    decoded[name].append(getattr(msg, field))
            else:
                decoded["fx"].append(msg.wrench.force.x)
                decoded["fy"].append(msg.wrench.force.y)
    samples = run.samples
    for name in fields:
        assert np.array_equal(getattr(samples, name), np.array(decoded[name])), name
    assert np.array_equal(samples.t, np.array(decoded["t"]))
    assert np.array_equal(samples.grf_x, np.array(decoded["fx"]))
    assert np.array_equal(samples.grf_y, np.array(decoded["fy"]))
    assert np.count_nonzero(samples.phase == 1) > 0 and np.count_nonzero(samples.grf_y) > 0


def test_a_bag_recorded_before_the_pitch_reads_with_the_fixed_bodys_zeros(
    energy: RunReport, mcap_path: Path, tmp_path: Path
) -> None:
    old = as_recorded_before_pitch(mcap_path, tmp_path / "old.mcap")
    with open(old, "rb") as stream:  # the old bag is sound: mcap_ros2 decodes it by its own schemas
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        kinds = {channel.topic: type(msg).__name__ for _, channel, _, msg in reader.iter_decoded_messages()}
        stream.seek(0)
        apex = next(msg for _, _, _, msg in reader.iter_decoded_messages(topics=[resolve(topics.APEX)]))
    assert not hasattr(apex, "pitch") and kinds[resolve(topics.STATE)] == "HopperState"
    new, before = read_run(mcap_path), read_run(old)
    assert before.apexes == new.apexes and before.contacts == new.contacts and before.strides == new.strides
    for field in ("t", "x", "y", "energy", "hip_torque", "pitch", "pitch_rate", "grf_y"):
        assert np.array_equal(getattr(before.samples, field), getattr(new.samples, field)), field
    assert len(before.samples) > 1000 and not np.any(before.samples.pitch)


def test_an_apex_published_again_reads_once(energy: RunReport, mcap_path: Path, tmp_path: Path) -> None:
    """A lockstep plant publishes an apex no command answered again (PlantRun.repeat_apex): a recording with
    every apex twice reads as the recording with each once."""
    twice = tmp_path / "twice.mcap"
    with RosbagMcapWriter(twice, bag_directory=False) as writer:
        for topic, type_name, log_time, publish_time, data in raw_messages(mcap_path):
            writer.add_topic(topic, type_name)
            for _ in range(2 if topic == resolve(topics.APEX) else 1):
                writer.write(topic, data, log_time, publish_time)
    assert Counter(topic for topic, *_ in raw_messages(twice))[resolve(topics.APEX)] == 2 * len(energy.apexes)
    once, repeated = read_run(mcap_path), read_run(twice)
    assert repeated.apexes == once.apexes and repeated.strides == once.strides
    assert len(once.apexes) == len(energy.apexes)


def test_parameters_come_from_the_bag_or_are_inferred_from_the_recording(energy: RunReport) -> None:
    run = read_run(energy.bag)
    assert run.params_source == "stored in the recording" and run.params == energy.params
    inferred = infer_params(run.apexes, run.contacts, energy.bag)
    for name in ("m", "k", "r0", "c", "g"):
        assert getattr(inferred, name) == pytest.approx(getattr(energy.params, name), rel=1e-12), name
    given = read_run(energy.bag, energy.params)
    assert given.params == energy.params and given.params_source == "given"


def test_parameters_that_contradict_the_recording_are_refused(energy: RunReport) -> None:
    wrong = type(energy.params)(m=energy.params.m * 1.01, k=energy.params.k, r0=1.0, c=energy.params.c)
    with pytest.raises(RunReadError, match="the hopper parameters given contradict the recorded energies"):
        read_run(energy.bag, wrong)


@pytest.mark.parametrize("factor", [1.0 + 1e-4, 0.5, 0.0])
def test_a_damping_that_contradicts_the_recorded_liftoffs_is_refused(
    energy: RunReport, factor: float
) -> None:
    """No energy shows the damping; the liftoffs do (leg force zero): a given damping off by even
    0.01 % is refused with what to do, not analysed into prediction errors of 1e-2."""
    params = energy.params
    wrong = type(params)(m=params.m, k=params.k, r0=params.r0, c=params.c * factor, g=params.g)
    with pytest.raises(RunReadError) as caught:
        read_run(energy.bag, wrong)
    message = str(caught.value)
    assert "the hopper parameters given contradict the recorded liftoff of stride 0" in message
    assert f"the liftoff shows c = {params.c:.6g} N s/m" in message and "--params FILE" in message


def test_stored_parameters_that_contradict_the_recording_are_refused(
    energy: RunReport, mcap_path: Path, tmp_path: Path
) -> None:
    stored = open_bag(energy.bag).custom_data
    key = interfaces.custom_data_key("plant", "damping")
    edited = rewrite(
        mcap_path, tmp_path / "edited.mcap", custom_data={**stored, key: str(energy.params.c * 2)}
    )
    with pytest.raises(RunReadError, match="the hopper parameters stored in the recording contradict"):
        read_run(edited)
    assert read_run(edited, energy.params).params == energy.params  # the right ones, given, are taken


def test_a_bare_mcap_file_reads_like_its_bag_directory(energy: RunReport, mcap_path: Path) -> None:
    assert read_run(mcap_path).strides == read_run(energy.bag).strides


def _state(theta: float, tau: float) -> HopperState:
    return HopperState(
        t=0.1, stride=0, phase=Phase.STANCE, x=0.0, y=0.9, xdot=5.0, ydot=-1.0, toe_x=0.3, toe_y=0.0, r=1.0,
        theta=theta, rdot=-1.0, thetadot=-5.0, hip_torque=tau, energy=1700.0, grf_x=math.nan, grf_y=math.nan,
    )  # fmt: skip


def _command(stride: int, angle: float, tau0: float, log_time: int) -> CommandRecord:
    return CommandRecord(stride, angle, tau0, 0.12, "energy", log_time)


def test_the_applied_command_is_the_one_the_touchdown_shows() -> None:
    contacts = [
        ContactRecord("touchdown", 0, 0.1, _state(0.35, -200.0)),
        ContactRecord("touchdown", 1, 0.4, _state(0.35, -200.0)),
        ContactRecord("touchdown", 2, 0.7, _state(0.30, -150.0)),
    ]
    commands = [
        _command(0, 0.36, -210.0, 1),  # superseded before touchdown
        _command(0, 0.35, -200.0, 2),  # applied
        _command(1, 0.40, -300.0, 3),  # rejected (late): the plant kept the command in force
        _command(2, 0.31, -150.0, 4),  # no match for stride 2: the touchdown shows a command not recorded
    ]
    applied = applied_commands(contacts, commands)
    assert applied == {0: commands[1], 1: commands[1]}


# --- damaged or incomplete input ------------------------------------------------------------------


def _expect_error(path: Path, *needles: str) -> str:
    with pytest.raises(RunReadError) as caught:
        read_run(path)
    message = str(caught.value)
    for needle in needles:
        assert needle in message, message
    return message


def test_missing_path(tmp_path: Path) -> None:
    _expect_error(tmp_path / "nothing", "no such file or directory")


def test_directory_without_a_recording(tmp_path: Path) -> None:
    _expect_error(tmp_path, "bag directory without an .mcap file")


def test_metadata_listing_a_missing_file(energy: RunReport, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    shutil.copytree(energy.bag, bag)
    next(bag.glob("*.mcap")).unlink()
    _expect_error(bag, "listed in metadata.yaml", "is missing")


def test_split_bags_are_refused(mcap_path: Path, tmp_path: Path) -> None:
    for name in ("a.mcap", "b.mcap"):
        shutil.copy(mcap_path, tmp_path / name)
    _expect_error(tmp_path, "split bags", "a.mcap", "b.mcap")


def test_not_an_mcap_file(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    path.write_text("stride,y,xdot\n0,1.0,5.0\n")
    _expect_error(path, "not an MCAP file")


@pytest.mark.parametrize("kept", [0.5, 0.999])
def test_truncated_file(mcap_path: Path, tmp_path: Path, kept: float) -> None:
    data = mcap_path.read_bytes()
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: int(len(data) * kept)])
    _expect_error(path, "truncated or not finalised", "footer")


ZSTD_FRAME = 1 + 8 + 8 + 8 + 8 + 4 + 4 + len("zstd") + 8
"""Bytes from a chunk record's start to its zstd frame: opcode, length, start and end time, uncompressed size
and CRC, the compression's name (length-prefixed) and the records' length (the MCAP specification)."""


@pytest.mark.parametrize("where", ["data", "frame"])
def test_corrupt_chunk(mcap_path: Path, tmp_path: Path, where: str) -> None:
    with open(mcap_path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    chunk = summary.chunk_indexes[0]
    # Inside the compressed data the zstd frame still decodes (to wrong bytes: the CRC catches it); in the
    # frame's header (its magic number) the decompressor itself fails.
    offset = chunk.chunk_start_offset + (2000 if where == "data" else ZSTD_FRAME)
    data = bytearray(mcap_path.read_bytes())
    data[offset : offset + 10] = bytes(b ^ 0xFF for b in data[offset : offset + 10])
    path = tmp_path / "corrupt.mcap"
    path.write_bytes(bytes(data))
    message = _expect_error(path, f"the chunk at byte {chunk.chunk_start_offset} is corrupt")
    assert ("CRC" if where == "data" else "ZstdError") in message


def test_the_apex_topic_is_required(mcap_path: Path, tmp_path: Path) -> None:
    path = rewrite(mcap_path, tmp_path / "no_apex_topic.mcap", keep=lambda t: t != resolve(topics.APEX))
    message = _expect_error(path, f"missing topic {resolve(topics.APEX)}")
    assert resolve(topics.STATE) in message.split("(recorded:")[1]


def test_topics_never_written_are_read_as_empty(energy: RunReport, mcap_path: Path, tmp_path: Path) -> None:
    """A recording without the status, state and force topics (a recorder stopped before the first
    status; a salvage tool that drops empty channels) still reads: those topics have no messages."""
    dropped = {resolve(topics.STATUS), resolve(topics.STATE), resolve(topics.GRF)}
    path = rewrite(mcap_path, tmp_path / "reduced.mcap", keep=lambda t: t not in dropped)
    run = read_run(path)
    assert run.outcome is None and run.statuses == () and len(run.samples) == 0
    assert len(run.samples.grf_t) == 0
    assert [s.y for s in run.strides] == [a.height for a in energy.apexes]
    assert dropped.isdisjoint(run.message_counts)


def test_a_topic_of_the_wrong_type(mcap_path: Path, tmp_path: Path) -> None:
    path = rewrite(
        mcap_path, tmp_path / "retyped.mcap", retype={resolve(topics.APEX): "tdslip_msgs/msg/Status"}
    )
    _expect_error(
        path,
        f"topic {resolve(topics.APEX)} has type tdslip_msgs/msg/Status",
        "expected tdslip_msgs/msg/ApexEvent",
    )


def test_no_apex_messages(mcap_path: Path, tmp_path: Path) -> None:
    path = rewrite(
        mcap_path, tmp_path / "no_apex.mcap", retype={resolve(topics.APEX): "tdslip_msgs/msg/ApexEvent"}
    )
    _expect_error(path, f"topic {resolve(topics.APEX)} has no messages")


def test_an_undecodable_message(mcap_path: Path, tmp_path: Path) -> None:
    path = rewrite(
        mcap_path,
        tmp_path / "bad_cdr.mcap",
        change=lambda topic, index, data: (
            data[:10] if (topic, index) == (resolve(topics.COMMAND), 2) else data
        ),
    )
    _expect_error(path, f"topic {resolve(topics.COMMAND)}: undecodable message")


def test_a_run_without_a_complete_stance_needs_its_parameters(mcap_path: Path, tmp_path: Path) -> None:
    path = rewrite(
        mcap_path,
        tmp_path / "no_contacts.mcap",
        retype={resolve(topics.CONTACT): "tdslip_msgs/msg/ContactEvent"},
    )
    _expect_error(path, "cannot infer the hopper parameters", "give the parameters")


def test_rewrite_keeps_every_message(mcap_path: Path, tmp_path: Path) -> None:
    """The helper the error tests rely on copies a recording faithfully."""
    copy = rewrite(mcap_path, tmp_path / "copy.mcap")
    assert list(raw_messages(copy)) == list(raw_messages(mcap_path))
