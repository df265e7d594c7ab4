"""The one boundary between SI (used everywhere inside) and the paper's dimensionless units (eq. 24).

ybar = y/r0, xdotbar = xdot/sqrt(g r0), Ebar = E/(m g r0), taubar = tau/(m g r0),
alpha = C/(m g sqrt(g r0)) for a power C.
The functions accept floats or numpy arrays.
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

from tdslip_ros.model.params import HopperParams

Scalar = TypeVar("Scalar", float, np.ndarray)


def length_scale(params: HopperParams) -> float:
    return params.r0


def speed_scale(params: HopperParams) -> float:
    return math.sqrt(params.g * params.r0)


def energy_scale(params: HopperParams) -> float:
    """Also the torque scale: both are m g r0."""
    return params.m * params.g * params.r0


def power_scale(params: HopperParams) -> float:
    return params.m * params.g * math.sqrt(params.g * params.r0)


def height_to_bar(params: HopperParams, y: Scalar) -> Scalar:
    return y / length_scale(params)


def height_from_bar(params: HopperParams, ybar: Scalar) -> Scalar:
    return ybar * length_scale(params)


def speed_to_bar(params: HopperParams, xdot: Scalar) -> Scalar:
    return xdot / speed_scale(params)


def speed_from_bar(params: HopperParams, xdotbar: Scalar) -> Scalar:
    return xdotbar * speed_scale(params)


def energy_to_bar(params: HopperParams, energy: Scalar) -> Scalar:
    return energy / energy_scale(params)


def energy_from_bar(params: HopperParams, ebar: Scalar) -> Scalar:
    return ebar * energy_scale(params)


def torque_to_bar(params: HopperParams, tau: Scalar) -> Scalar:
    return tau / energy_scale(params)


def torque_from_bar(params: HopperParams, taubar: Scalar) -> Scalar:
    return taubar * energy_scale(params)


def power_to_alpha(params: HopperParams, power: Scalar) -> Scalar:
    return power / power_scale(params)


def power_from_alpha(params: HopperParams, alpha: Scalar) -> Scalar:
    return alpha * power_scale(params)
