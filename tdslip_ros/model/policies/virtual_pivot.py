"""Posture inside the stance: the virtual pivot point (VPP) of Maus et al. (2010) as a sampled stance law
on the plant's 1 kHz torque interface (:mod:`tdslip_ros.model.plant.stance_laws`), for a hopper with a
rigid body (:class:`tdslip_ros.model.params.RigidBody`, docs/rotating_body.md).

The hip torque sets the direction of the ground's force: the massless leg's force is
F = f e_r + (tau / r) e_theta at the toe (:func:`.dynamics.ground_reaction_force`). The law picks the tau
that points F from the toe through the pivot V, a point fixed in the body, ``above`` [m] along its axis
and ``forward`` [m] across it from the centre of mass. With w = V - toe in the leg's polar frame,
F || w gives tau = r f w_theta / w_r. A pivot above the centre of mass makes the body hang from it like
a pendulum: the force's moment about the centre of mass turns the body back towards the pivot's line.

One actuator has two jobs here (issue 36): the pivot holds the posture, and the energy term of the paper's
ref. 36 baseline (:mod:`.stance_pd`), tau_E = k_E (E - E*), replaces what the damper takes. The sum is
held; with k_E = 0 the force passes through the pivot at every sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tdslip_ros.model import body_dynamics, dynamics
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.plant.stance_laws import StanceSample, finite_field


def pivot_torque(model: HopperParams, sample: StanceSample, above: float, forward: float) -> Any:
    """The hip torque [N m] that directs the ground's force through the pivot (module docstring)."""
    body = model.body
    if body is None:
        raise ParameterError("the virtual pivot point needs a hopper with a rigid body (HopperParams.body)")
    sin_t, cos_t = np.sin(sample.theta), np.cos(sample.theta)
    sin_p, cos_p = np.sin(sample.pitch), np.cos(sample.pitch)
    hip_x, hip_y = body_dynamics.hip_offset(body, sin_p, cos_p)
    # V - toe = (hip - toe) - (hip - com) + (V - com), the last turned into the world by the pitch.
    w_x = -sample.r * sin_t - hip_x + forward * cos_p - above * sin_p
    w_y = sample.r * cos_t - hip_y + forward * sin_p + above * cos_p
    w_r = -w_x * sin_t + w_y * cos_t
    w_theta = -w_x * cos_t - w_y * sin_t
    return sample.r * dynamics.leg_force(model, sample.r, sample.rdot) * w_theta / w_r


@dataclass(frozen=True)
class VirtualPivot:
    """The pivot ``above`` [m] the centre of mass along the body's axis and ``forward`` [m] across it, plus
    the energy term k_E (E - E*) with ``energy_gain`` [N m/J] towards ``target_energy`` [J] (the stance's
    translational and spring energy above the ground, as :mod:`.stance_pd` measures it, plus the body's
    rotation). ``model`` is the hopper the law computes with, a rigid body's."""

    model: HopperParams
    above: float
    forward: float = 0.0
    energy_gain: float = 0.0
    target_energy: float = 0.0

    def __post_init__(self) -> None:
        if self.model.body is None:
            raise ParameterError(
                "the virtual pivot point needs a hopper with a rigid body (HopperParams.body)"
            )
        for name in ("above", "forward", "energy_gain", "target_energy"):
            object.__setattr__(self, name, finite_field(name, getattr(self, name)))

    def torque(self, sample: StanceSample, lanes: npt.NDArray[np.int64] | None = None) -> Any:
        tau = pivot_torque(self.model, sample, self.above, self.forward)
        if self.energy_gain == 0.0:
            return tau
        body = self.model.body
        assert body is not None
        energy = body_dynamics.rigid_stance_energy(
            self.model,
            body,
            sample.r,
            math.sin(sample.theta),
            math.cos(sample.theta),
            sample.rdot,
            sample.thetadot,
            math.sin(sample.pitch),
            math.cos(sample.pitch),
            sample.pitch_rate,
        )
        return tau + self.energy_gain * (energy - self.target_energy)
