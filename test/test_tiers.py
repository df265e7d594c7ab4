"""The two tiers of the suite (test/conftest.py): the ``nodes`` marker and the guard that keeps it exact."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import NODE_FIXTURES, RECORDED_RUNS, NodeGuard, node_process
from rclpy.context import Context
from support.analysis_runs import AGAIN, RUNS

PYTHON = sys.executable


def test_every_recorded_run_is_a_session_fixture_that_starts_nodes() -> None:
    assert set(RECORDED_RUNS) == set(RUNS) | set(AGAIN)
    assert {"ros", *RUNS, *AGAIN} <= NODE_FIXTURES


@pytest.mark.parametrize(
    "command",
    [
        [PYTHON, "-m", "tdslip_ros.commands.cli", "run", "--strides", "3"],
        [PYTHON, "-m", "tdslip_ros.commands.cli", "replay", "bag"],
        [PYTHON, "-m", "tdslip_ros.commands.cli", "compare", "--out", "x"],
        [PYTHON, "-m", "tdslip_ros.commands.cli", "run", "--strides", "3"],  # the commands layer
        [PYTHON, "-m", "tdslip_ros.commands.replay", "bag"],
        [PYTHON, "-m", "tdslip_ros.nodes.plant_node", "--ros-args"],
        [PYTHON, "-c", "import rclpy; rclpy.init()"],
        ["tdslip", "run"],
        ["plant_node"],
        [f"{sys.prefix}/lib/tdslip_ros/recorder_node", "--ros-args"],
        ["colcon", "build"],
        ["bash", "-c", 'source install/local_setup.bash && exec "install/lib/tdslip_ros/plant_node"'],
    ],
)
def test_the_guard_knows_a_command_that_starts_nodes(command: list[str]) -> None:
    assert node_process(command) is not None


@pytest.mark.parametrize(
    "command",
    [
        [PYTHON, "-m", "tdslip_ros.commands.cli", "analyze", "bag"],
        [PYTHON, "-m", "tdslip_ros.commands.cli", "simulate", "--strides", "3"],
        [PYTHON, "-m", "tdslip_ros.commands.cli", "figures", "--out", "x"],
        [PYTHON, "-c", "import tdslip_ros.nodes.replay, sys; print('rclpy' in sys.modules)"],
        [PYTHON, "-m", "ruff", "check", "."],
        ["/tmp/stand-in/lib/tdslip_ros/plant_node", "--flag"],  # a launcher moved to another prefix
        ["dask", "scheduler"],
    ],
)
def test_the_guard_lets_other_commands_run(command: list[str]) -> None:
    assert node_process(command) is None


def test_outside_the_nodes_tier_no_rclpy_context_is_initialised(node_guard: NodeGuard) -> None:
    with pytest.raises(pytest.fail.Exception, match="rclpy context initialised"):
        Context().init()
    assert node_guard.violations
    node_guard.violations.clear()  # this test's own, expected


def test_outside_the_nodes_tier_no_node_process_starts(node_guard: NodeGuard) -> None:
    with pytest.raises(pytest.fail.Exception, match="tdslip run"):
        subprocess.run([PYTHON, "-m", "tdslip_ros.commands.cli", "run", "--help"], check=False)
    assert node_guard.violations
    node_guard.violations.clear()


@pytest.mark.nodes
def test_in_the_nodes_tier_the_guard_stands_aside(node_guard: NodeGuard) -> None:
    context = Context()
    context.init(domain_id=0)
    context.try_shutdown()
    assert not node_guard.violations
