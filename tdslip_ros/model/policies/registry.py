"""The stance policies by name, and their settings declared once.

:data:`POLICY_SETTINGS` declares every setting of the policies: name, type, SI unit, range (or, for a
text setting, its choices), default, one line of description and the policies that use it. Whatever lists
the settings derives from it: the controller node's parameters (a parameter per setting, of the same name),
the study designs' policy columns (:mod:`tdslip_ros.studies.design`), the analysis report's account of a
policy; config/controller.yaml, which users edit, is checked against it (test/test_policies_settings.py). A
:class:`PolicySpec` names one of :data:`POLICIES` with a value for each setting and answers apexes with the
policy's commands (:mod:`tdslip_ros.model.policies.controllers`).

The policies of :data:`POLICIES` answer an apex with a ramp (a touchdown angle, tau0 and t_f). Those of
:data:`STANCE_FEEDBACK_POLICIES` answer it with stance feedback instead (:mod:`.stance_laws`): a touchdown
angle and a law that decides the hip torque at every tick of the stance (:meth:`PolicySpec.stance_feedback`).
In the node suite a controller of its own serves them (``nodes/stance_controller_node.py``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy.typing as npt

from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import ANALYTIC_MAPS, DEFAULT_ANALYTIC_MAP, SpeedSource
from tdslip_ros.model.arrays import CommandArrays
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams
from tdslip_ros.model.plant.stance_laws import StanceFeedback
from tdslip_ros.model.policies import learned
from tdslip_ros.model.policies.controllers import (
    FOOT_PLACEMENT_KD,
    FOOT_PLACEMENT_KP,
    apex_foot_placement,
    deadbeat,
    energy_regulation,
    exact_energy_regulation,
    fixed_power,
)
from tdslip_ros.model.policies.posture import (
    DEFAULT_DAMPING_RATIO,
    DEFAULT_NATURAL_FREQUENCY,
    PostureRegulation,
)
from tdslip_ros.model.policies.stance_pd import (
    DEFAULT_ENERGY_GAIN,
    DEFAULT_SPEED_GAIN,
    DEFAULT_SPEED_RATE_GAIN,
    StancePDSpeedEnergy,
)

LEARNED = "learned"
"""A learned linear residual on a base policy, read from the file ``policy_file`` (:mod:`.learned`)."""
POLICIES = ("open_loop", "energy", "energy_exact", "deadbeat", "apex_foot_placement", LEARNED)
"""The policies that answer an apex with a ramp command (:meth:`PolicySpec.commands`)."""
STANCE_PD_SPEED_ENERGY = "stance_pd_speed_energy"
"""The baseline of the paper's ref. 36: an energy term for height and PD on forward speed, fed back at every
tick of the stance (:class:`.stance_pd.StancePDSpeedEnergy`), at a fixed touchdown angle."""
POSTURE = "posture"
"""For a rigid body (docs/rotating_body.md): the paper's energy regulation planned on the hip, at a fixed
touchdown angle, with a stance PD that holds the balancing lean (:class:`.posture.PostureRegulation`)."""
STANCE_FEEDBACK_POLICIES = (STANCE_PD_SPEED_ENERGY, POSTURE)
"""The policies that answer an apex with stance feedback (:meth:`PolicySpec.stance_feedback`)."""
FIXED_ANGLE_POLICIES = ("open_loop", "energy", "energy_exact")
"""Policies that touch down at the fixed ``touchdown_angle``."""
TARGET_APEX_POLICIES = ("deadbeat", "apex_foot_placement")
"""Policies that steer towards the target apex (``target_height``, ``target_speed``)."""
ANALYTIC_MAP_POLICIES = ("open_loop", "energy", "deadbeat", "apex_foot_placement")
"""Policies that plan on the analytic map (``analytic_map``); energy_exact plans on the exact plant's."""
DEFAULT_POLICY = "energy"
"""The policy of the controller node and of a study where none is chosen."""

DEFAULT_APEX_HEIGHT = 1.0
"""m; with DEFAULT_APEX_SPEED [m/s], the apex the default settings are made for (the node suite's runs
start there): energy regulation holds its energy on the paper's hopper, deadbeat and apex_foot_placement
steer towards it."""
DEFAULT_APEX_SPEED = 5.0
DEFAULT_TOUCHDOWN_ANGLE = math.radians(20.0)
"""rad; under energy regulation the default apex (1 m, 5 m/s) converges fast (exact |lambda| = 0.08)."""
DEFAULT_STANCE_TOUCHDOWN_ANGLE = math.radians(22.0)
"""rad; the baseline's touchdown angle: with the default gains, targets of 1.2 m and 4 to 7 m/s settle
within 2.1 % of their speed on the paper's hopper (:mod:`.stance_laws`; the angle nearly pins the height)."""
DEFAULT_TARGET_ENERGY = PAPER_PARAMS.m * (PAPER_PARAMS.g * DEFAULT_APEX_HEIGHT + 0.5 * DEFAULT_APEX_SPEED**2)
"""J, the energy of the default apex: energy regulation then keeps the hopper's energy."""


@dataclass(frozen=True)
class PolicySetting:
    """One setting of the policies, used by ``policies``: a number of type ``kind`` (float or int) in [lower,
    upper], in ``unit`` (SI; "" where it has none), or a text (``kind`` str) that is one of ``choices``, with
    no range (lower and upper None) and no unit. A text without choices is free (a file path), default ""."""

    name: str
    kind: type[float] | type[int] | type[str]
    unit: str
    lower: float | None
    upper: float | None
    default: float | str
    description: str
    policies: tuple[str, ...]
    choices: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if type(self.default) is not self.kind:
            raise ValueError(f"{self.name}: default {self.default!r} is not a {self.kind.__name__}")
        if self.kind is str:
            if self.lower is not None or self.upper is not None or self.unit:
                raise ValueError(f"{self.name}: a text setting has choices, not a range or a unit")
            if self.default not in (self.choices or ("",)):
                raise ValueError(f"{self.name}: default {self.default!r} is not one of {self.choices}")
        else:
            if self.choices or self.lower is None or self.upper is None:
                raise ValueError(f"{self.name}: a number setting has a range, not choices")
            if not self.lower <= float(self.default) <= self.upper:
                raise ValueError(f"{self.name}: default {self.default!r} is not in range")
        if not set(self.policies) <= {*POLICIES, *STANCE_FEEDBACK_POLICIES}:
            raise ValueError(f"{self.name}: unknown policies in {self.policies}")

    @property
    def text(self) -> str:
        """The setting in one line: the policies that use it (unless all do), its description, its unit."""
        users = "" if self.policies == POLICIES else f"{', '.join(self.policies)}: "
        unit = f" [{self.unit}]" if self.unit else ""
        return f"{users}{self.description}{unit}"


POLICY_SETTINGS: tuple[PolicySetting, ...] = (
    PolicySetting(
        "touchdown_angle",
        float,
        "rad",
        1e-6,
        1.5707953,
        DEFAULT_TOUCHDOWN_ANGLE,
        "touchdown angle beta",
        FIXED_ANGLE_POLICIES,
    ),
    PolicySetting("touchdown_power", float, "W", 0.0, 1e7, 925.0, "hip power C at touchdown", ("open_loop",)),
    PolicySetting(
        "target_energy",
        float,
        "J",
        1e-6,
        1e9,
        DEFAULT_TARGET_ENERGY,
        "apex energy to hold (posture: the hip's, m g y_hip + m xdot^2 / 2)",
        ("energy", "energy_exact", POSTURE),
    ),
    PolicySetting(
        "target_height",
        float,
        "m",
        1e-3,
        1e2,
        DEFAULT_APEX_HEIGHT,
        "target apex height",
        (*TARGET_APEX_POLICIES, STANCE_PD_SPEED_ENERGY),
    ),
    PolicySetting(
        "target_speed",
        float,
        "m/s",
        0.0,
        1e2,
        DEFAULT_APEX_SPEED,
        "target apex speed",
        (*TARGET_APEX_POLICIES, STANCE_PD_SPEED_ENERGY),
    ),
    PolicySetting(
        "foot_placement_kp",
        float,
        "rad/(m/s)",
        0.0,
        10.0,
        FOOT_PLACEMENT_KP,
        "proportional gain on speed error",
        ("apex_foot_placement",),
    ),
    PolicySetting(
        "foot_placement_kd",
        float,
        "rad/(m/s)",
        0.0,
        10.0,
        FOOT_PLACEMENT_KD,
        "derivative gain on speed change per stride",
        ("apex_foot_placement",),
    ),
    PolicySetting(
        "corrections",
        int,
        "",
        0,
        10,
        1,
        "correction iterations of the analytic map the policies plan with",
        POLICIES,
    ),
    PolicySetting(
        "analytic_map",
        str,
        "",
        None,
        None,
        DEFAULT_ANALYTIC_MAP,
        "analytic map planned on: ours (next apex speed from the energy balance) or paper (from eq. 7)",
        ANALYTIC_MAP_POLICIES,
        choices=tuple(ANALYTIC_MAPS),
    ),
    PolicySetting(
        "policy_file",
        str,
        "",
        None,
        None,
        "",
        "the learned policy's file (JSON, model/policies/learned.py)",
        (LEARNED,),
    ),
    PolicySetting(
        "stance_touchdown_angle",
        float,
        "rad",
        1e-6,
        1.5707953,
        DEFAULT_STANCE_TOUCHDOWN_ANGLE,
        "fixed touchdown angle of the stance feedback",
        STANCE_FEEDBACK_POLICIES,
    ),
    PolicySetting(
        "stance_energy_gain",
        float,
        "N m/J",
        0.0,
        1e3,
        DEFAULT_ENERGY_GAIN,
        "k_E: torque per joule of stance energy above the target apex's",
        (STANCE_PD_SPEED_ENERGY,),
    ),
    PolicySetting(
        "stance_speed_gain",
        float,
        "N s",
        0.0,
        1e6,
        DEFAULT_SPEED_GAIN,
        "k_p: torque per m/s of forward speed above the target",
        (STANCE_PD_SPEED_ENERGY,),
    ),
    PolicySetting(
        "stance_speed_rate_gain",
        float,
        "N s^2",
        0.0,
        1e4,
        DEFAULT_SPEED_RATE_GAIN,
        "k_d: torque per m/s^2 of forward acceleration",
        (STANCE_PD_SPEED_ENERGY,),
    ),
    PolicySetting(
        "posture_natural_frequency",
        float,
        "rad/s",
        1e-3,
        1e4,
        DEFAULT_NATURAL_FREQUENCY,
        "omega of the stance PD about the lean (gains J omega^2 and 2 zeta J omega)",
        (POSTURE,),
    ),
    PolicySetting(
        "posture_damping_ratio",
        float,
        "",
        0.0,
        1e2,
        DEFAULT_DAMPING_RATIO,
        "zeta of the stance PD about the lean",
        (POSTURE,),
    ),
)
"""Every setting of the policies, in the order the controller's parameters and a study's columns take."""
SETTING_DEFAULTS: Mapping[str, float | str] = MappingProxyType(
    {setting.name: setting.default for setting in POLICY_SETTINGS}
)
"""Each setting's default, by name."""


def settings_of(policy: str) -> tuple[PolicySetting, ...]:
    """The settings ``policy`` uses."""
    return tuple(setting for setting in POLICY_SETTINGS if policy in setting.policies)


class PolicyError(ValueError):
    """The policy settings are incomplete or unknown."""


@dataclass(frozen=True)
class PolicySpec:
    """A named policy with a value for each of :data:`POLICY_SETTINGS` (its fields, in their order), in one
    place for the controller node, the studies and the offline analysis. ``source`` says where the values
    came from."""

    name: str
    touchdown_angle: float
    touchdown_power: float
    target_energy: float
    target_height: float
    target_speed: float
    foot_placement_kp: float
    foot_placement_kd: float
    corrections: int
    analytic_map: str
    policy_file: str
    stance_touchdown_angle: float
    stance_energy_gain: float
    stance_speed_gain: float
    stance_speed_rate_gain: float
    posture_natural_frequency: float
    posture_damping_ratio: float
    source: str = ""

    def __post_init__(self) -> None:
        if self.analytic_map not in ANALYTIC_MAPS:
            raise PolicyError(
                f"unknown analytic_map {self.analytic_map!r}; one of {', '.join(ANALYTIC_MAPS)}"
            )

    @property
    def speed(self) -> SpeedSource:
        """The next apex speed of the analytic map the policy plans on (``analytic_map``)."""
        return ANALYTIC_MAPS[self.analytic_map]

    def commands(
        self, params: HopperParams, y: npt.ArrayLike, xdot: npt.ArrayLike, previous_xdot: npt.ArrayLike
    ) -> CommandArrays:
        """The policy's commands at apexes (y, xdot), vectorised; previous_xdot is used by
        ``apex_foot_placement`` only."""
        if self.name == "open_loop":
            alpha = units.power_to_alpha(params, self.touchdown_power)
            return fixed_power(
                params, y, xdot, self.touchdown_angle, alpha, self.corrections, speed=self.speed
            )
        if self.name == "energy":
            return energy_regulation(
                params, y, xdot, self.touchdown_angle, self.target_energy, self.corrections, speed=self.speed
            )
        if self.name == "energy_exact":
            return exact_energy_regulation(
                params, y, xdot, self.touchdown_angle, self.target_energy, self.corrections
            )
        if self.name == "deadbeat":
            return deadbeat(
                params, y, xdot, self.target_height, self.target_speed, self.corrections, speed=self.speed
            )
        if self.name == "apex_foot_placement":
            return apex_foot_placement(
                params,
                y,
                xdot,
                previous_xdot,
                self.target_height,
                self.target_speed,
                kp=self.foot_placement_kp,
                kd=self.foot_placement_kd,
                corrections=self.corrections,
                speed=self.speed,
            )
        if self.name == LEARNED:
            residual, base = self.learned_residual()
            return residual.commands(base.commands(params, y, xdot, previous_xdot), y, xdot)
        if self.name in STANCE_FEEDBACK_POLICIES:
            raise PolicyError(f"{self.name} answers with stance feedback, not a ramp (stance_feedback)")
        raise PolicyError(f"unknown policy {self.name!r}; one of {', '.join(POLICIES)}")

    def learned_residual(self) -> tuple[learned.LinearResidual, PolicySpec]:
        """The learned policy's residual, from the file ``policy_file``, and the spec of its base policy: the
        file's settings, but this spec's corrections (a study's). PolicyError, naming the file and what is
        wrong with it, if it cannot serve."""
        if not self.policy_file:
            raise PolicyError("the learned policy needs its file (policy_file)")
        try:
            residual = learned.load(self.policy_file)
            if residual.base_policy not in POLICIES or residual.base_policy == LEARNED:
                bases = ", ".join(policy for policy in POLICIES if policy != LEARNED)
                raise ValueError(f"its base policy must be one of {bases}, not {residual.base_policy!r}")
            if unknown := sorted(residual.base_settings.keys() - SETTING_DEFAULTS.keys()):
                raise ValueError(f"its base settings name no setting {', '.join(unknown)}")
            values = {**SETTING_DEFAULTS, **residual.base_settings, "corrections": self.corrections}
            base = PolicySpec.of(residual.base_policy, values)
        except (OSError, ValueError, TypeError) as error:
            raise PolicyError(f"the learned policy's file {self.policy_file}: {error}") from None
        return residual, base

    def stance_feedback(self, params: HopperParams, apex: ApexState | None = None) -> StanceFeedback:
        """The stance feedback a policy of :data:`STANCE_FEEDBACK_POLICIES` answers ``apex`` with (its height
        above the ground of the last stance, its speed and pitch as the controller sees them), the law
        computing with ``params`` (the controller's hopper); sampled at the plant node's tick.
        STANCE_PD_SPEED_ENERGY answers every apex alike (``apex`` may be None); POSTURE plans on it."""
        if self.name == POSTURE:
            if apex is None:
                raise PolicyError(f"{POSTURE} plans on the apex it answers (stance_feedback(params, apex))")
            posture = PostureRegulation(
                self.stance_touchdown_angle,
                self.target_energy,
                self.posture_natural_frequency,
                self.posture_damping_ratio,
            )
            return posture(params, apex)
        if self.name != STANCE_PD_SPEED_ENERGY:
            raise PolicyError(f"{self.name} answers with a ramp, not stance feedback (commands)")
        law = StancePDSpeedEnergy(
            params,
            self.target_height,
            self.target_speed,
            self.stance_energy_gain,
            self.stance_speed_gain,
            self.stance_speed_rate_gain,
        )
        return StanceFeedback(self.stance_touchdown_angle, law)

    @classmethod
    def settings(cls) -> tuple[str, ...]:
        """The names of the settings (:data:`POLICY_SETTINGS`)."""
        return tuple(setting.name for setting in POLICY_SETTINGS)

    @classmethod
    def default(cls, name: str) -> PolicySpec:
        """The policy ``name`` with each setting at its declared default."""
        return cls.of(name, SETTING_DEFAULTS)

    @classmethod
    def of(cls, name: str, values: Mapping[str, str | float], source: str = "") -> PolicySpec:
        """A spec from setting values as parameters or text give them, each converted to its setting's
        type."""
        converted: dict[str, Any] = {
            setting.name: setting.kind(values[setting.name]) for setting in POLICY_SETTINGS
        }
        return cls(name=name, source=source, **converted)

    @property
    def target(self) -> tuple[float, float] | None:
        """The target apex (y, xdot) of a policy that has one."""
        if self.name in TARGET_APEX_POLICIES:
            return self.target_height, self.target_speed
        return None


def check_policy_file(policy_file: str) -> None:
    """PolicyError, naming the file and what is wrong with it, unless the learned policy can serve from
    ``policy_file``: the commands that start nodes or workers refuse a bad file before anything runs."""
    PolicySpec.of(LEARNED, {**SETTING_DEFAULTS, "policy_file": policy_file}).learned_residual()
