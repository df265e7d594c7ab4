"""Energy regulation against open loop over the same rough ground (``tdslip terrain``, the README figure):
closed-loop hops of the 1 kHz plant (:class:`~tdslip_ros.model.plant.stepper.FixedStepStepper`, the plant
node's physics) over random blocks, each apex answered as the controller node answers it, from energy
regulation's fixed point on flat ground where both policies would hop identically forever; and the figure
of their centre-of-mass paths and apex energies above the ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np
from matplotlib.figure import Figure

from tdslip_ros.interfaces import installed_parameters
from tdslip_ros.model import dynamics, units
from tdslip_ros.model.events import EventKind, FailureKind
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.model.plant.terrain import Blocks
from tdslip_ros.model.policies.registry import POLICY_SETTINGS, PolicySpec
from tdslip_ros.reporting.style import POLICY_COLOURS, save_figure

LABELS = {"energy": "energy regulation", "open_loop": "open loop (fixed hip power)"}
TOUCHDOWN_ANGLE_DEG = 22.0
"""The figure's touchdown angle [deg]: at the gait's apex the toe clears the ground by about 10 cm, so both
policies hop all their strides over the default blocks; at the model's 20 deg it clears 3 cm, and both stub
their toe within a dozen strides, before the energies part."""


@dataclass(frozen=True)
class Hop:
    """A closed-loop run: the body's path (x, y [m]) at every tick, the apexes (x, y above the ground,
    xdot) and the energy above the ground at each apex [J], and the failure that ended it (None: it ran
    all its strides)."""

    policy: str
    x: np.ndarray
    y: np.ndarray
    apexes: list[tuple[float, float, float]]
    energies: list[float]
    failure: FailureKind | None
    reason: str


def hop(
    params: HopperParams, policy: PolicySpec, apex: ApexState, perturbations: Perturbations, strides: int
) -> Hop:
    """Hop the plant under ``policy`` for ``strides`` apexes or to a failure (module docstring). An apex the
    policy has no command for keeps the command in force, as the plant node does."""
    first = policy.commands(params, apex.y, apex.xdot, apex.xdot).command()
    stepper = FixedStepStepper(params, apex, first, perturbations=perturbations)
    x, y = [stepper.state.x], [stepper.state.y]
    apexes: list[tuple[float, float, float]] = []
    energies: list[float] = []
    previous = apex.xdot

    def answer() -> None:
        nonlocal previous
        state = stepper.apex_state
        height = state.y - stepper.ground
        apexes.append((state.x, height, state.xdot))
        energies.append(params.m * (params.g * height + 0.5 * state.xdot**2))
        measured_y, measured_xdot = stepper.measured_apex
        plan = policy.commands(params, measured_y - stepper.ground, measured_xdot, previous)
        previous = measured_xdot
        try:
            stepper.set_command(plan.command())
        except ParameterError:
            pass  # no command: the one in force stays

    answer()
    reason = ""
    while stepper.failed is None and stepper.stride < strides:
        for event in stepper.step():
            if event.kind is EventKind.APEX and stepper.failed is None:
                answer()
            elif event.kind is EventKind.FAILURE:
                reason = event.reason
        x.append(stepper.state.x)
        y.append(stepper.state.y)
    return Hop(policy.name, np.array(x), np.array(y), apexes, energies, stepper.failed, reason)


FIXED_POINT_STRIDES = 30
"""Flat-ground strides of energy regulation from the given apex to its fixed point (|lambda| ~ 0.1 at the
defaults: converged to rounding)."""


def policies(params: HopperParams, apex: ApexState, angle: float) -> tuple[ApexState, dict[str, PolicySpec]]:
    """The start and the two policies: energy regulation at ``angle`` holding the energy of ``apex``, and its
    fixed point on flat ground, where both start; open loop at the same angle with the hip power that energy
    regulation applies there, so that on flat ground both would hop on at that fixed point forever (the
    installed controller defaults otherwise)."""
    installed = installed_parameters("controller.yaml")  # an older install may lack a setting: its default
    values = {setting.name: installed.get(setting.name, setting.default) for setting in POLICY_SETTINGS}
    values |= {"touchdown_angle": angle, "target_energy": apex.energy(params)}
    energy = PolicySpec.of("energy", values)
    flat = hop(params, energy, apex, Perturbations(), FIXED_POINT_STRIDES)
    if flat.failure is not None:
        raise ParameterError(
            f"energy regulation at {math.degrees(angle):g} deg fails from {apex}: {flat.reason}"
        )
    _, height, speed = flat.apexes[-1]
    start = ApexState(height, speed)
    tau0 = float(energy.commands(params, start.y, start.xdot, start.xdot).command().tau0)
    thetadot = dynamics.touchdown_leg_rate(params, start.y, start.xdot, angle)
    open_loop = PolicySpec.of("open_loop", values | {"touchdown_power": tau0 * thetadot})
    return start, {"open_loop": open_loop, "energy": energy}


def draw(params: HopperParams, blocks: Blocks, hops: list[Hop], path: Path) -> Figure:
    """The COM paths over the ground and the apex energies per stride (module docstring)."""
    figure = Figure(figsize=(10, 6.5))
    paths, energy = figure.subplots(2, 1, height_ratios=(3, 2))
    x_end = max(float(np.max(h.x)) for h in hops)
    x = np.linspace(-0.5, x_end + 0.5, 6000)
    ground = blocks.height(x)
    paths.fill_between(x, ground, np.min(ground) - 0.1 * params.r0, color="tan", alpha=0.6, lw=0)
    paths.plot(x, ground, color="saddlebrown", lw=0.8, label=f"ground: {blocks.spec()}")
    scale = units.energy_scale(params)
    for h in hops:
        colour = POLICY_COLOURS[h.policy]
        ended = "" if h.failure is None else f", {h.failure.value} at stride {len(h.apexes) - 1}"
        paths.plot(
            h.x, h.y, color=colour, lw=1.1, label=f"{LABELS[h.policy]}: {len(h.apexes) - 1} strides{ended}"
        )
        if h.failure is not None:
            paths.plot(h.x[-1], h.y[-1], "X", color=colour, ms=10)
        energy.plot(np.arange(len(h.energies)), np.array(h.energies) / scale, "o-", color=colour, ms=3)
    energy.axhline(hops[0].energies[0] / scale, color="grey", ls=":", lw=1, label="initial apex energy")
    paths.set_xlabel("x [m]")
    paths.set_ylabel("y [m]")
    paths.set_title("TD-SLIP over random blocks: centre-of-mass paths")
    paths.legend(fontsize=7, loc="center left", ncol=1)
    paths.grid(alpha=0.3)
    energy.set_xlabel("stride")
    energy.set_ylabel("apex energy above the ground, Ebar")
    energy.legend(fontsize=7)
    energy.grid(alpha=0.3)
    save_figure(figure, path)
    return figure
