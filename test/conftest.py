"""Shared fixtures of the test suite, and its two tiers.

Every test that starts a node process or a ROS context (rclpy.init, the ``ros`` graph, a recorded run,
``tdslip run``/``replay``/``compare``, a node executable, colcon) carries the marker ``nodes``; the rest
is the fast tier, ``pytest -m "not nodes" -n 2`` (pytest-xdist, --dist loadgroup in pyproject.toml; the
full suite runs in one process, where the recorded runs below are made once). Tests using a fixture of
:data:`NODE_FIXTURES` are marked here; modules and tests that start nodes by themselves are marked where
they are written. A guard (:func:`node_guard`) fails any test without the marker that inits an rclpy
context or spawns a node process, in both tiers, so that the marker stays exact.

The fast tier runs first. Meanwhile a background child (support/analysis_runs.py: Background) makes the
node runs the selected tests will use (recorded runs, tdslip compare, some tdslip run processes), and the
README's colcon build (support/colcon_workspace.py) compiles at the lowest CPU priority: on a 2-core machine
most fast tests leave one core idle. The tests that use them wait for them.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from support.colcon_workspace import ColconBuild
    from support.ros_harness import RosGraph

    from tdslip_ros.nodes.runner import RunReport

REPO_ROOT = Path(__file__).resolve().parents[1]

IN_XDIST_WORKER = "PYTEST_XDIST_WORKER" in os.environ
"""Whether this process is a worker of pytest-xdist (the fast tier's ``-n 2``)."""
RECORDED_RUNS = (
    "energy",
    "fall",
    "energy_exact",
    "deadbeat",
    "rough",
    "wall",
    "energy_again",
    "stance_pd",
    "posture",
)
"""Session fixtures, one per run of analysis_runs.RUNS and AGAIN: its RunReport, recorded by the node suite
once per test process (by the background child, or here on first use)."""
NODE_FIXTURES = frozenset({"ros", "readme_colcon_build", "compare_sweep", *RECORDED_RUNS})
"""Fixtures that start nodes: every test using one (directly or through another fixture) is ``nodes``."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark the tests that use a node fixture, and run the fast tier first: the recorded runs and the
    colcon build (below) are made in the background meanwhile, on the core the fast tests leave idle."""
    for item in items:
        if NODE_FIXTURES.intersection(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.nodes)
        if "dask_scheduler" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.xdist_group("dask"))  # one cluster, not one per worker
    # Stable, so file order is kept within each part. Tests in an xdist group share a costly fixture (a
    # figure's document, the Dask cluster): the fast tier's workers take those first, the longest work
    # first. In one process they keep their place: the background child draws the documents meanwhile.
    items.sort(
        key=lambda item: (
            item.get_closest_marker("nodes") is not None,
            IN_XDIST_WORKER and item.get_closest_marker("xdist_group") is None,
        )
    )


_colcon_build: ColconBuild | None = None


def pytest_collection_finish(session: pytest.Session) -> None:
    """Start in the background what the selected tests will need: the figure documents they read and the
    recorded runs they use, in the order they use them (support/analysis_runs.py: Background), and the
    README's colcon build (support/colcon_workspace.py)."""
    global _colcon_build
    if session.config.option.collectonly:
        return
    used = [name for item in session.items for name in getattr(item, "fixturenames", ())]
    runs = tuple(dict.fromkeys(name for name in used if name in RECORDED_RUNS))
    # The session's tmp_path_factory (pytest's tmpdir plugin keeps it there; fixtures are not up yet).
    factory: pytest.TempPathFactory = session.config._tmp_path_factory  # type: ignore[attr-defined]
    # The compare_sweep fixture's tdslip compare (test_analysis_controller_comparison.py, the second node
    # module), then a module's IN_BACKGROUND: tdslip run processes of its tests, by test name
    # (test_nodes_run.py, late in the node tier).
    compare = {"tdslip_compare": (compare_sweep_arguments(), "compare")} if "compare_sweep" in used else {}
    commands = compare | {
        f"tdslip_run_{index}": (["run", *arguments], relative)
        for index, (arguments, relative) in enumerate(
            getattr(item.module, "IN_BACKGROUND", {})[item.name]
            for item in session.items
            if isinstance(item, pytest.Function) and item.name in getattr(item.module, "IN_BACKGROUND", {})
        )
    }
    # A module's draw(name) of the figure document its tests in xdist group ``name`` read
    # (test_claims_paper.py), drawn by the child on the core the fast tests leave idle: not under xdist,
    # whose two workers keep both cores busy.
    drawings = list(
        dict.fromkeys(
            (item.module.__name__, marker.args[0])
            for item in session.items
            if isinstance(item, pytest.Function) and hasattr(item.module, "draw") and not IN_XDIST_WORKER
            for marker in item.iter_markers("xdist_group")
        )
    )
    if runs or commands or drawings:
        from support import analysis_runs

        analysis_runs.BACKGROUND = analysis_runs.Background.start(
            factory.getbasetemp() / "analysis_runs", runs, commands, drawings
        )
    if "readme_colcon_build" in used:
        from support.colcon_workspace import ColconBuild

        _colcon_build = ColconBuild.start(REPO_ROOT)


def pytest_sessionfinish(session: pytest.Session) -> None:
    if _colcon_build is not None:
        _colcon_build.remove()
    runs = sys.modules.get("support.analysis_runs")
    if runs is not None and runs.BACKGROUND is not None:
        runs.BACKGROUND.stop()


def compare_sweep_arguments() -> list[str]:
    """``tdslip compare`` on test_analysis_controller_comparison's speeds and strides (without --out)."""
    from test_analysis_controller_comparison import SPEEDS, STRIDES

    return ["compare", "--speeds-bar", *(str(speed) for speed in SPEEDS), "--strides", str(STRIDES)]


@pytest.fixture(scope="session")
def compare_sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The output directory of :func:`compare_sweep_arguments`; it exited with status 0. Made by the
    background child after its runs (lockstep, while the fast tests run), else here."""
    out = tmp_path_factory.getbasetemp() / "compare"
    background = getattr(sys.modules.get("support.analysis_runs"), "BACKGROUND", None)
    ran = None if background is None else background.command(compare_sweep_arguments(), out)
    if ran is not None:
        assert ran.returncode == 0, ran.stdout[-2000:] + ran.stderr[-2000:]
        return out
    from tdslip_ros.commands import cli

    assert cli.main([*compare_sweep_arguments(), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="session")
def readme_colcon_build() -> ColconBuild:
    """The README's colcon build, started as collection ended (support/colcon_workspace.py): running or
    finished."""
    global _colcon_build
    if _colcon_build is None:  # requested by a test collection did not see
        from support.colcon_workspace import ColconBuild

        _colcon_build = ColconBuild.start(REPO_ROOT)
    return _colcon_build


@pytest.fixture(scope="session")
def dask_scheduler() -> Iterator[str]:
    """The address of one local Dask cluster of 2 worker processes, started as the study engine starts one
    (``engine.connect``) and shared by the tests that run studies on a cluster: each cluster's start, its
    workers importing the model's kernels, takes seconds. The commands reach it with ``--scheduler``."""
    from tdslip_ros.studies import engine

    with engine.connect(engine.Where(workers=2)) as client:
        yield str(client.scheduler.address)


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
    from support.ros_harness import ros_graph

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


def _recorded(name: str, tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    from support.analysis_runs import recorded_run

    return recorded_run(name, tmp_path_factory)


@pytest.fixture(scope="session")
def energy(tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """Energy regulation from the default apex, 12 strides (analysis_runs.RUNS)."""
    return _recorded("energy", tmp_path_factory)


@pytest.fixture(scope="session")
def fall(tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """Deadbeat into a fall the analytic map did not foresee (analysis_runs.RUNS)."""
    return _recorded("fall", tmp_path_factory)


@pytest.fixture(scope="session")
def energy_exact(tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """The ideal regulator holding the initial apex energy, 6 strides (analysis_runs.RUNS)."""
    return _recorded("energy_exact", tmp_path_factory)


@pytest.fixture(scope="session")
def deadbeat(tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """Deadbeat to 4 m/s, 4 strides (analysis_runs.RUNS)."""
    return _recorded("deadbeat", tmp_path_factory)


@pytest.fixture(scope="session")
def energy_again(tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """A second run with energy's options, recorded once as it comes (analysis_runs.AGAIN)."""
    return _recorded("energy_again", tmp_path_factory)


@pytest.fixture(scope="session")
def rough(tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """Every perturbation at once, 12 strides (analysis_runs.RUNS)."""
    return _recorded("rough", tmp_path_factory)


@pytest.fixture(scope="session")
def wall(tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """A 30 cm wall 8 m ahead that the toe cannot clear (analysis_runs.RUNS)."""
    # Recorded outside the tests that use it: rclpy's EventsExecutor enables faulthandler, which needs a
    # real stderr (capsys replaces it).
    return _recorded("wall", tmp_path_factory)


@pytest.fixture(scope="session")
def posture(tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """A rigid body balanced by the posture policy, 8 strides (analysis_runs.RUNS)."""
    return _recorded("posture", tmp_path_factory)


@pytest.fixture(scope="session")
def stance_pd(tmp_path_factory: pytest.TempPathFactory) -> RunReport:
    """The baseline of ref. 36 streaming hip torques at 1 kHz, 8 strides (analysis_runs.RUNS)."""
    return _recorded("stance_pd", tmp_path_factory)


# --- the guard of the fast tier -----------------------------------------------------------------

NODE_EXECUTABLES = ("plant_node", "controller_node", "stance_controller_node", "recorder_node")
NODE_SUBCOMMANDS = ("run", "replay", "compare")
"""``tdslip`` sub-commands that start nodes (``compare`` records runs)."""
_STARTS_ROS = re.compile(
    r"rclpy\.init\b|\bros_graph\(|\bChildNode\.start\(|\bRunOptions\(|\b(runner|replay)\.main\("
)
"""What starts a ROS context or nodes in the code of a Python child process (``-c`` or a script)."""


def _python_code(arguments: Sequence[str]) -> str | None:
    """The code a ``python ...`` command line runs: the ``-c`` text, the script's text, or ``-m module``
    (as the module's name); None if it is none of these."""
    for index, argument in enumerate(arguments):
        if argument == "-c" and index + 1 < len(arguments):
            return arguments[index + 1]
        if argument == "-m" and index + 1 < len(arguments):
            return "-m " + " ".join(arguments[index + 1 :])
        if argument.startswith("-"):
            continue
        try:
            return Path(argument).read_text(errors="replace")
        except OSError:
            return None
    return None


def node_process(arguments: Sequence[str]) -> str | None:
    """Why the command line ``arguments`` starts a node or a ROS context, or None if it does not."""
    if not arguments:
        return None
    program = Path(arguments[0])
    name = program.name
    if name in ("bash", "sh") and "-c" in arguments[1:-1]:
        return _shell_starts_nodes(arguments[arguments.index("-c") + 1])
    if name in NODE_EXECUTABLES and (program.parent == Path() or program.parent in _installed_bins()):
        return f"runs the node executable {name}"
    if name in ("colcon", "ros2"):
        return f"runs {name}"
    if name == "tdslip" and len(arguments) > 1 and arguments[1] in NODE_SUBCOMMANDS:
        return f"runs tdslip {arguments[1]}"
    if name.startswith("python"):
        code = _python_code(arguments[1:])
        if code is None:
            return None
        module, subcommand = (code.split()[1:3] + ["", ""])[:2] if code.startswith("-m ") else ("", "")
        if module in ("tdslip_ros.cli", "tdslip_ros.commands.cli") and subcommand in NODE_SUBCOMMANDS:
            return f"runs tdslip {subcommand}"
        if module.startswith("tdslip_ros.nodes.") or module in [
            f"tdslip_ros.commands.{s}" for s in NODE_SUBCOMMANDS
        ]:
            return f"runs python -m {module}"
        if not code.startswith("-m ") and _STARTS_ROS.search(code):
            return f"runs Python code that starts ROS ({_STARTS_ROS.search(code).group(0)})"  # type: ignore[union-attr]
    return None


def _shell_starts_nodes(script: str) -> str | None:
    words = re.findall(r"[\w./-]+", script)
    for word in words:
        if Path(word).name in (*NODE_EXECUTABLES, "colcon", "ros2"):
            return f"runs {Path(word).name} from a shell"
    return None


def _installed_bins() -> tuple[Path, ...]:
    return (Path(sys.prefix) / "bin", Path(sys.prefix) / "lib" / "tdslip_ros")


class NodeGuard:
    """What a test without the ``nodes`` marker tried that only the nodes tier may do."""

    def __init__(self) -> None:
        self.violations: list[str] = []

    def refuse(self, what: str) -> None:
        self.violations.append(what)
        pytest.fail(f"{what}: only a test marked 'nodes' may start nodes or a ROS context", pytrace=False)


@pytest.fixture(autouse=True)
def node_guard(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> Iterator[NodeGuard]:
    """Outside the ``nodes`` tier: rclpy contexts cannot be initialised and node processes cannot be
    spawned (the test fails, even if it catches the failure)."""
    guard = NodeGuard()
    if request.node.get_closest_marker("nodes") is not None:
        yield guard
        return
    from rclpy.context import Context

    def refused_init(self: Context, *args: Any, **kwargs: Any) -> None:
        guard.refuse("rclpy context initialised")

    popen_init = subprocess.Popen.__init__

    def checked_popen(self: subprocess.Popen[Any], args: Any, *rest: Any, **kwargs: Any) -> None:
        arguments = [args] if isinstance(args, str | bytes | os.PathLike) else list(args)
        if kwargs.get("shell") and len(arguments) == 1:
            arguments = ["sh", "-c", os.fsdecode(arguments[0])]
        reason = node_process([os.fsdecode(a) for a in arguments])
        if reason is not None:
            guard.refuse(f"{reason} ({shlex.join(os.fsdecode(a) for a in arguments)[:200]})")
        popen_init(self, args, *rest, **kwargs)

    monkeypatch.setattr(Context, "init", refused_init)
    monkeypatch.setattr(subprocess.Popen, "__init__", checked_popen)
    yield guard
    if guard.violations:
        pytest.fail("; ".join(guard.violations) + ": only a test marked 'nodes' may do that", pytrace=False)
