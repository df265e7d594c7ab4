"""``tdslip simulate``: a plant-only run of the 1 kHz stepper, printed as one table row per apex.

The hopper runs open loop under one constant stance command (touchdown angle beta, ramp torque
tau0 over t_f). Unless given, tau0 and t_f are chosen once, before the run, so that the hip
replaces the losses of the first stride: t_f is that stride's stance duration (the paper's
t_f = t_lo) and tau0 the torque for which the exact return map brings the first apex back to
its own energy (a root of E_1 - E_0 in tau0, alternating with t_f until both settle).
Open-loop hopping is at best marginally stable (paper, section III), so the run drifts and may
end in a named failure; a controller policy (issue 3) will replace the constant command.
"""

from __future__ import annotations

import argparse
import math
import sys

from tdslip_ros.analysis.simulate import energy_neutral_command
from tdslip_ros.commands.options import (
    add_hopper,
    add_initial_apex,
    add_touchdown_angle,
    check_strides_and_angle,
    command_parser,
    hopper_of,
)
from tdslip_ros.model import dynamics, units
from tdslip_ros.model.events import Event, EventKind
from tdslip_ros.model.limits import PlausibilityLimits, check_hopper
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.stepper import FixedStepStepper


def _row(
    params: HopperParams, stride: int, t: float, apex: ApexState, flows: tuple[float, ...] | None
) -> str:
    energy = apex.energy(params)
    work = "".join(f"{value:10.2f}" for value in flows) if flows else f"{'':>30}"
    return (
        f"{stride:6d} {t:9.4f} {apex.y:8.4f} {apex.xdot:9.4f} {energy:9.2f}{work}   "
        f"{units.height_to_bar(params, apex.y):7.4f} {units.speed_to_bar(params, apex.xdot):8.4f} "
        f"{units.energy_to_bar(params, energy):7.4f}"
    )


DESCRIPTION = """\
Simulate the hopper alone (no ROS) on the 1 kHz stepper and print one table row per apex.
It hops open loop under one constant stance command: the touchdown angle and a hip torque ramp tau0
over t_f, by default chosen so that the first stride replaces its own losses. Open-loop hopping is at
best marginally stable, so the run drifts and may end in a named failure (exit status 1)."""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("simulate", DESCRIPTION)
    parser.add_argument("--strides", type=int, default=10, help="apexes to simulate")
    add_hopper(parser, "the paper's, kbar 36, zeta0 0.08, 80 kg, 1 m", "--r0")
    add_touchdown_angle(parser, "--beta-deg")
    add_initial_apex(parser)
    parser.add_argument("--tau0", type=float, help="ramp torque [N m] (default: energy-neutral first stride)")
    parser.add_argument("--t-f", type=float, help="ramp duration [s] (default: first stride's stance time)")
    parser.add_argument("--dt", type=float, default=1e-3, help="stepper tick [s]")
    return parser


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    # Bad input: one line on stderr and exit code 2 (argparse's code for a usage error); 1 is a failure.
    try:
        check_strides_and_angle(args.strides, args.touchdown_angle_deg)
        params = hopper_of(args, PAPER_PARAMS)
        check_hopper(params)
        limits = PlausibilityLimits.for_hopper(params)
        apex = ApexState(args.height, args.speed)
        limits.check_apex(apex)
        angle = math.radians(args.touchdown_angle_deg)
        dynamics.check_placement(params, apex.y, angle)
        if args.tau0 is None:
            command = energy_neutral_command(params, apex, angle, args.t_f)
        else:
            command = StanceCommand(
                angle, args.tau0, args.t_f if args.t_f is not None else math.pi / params.omega0
            )
        limits.check_command(command)
        stepper = FixedStepStepper(params, apex, command, dt=args.dt, limits=limits)
    except ParameterError as error:
        print(f"tdslip simulate: {error}", file=sys.stderr)
        return 2

    print(
        f"TD-SLIP plant, {args.dt * 1e3:g} ms RK4 stepper: m = {params.m:g} kg, k = {params.k:.1f} N/m, "
        f"r0 = {params.r0:g} m, c = {params.c:.2f} N s/m (kbar = {params.kbar:g}, zeta0 = {params.zeta0:g})"
    )
    print(
        f"constant command: touchdown angle {args.touchdown_angle_deg:g} deg, tau0 = {command.tau0:.2f} N m "
        f"(taubar = {units.torque_to_bar(params, command.tau0):.4f}), t_f = {command.t_f:.4f} s"
    )
    print(
        f"{'stride':>6} {'t [s]':>9} {'y [m]':>8} {'xdot[m/s]':>9} {'E [J]':>9}{'W_hip[J]':>10}"
        f"{'E_c [J]':>10}{'E_k [J]':>10}   {'ybar':>7} {'xdotbar':>8} {'Ebar':>7}"
    )
    print(_row(params, 0, 0.0, apex, None))
    failure: Event | None = None
    while stepper.stride < args.strides and failure is None:
        for event in stepper.step():
            if event.kind is EventKind.APEX and stepper.last_stride_energy is not None:
                flows = stepper.last_stride_energy
                reached = ApexState(event.state.y, event.state.xdot)
                columns = (flows.hip_work, flows.damping_loss, flows.spring_loss)
                print(_row(params, event.stride, event.t, reached, columns))
            elif event.kind is EventKind.FAILURE:
                failure = event
    if failure is not None:
        print(
            f"failure at t = {failure.t:.4f} s, stride {failure.stride}: {failure.failure}: {failure.reason}"
        )
        return 1
    return 0
