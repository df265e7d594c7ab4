"""The paper's question for a freely rotating body (issue 36, docs/rotating_body.md; ``tdslip body``): does
energy regulation with a fixed touchdown angle keep stable gaits when the hip's torque also turns the body,
for which hips and inertias, and at what cost; and what the posture law
(:class:`~tdslip_ros.model.policies.posture.PostureRegulation`) changes.

All on the exact map, the paper's hopper (kbar 36, zeta0 0.08, m 80 kg, r0 1 m) at the suite's default gait
(touchdown angle 20 deg, the energy of the hip's apex 1 m at 5 m/s: ``registry.DEFAULT_*``).

**Which hips.** A free body's frame is ours to choose: the hopper depends on the hip's distance |d| from the
centre of mass and on J, not on the direction of d in the body (test_stability_rigid_fixed_points.py turns
it a quarter turn). What the gait adds is a branch: the body *stands* on its hip (the hip below the centre
of mass, an upright trunk, an inverted pendulum) or *hangs* from it (the hip above). The map's rows are the
two, as hip_y = -|d| and +|d| with hip_x = 0.

Three figures (PNG and JSON each):
* ``body_map``: the spectral radius of the regulated gait's 4-D fixed point over |d| x the radius of
  gyration, standing and hanging, under the paper's regulator alone and with the posture law; and the hip's
  positive work per metre there against the fixed body's;
* ``body_strides``: pitch and apex energy over strides from the same start off the gait, both policies and
  the virtual pivot point with its energy term (model/policies/virtual_pivot.py);
* ``body_grf``: the ground reaction force over one stance (the paper's fig. 12 hopper and gait) of the
  fixed body beside the rotating one held by the posture law, with the rotating body's pitch.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from tdslip_ros.analysis.figures.ground_reaction import BETA_DEG as GRF_BETA_DEG
from tdslip_ros.analysis.figures.ground_reaction import fig12_hopper, regulated_gait, sample_stance
from tdslip_ros.model import body_dynamics, dynamics
from tdslip_ros.model.paper import PAPER_PARAMS, UPRIGHT_TRUNK_GYRATION_RADIUS, UPRIGHT_TRUNK_HIP_Y
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, RigidBody
from tdslip_ros.model.plant.stance_laws import StanceFeedback, StanceLaw, StanceSample
from tdslip_ros.model.policies.posture import HipEnergyRegulation, PostureRegulation, balance_lean
from tdslip_ros.model.policies.registry import DEFAULT_TARGET_ENERGY, DEFAULT_TOUCHDOWN_ANGLE
from tdslip_ros.model.policies.virtual_pivot import VirtualPivot
from tdslip_ros.model.stability.rigid_fixed_points import (
    ApexPolicy,
    RigidFixedPoint,
    closed_loop_stride,
    rigid_fixed_point,
)

HIP_DISTANCES = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3)
"""|d| [m]: the hip's distance from the centre of mass, the map's columns."""
GYRATION_RADII = (0.1, 0.2, 0.3, 0.45, 0.6)
"""m: the body's radius of gyration, J = m radius^2, the map's rows (a human trunk is about 0.3 m)."""
BRANCHES = {"standing": -1.0, "hanging": 1.0}
"""The sign of hip_y: the body stands on its hip (below the centre of mass) or hangs from it."""
EXAMPLE_HIP_Y, EXAMPLE_RADIUS = UPRIGHT_TRUNK_HIP_Y, UPRIGHT_TRUNK_GYRATION_RADIUS
"""The upright trunk of ``body_strides`` and ``body_grf`` (model/paper.py)."""
OFF_GAIT = (0.15, -0.2, 0.1, 0.3)
"""``body_strides``' start: the gait's apex moved by these (y [m], xdot [m/s], pitch [rad], rate [rad/s])."""
STRIDES = 40
"""Strides of ``body_strides``."""
MAP_HIP_APEX = ApexState(1.0, 5.0)
"""The hip's apex the fixed points are searched from (the default gait's)."""


PIVOT_ABOVE, PIVOT_ENERGY_GAIN = 0.3, 1.0
"""The virtual pivot of ``body_strides``: 0.3 m above the centre of mass, k_E 1 N m/J (from its gait, pivots
0.1-0.6 m above with k_E 0.3-3 tip the trunk or stall within 5-9 strides alike)."""


def policies(
    beta: float = DEFAULT_TOUCHDOWN_ANGLE, target: float = DEFAULT_TARGET_ENERGY
) -> dict[str, ApexPolicy]:
    """The two policies of the map: the paper's regulator planned on the hip, and with the posture law."""
    return {"regulation": HipEnergyRegulation(beta, target), "posture": PostureRegulation(beta, target)}


def pivot_policy(params: HopperParams, target: float, beta: float = DEFAULT_TOUCHDOWN_ANGLE) -> ApexPolicy:
    """The virtual pivot point with its energy term towards ``target`` [J] (the stance's total energy), at a
    fixed touchdown angle."""
    law = VirtualPivot(params, PIVOT_ABOVE, 0.0, PIVOT_ENERGY_GAIN, target)
    return lambda _params, _apex: StanceFeedback(beta, law)


def rigid_hopper(hip_y: float, radius: float, params: HopperParams = PAPER_PARAMS) -> HopperParams:
    return dataclasses.replace(params, body=RigidBody.from_gyration(params.m, radius, hip_y=hip_y))


def gait_guess(params: HopperParams, hip_apex: ApexState = MAP_HIP_APEX) -> ApexState | None:
    """Where to look for the regulated gait: the hip at ``hip_apex``, the body at the balancing lean of the
    paper's ramp from there; None when no lean balances it (the hip too close to the centre of mass)."""
    body = params.body
    assert body is not None
    level = ApexState(hip_apex.y - body.hip_y, hip_apex.xdot)
    ramp = HipEnergyRegulation(DEFAULT_TOUCHDOWN_ANGLE, DEFAULT_TARGET_ENERGY)(params, level)
    try:
        lean = balance_lean(params, level, ramp)
    except ParameterError:
        return None
    hip_y = body_dynamics.hip_offset(body, math.sin(lean), math.cos(lean))[1]
    return ApexState(hip_apex.y - hip_y, hip_apex.xdot, lean, 0.0)


@dataclass(frozen=True)
class GaitCell:
    """One cell of the map: the fixed point (or why there is none) and, at it, the hip's positive work per
    stride [J] and the distance per stride [m]."""

    point: RigidFixedPoint | None
    reason: str
    hip_work: float = math.nan
    distance: float = math.nan

    def row(self) -> dict[str, Any]:
        point, apex = self.point, None if self.point is None else self.point.apex
        return {
            "stable": bool(point is not None and point.stable),
            "spectral_radius": math.nan if point is None else point.spectral_radius,
            "apex": None if apex is None else dataclasses.asdict(apex),
            "hip_work_per_metre": self.hip_work / self.distance if self.distance > 0.0 else math.nan,
            "reason": self.reason,
        }


def gait_cell(params: HopperParams, policy: ApexPolicy) -> GaitCell:
    guess = gait_guess(params)
    if guess is None:
        return GaitCell(None, "no lean balances the thrust")
    point = rigid_fixed_point(params, policy, guess)
    if point.apex is None:
        return GaitCell(point, point.message)
    stride = closed_loop_stride(params, policy, point.apex)
    assert stride.energy is not None and stride.apex_x is not None, stride.reason
    return GaitCell(point, "", stride.energy.hip_work, stride.apex_x)


def fixed_body_work_per_metre(params: HopperParams = PAPER_PARAMS) -> float:
    """The hip's work per metre [J/m] of the fixed body's regulated gait at the same settings (the same
    planner; the point mass's fixed point by iteration)."""
    regulation = HipEnergyRegulation(DEFAULT_TOUCHDOWN_ANGLE, DEFAULT_TARGET_ENERGY)
    # a body with the hip at the centre of mass and no inertia to speak of is the point mass, never turned
    stiff = dataclasses.replace(params, body=RigidBody(1e12))
    apex = MAP_HIP_APEX
    for _ in range(200):
        stride = closed_loop_stride(stiff, regulation, apex)
        assert stride.apex is not None, stride.reason
        apex = stride.apex
    assert stride.energy is not None and stride.apex_x is not None
    return stride.energy.hip_work / stride.apex_x


def gait_map(
    distances: tuple[float, ...] = HIP_DISTANCES,
    radii: tuple[float, ...] = GYRATION_RADII,
    progress: Callable[[str], None] = lambda _: None,
) -> dict[str, Any]:
    """Every cell of the map, by branch, policy, radius (rows) and distance (columns)."""
    cells: dict[str, dict[str, list[list[dict[str, Any]]]]] = {}
    for branch, sign in BRANCHES.items():
        for name, policy in policies().items():
            rows = []
            for radius in radii:
                rows.append([gait_cell(rigid_hopper(sign * d, radius), policy).row() for d in distances])
                progress(f"{branch}, {name}: radius {radius:g} m done")
            cells.setdefault(branch, {})[name] = rows
    return {
        "hip_distances": list(distances),
        "gyration_radii": list(radii),
        "cells": cells,
        "fixed_body_hip_work_per_metre": fixed_body_work_per_metre(),
    }


def draw_map(data: dict[str, Any]) -> Figure:
    distances, radii = np.array(data["hip_distances"]), np.array(data["gyration_radii"])
    figure = Figure(figsize=(12, 8.5))
    layout = figure.add_gridspec(2, 3, width_ratios=(1.0, 1.0, 0.04))
    for row, branch in enumerate(BRANCHES):
        for column, name in enumerate(("regulation", "posture")):
            axes = figure.add_subplot(layout[row, column])
            cells = data["cells"][branch][name]
            radius = np.array([[cell["spectral_radius"] for cell in line] for line in cells])
            image = axes.imshow(
                np.log10(radius),
                origin="lower",
                cmap="RdYlGn_r",
                vmin=-1.0,
                vmax=1.0,
                aspect="auto",
                extent=(-0.5, distances.size - 0.5, -0.5, radii.size - 0.5),
            )
            for i, line in enumerate(cells):
                for j, cell in enumerate(line):
                    value = cell["spectral_radius"]
                    text = "no gait" if math.isnan(value) else f"{value:.2f}"
                    axes.text(j, i, text, ha="center", va="center", fontsize=8)
            axes.set_xticks(range(distances.size), [f"{d:g}" for d in distances])
            axes.set_yticks(range(radii.size), [f"{r:g}" for r in radii])
            label = "paper's regulator alone" if name == "regulation" else "with the posture law"
            axes.set_title(f"{branch} on the hip ({'below' if branch == 'standing' else 'above'}): {label}")
            if row == 1:
                axes.set_xlabel("hip's distance from the centre of mass |d| [m]")
            if column == 0:
                axes.set_ylabel("radius of gyration [m]")
    colour = figure.colorbar(image, cax=figure.add_subplot(layout[:, 2]))
    colour.set_label("log10 spectral radius of the 4-D apex map (< 0: stable)")
    figure.suptitle("Energy regulation (beta 20 deg) with a rotating body: stability of the regulated gait")
    return figure


def strides_data(hip_y: float = EXAMPLE_HIP_Y, radius: float = EXAMPLE_RADIUS) -> dict[str, Any]:
    """Pitch and apex energy (translational and rotational) over STRIDES strides from OFF_GAIT, for both
    policies and the virtual pivot, until the run ends or fails."""
    params = rigid_hopper(hip_y, radius)
    gait = gait_cell(params, policies()["posture"]).point
    assert gait is not None and gait.apex is not None, "the posture law's gait is the start's reference"
    runs: dict[str, Any] = {}
    compared = {**policies(), "pivot": pivot_policy(params, gait.apex.energy(params))}
    for name, policy in compared.items():
        apex = ApexState(*(a + b for a, b in zip(dataclasses.astuple(gait.apex), OFF_GAIT, strict=True)))
        pitch, energy, failure = [apex.pitch], [apex.energy(params)], ""
        for _ in range(STRIDES):
            stride = closed_loop_stride(params, policy, apex)
            if stride.apex is None:
                failure = f"{stride.failure}: {stride.reason}"
                break
            apex = stride.apex
            pitch.append(apex.pitch)
            energy.append(apex.energy(params))
        runs[name] = {"pitch": pitch, "energy": energy, "failure": failure}
    return {"hip_y": hip_y, "gyration_radius": radius, "off_gait": list(OFF_GAIT), "runs": runs}


STRIDE_LABELS = {
    "regulation": "paper's regulator alone",
    "posture": "with the posture law",
    "pivot": f"virtual pivot {PIVOT_ABOVE:g} m above, energy term {PIVOT_ENERGY_GAIN:g} N m/J",
}


def draw_strides(data: dict[str, Any]) -> Figure:
    figure = Figure(figsize=(10, 6.5))
    pitch_axes, energy_axes = figure.subplots(2, 1, sharex=True)
    for name, run in data["runs"].items():
        label = STRIDE_LABELS[name]
        if run["failure"]:
            label += f" ({run['failure'].split(':')[0]} in stride {len(run['pitch'])})"
        pitch_axes.plot(run["pitch"], marker="o", markersize=3, label=label)
        energy_axes.plot(run["energy"], marker="o", markersize=3, label=label)
    pitch_axes.axhline(math.pi / 2, color="grey", linestyle=":")
    pitch_axes.axhline(-math.pi / 2, color="grey", linestyle=":", label="tip limit")
    pitch_axes.set_ylabel("apex pitch [rad] (> 0: leaning back)")
    energy_axes.set_ylabel("apex energy [J] (with J phidot^2 / 2)")
    energy_axes.set_xlabel("stride")
    pitch_axes.legend(fontsize=8)
    figure.suptitle(
        f"Upright trunk (hip {-data['hip_y']:g} m below the centre of mass, radius of gyration "
        f"{data['gyration_radius']:g} m) from off the gait"
    )
    return figure


class _SampleKeeper:
    """A stance law that keeps each sample and the torque another law holds from it."""

    def __init__(self, law: StanceLaw) -> None:
        self.law = law
        self.samples: list[StanceSample] = []
        self.torques: list[float] = []

    def torque(self, sample: StanceSample, lanes: Any = None) -> float:
        tau = float(self.law.torque(sample))
        self.samples.append(sample)
        self.torques.append(tau)
        return tau


def grf_data() -> dict[str, Any]:
    """The paper's fig. 12 hopper (m 65.4 kg) at its regulated gait (3 m/s, beta 17 deg, energy_exact): the
    fixed body's GRF over the stance, and the upright trunk's under the posture law at the same energy and
    touchdown angle (sampled at 1 kHz, the law's samples)."""
    fixed = fig12_hopper()
    beta = math.radians(GRF_BETA_DEG)
    apex, command = regulated_gait(fixed, 3.0, beta)
    stance = sample_stance(fixed, apex, command)
    params = dataclasses.replace(
        fixed, body=RigidBody.from_gyration(fixed.m, EXAMPLE_RADIUS, hip_y=EXAMPLE_HIP_Y)
    )
    posture = PostureRegulation(beta, apex.energy(fixed))
    level = ApexState(apex.y - EXAMPLE_HIP_Y, apex.xdot)
    ramp = HipEnergyRegulation(beta, apex.energy(fixed))(params, level)
    lean = balance_lean(params, level, ramp)
    guess = ApexState(apex.y - EXAMPLE_HIP_Y * math.cos(lean), apex.xdot, lean, 0.0)
    point = rigid_fixed_point(params, posture, guess)
    if point.apex is None:
        raise ValueError(f"the rotating body has no regulated gait at fig. 12's settings: {point.message}")
    command_rigid = posture(params, point.apex)
    keeper = _SampleKeeper(command_rigid.law)
    closed = closed_loop_stride(
        params, lambda _p, _a: StanceFeedback(command_rigid.touchdown_angle, keeper), point.apex
    )
    assert closed.apex is not None, closed.reason
    s = np.array([sample.s for sample in keeper.samples])
    forces = [
        dynamics.ground_reaction_force(
            params, sample.r, math.sin(sample.theta), math.cos(sample.theta), sample.rdot, tau
        )
        for sample, tau in zip(keeper.samples, keeper.torques, strict=True)
    ]
    return {
        "fixed": {"s": stance.s.tolist(), "fx": stance.fx.tolist(), "fy": stance.fy.tolist()},
        "rotating": {
            "s": s.tolist(),
            "fx": [f[0] for f in forces],
            "fy": [f[1] for f in forces],
            "pitch": [sample.pitch for sample in keeper.samples],
            "apex": dataclasses.asdict(point.apex),
            "spectral_radius": point.spectral_radius,
        },
        "apex": dataclasses.asdict(apex),
        "beta_deg": GRF_BETA_DEG,
        "m": fixed.m,
    }


def draw_grf(data: dict[str, Any]) -> Figure:
    figure = Figure(figsize=(10, 8))
    fx_axes, fy_axes, pitch_axes = figure.subplots(3, 1, sharex=True)
    for key, label in (("fixed", "fixed body (the paper's)"), ("rotating", "rotating trunk, posture law")):
        run = data[key]
        fx_axes.plot(run["s"], run["fx"], label=label)
        fy_axes.plot(run["s"], run["fy"], label=label)
    pitch_axes.plot(data["rotating"]["s"], data["rotating"]["pitch"], color="C1")
    fx_axes.set_ylabel("F_x [N]")
    fy_axes.set_ylabel("F_y [N]")
    pitch_axes.set_ylabel("trunk pitch [rad]")
    pitch_axes.set_xlabel("time since touchdown [s]")
    fx_axes.legend(fontsize=8)
    figure.suptitle(
        f"Fig. 12's stance (m {data['m']:g} kg, 3 m/s, beta {data['beta_deg']:g} deg): "
        "the fixed body and an upright trunk"
    )
    return figure
