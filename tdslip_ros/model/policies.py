"""The stance policies by name, with their settings: what the controller node and the offline analysis choose.

A :class:`PolicySpec` names one of :data:`POLICIES` with the values of its settings and answers apexes with
the policy's commands (:mod:`tdslip_ros.model.controllers`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy.typing as npt

from tdslip_ros.model import units
from tdslip_ros.model.arrays import CommandArrays
from tdslip_ros.model.controllers import (
    deadbeat,
    energy_regulation,
    exact_energy_regulation,
    fixed_power,
    pd_speed_energy_height,
)
from tdslip_ros.model.params import HopperParams

POLICIES = ("open_loop", "energy", "energy_exact", "deadbeat", "pd")
FIXED_ANGLE_POLICIES = ("open_loop", "energy", "energy_exact")
"""Policies that touch down at the fixed ``touchdown_angle``."""
TARGET_APEX_POLICIES = ("deadbeat", "pd")
"""Policies that steer towards the target apex (``target_height``, ``target_speed``)."""


class PolicyError(ValueError):
    """The policy settings are incomplete or unknown."""


@dataclass(frozen=True)
class PolicySpec:
    """A named policy with its settings (SI; the controller node's parameters), in one place for the
    controller node and the offline analysis. ``source`` says where the settings came from."""

    name: str
    touchdown_angle: float
    touchdown_power: float
    target_energy: float
    target_height: float
    target_speed: float
    pd_kp: float
    pd_kd: float
    corrections: int
    source: str = ""

    def commands(
        self, params: HopperParams, y: npt.ArrayLike, xdot: npt.ArrayLike, previous_xdot: npt.ArrayLike
    ) -> CommandArrays:
        """The policy's commands at apexes (y, xdot), vectorised; previous_xdot is used by ``pd`` only."""
        if self.name == "open_loop":
            alpha = units.power_to_alpha(params, self.touchdown_power)
            return fixed_power(params, y, xdot, self.touchdown_angle, alpha, self.corrections)
        if self.name == "energy":
            return energy_regulation(
                params, y, xdot, self.touchdown_angle, self.target_energy, self.corrections
            )
        if self.name == "energy_exact":
            return exact_energy_regulation(
                params, y, xdot, self.touchdown_angle, self.target_energy, self.corrections
            )
        if self.name == "deadbeat":
            return deadbeat(params, y, xdot, self.target_height, self.target_speed, self.corrections)
        if self.name == "pd":
            return pd_speed_energy_height(
                params,
                y,
                xdot,
                previous_xdot,
                self.target_height,
                self.target_speed,
                kp=self.pd_kp,
                kd=self.pd_kd,
                corrections=self.corrections,
            )
        raise PolicyError(f"unknown policy {self.name!r}; one of {', '.join(POLICIES)}")

    @classmethod
    def settings(cls) -> tuple[str, ...]:
        """The names of the settings: the controller node's parameters of the same names."""
        return tuple(field.name for field in fields(cls) if field.name not in ("name", "source"))

    @classmethod
    def of(cls, name: str, values: Mapping[str, str | float], source: str = "") -> PolicySpec:
        """A spec from setting values as parameters or text give them: ``corrections`` an int, the rest
        floats."""
        converted: dict[str, Any] = {key: float(values[key]) for key in cls.settings()}
        converted["corrections"] = int(values["corrections"])
        return cls(name=name, source=source, **converted)

    @property
    def target(self) -> tuple[float, float] | None:
        """The target apex (y, xdot) of a policy that has one."""
        if self.name in TARGET_APEX_POLICIES:
            return self.target_height, self.target_speed
        return None
