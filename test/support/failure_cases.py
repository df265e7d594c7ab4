"""One input per named failure of a stride, shared by the exact map's, the stepper's and the batched
engine's tests (each must report the same failure for the same input); PERTURBED_FAILURE_CASES are the
failures that perturbations cause (test_plant_perturbed_engines.py)."""

from __future__ import annotations

import math
from typing import NamedTuple

from tdslip_ros.model.events import FailureKind
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, StanceCommand
from tdslip_ros.model.plant.perturbations import Perturbations, PlacementNoise, Pushes
from tdslip_ros.model.plant.terrain import Step

PARAMS = PAPER_PARAMS
LOSSLESS = HopperParams.from_dimensionless(36.0, 0.0)


class FailureCase(NamedTuple):
    name: str
    params: HopperParams
    apex: ApexState
    command: StanceCommand
    kind: FailureKind
    phrase: str  # what the exact map's reason must contain


FAILURE_CASES = (
    FailureCase(
        "toe_stubbing: apex below the touchdown height",
        PARAMS,
        ApexState(0.85, 4.0),
        StanceCommand(math.radians(20.0), -300.0, 0.15),
        FailureKind.TOE_STUBBING,
        "below the touchdown height",
    ),
    FailureCase(
        "reversal at touchdown: a slow, steep drop lands with thetadot > 0",
        PARAMS,
        ApexState(1.2, 0.5),
        StanceCommand(math.radians(26.0), -300.0, 0.15),
        FailureKind.REVERSAL,
        "at touchdown",
    ),
    FailureCase(
        "reversal in stance: a braking hip torque swings the body back",
        PARAMS,
        ApexState(1.2, 2.0),
        StanceCommand(math.radians(26.0), 300.0, 0.15),
        FailureKind.REVERSAL,
        "into stance",
    ),
    FailureCase(
        "reversal at liftoff: the leg throws the body backwards",
        PARAMS,
        ApexState(1.2, 2.0),
        StanceCommand(math.radians(26.0), -100.0, 0.15),
        FailureKind.REVERSAL,
        "xdot",
    ),
    FailureCase(
        "fall after liftoff: a long forward torque tips the body over, liftoff while descending",
        PARAMS,
        ApexState(1.0, 1.0),
        StanceCommand(math.radians(10.0), -3000.0, 1.0),
        FailureKind.FALL,
        "no apex",
    ),
    FailureCase(
        "fall in stance: a soft leg collapses to the ground",
        HopperParams.from_dimensionless(1.2, 0.3),
        ApexState(math.cos(0.8) + 0.05, 3.0),
        StanceCommand(0.8, 0.0, 1.0),
        FailureKind.FALL,
        "body height reached 0",
    ),
    FailureCase(
        "no_liftoff: a heavily damped leg balanced upright on a near-vertical touchdown",
        HopperParams.from_dimensionless(36.0, 0.5),
        ApexState(math.cos(1e-6) + 1e-3, 1e-5),
        StanceCommand(1e-6, 0.0, 0.1),
        FailureKind.NO_LIFTOFF,
        "no liftoff",
    ),
    # Issue 9: torques far beyond the actuator limit (20 m g r0 = 15.7 kN m) crashed the stepper ("math
    # domain error" at 1e300, E = inf at 1e100), flew it to 7.7e6 m (1e12), made the exact map drop the
    # torque (|tau0| >= 1e200) or report an apex at 130 km (1e12) while the batch said no_liftoff.
    *(
        FailureCase(
            f"state_limit: tau0 = {tau0:g} N m, beyond the actuator limit, ends the stride at touchdown",
            PARAMS,
            ApexState(1.0, 5.0),
            StanceCommand(math.radians(20.0), tau0, 0.13),
            FailureKind.STATE_LIMIT,
            "actuator limit",
        )
        for tau0 in (-1e12, -1e100, -1e200, -1e300, 1e300, -1.6e4)
    ),
    FailureCase(
        "state_limit: a lossless leg bounces a 9.9 m apex above max_apex_height (10 r0)",
        LOSSLESS,
        ApexState(9.9, 3.0),
        StanceCommand(0.2, 0.0, 0.1),
        FailureKind.STATE_LIMIT,
        "apex height",
    ),
    FailureCase(
        "state_limit: an 8 kN m thrust at 30 m/s lifts off faster than max_apex_speed (10 sqrt(g r0))",
        LOSSLESS,
        ApexState(1.2, 30.0),
        StanceCommand(0.9, -8000.0, 0.05),
        FailureKind.STATE_LIMIT,
        "apex speed",
    ),
)


class PerturbedFailureCase(NamedTuple):
    """A failure that a perturbation causes (stride 0 of trajectory 0 of ``perturbations``)."""

    name: str
    params: HopperParams
    apex: ApexState
    command: StanceCommand
    perturbations: Perturbations
    kind: FailureKind
    phrase: str  # what the exact map's reason must contain


PERTURBED_FAILURE_CASES = (
    PerturbedFailureCase(
        "toe_stubbing: the leg placed at the apex puts its toe inside a 12 cm step up",
        PARAMS,
        ApexState(1.0, 4.0),
        StanceCommand(math.radians(20.0), -300.0, 0.15),
        Perturbations(terrain=Step(0.12, 0.2)),
        FailureKind.TOE_STUBBING,
        "below the ground",
    ),
    PerturbedFailureCase(
        "toe_stubbing: a placement error of -6.8 deg puts the toe below flat ground",
        PARAMS,
        ApexState(0.95, 4.0),
        StanceCommand(math.radians(20.0), -300.0, 0.15),
        Perturbations(placement=PlacementNoise(math.radians(5.0), seed=2)),
        FailureKind.TOE_STUBBING,
        "below the touchdown height",
    ),
    PerturbedFailureCase(
        "reversal in stance: a 1 m step down at a steep 30 deg swings the body back",
        PARAMS,
        ApexState(1.0, 3.0),
        StanceCommand(math.radians(30.0), -273.0, 0.13),
        Perturbations(terrain=Step(-1.0, 0.3)),
        FailureKind.REVERSAL,
        "into stance",
    ),
    PerturbedFailureCase(
        "reversal at touchdown: a push of -6 m/s at the apex sends the body backwards",
        PARAMS,
        ApexState(1.0, 5.0),
        StanceCommand(math.radians(20.0), -273.0, 0.13),
        Perturbations(pushes=Pushes(((0, -6.0),))),
        FailureKind.REVERSAL,
        "at touchdown",
    ),
    PerturbedFailureCase(
        "state_limit: a push of 30 m/s at the apex takes the speed beyond max_apex_speed",
        PARAMS,
        ApexState(1.0, 5.0),
        StanceCommand(math.radians(20.0), -273.0, 0.13),
        Perturbations(pushes=Pushes(((0, 30.0),))),
        FailureKind.STATE_LIMIT,
        "a push of 30 m/s",
    ),
    PerturbedFailureCase(
        "fall: a soft leg under a saturated hip lifts off sinking after a 30 cm step down",
        HopperParams.from_dimensionless(1.2, 0.3),
        ApexState(math.cos(0.5) + 0.05, 3.0),
        StanceCommand(0.5, -200.0, 0.3),
        Perturbations(terrain=Step(-0.3, 0.3), tau_max=50.0),
        FailureKind.FALL,
        "no apex",
    ),
)
