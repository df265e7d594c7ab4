"""``ros2 launch tdslip_ros hop.launch.py`` with the real launch: the README's launch line ends by itself
with exit status 0 and a bag that ``tdslip analyze`` reads; a node that fails makes the launch fail; two
launches in two namespaces on one domain are two hoppers.

Skipped with one line where ../shared/ros2-tools is absent (support/ros2_tools.py). About 60 s.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from support.ros2_processes import bag_messages, readme_command, ros2_processes
from support.ros2_tools import ros2_command

from tdslip_ros.interfaces import resolve
from tdslip_ros.nodes import isolation, topics

pytestmark = pytest.mark.nodes

LAUNCH = "ros2 launch tdslip_ros hop.launch.py strides:=20 output:=runs/launched"
README_STRIDES = 20  # as LAUNCH says
RUN_THERE = (LAUNCH,)
LAUNCH_TIMEOUT = 90.0  # s; a 20-stride lockstep launch takes about 20 s on the 2-core VM


def test_readme_launch_ends_by_itself_with_status_0_and_a_bag_tdslip_analyze_reads(tmp_path: Path) -> None:
    bag = tmp_path / "runs" / "launched"
    with isolation.reserved_domain() as domain_id, ros2_processes(domain_id, tmp_path) as processes:
        status = processes.run("launch", readme_command(LAUNCH), LAUNCH_TIMEOUT)  # runs/launched: in tmp_path
        assert status == 0, processes.output("launch")
    tdslip = shutil.which("tdslip", path=str(Path(sys.executable).parent))
    assert tdslip is not None
    analysis = subprocess.run([tdslip, "analyze", str(bag)], capture_output=True, text=True, timeout=120)
    assert analysis.returncode == 0, analysis.stderr
    run = json.loads((bag / "report" / "summary.json").read_text())["run"]
    assert run["outcome"]["kind"] == "run_complete" and run["outcome"]["stride"] == README_STRIDES
    assert run["apexes_recorded"] == README_STRIDES + 1


def test_a_failed_run_fails_the_launch_with_the_bag_finalised(tmp_path: Path) -> None:
    """controller:=none and nobody answers: the plant's run fails at its first apex (exit status 1)."""
    params_file = tmp_path / "impatient.yaml"
    params_file.write_text("/**:\n  ros__parameters:\n    command_timeout: 1.0\n")
    bag = tmp_path / "failed"
    launch = [
        str(ros2_command()),
        "launch",
        "tdslip_ros",
        "hop.launch.py",
        "controller:=none",
        f"params_file:={params_file}",
        f"output:={bag}",
    ]
    with isolation.reserved_domain() as domain_id, ros2_processes(domain_id, tmp_path) as processes:
        status = processes.run("launch", launch, LAUNCH_TIMEOUT)
        assert status == 1, processes.output("launch")
        assert "plant_node-2 failed (exit status 1)" in processes.output("launch")
    statuses = [status for _, status in bag_messages(bag)[resolve(topics.STATUS)]]
    assert [status.kind for status in statuses] == ["command_timeout"]


def test_two_launches_in_two_namespaces_on_one_domain_are_two_hoppers(tmp_path: Path) -> None:
    strides = {"h1": 4, "/h2": 7}  # namespaces as a user may write them
    ros2 = str(ros2_command())
    with isolation.reserved_domain() as domain_id, ros2_processes(domain_id, tmp_path) as processes:
        launches = {
            namespace: processes.start(
                f"launch{count}",
                [ros2, "launch", "tdslip_ros", "hop.launch.py", f"namespace:={namespace}", f"strides:={n}"]
                + [f"output:={tmp_path / namespace.strip('/')}"],
            )
            for count, (namespace, n) in enumerate(strides.items())
        }
        for count, launch in enumerate(launches.values()):
            assert launch.wait(LAUNCH_TIMEOUT) == 0, processes.output(f"launch{count}")
    for namespace, n in strides.items():
        messages = bag_messages(tmp_path / namespace.strip("/"))
        assert all(topic.startswith(f"/{namespace.strip('/')}/") for topic in messages), sorted(messages)
        apexes = [apex.stride for _, apex in messages[resolve(topics.APEX, namespace)]]
        assert apexes == list(range(n + 1))
