"""Any bag through a topic map, and the strides found in its data (issue 33, analysis/topic_map.py,
analysis/measured_reading.py, analysis/stride_detection.py).

Independent truth: (1) one run of the suite's plant with a hopper unlike the default, recorded as the suite
records it and re-expressed in standard messages (test/support/standard_bags.py): both give the same strides;
(2) a separate integration of the stance equations written here (scipy solve_ivp, not the package's
engines), with a ramp torque per stride, recorded as a motion-capture + force-plate setup would: the strides
found agree with the events that integration located. Bad input gets one line. About 6 s in all on the
2-core VM (the bags are written once per module).
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs
from mcap.reader import SeekingReader
from scipy.integrate import solve_ivp
from support.standard_bags import (
    GAZEBO_MAP,
    KNOWN_HOPPER,
    PlantRun,
    Topics,
    header,
    plant_run,
    stride_command,
    write_gazebo_bag,
    write_suite_bag,
)

from tdslip_ros.analysis import json_schema
from tdslip_ros.analysis.measured_reading import MapMismatchError, MeasuredDataError, measured_run_from_bag
from tdslip_ros.analysis.stride_detection import NoStanceError, find_strides
from tdslip_ros.analysis.topic_map import (
    UNITS,
    TopicMapError,
    load_topic_map,
    schema,
    suite_topic_map,
    topic_map_from_document,
)
from tdslip_ros.bag import RosbagMcapWriter
from tdslip_ros.bag.reader import BagReadError, iter_messages, open_bag, topic_messages
from tdslip_ros.commands import analyze

pytestmark = pytest.mark.xdist_group("standard_bags")


@pytest.fixture(scope="module")
def plant() -> PlantRun:
    return plant_run()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory, plant: PlantRun) -> dict[str, Path]:
    directory = tmp_path_factory.mktemp("standard_bags")
    return {
        "suite": write_suite_bag(directory / "suite", plant),
        "gazebo": write_gazebo_bag(directory / "gazebo", plant),
    }


def gazebo_map(change: dict[str, dict[str, object]] | None = None) -> dict[str, object]:
    document = copy.deepcopy(GAZEBO_MAP)
    for quantity, entry in (change or {}).items():
        document["quantities"].setdefault(quantity, {}).update(entry)  # type: ignore[attr-defined]
    return document


def test_the_suite_and_standard_messages_give_the_same_strides(recorded: dict[str, Path]) -> None:
    """Same plant run, two recordings: the suite's own topics at 1 kHz, and Odometry (z up) at 250 Hz,
    a force plate and JointState (hip angle and effort of the opposite sign). Tolerances: apex times 1e-9 s
    (the flight's velocity is linear in time, so both interpolate it exactly); touchdown 1e-6 s and its
    angle 1e-5 rad (the toe is placed from the first stance sample's body position, which the 250 Hz pose
    gives by Hermite interpolation through stance, O(h^4)); liftoff identical (the same 1 kHz force)."""
    ours = find_strides(measured_run_from_bag(recorded["suite"], suite_topic_map()))
    theirs_run = measured_run_from_bag(recorded["gazebo"], topic_map_from_document(gazebo_map(), "gazebo"))
    theirs = find_strides(theirs_run)
    assert len(ours) == len(theirs) == 9 and all(s.usable for s in ours + theirs)
    for a, b in zip(ours, theirs, strict=True):
        assert (a.apex_index, a.touchdown_index, a.liftoff_index, a.next_apex_index) == (
            b.apex_index,
            b.touchdown_index,
            b.liftoff_index,
            b.next_apex_index,
        )
        assert b.apex_time == pytest.approx(a.apex_time, abs=1e-9)
        assert b.next_apex_time == pytest.approx(a.next_apex_time, abs=1e-9)
        assert b.touchdown_time == pytest.approx(a.touchdown_time, abs=1e-6)
        assert b.liftoff_time == a.liftoff_time
        assert b.touchdown_angle == pytest.approx(a.touchdown_angle, abs=1e-5)
    # The conversion to the model's plane, checked on the samples: same height, same force, same torque.
    ours_run = measured_run_from_bag(recorded["suite"], suite_topic_map())
    flight = ours_run.ground_force is not None and ours_run.ground_force[:, 1] == 0.0
    assert np.allclose(theirs_run.body_position[flight], ours_run.body_position[flight], atol=1e-12)
    assert theirs_run.ground_force is not None and ours_run.ground_force is not None
    assert np.array_equal(theirs_run.ground_force, ours_run.ground_force)
    assert theirs_run.hip_torque is not None and ours_run.hip_torque is not None
    assert np.array_equal(theirs_run.hip_torque, ours_run.hip_torque)
    assert dict(theirs_run.sources)["body_position"] == "/odom"


# --- a separate integration ---------------------------------------------------------------------------

G = KNOWN_HOPPER.g


def _stance(y0: list[float], tau0: float, t_f: float) -> tuple[object, float]:
    """The stance from touchdown (r, theta, rdot, thetadot), integrated here: polar coordinates about the
    toe, body - toe = (-r sin theta, r cos theta), m r'' = m r theta'^2 - m g cos theta + k (r0 - r) - c r',
    m r^2 theta'' = m g r sin theta - 2 m r r' theta' + tau (NOTES.md), ending where the leg force is zero."""
    p = KNOWN_HOPPER

    def rhs(s: float, y: np.ndarray) -> list[float]:
        r, theta, rdot, thetadot = y
        tau = tau0 * (1.0 - s / t_f) if s < t_f else 0.0
        force = p.k * (p.r0 - r) - p.c * rdot
        rddot = r * thetadot**2 - G * math.cos(theta) + force / p.m
        thetaddot = (G * math.sin(theta) - 2.0 * rdot * thetadot) / r + tau / (p.m * r * r)
        return [rdot, thetadot, rddot, thetaddot]

    def leg_force(s: float, y: np.ndarray) -> float:
        return s < 0.02 or p.k * (p.r0 - y[0]) - p.c * y[2]

    leg_force.terminal = True  # type: ignore[attr-defined]
    leg_force.direction = -1  # type: ignore[attr-defined]
    first = solve_ivp(rhs, (0.0, t_f), y0, rtol=1e-12, atol=1e-12, dense_output=True)
    second = solve_ivp(
        rhs, (t_f, 1.0), first.y[:, -1], rtol=1e-12, atol=1e-12, dense_output=True, events=leg_force
    )
    t_lo = float(second.t_events[0][0])

    def state(s: np.ndarray) -> np.ndarray:
        return np.where(s < t_f, first.sol(np.minimum(s, t_f)), second.sol(np.clip(s, t_f, t_lo)))

    return state, t_lo


def synthetic_recording(path: Path) -> dict[str, list[float]]:
    """Six strides of KNOWN_HOPPER from the apex (1 m, 4 m/s), integrated here, recorded as a mocap pose of
    the body (500 Hz, mm, z up), the toe marker (1 kHz, mm) and a force plate (1 kHz, the force on the
    plate); the events as the integration located them."""
    p = KNOWN_HOPPER
    dt = 1e-3
    t_apex, x_apex, y_apex, xdot = 0.0, 0.0, 1.0, 4.0
    t_liftoff = 0.0
    pieces: list[tuple[float, float, object]] = []  # (start, end, sampler of body, toe, force at times)
    truth: dict[str, list[float]] = {"apex": [], "touchdown": [], "liftoff": [], "angle": []}
    for stride in range(6):
        command = stride_command(p, xdot, stride)
        theta = command.touchdown_angle
        fall = math.sqrt(2.0 * (y_apex - p.r0 * math.cos(theta)) / G)
        t_td, x_td, ydot_td = t_apex + fall, x_apex + xdot * fall, -G * fall
        toe_x = x_td + p.r0 * math.sin(theta)
        truth["apex"].append(t_apex)
        truth["touchdown"].append(t_td)
        truth["angle"].append(theta)

        def flight(t: np.ndarray, t0=t_apex, x0=x_apex, y0=y_apex, v=xdot, angle=theta) -> tuple:
            x, y = x0 + v * (t - t0), y0 - 0.5 * G * (t - t0) ** 2
            toe = np.stack([x + p.r0 * math.sin(angle), y - p.r0 * math.cos(angle)])
            return np.stack([x, y]), toe, np.zeros((2, len(t)))

        pieces.append((t_liftoff, t_td, flight))  # ballistic through the apex
        rdot = -xdot * math.sin(theta) + ydot_td * math.cos(theta)
        thetadot = (-xdot * math.cos(theta) - ydot_td * math.sin(theta)) / p.r0
        state, t_lo = _stance([p.r0, theta, rdot, thetadot], command.tau0, command.t_f)

        def stance(t: np.ndarray, state=state, t0=t_td, toe_x=toe_x, command=command) -> tuple:
            r, th, rd, thd = state(t - t0)
            body = np.stack([toe_x - r * np.sin(th), r * np.cos(th)])
            tau = np.where(t - t0 < command.t_f, command.tau0 * (1 - (t - t0) / command.t_f), 0.0)
            axial = p.k * (p.r0 - r) - p.c * rd
            force = np.stack(
                [-axial * np.sin(th) - tau / r * np.cos(th), axial * np.cos(th) - tau / r * np.sin(th)]
            )
            return body, np.stack([np.full_like(t, toe_x), np.zeros_like(t)]), force

        pieces.append((t_td, t_td + t_lo, stance))
        truth["liftoff"].append(t_td + t_lo)
        t_liftoff = t_td + t_lo
        (r, th, rd, thd) = state(np.array([t_lo]))[:, 0]
        x_lo, y_lo = toe_x - r * math.sin(th), r * math.cos(th)
        xdot = -rd * math.sin(th) - r * thd * math.cos(th)
        ydot = rd * math.cos(th) - r * thd * math.sin(th)
        rise = ydot / G
        t_apex, x_apex, y_apex = (
            t_td + t_lo + rise,
            x_lo + xdot * rise,
            y_lo + ydot * rise - 0.5 * G * rise**2,
        )
    truth["apex"].append(t_apex)
    last_angle = stride_command(p, xdot, 6).touchdown_angle

    def last_flight(t: np.ndarray) -> tuple:
        x, y = x_apex + xdot * (t - t_apex), y_apex - 0.5 * G * (t - t_apex) ** 2
        toe = np.stack([x + p.r0 * math.sin(last_angle), y - p.r0 * math.cos(last_angle)])
        return np.stack([x, y]), toe, np.zeros((2, len(t)))

    pieces.append((t_liftoff, t_apex, last_flight))
    time = np.arange(1, int(t_apex / dt)) * dt
    body, toe, force = (
        np.full((2, len(time)), np.nan),
        np.full((2, len(time)), np.nan),
        np.zeros((2, len(time))),
    )
    for start, end, sampler in pieces:
        inside = (time >= start) & (time < end)
        body[:, inside], toe[:, inside], force[:, inside] = sampler(time[inside])  # type: ignore[operator]
    with RosbagMcapWriter(path) as writer:
        topics = Topics(writer)
        topics.add(
            "/mocap/body",
            "geometry_msgs/msg/PoseStamped",
            {"header": header(0.0)},
            ["pose.position.x", "pose.position.z"],
        )
        topics.add(
            "/mocap/toe", "geometry_msgs/msg/PointStamped", {"header": header(0.0)}, ["point.x", "point.z"]
        )
        topics.add(
            "/plate/wrench",
            "geometry_msgs/msg/WrenchStamped",
            {"header": header(0.0)},
            ["wrench.force.x", "wrench.force.z"],
        )
        for i, t in enumerate(time.tolist()):
            if i % 2 == 0:
                topics.write("/mocap/body", t, (body[:, i] * 1e3).tolist())
            topics.write("/mocap/toe", t, (toe[:, i] * 1e3).tolist())
            topics.write("/plate/wrench", t, (-force[:, i]).tolist())
    return truth


def documented_maps() -> list[dict[str, object]]:
    """The worked examples of docs/identify.md's "The topic map", parsed: the tests read through them."""
    page = (Path(__file__).parents[1] / "docs" / "identify.md").read_text()
    section = page.split("## The topic map", 1)[1].split("\n## ", 1)[0]
    return [yaml.safe_load(block.split("```", 1)[0]) for block in section.split("```yaml\n")[1:]]


def test_strides_agree_with_a_separate_integration(tmp_path: Path) -> None:
    """Tolerances: apex 1e-9 s (the differentiated 500 Hz pose is exact in flight, a parabola); touchdown
    2e-6 s and its angle 5e-6 rad (placed by the geometry from the samples 1 ms apart around it, across the
    kink of the motion: observed 8e-7 s, 1.5e-6 rad); liftoff 2e-6 s (the force extrapolated linearly to
    zero over the last millisecond: observed 9e-7 s; the leaving level alone is up to a sample early)."""
    truth = synthetic_recording(tmp_path / "mocap")
    (tmp_path / "mocap.yaml").write_text(yaml.safe_dump(documented_maps()[0]))
    run = measured_run_from_bag(tmp_path / "mocap", load_topic_map(tmp_path / "mocap.yaml"))
    assert not run.velocity_measured
    strides = find_strides(run)
    # The first apex is the recording's first sample, and it ends just before the last: five strides found,
    # the last set aside.
    assert len(strides) == 5 and all(s.usable for s in strides[:4])
    assert not strides[4].usable and strides[4].reason == "the recording ends before the next apex"
    for k, stride in enumerate(strides[:4], start=1):
        assert stride.apex_time == pytest.approx(truth["apex"][k], abs=1e-9)
        assert stride.next_apex_time == pytest.approx(truth["apex"][k + 1], abs=1e-9)
        assert stride.touchdown_time == pytest.approx(truth["touchdown"][k], abs=2e-6)
        assert stride.touchdown_angle == pytest.approx(truth["angle"][k], abs=5e-6)
        assert stride.liftoff_time == pytest.approx(truth["liftoff"][k], abs=2e-6)


# --- the map and bad input ------------------------------------------------------------------------------


def test_the_documented_gazebo_map_is_the_one_tested() -> None:
    assert documented_maps()[1]["quantities"] == GAZEBO_MAP["quantities"]


def test_the_schema_states_every_unit_the_code_converts() -> None:
    """The units the schema allows per quantity are exactly those with an SI value here."""
    allowed = {
        unit
        for name, node in schema()["$defs"].items()
        if name != "source"
        for unit in node["properties"]["unit"]["enum"]
    }
    assert allowed == set(UNITS)


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (
            {"body_vertical": {"unit": "furlong"}},
            "quantities.body_vertical.unit: 'furlong' is not one of 'm', 'cm', 'mm'",
        ),
        ({"leg_angle": {"unit": "m"}}, "quantities.leg_angle.unit: 'm' is not one of 'rad', 'deg'"),
        (
            {"body_vertical": {"type": "sensor_msgs/msg/Imu"}},
            "quantities.body_vertical.type: 'sensor_msgs/msg/Imu' is not one of",
        ),
        ({"hip_torque": {"sign": 2}}, "quantities.hip_torque.sign: 2 is not one of 1, -1"),
        (
            {"body_forward": {"stamp": "receipt"}},
            "quantities.body_forward.stamp: 'receipt' is not one of 'header', 'log'",
        ),
        ({"body_forward": {"colour": "red"}}, "quantities.body_forward.colour: not allowed here"),
        ({"leg_length": {"joint": None}}, "quantities.leg_length.joint: must be of type string"),
    ],
)
def test_a_map_the_schema_refuses_gets_one_line(change: dict, expected: str) -> None:
    with pytest.raises(TopicMapError) as error:
        topic_map_from_document(gazebo_map(change), "robot.yaml")
    assert str(error.value).startswith(f"robot.yaml: {expected}") and "\n" not in str(error.value)


def test_the_validator_reads_its_rules_from_the_schema() -> None:
    """A keyword it does not implement is refused, not ignored."""
    with pytest.raises(json_schema.SchemaError, match="minItems"):
        json_schema.check_schema({"properties": {"a": {"minItems": 1}}})
    document = gazebo_map()
    del document["quantities"]["body_forward"]  # type: ignore[attr-defined]
    assert json_schema.first_error(schema(), document) == "quantities: body_forward is missing"


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (
            {"body_vertical": {"topic": "/mocap"}},
            "quantities.body_vertical: the recording has no topic /mocap",
        ),
        ({"body_vertical": {"field": "pose.pose.height", "axis": None}}, "has no field 'pose.pose.height'"),
        (
            {"leg_length": {"joint": "knee"}},
            "quantities.leg_length: /joint_states has no joint 'knee' (its joints: hip_pitch, leg_slider)",
        ),
        (
            {"ground_force_forward": {"type": "geometry_msgs/msg/Vector3Stamped"}},
            "/force_plate is geometry_msgs/msg/WrenchStamped in the recording, not "
            "geometry_msgs/msg/Vector3Stamped",
        ),
        (
            {
                "contact": {
                    "topic": "/foot_contact",
                    "type": "std_msgs/msg/Bool",
                    "field": "data",
                    "unit": "1",
                }
            },
            "quantities.contact: std_msgs/msg/Bool has no header to stamp by (stamp: log)",
        ),
        (
            {"body_forward": {"field": "child_frame_id", "axis": None}},
            "is not a number (string) at 'child_frame_id'",
        ),
    ],
)
def test_a_map_that_does_not_fit_the_bag_gets_one_line(
    recorded: dict[str, Path], change: dict, expected: str
) -> None:
    document = gazebo_map(change)
    for entry in document["quantities"].values():  # type: ignore[attr-defined]
        if entry.get("axis", "") is None:
            del entry["axis"]
    with pytest.raises(MapMismatchError) as error:
        measured_run_from_bag(recorded["gazebo"], topic_map_from_document(document, "robot.yaml"))
    assert expected in str(error.value) and "\n" not in str(error.value)


def _bag_with(path: Path, times: list[float], heights: list[float], force: list[float] | None = None) -> Path:
    with RosbagMcapWriter(path) as writer:
        topics = Topics(writer)
        topics.add("/pose", "geometry_msgs/msg/PoseStamped", {"header": header(0.0)}, ["pose.position.z"])
        topics.add("/plate", "geometry_msgs/msg/WrenchStamped", {"header": header(0.0)}, ["wrench.force.z"])
        for i, (t, y) in enumerate(zip(times, heights, strict=True)):
            topics.write("/pose", t, [y])
            topics.write("/plate", t, [0.0 if force is None else force[i]])
    return path


SIMPLE_MAP = {
    "format": "tdslip_topic_map/1",
    "quantities": {
        "body_forward": {
            "topic": "/pose",
            "type": "geometry_msgs/msg/PoseStamped",
            "field": "pose.position.x",
            "unit": "m",
        },
        "body_vertical": {
            "topic": "/pose",
            "type": "geometry_msgs/msg/PoseStamped",
            "field": "pose.position.z",
            "unit": "m",
        },
        "ground_force_forward": {
            "topic": "/plate",
            "type": "geometry_msgs/msg/WrenchStamped",
            "field": "wrench.force.x",
            "unit": "N",
        },
        "ground_force_vertical": {
            "topic": "/plate",
            "type": "geometry_msgs/msg/WrenchStamped",
            "field": "wrench.force.z",
            "unit": "N",
            "sign": -1,
        },
    },
}


def test_bad_data_gets_one_line(tmp_path: Path) -> None:
    """Stamps that go backwards, a NaN, and a bag without stance (the force plate reads nothing)."""
    topic_map = topic_map_from_document(copy.deepcopy(SIMPLE_MAP), "simple")
    times = [0.001 * i for i in range(1, 200)]
    heights = [1.0 - 0.5 * G * t * t for t in times]
    backwards = times[:50] + [times[48]] + times[51:]
    with pytest.raises(
        MeasuredDataError,
        match=r"^/pose: the header stamps go backwards at message 50 "
        r"\(0\.049000000 s after 0\.050000000 s\)$",
    ):
        measured_run_from_bag(_bag_with(tmp_path / "backwards", backwards, heights), topic_map)
    with pytest.raises(
        MeasuredDataError,
        match=r"^/pose pose\.position\.z: 1 values are not finite \(the first at 0\.100000 s\)$",
    ):
        measured_run_from_bag(
            _bag_with(tmp_path / "nan", times, heights[:99] + [math.nan] + heights[100:]), topic_map
        )
    run = measured_run_from_bag(_bag_with(tmp_path / "flight", times, heights), topic_map)
    with pytest.raises(NoStanceError, match="^no stance: the vertical ground force is never positive$"):
        find_strides(run)
    holed = times[:80] + times[90:]  # 10 ms lost: the samples in between are flagged, none else
    run = measured_run_from_bag(_bag_with(tmp_path / "gap", holed, heights[:80] + heights[90:]), topic_map)
    assert run.in_gap is not None
    assert np.array_equal(np.flatnonzero(run.in_gap), np.arange(80, 90))


def test_a_gap_sets_the_stride_aside(tmp_path: Path, recorded: dict[str, Path]) -> None:
    """Gazebo's odometry loses 40 ms in the middle of one stride: that stride is set aside, saying where,
    and the others stand."""
    run = measured_run_from_bag(recorded["gazebo"], topic_map_from_document(gazebo_map(), "gazebo"))
    strides = find_strides(run)
    middle = strides[4]
    t_gap = 0.5 * (middle.touchdown_time + middle.liftoff_time)
    in_gap = (run.time > t_gap - 0.02) & (run.time < t_gap + 0.02)
    found = find_strides(replace(run, in_gap=in_gap))
    assert [s.usable for s in found] == [k != 4 for k in range(len(strides))]
    assert found[4].reason.startswith("a gap in the recording from ")


# --- tdslip analyze --topic-map -------------------------------------------------------------------------


def hopper_file(path: Path) -> Path:
    h = KNOWN_HOPPER
    values = {"mass": h.m, "stiffness": h.k, "rest_length": h.r0, "damping": h.c, "gravity": h.g}
    path.write_text(yaml.safe_dump({"plant": {"ros__parameters": values}}))
    return path


def test_analyze_a_standard_bag_infers_the_commands_the_plant_was_given(
    tmp_path: Path, recorded: dict[str, Path], plant: PlantRun, capsys: pytest.CaptureFixture[str]
) -> None:
    """The report of the Gazebo-style bag: the commands inferred from its data are those the plant ran
    (angle 1e-5 rad; the least-squares ramp through the recorded torque to 1e-5 relative: the touchdown, known
    to 1e-6 s, shifts the ramp by tau0 / t_f times that, 8e-6 of tau0), and the exact map with
    the run's hopper predicts every next apex to 1e-5 (dimensionless: the apex read from 1 kHz samples)."""
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(GAZEBO_MAP))
    out = tmp_path / "report"
    argv = [str(recorded["gazebo"]), "--topic-map", str(tmp_path / "robot.yaml"), "--out", str(out)]
    assert analyze.main([*argv, "--params", str(hopper_file(tmp_path / "hopper.yaml"))]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["strides_compared"] == 9 and summary["measured"]["hip_torque"] == "/joint_states"
    given = plant.commands[1:10]  # the first apex is the run's start, not found in its data
    for row, command in zip(summary["strides"], given, strict=True):
        assert row["touchdown_angle_rad"] == pytest.approx(command.touchdown_angle, abs=1e-5)
        assert row["tau0_N_m"] == pytest.approx(command.tau0, rel=1e-5)
        assert row["t_f_s"] == pytest.approx(command.t_f, rel=1e-5)
    assert summary["errors"]["exact"]["max_error_ybar"] < 1e-5
    assert summary["errors"]["exact"]["max_error_xdotbar"] < 1e-5
    assert "inferred: ramp_torque, fitted to the measured hip torque" in (out / "report.md").read_text()
    # Without --params the hopper is the paper's, and the report says so.
    assert analyze.main([*argv[:3], "--out", str(tmp_path / "paper")]) == 0
    assert "Hopper: the paper's" in (tmp_path / "paper" / "report.md").read_text()
    assert "9 of 9 strides compared" in capsys.readouterr().out


def test_analyze_refuses_bad_input_with_one_line_and_writes_nothing(
    tmp_path: Path, recorded: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    def refused(bag: Path, document: object, status: int, expected: str) -> None:
        (tmp_path / "map.yaml").write_text(
            document if isinstance(document, str) else yaml.safe_dump(document)
        )
        out = tmp_path / "out"
        assert (
            analyze.main([str(bag), "--topic-map", str(tmp_path / "map.yaml"), "--out", str(out)]) == status
        )
        error = capsys.readouterr().err
        assert error.startswith("tdslip analyze: ") and expected in error and error.count("\n") == 1
        assert not out.exists()

    gazebo = recorded["gazebo"]
    refused(gazebo, "format: [", 2, "not a YAML file")
    refused(gazebo, gazebo_map({"hip_torque": {"unit": "lbf ft"}}), 2, "'lbf ft' is not one of 'N m', 'N mm'")
    refused(gazebo, gazebo_map({"hip_torque": {"type": "sensor_msgs/msg/Imu"}}), 2, "is not one of")
    refused(gazebo, gazebo_map({"body_forward": {"topic": "/mocap"}}), 2, "the recording has no topic /mocap")
    refused(gazebo, gazebo_map({"body_forward": {"field": "pose.pose.place"}}), 2, "has no field")
    refused(gazebo, gazebo_map({"hip_torque": {"joint": "knee"}}), 2, "has no joint 'knee'")
    simple = copy.deepcopy(SIMPLE_MAP)
    times = [0.001 * i for i in range(1, 200)]
    heights = [1.0 - 0.5 * G * t * t for t in times]
    backwards = times[:50] + [times[48]] + times[51:]
    refused(_bag_with(tmp_path / "backwards", backwards, heights), simple, 1, "stamps go backwards")
    nan = heights[:99] + [math.nan] + heights[100:]
    refused(_bag_with(tmp_path / "nan", times, nan), simple, 1, "values are not finite")
    refused(_bag_with(tmp_path / "flight", times, heights), simple, 1, "no stance")


def test_the_fast_topic_reader_reads_what_the_checked_iterator_reads(
    tmp_path: Path, recorded: dict[str, Path]
) -> None:
    """bag.reader.topic_messages (chunks walked with struct) against iter_messages (mcap's own reader), and
    a damaged chunk is one line, not a wrong column."""
    bag = open_bag(recorded["gazebo"])
    topics = {"/odom", "/joint_states"}
    fast = topic_messages(bag, topics)
    for topic in topics:
        slow = [(m.data, m.log_time) for c, m in iter_messages(bag, {topic})]
        assert list(zip(*fast[topic], strict=True)) == slow and len(slow) > 500
    damaged = tmp_path / "damaged.mcap"
    content = bytearray(bag.mcap_path.read_bytes())
    with open(bag.mcap_path, "rb") as stream:
        summary = SeekingReader(stream).get_summary()
    assert summary is not None
    chunk = summary.chunk_indexes[len(summary.chunk_indexes) // 2]
    content[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0xFF  # inside its compressed records
    damaged.write_bytes(bytes(content))
    with pytest.raises(BagReadError, match=r"the chunk at byte \d+ is corrupt"):
        topic_messages(open_bag(damaged), topics)


def test_without_force_stance_comes_from_the_contact_flag_or_the_leg_length(
    recorded: dict[str, Path],
) -> None:
    """The suite's run again, its force withheld: stance from its phase mapped as the contact, then from the
    leg length against r0. The apexes and the touchdowns (placed by the geometry either way) stay those found
    from the force; liftoff moves within a sample (the flag changes between two samples) or, from the leg
    length, later by the time the leg takes to return within LEG_OFF of r0 after its force vanished
    (observed 1.5-2.5 ms; the bound 5 ms)."""
    run = measured_run_from_bag(recorded["suite"], suite_topic_map())
    assert run.leg_length is not None and run.ground_force is not None
    by_force = find_strides(run)
    document = yaml.safe_load(Path(suite_topic_map().origin).read_text())
    del document["quantities"]["ground_force_forward"], document["quantities"]["ground_force_vertical"]
    document["quantities"]["contact"] = {
        "topic": "/tdslip/state",
        "type": "tdslip_msgs/msg/HopperState",
        "field": "phase",
        "unit": "1",
    }
    flag = measured_run_from_bag(recorded["suite"], topic_map_from_document(document, "phase as contact"))
    assert flag.contact is not None and dict(flag.sources)["contact"] == "/tdslip/state"
    by_length = replace(run, ground_force=None)
    with pytest.raises(NoStanceError, match="no rest length was given"):
        find_strides(by_length)
    for strides, liftoff in (
        (find_strides(flag), (-1e-3, 1e-3)),
        (find_strides(by_length, KNOWN_HOPPER.r0), (0, 5e-3)),
    ):
        assert len(strides) == len(by_force) and all(s.usable for s in strides)
        for found, truth in zip(strides, by_force, strict=True):
            assert found.apex_time == truth.apex_time and found.next_apex_time == truth.next_apex_time
            assert found.touchdown_time == pytest.approx(truth.touchdown_time, abs=1e-9)
            assert found.touchdown_angle == pytest.approx(truth.touchdown_angle, abs=1e-9)
            assert liftoff[0] <= found.liftoff_time - truth.liftoff_time < liftoff[1]


def test_the_hysteresis_keeps_a_noisy_force_from_chattering(recorded: dict[str, Path]) -> None:
    """The suite's run with Gaussian noise of 1 % of the peak on the force (seeded): the same strides, all
    usable, touchdowns unmoved (placed by the geometry) and liftoffs within 2 ms. The entering level sits
    five standard deviations above the flight's noise; one level low enough to find liftoff (FORCE_OFF)
    would see stances in the flight's noise."""
    run = measured_run_from_bag(recorded["suite"], suite_topic_map())
    assert run.ground_force is not None
    clean = find_strides(run)
    peak = float(np.max(run.ground_force[:, 1]))
    noise = np.random.default_rng(7).normal(0.0, 0.01 * peak, run.ground_force.shape)
    noisy = find_strides(replace(run, ground_force=run.ground_force + noise))
    assert len(noisy) == len(clean) and all(s.usable for s in noisy)
    for found, truth in zip(noisy, clean, strict=True):
        assert found.touchdown_time == pytest.approx(truth.touchdown_time, abs=1e-9)
        assert found.liftoff_time == pytest.approx(truth.liftoff_time, abs=2e-3)


def test_log_time_stamps_and_a_foot_switch(recorded: dict[str, Path]) -> None:
    """The Gazebo-style bag stamped by the recorder's log time (0.2 ms after the header stamp there), its
    force plate replaced by the headerless foot switch: every apex and touchdown comes 0.2 ms later than by
    the header stamps (1e-9 s and 1e-6 s, as against the suite's topics), liftoff within a sample of it."""
    by_header = find_strides(
        measured_run_from_bag(recorded["gazebo"], topic_map_from_document(gazebo_map(), "gazebo"))
    )
    document = gazebo_map({name: {"stamp": "log"} for name in GAZEBO_MAP["quantities"]})  # type: ignore[attr-defined]
    del document["quantities"]["ground_force_forward"], document["quantities"]["ground_force_vertical"]  # type: ignore[attr-defined]
    document["quantities"]["contact"] = {  # type: ignore[index]
        "topic": "/foot_contact",
        "type": "std_msgs/msg/Bool",
        "field": "data",
        "unit": "1",
        "stamp": "log",
    }
    run = measured_run_from_bag(recorded["gazebo"], topic_map_from_document(document, "log stamps"))
    by_log = find_strides(run)
    assert dict(run.sources)["contact"] == "/foot_contact" and len(by_log) == len(by_header)
    for found, truth in zip(by_log, by_header, strict=True):
        assert found.usable and found.apex_time == pytest.approx(truth.apex_time + 2e-4, abs=1e-9)
        assert found.touchdown_time == pytest.approx(truth.touchdown_time + 2e-4, abs=1e-6)
        assert found.liftoff_time - 2e-4 == pytest.approx(truth.liftoff_time, abs=1e-3)
