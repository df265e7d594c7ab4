"""The constant stance command of a plant-only run (``tdslip simulate``): tau0 and t_f chosen once, before the
run, so that the hip replaces the losses of the first stride (t_f that stride's stance duration, the
paper's t_f = t_lo, and tau0 a root of E_1 - E_0 on the exact return map).
"""

from __future__ import annotations

import math

from scipy.optimize import brentq

from tdslip_ros.model import units
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map

_CALIBRATION_ROUNDS = 4
_MAX_THRUST = 3.0  # most forward torque tried by the calibration, in units of m g r0


def energy_neutral_command(
    params: HopperParams, apex: ApexState, touchdown_angle: float, t_f: float | None = None
) -> StanceCommand:
    """The constant command whose first stride from ``apex`` returns to the same apex energy.

    With t_f None, t_f is set to the stance duration of that stride. Raises ParameterError when no
    forward torque up to 3 m g r0 balances the first stride's losses.
    """
    duration = math.pi / params.omega0 if t_f is None else t_f  # half a spring period to start
    tau0 = 0.0
    thrust_limit = -_MAX_THRUST * units.energy_scale(params)

    def energy_gain(torque: float) -> float:
        result = apex_return_map(params, apex, StanceCommand(touchdown_angle, torque, duration), rtol=1e-10)
        if result.energy is None:  # failed before liftoff: the stride gained nothing usable
            return -units.energy_scale(params)
        return result.energy.net_gain

    for _ in range(_CALIBRATION_ROUNDS if t_f is None else 1):
        if energy_gain(0.0) * energy_gain(thrust_limit) > 0.0:
            raise ParameterError(
                f"no tau0 in [{thrust_limit:.4g}, 0] N m replaces the first stride's losses from {apex} "
                f"at a touchdown angle of {math.degrees(touchdown_angle):.4g} deg; give --tau0 and --t-f"
            )
        tau0 = brentq(energy_gain, thrust_limit, 0.0, xtol=1e-9)
        result = apex_return_map(params, apex, StanceCommand(touchdown_angle, tau0, duration))
        if t_f is None and result.liftoff is not None and result.touchdown is not None:
            duration = result.liftoff.t - result.touchdown.t
    return StanceCommand(touchdown_angle, tau0, duration)
