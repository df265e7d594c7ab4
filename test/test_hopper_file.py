"""The hopper file of tdslip_ros.interfaces, what identify writes and every command reads, and the
commands' hopper options (under 2 s)."""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import pytest

from tdslip_ros.commands.options import add_hopper, hopper_of
from tdslip_ros.interfaces import (
    HOPPER_PARAMETERS,
    HopperFileError,
    hopper_from_parameters,
    hopper_parameters,
    read_hopper_file,
    write_hopper_file,
)
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import HopperParams, ParameterError, RigidBody


def test_a_hopper_file_round_trips_exactly(tmp_path: Path) -> None:
    # values with no short decimal form: the file must keep every bit
    params = HopperParams(m=65.4 / 3.0, k=32490.72 * (1.0 + 1e-12), r0=0.95 / 7.0, c=168.3812633757, g=9.8066)
    path = tmp_path / "robot.yaml"
    write_hopper_file(path, params, {"made_by": "tdslip identify", "k_interval_N_per_m": [1.0, 2.0]})
    assert read_hopper_file(path) == params
    assert not list(tmp_path.glob("*.partial"))


def test_gravity_may_be_left_out_and_takes_the_models_default(tmp_path: Path) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text("hopper:\n  mass: 70\n  stiffness: 20000\n  rest_length: 1.0\n  damping: 100\n")
    assert read_hopper_file(path) == HopperParams(m=70.0, k=20000.0, r0=1.0, c=100.0)


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("hopper:\n  mass: 70\n  stiffness: 20000\n  rest_length: 1.0\n", "missing damping"),
        (
            "hopper:\n  mass: 70\n  stifness: 2e4\n  rest_length: 1\n  damping: 1\n",
            "unknown name(s) stifness",
        ),
        (
            "hopper:\n  mass: heavy\n  stiffness: 2e4\n  rest_length: 1\n  damping: 1\n",
            "mass must be a finite number",
        ),
        ("hopper:\n  mass: -70\n  stiffness: 2e4\n  rest_length: 1\n  damping: 1\n", "m must be positive"),
        ("mass: 70\n", "no 'hopper:' block"),
        ("hopper: [\n", "not YAML"),
    ],
)
def test_a_bad_hopper_file_is_one_line_naming_the_file(tmp_path: Path, text: str, says: str) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    with pytest.raises(HopperFileError) as error:
        read_hopper_file(path)
    message = str(error.value)
    assert says in message and str(path) in message and "\n" not in message


def test_a_missing_hopper_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(HopperFileError, match="cannot be read"):
        read_hopper_file(tmp_path / "absent.yaml")


def test_the_file_names_are_the_node_parameters(tmp_path: Path) -> None:
    path = tmp_path / "robot.yaml"
    write_hopper_file(path, HopperParams(m=1.0, k=2.0, r0=3.0, c=4.0), {})
    assert set(path.read_text().split("provenance")[0].split()) >= {
        f"{n}:" for n in HOPPER_PARAMETERS.values()
    }


def test_the_hopper_options_replace_the_files_values(tmp_path: Path) -> None:
    """commands/options.py's one declaration of the hopper options: the file, then each value given."""
    parser = argparse.ArgumentParser()
    add_hopper(parser, "the paper's")
    path = tmp_path / "robot.yaml"
    robot = HopperParams(m=65.4, k=32490.72, r0=0.95, c=168.38)
    write_hopper_file(path, robot, {})
    assert hopper_of(parser.parse_args(["--hopper", str(path)]), PAPER_PARAMS) == robot
    assert hopper_of(parser.parse_args(["--hopper", str(path), "--damping", "100"]), PAPER_PARAMS) == replace(
        robot, c=100.0
    )
    # kbar = k r0/(m g) and zeta0 = c/(2 sqrt(m k)) (eq. 24) with the file's m and r0
    bar = hopper_of(
        parser.parse_args(["--hopper", str(path), "--kbar", "30", "--zeta0", "0.1"]), PAPER_PARAMS
    )
    assert (bar.k, bar.c) == pytest.approx(
        (30.0 * 65.4 * 9.81 / 0.95, 0.2 * math.sqrt(65.4 * bar.k)), rel=1e-15
    )
    assert hopper_of(parser.parse_args([]), PAPER_PARAMS) == PAPER_PARAMS
    with pytest.raises(ParameterError, match="give --damping or --zeta0, not both"):
        hopper_of(parser.parse_args(["--damping", "1", "--zeta0", "0.1"]), PAPER_PARAMS)


def test_a_rigid_body_round_trips_through_the_node_parameters() -> None:
    """hopper_parameters and hopper_from_parameters are each other's inverse, the body included; values
    without ``body`` (a bag recorded before it was one) are the fixed body's; a body of another kind is
    refused by name."""
    rigid = replace(PAPER_PARAMS, body=RigidBody(3.5, hip_x=0.05, hip_y=-0.25, tip_limit=1.2))
    for params in (PAPER_PARAMS, rigid):
        values = hopper_parameters(params)
        assert hopper_from_parameters(values) == params
        as_text = {name: str(value) for name, value in values.items()}  # as custom_data stores them
        assert hopper_from_parameters(as_text) == params
    assert hopper_parameters(PAPER_PARAMS)["body"] == "fixed"
    old = {name: value for name, value in hopper_parameters(rigid).items() if name != "body"}
    assert hopper_from_parameters(old) == PAPER_PARAMS
    with pytest.raises(ParameterError, match="body must be one of fixed, rigid, got 'wobbly'"):
        hopper_from_parameters({**hopper_parameters(rigid), "body": "wobbly"})
