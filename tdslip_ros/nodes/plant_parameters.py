"""The plant node's parameters: each one's default, description, range and whether it is read-only.

``plant_node`` declares them (:func:`tdslip_ros.nodes.parameters.declare`), validates their changes and
checks its command line against them; ``config/plant.yaml`` sets every one to its default (a test keeps
the two alike). The hopper's (:data:`~tdslip_ros.nodes.parameters.HOPPER`) and the perturbations'
(:data:`~tdslip_ros.nodes.parameters.PERTURBATIONS`) come from :mod:`tdslip_ros.nodes.parameters`.
"""

from __future__ import annotations

from tdslip_ros.model.policies.registry import (
    DEFAULT_APEX_HEIGHT,
    DEFAULT_APEX_SPEED,
    DEFAULT_TOUCHDOWN_ANGLE,
)
from tdslip_ros.nodes import parameters
from tdslip_ros.nodes.diagnostics import PLANT_THRESHOLDS, specs_of
from tdslip_ros.nodes.lifecycle import AUTOSTART
from tdslip_ros.nodes.parameters import ParameterSpec

CLOCK_MODES = ("realtime", "lockstep")
SPECS: tuple[ParameterSpec, ...] = (
    AUTOSTART,
    *parameters.HOPPER,
    ParameterSpec(
        "initial_height",
        DEFAULT_APEX_HEIGHT,
        "initial apex height [m] above the ground under the body",
        1e-3,
        1e2,
        read_only=True,
    ),
    ParameterSpec(
        "initial_forward_speed",
        DEFAULT_APEX_SPEED,
        "initial apex forward speed [m/s]",
        0.0,
        1e2,
        read_only=True,
    ),
    ParameterSpec(
        "initial_touchdown_angle",
        DEFAULT_TOUCHDOWN_ANGLE,
        "touchdown angle [rad] of the command in force until a controller answers",
        1e-6,
        1.5707953,
        read_only=True,
    ),
    ParameterSpec(
        "initial_tau0",
        -273.0,
        "ramp torque tau0 [N m] of the initial command (negative = forward thrust)",
        -1e6,
        1e6,
        read_only=True,
    ),
    ParameterSpec(
        "initial_t_f", 0.13, "ramp duration t_f [s] of the initial command", 1e-4, 1e2, read_only=True
    ),
    ParameterSpec(
        "max_torque",
        0.0,
        "actuator limit |tau0| [N m]: a command beyond it is rejected (0: 20 m g r0 of this hopper, "
        "tdslip_ros.model.limits)",
        0.0,
        1e9,
        read_only=True,
    ),
    *parameters.PERTURBATIONS,
    ParameterSpec(
        "clock_mode",
        "lockstep",
        "realtime: 1 kHz against wall time; lockstep: as fast as possible, each apex waiting for its command",
        choices=CLOCK_MODES,
        read_only=True,
    ),
    ParameterSpec(
        "command_timeout",
        5.0,
        "wall time [s] to wait for a controller before starting, and in lockstep at an apex for its "
        "command before the run ends",
        1e-3,
        3600.0,
        read_only=True,
    ),
    ParameterSpec(
        "max_stale_strides",
        3,
        "realtime: the run ends (command_timeout) after this many strides in a row without a valid "
        "command answering them (0: never; the plant hops on the command in force)",
        0,
        1_000_000,
        read_only=True,
    ),
    ParameterSpec(
        "torque_max_age",
        0.003,
        "realtime, stance feedback: the plant holds a streamed hip torque for at most this long [s] of "
        "simulated time after the tick it was sent for; then, or without one, the hip holds zero "
        "(a stale tick)",
        0.0,
        1.0,
        read_only=True,
    ),
    ParameterSpec(
        "max_strides", 50, "the run ends at this apex (0: never)", 0, 2_000_000_000, read_only=True
    ),
    ParameterSpec(
        "realtime_priority",
        0,
        "realtime: SCHED_FIFO priority of the tick process (0: normal scheduling; needs CAP_SYS_NICE)",
        0,
        99,
        read_only=True,
    ),
    ParameterSpec(
        "realtime_cpu",
        -1,
        "realtime: the CPU the tick process is pinned to (-1: any; e.g. one kept free with isolcpus)",
        -1,
        1023,
        read_only=True,
    ),
    ParameterSpec(
        "min_subscribers",
        0,
        "the run starts once each of the plant's topics has this many subscribers "
        "(a recorder of tdslip/samples counts for the state and the force)",
        0,
        1000,
        read_only=True,
    ),
    ParameterSpec(
        "wait_for_recorder",
        False,
        "start once a recorder_node has matched every publisher, keep a lockstep run within reach of "
        "what it has written, and wait at the end until everything is in its bag",
        read_only=True,
    ),
    ParameterSpec(
        "publish_clock",
        True,
        "publish /clock (simulated time) while someone subscribes to it; off for all hoppers but one "
        "when several share a domain",
        read_only=True,
    ),
    ParameterSpec(
        "marker_rate",
        60.0,
        "rate [Hz of simulated time] of the tdslip/markers drawing (0: none)",
        0.0,
        1000.0,
        read_only=True,
    ),
    ParameterSpec(
        "exit_when_done", True, "plant_node exits when the run has ended (else it stays for tdslip/reset)"
    ),
    *specs_of(PLANT_THRESHOLDS),
)
