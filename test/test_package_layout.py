"""The installed ROS 2 layout: what ``ros2 run`` and ``ros2 interface`` look up, after our pip-based
set-up (the venv is the ament prefix) and after a ``colcon build`` with the venv as underlay.

There is no ros2cli in the venv, so ros2run's lookup is re-implemented here as it is written:
``get_package_prefix(package)``, then the executable files under ``<prefix>/lib/<package>/``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from importlib.metadata import distribution
from pathlib import Path
from typing import Any

import pytest
from ament_index_python.packages import get_package_share_directory
from ament_index_python.resources import get_resource
from support.colcon_workspace import ColconBuild

from tdslip_ros.nodes import isolation

PACKAGE = "tdslip_ros"
EXECUTABLES = {
    "tdslip": "tdslip_ros.commands.cli:main",
    "plant_node": "tdslip_ros.nodes.plant_node:main",
    "controller_node": "tdslip_ros.nodes.controller_node:main",
    "recorder_node": "tdslip_ros.nodes.recorder_node:main",
    "stance_controller_node": "tdslip_ros.nodes.stance_controller_node:main",
    "lifecycle_manager": "tdslip_ros.nodes.lifecycle_manager:main",
}
INTERFACES = [
    "msg/HopperState.msg",
    "msg/ApexEvent.msg",
    "msg/StanceCommand.msg",
    "msg/ContactEvent.msg",
    "msg/Status.msg",
    "msg/RecorderStatus.msg",
    "msg/HipTorque.msg",
    "srv/Reset.srv",
]

# Runs in a child process (possibly in a colcon-sourced shell): the ros2run-style lookup, then
# `ros2 run tdslip_ros tdslip --help` the way ros2run starts it; reported as JSON.
LOOKUP_SCRIPT = textwrap.dedent(
    """
    import json, os, subprocess, sys
    from ament_index_python.packages import get_package_prefix

    def ros2run_executables(package):
        # ros2run.api.get_executable_paths: executable files below <prefix>/lib/<package>
        base = os.path.join(get_package_prefix(package), "lib", package)
        found = {}
        for dirpath, dirnames, filenames in os.walk(base):
            dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
            for filename in sorted(filenames):
                path = os.path.join(dirpath, filename)
                if os.access(path, os.X_OK):
                    found[filename] = path
        return found

    import tdslip_msgs.msg
    executables = ros2run_executables("tdslip_ros")
    help_run = subprocess.run([executables["tdslip"], "--help"], capture_output=True, text=True)
    json.dump({
        "tdslip_ros_prefix": get_package_prefix("tdslip_ros"),
        "tdslip_msgs_prefix": get_package_prefix("tdslip_msgs"),
        "tdslip_msgs_module": tdslip_msgs.msg.__file__,
        "executables": executables,
        "tdslip_help": [help_run.returncode, help_run.stdout + help_run.stderr],
    }, sys.stdout)
    """
)


def ros2run_lookup(environment: dict[str, str], shell_prefix: str = "") -> dict[str, Any]:
    """The lookup as a fresh process sees it, optionally after shell commands (e.g. sourcing)."""
    command = f'{shell_prefix}exec "{sys.executable}" -c "$LOOKUP_SCRIPT"'
    result = subprocess.run(
        ["bash", "-c", command],
        env={**environment, "LOOKUP_SCRIPT": LOOKUP_SCRIPT},
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    lookup: dict[str, Any] = json.loads(result.stdout)
    return lookup


def check_ros2run_layout(lookup: dict[str, Any], prefix: Path) -> None:
    """tdslip_ros resolves to `prefix`, every console script is a ros2run executable there, and the
    launcher really runs the console script (checked end to end with `tdslip --help`)."""
    assert Path(lookup["tdslip_ros_prefix"]) == prefix
    assert lookup["executables"] == {name: str(prefix / "lib" / PACKAGE / name) for name in EXECUTABLES}
    returncode, output = lookup["tdslip_help"]
    assert returncode == 0, output
    assert "simulate" in output


@pytest.mark.usefixtures("ament_index")
def test_pip_layout_is_found_like_ros2run() -> None:
    lookup = ros2run_lookup(dict(os.environ))
    check_ros2run_layout(lookup, Path(sys.prefix))
    assert Path(lookup["tdslip_msgs_prefix"]) == Path(sys.prefix)


def test_console_scripts_are_the_node_entry_points() -> None:
    scripts = {
        ep.name: ep.value for ep in distribution(PACKAGE).entry_points if ep.group == "console_scripts"
    }
    assert scripts == EXECUTABLES


@pytest.mark.parametrize("arguments", [[], ["--flag", "two words", "*", "$HOME"]])
def test_launcher_execs_its_console_script_with_the_arguments(tmp_path: Path, arguments: list[str]) -> None:
    """Each ros2run launcher, moved to another prefix, runs `<that prefix>/bin/<name>` with the
    arguments unchanged (a stand-in console script records them)."""
    installed_lib = Path(sys.prefix) / "lib" / PACKAGE
    (tmp_path / "bin").mkdir()
    (tmp_path / "lib" / PACKAGE).mkdir(parents=True)
    for name in EXECUTABLES:
        stand_in = tmp_path / "bin" / name
        stand_in.write_text(f'#!/bin/sh\nprintf "%s\\n" {name} "$@"\n')
        stand_in.chmod(0o755)
        launcher = tmp_path / "lib" / PACKAGE / name
        launcher.write_bytes((installed_lib / name).read_bytes())
        launcher.chmod(0o755)
        result = subprocess.run(
            [launcher, *arguments], capture_output=True, text=True, timeout=30, check=True
        )
        assert result.stdout.splitlines() == [name, *arguments]


@pytest.mark.usefixtures("ament_index")
def test_installed_manifest_parameter_and_launch_files_are_the_work_tree_ones(repo_root: Path) -> None:
    share = Path(get_package_share_directory(PACKAGE))
    assert ET.parse(share / "package.xml").findtext("name") == PACKAGE
    assert (share / "package.xml").read_text() == (repo_root / "package.xml").read_text()
    for folder, pattern in (("config", "*.yaml"), ("launch", "*.launch.py")):  # where ros2 launch looks
        work_tree = {path.name: path.read_text() for path in (repo_root / folder).glob(pattern)}
        installed = {path.name: path.read_text() for path in (share / folder).glob(pattern)}
        assert installed == work_tree, folder


@pytest.mark.usefixtures("ament_index")
def test_tdslip_msgs_is_an_installed_interface_package() -> None:
    content, prefix = get_resource("rosidl_interfaces", "tdslip_msgs")
    assert Path(prefix) == Path(sys.prefix)
    listed = set(content.split())
    share = Path(get_package_share_directory("tdslip_msgs"))
    for interface in INTERFACES:
        assert interface in listed
        # The definition text and the type description (with its RIHS01 hash) that rosbag2 records.
        assert (share / interface).is_file()
        description = json.loads((share / interface).with_suffix(".json").read_text())
        own_hash = description["type_hashes"][0]
        assert own_hash["type_name"] == f"tdslip_msgs/{interface.rsplit('.', 1)[0]}"
        assert own_hash["hash_string"].startswith("RIHS01_")
    import tdslip_msgs.msg

    assert Path(tdslip_msgs.msg.__file__).is_relative_to(sys.prefix)


@pytest.mark.nodes
def test_the_readmes_colcon_command_builds_both_packages_and_plant_node_runs_from_the_install(
    readme_colcon_build: ColconBuild,
) -> None:
    """A plain workspace (this repository cloned as src/tdslip_ros) built with the README's command,
    the venv as underlay (as an activated venv presents it): after `source install/local_setup.bash`
    both packages come from the overlay, and `ros2 run tdslip_ros plant_node` hops. (The build started
    in the background when collection ended: support/colcon_workspace.py.)"""
    build = readme_colcon_build.wait()
    assert build.returncode == 0, build.stdout + build.stderr
    assert "Summary: 2 packages finished" in build.stdout, build.stdout
    environment = readme_colcon_build.environment
    install = readme_colcon_build.workspace / "install"

    sourced = f'source "{install}/local_setup.bash" && '
    lookup = ros2run_lookup(environment, sourced)
    check_ros2run_layout(lookup, install / PACKAGE)
    assert Path(lookup["tdslip_msgs_prefix"]) == install / "tdslip_msgs"
    assert Path(lookup["tdslip_msgs_module"]).is_relative_to(install / "tdslip_msgs")

    # ros2run execs the executable it found with the user's arguments: a short lockstep hop with the
    # installed controller, on a private domain.
    executables = lookup["executables"]
    with isolation.reserved_domain() as domain_id:
        hop = {**isolation.isolated_environment(domain_id, environment)}
        controller = subprocess.Popen(
            ["bash", "-c", f'{sourced}exec "{executables["controller_node"]}"'],
            env=hop,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            plant = subprocess.run(
                # command_timeout: on a loaded machine sourcing the overlay takes the controller seconds.
                [
                    "bash",
                    "-c",
                    f'{sourced}exec "{executables["plant_node"]}" --ros-args -p max_strides:=2 '
                    "-p command_timeout:=60.0",
                ],
                env=hop,
                capture_output=True,
                text=True,
                timeout=120,
                check=False,
            )
        finally:
            controller.send_signal(signal.SIGINT)
            controller.wait(30)
    assert plant.returncode == 0, plant.stderr
    assert "run complete at stride 2" in plant.stderr
