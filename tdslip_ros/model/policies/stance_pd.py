"""The baseline of the paper's ref. 36 as a sampled stance law: a hip torque decided at every tick of the
stance from feedback, on the plant's stance-law interface (:mod:`tdslip_ros.model.plant.stance_laws`).

What the paper says of it (section V, fig. 13), all we have of it:

    "Among notable exceptions is recent work on locomotion over mildly rough terrain [36] where the
    authors use TD-SLIP equations of motion to derive an approximate energy controller to regulate hopping
    height, and a PD-based torque policy to regulate forward speed."

    "Note that parameters used by Papadopoulos et al. [36] were also not substantially different from
    ours when converted to dimensionless units."

    "Finally, our controller does not require any feedback or sensory measurements during stance [...]
    compared to the active PD control strategy since high-bandwidth feedback is usually very challenging
    for fast legged robots."

So: one hip torque during stance, with an energy term for height and a PD term on forward speed, computed
from feedback during stance. Where we had to choose (:func:`pd_speed_energy_torque`):

* the energy term drives the stance's mechanical energy E (kinetic, gravitational above the stance's
  ground, spring) toward the target apex's energy E* = m g y* + m xdot*^2 / 2, in proportion to the error:
  tau_E = k_E (E - E*). In stance thetadot < 0, so its power tau_E thetadot = k_E (E* - E) |thetadot|
  pumps energy in below the target and takes it out above (negative work is allowed, unlike the ramp's);
* the speed term is PD on the body's forward speed xdot: tau_v = k_p (xdot - xdot*) + k_d xddot. Forward
  thrust needs tau < 0, so a slow body is pushed. The error's rate xddot is the body's horizontal
  acceleration F_x / m from the ground reaction force (:func:`.dynamics.ground_reaction_force`) of the
  sampled state and the held torque: the model's derivative, not a finite difference, so the law needs no
  memory of past samples;
* the touchdown angle is not the law's: :class:`StanceFeedback` takes it per stride, from whoever plans the
  stride. It matters: the torque puts energy mostly into forward speed, and the angle nearly pins the apex
  height at a given speed. On the paper's hopper with the default gains, target 1.2 m at 4 m/s, from
  1.3 m at 3.5 m/s, 50 strides settle at 1.03 m and 4.10 m/s with the angle at 20 deg, 1.218 m and
  3.967 m/s at 22 deg, 1.40 m and 3.84 m/s at 23 deg. At 22 deg, targets of 1.2 m and 4 to 7 m/s
  settle within 2.1 % of their speeds, of 3.5 down to 2 m/s 6 % to 19 % slow, at heights between
  0.95 m and 1.64 m;
* the defaults (:data:`DEFAULT_ENERGY_GAIN`, :data:`DEFAULT_SPEED_GAIN`, :data:`DEFAULT_SPEED_RATE_GAIN`)
  hold the paper's hopper within 2 % of the target 1.2 m at 4 m/s with the angle at 22 deg
  (``test/test_plant_stance_laws.py``). Sampled, the law's apexes jitter by some 5e-5 m from stride to stride
  about that point, as the touchdown's phase in the tick changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tdslip_ros.model import dynamics
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.plant.stance_laws import StanceSample, finite_field, lane_values

DEFAULT_ENERGY_GAIN = 3.0
"""N m/J: k_E of :func:`pd_speed_energy_torque`; 100 J below the target pushes with 300 N m."""
DEFAULT_SPEED_GAIN = 3000.0
"""N m/(m/s) = N s: k_p; 0.1 m/s too slow pushes with 300 N m."""
DEFAULT_SPEED_RATE_GAIN = 20.0
"""N m/(m/s^2) = N s^2: k_d. The sampled law feeds its held torque back through xddot with the gain
k_d cos(theta) / (m r) per sample (0.25 on the paper's hopper); below 1 that loop decays."""


def pd_speed_energy_torque(
    model: HopperParams,
    target_energy: Any,
    target_xdot: Any,
    energy_gain: Any,
    speed_gain: Any,
    speed_rate_gain: Any,
    r: Any,
    sin_t: Any,
    cos_t: Any,
    rdot: Any,
    thetadot: Any,
    held: Any,
) -> Any:
    """The torque [N m] of :class:`StancePDSpeedEnergy` (module docstring), floats or arrays:

        tau = k_E (E - E*) + k_p (xdot - xdot*) + k_d F_x / m

    E the stance energy of the sampled state, xdot its forward speed, F_x the horizontal ground reaction
    force under the held torque, all in ``model``'s parameters; sin and cos of theta from the caller.
    """
    energy = dynamics.stance_energy(model, r, cos_t, rdot, thetadot)
    xdot, _ = dynamics.cartesian_velocity(r, sin_t, cos_t, rdot, thetadot)
    force_x, _ = dynamics.ground_reaction_force(model, r, sin_t, cos_t, rdot, held)
    return (
        energy_gain * (energy - target_energy)
        + speed_gain * (xdot - target_xdot)
        + speed_rate_gain * force_x / model.m
    )


@dataclass(frozen=True, eq=False)
class StancePDSpeedEnergy:
    """The baseline of the paper's ref. 36 as a sampled law (module docstring): an energy term toward the
    target apex (target_y [m] above the stance's ground, target_xdot [m/s]) and PD on forward speed.

    model: the hopper the law computes with (the plant's, or the controller's under mismatch);
    energy_gain [N m/J], speed_gain [N s], speed_rate_gain [N s^2]. Targets and gains may be arrays over
    the lanes of a batched stride.
    """

    model: HopperParams
    target_y: Any
    target_xdot: Any
    energy_gain: Any = DEFAULT_ENERGY_GAIN
    speed_gain: Any = DEFAULT_SPEED_GAIN
    speed_rate_gain: Any = DEFAULT_SPEED_RATE_GAIN

    def __post_init__(self) -> None:
        for name in ("target_y", "target_xdot", "energy_gain", "speed_gain", "speed_rate_gain"):
            object.__setattr__(self, name, finite_field(name, getattr(self, name)))

    def torque(self, sample: StanceSample, lanes: npt.NDArray[np.int64] | None = None) -> Any:
        model = self.model
        target_y, target_xdot = lane_values(self.target_y, lanes), lane_values(self.target_xdot, lanes)
        target_energy = dynamics.apex_energy(model.m, model.g, target_y, target_xdot)
        if isinstance(sample.theta, float):  # the scalar engines: math is faster than numpy on floats
            sin_t, cos_t = math.sin(sample.theta), math.cos(sample.theta)
        else:
            sin_t, cos_t = np.sin(sample.theta), np.cos(sample.theta)
        return pd_speed_energy_torque(
            model,
            target_energy,
            target_xdot,
            lane_values(self.energy_gain, lanes),
            lane_values(self.speed_gain, lanes),
            lane_values(self.speed_rate_gain, lanes),
            sample.r,
            sin_t,
            cos_t,
            sample.rdot,
            sample.thetadot,
            sample.held,
        )
