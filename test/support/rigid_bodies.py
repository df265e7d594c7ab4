"""Rigid bodies (issue 36) and a ramp policy that hops them, shared by the 1 kHz stepper's and the batched
engine's tests of a rigid body (test_plant_stepper_rigid_body.py, test_plant_batch_rigid_body.py): each
engine must meet the exact map on the same strides."""

from __future__ import annotations

import math
from collections.abc import Callable

from tdslip_ros.model import body_dynamics
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, RigidBody, StanceCommand

BETA = math.radians(20.0)
TARGET_ENERGY = ApexState(1.2, 4.0).energy(PAPER_PARAMS)


def with_body(body: RigidBody, params: HopperParams = PAPER_PARAMS) -> HopperParams:
    return HopperParams(params.m, params.k, params.r0, params.c, params.g, body)


def hip_regulator(params: HopperParams) -> Callable[[ApexState], StanceCommand]:
    """The proportional energy regulator of test_plant_stepper.py on the hip's height, with pitch and
    pitch-rate terms on tau0 (found by trial): a ramp per stride that keeps the bodies below hopping for 4-5
    strides while they turn."""
    body = params.body
    assert body is not None

    def command(apex: ApexState) -> StanceCommand:
        hip_y = apex.y + body_dynamics.hip_offset(body, math.sin(apex.pitch), math.cos(apex.pitch))[1]
        energy = params.m * (params.g * hip_y + 0.5 * apex.xdot**2)
        tau0 = -600.0 + 3.0 * (energy - TARGET_ENERGY) + 1000.0 * apex.pitch + 100.0 * apex.pitch_rate
        return StanceCommand(BETA, tau0, 0.15)

    return command


# The hip behind, below, above and far below the centre of mass; inertias from a light trunk's to a heavy
# body's, and the strides they hop from ramp_start under hip_regulator. tip_limit pi: the bodies turn by up to
# 2 rad over the strides, the tests are the engines' accuracy.
RAMP_BODIES = {
    "behind_and_below_J7": (RigidBody(7.2, -0.15, -0.1, math.pi), 4),
    "behind_J20": (RigidBody(20.0, -0.15, 0.0, math.pi), 5),
    "ahead_and_above_J100": (RigidBody(100.0, 0.1, 0.15, math.pi), 5),
    "below_J100": (RigidBody(100.0, 0.0, -0.1, math.pi), 5),
    "far_below_J1000": (RigidBody(1000.0, 0.1, -0.3, math.pi), 5),
}


def ramp_start(body: RigidBody) -> ApexState:
    """The apex the RAMP_BODIES hop from: the hip's at 1.2 m, pitched and turning."""
    return ApexState(1.2 - body.hip_y, 4.0, 0.05, -0.3)


# Bodies that hop under the virtual pivot point (above=0.3, forward=0.03) from the hip's apex at 1 m, 5 m/s.
PIVOT_BODIES = {
    "below": RigidBody.from_gyration(80.0, 0.3, hip_y=-0.2),
    "above": RigidBody.from_gyration(80.0, 0.3, hip_y=0.2),
    "behind_and_below": RigidBody(20.0, -0.1, -0.15),
}

# Each way to tip (the exact map's reason says where), under StanceCommand(22 deg, tau0, 0.15 s): the body,
# the apex, tau0 [N m], the reason's phrase and a max_apex_height [m] of the limits (None: the default).
TIPPING = {
    # tip_limit 0.05: the ramp's reaction turns a light body past it early in the stance.
    "in_stance": (RigidBody(2.0, tip_limit=0.05), ApexState(1.2, 3.0), -40.0, "into stance", None),
    # Turning at -1 rad/s from 0.04 rad: past -0.05 rad after 0.09 s, before touchdown.
    "before_touchdown": (
        RigidBody(2.0, tip_limit=0.05),
        ApexState(1.2, 3.0, 0.04, -1.0),
        -40.0,
        "before touchdown",
        None,
    ),
    # The stance spins the body up to 1.5 rad/s; it passes 0.35 rad in the rise.
    "after_liftoff": (RigidBody(2.0, tip_limit=0.35), ApexState(1.2, 3.0), -40.0, "after liftoff", None),
    # Lifting off at 0.13 rad and 1.1 rad/s towards an apex at 1.20 m, beyond a bound of 1.15 m: the body
    # passes 0.25 rad before that apex, and the exact map says tipped, not state_limit.
    "after_liftoff_towards_an_apex_beyond_the_limits": (
        RigidBody(20.0, tip_limit=0.25),
        ApexState(1.1, 3.0),
        -300.0,
        "after liftoff",
        1.15,
    ),
}
