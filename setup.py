"""Build of the ament_python package tdslip_ros (static metadata in setup.cfg).

Installs the Python package, the console scripts, and the ROS 2 layout: the ament index marker,
package.xml, the node parameter files, the launch files, the hopper's URDF and one launcher per console
script where
``ros2 run`` looks.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

from setuptools import Distribution, find_packages, setup

# isort: split
# distutils only after setuptools: it is then setuptools' copy (the stdlib has none from Python 3.12).
from distutils.command.install_data import install_data

PACKAGE = "tdslip_ros"
HERE = Path(__file__).resolve().parent

CONSOLE_SCRIPTS = {
    "tdslip": "tdslip_ros.commands.cli:main",
    "plant_node": "tdslip_ros.nodes.plant_node:main",
    "controller_node": "tdslip_ros.nodes.controller_node:main",
    "stance_controller_node": "tdslip_ros.nodes.stance_controller_node:main",
    "recorder_node": "tdslip_ros.nodes.recorder_node:main",
    "lifecycle_manager": "tdslip_ros.nodes.lifecycle_manager:main",
}


class InstallDataWithRos2RunLaunchers(install_data):
    """install_data that also writes ``<prefix>/lib/tdslip_ros/<script>`` for every console script.

    ros2run finds executables only in ``<prefix>/lib/<package>/``, while console scripts land in
    ``<prefix>/bin``; pip ignores setup.cfg's ``[install] install_scripts``, so instead of moving the
    scripts each one gets a two-line launcher that execs its sibling ``../../bin/<script>``. Both pip
    (wheel and editable) and colcon run install_data, so one mechanism serves both layouts.
    """

    def run(self) -> None:
        super().run()
        launcher_dir = Path(self.install_dir) / "lib" / PACKAGE
        self.mkpath(str(launcher_dir))
        for script in CONSOLE_SCRIPTS:
            launcher = launcher_dir / script
            if not self.dry_run:
                launcher.write_text(f'#!/bin/sh\nexec "$(dirname "$0")/../../bin/{script}" "$@"\n')
                launcher.chmod(0o755)
            self.outfiles.append(str(launcher))


class Ros2Distribution(Distribution):
    """setuptools' editable_wheel installs data files only if the distribution has ``has_data()``,
    which no Distribution defines (it is ``has_data_files()``), so ``pip install -e`` would skip the
    whole ROS layout; this alias makes editable installs install data files like regular ones."""

    def has_data(self) -> bool:
        return bool(self.has_data_files())


def package_version() -> str:
    """The version is kept once, in package.xml."""
    version = ET.parse(HERE / "package.xml").findtext("version")
    if not version:
        raise RuntimeError("package.xml has no <version>")
    return version.strip()


def relative_files(pattern: str) -> list[str]:
    """Files matching a glob under the package root, as the relative paths setuptools wants."""
    return sorted(os.path.relpath(path, HERE) for path in HERE.glob(pattern))


setup(
    version=package_version(),
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", relative_files("config/*.yaml") + relative_files("config/*.json")),
        (f"share/{PACKAGE}/launch", relative_files("launch/*.launch.py")),
        (f"share/{PACKAGE}/urdf", relative_files(f"{PACKAGE}/nodes/urdf/*.urdf")),
    ],
    package_data={f"{PACKAGE}.nodes": ["urdf/*.urdf"]},
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in CONSOLE_SCRIPTS.items()]},
    cmdclass={"install_data": InstallDataWithRos2RunLaunchers},
    distclass=Ros2Distribution,
)
