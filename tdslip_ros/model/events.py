"""Records of the hopper's state, its hybrid events and its named failures (no physics here).

Failures are data, never exceptions: an integrator that meets one returns it by name with a
human-readable reason. Their meaning, shared by every integrator in this package:

* ``toe_stubbing``: touchdown is infeasible: when the leg is placed at the touchdown angle (at the apex),
  the toe is already below the ground under it (on flat ground: the body is below the touchdown height
  ``r0 cos(theta_td)``, the apex is too low for the commanded angle);
* ``no_liftoff``: the stance lasts longer than ``max_stance_time`` of the plausibility limits (by default
  :func:`tdslip_ros.model.dynamics.max_stance_duration`) without liftoff, fall or reversal;
* ``fall``: the body height ``r cos(theta)`` reaches 0 in stance (leg horizontal or fully
  compressed), or the leg lifts off with ``ydot <= 0`` so that the coming flight has no apex;
* ``reversal``: the motion turns back: ``thetadot >= 0`` in stance (at touchdown or later, the
  body swings back over the toe), or the leg lifts off with ``xdot <= 0`` (apex speed <= 0);
* ``state_limit``: the motion leaves the hopper's plausibility limits
  (:class:`tdslip_ros.model.limits.PlausibilityLimits`): the leg touches down under a ramp torque beyond
  the actuator limit, lifts off towards an apex beyond the height or speed bounds, or a push at the apex
  takes the speed beyond its bound;
* ``tipped``: a rigid body (:class:`tdslip_ros.model.params.RigidBody`) pitches past its tip_limit, in
  stance or in flight.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class EventKind(enum.Enum):
    TOUCHDOWN = "touchdown"
    BOTTOM = "bottom"
    LIFTOFF = "liftoff"
    APEX = "apex"
    FAILURE = "failure"


class FailureKind(enum.StrEnum):
    TOE_STUBBING = "toe_stubbing"
    NO_LIFTOFF = "no_liftoff"
    FALL = "fall"
    REVERSAL = "reversal"
    STATE_LIMIT = "state_limit"
    TIPPED = "tipped"


class Phase(enum.StrEnum):
    FLIGHT = "flight"
    STANCE = "stance"


NO_FAILURE_CODE = -1
"""Failure code of a lane that did not fail; other codes index :data:`FAILURE_KINDS`."""

FAILURE_KINDS: tuple[FailureKind, ...] = tuple(FailureKind)


def failure_code(kind: FailureKind | None) -> int:
    """Integer code of a failure for numpy arrays: its index in FailureKind, or -1 for none."""
    return NO_FAILURE_CODE if kind is None else FAILURE_KINDS.index(kind)


def failure_from_code(code: int) -> FailureKind | None:
    return None if code == NO_FAILURE_CODE else FAILURE_KINDS[code]


@dataclass(frozen=True)
class HopperState:
    """Full state at one instant, SI units.

    stride is the index of the latest apex (the initial apex is stride 0). Positions are in the world
    frame (flat ground at y = 0). In flight the massless leg is shown at rest length and at the touchdown
    angle it will land at (rdot = thetadot = 0), its toe in the air; in stance the toe is fixed at
    (toe_x, toe_y), toe_y the stance's ground height. energy is the total mechanical energy, spring energy
    included, with m g y from the datum y = 0; (grf_x, grf_y) is the ground reaction force acting on the
    body; ground_height is the ground height h(x) under the body. With a rigid body, (x, y) is its centre
    of mass, (r, theta) the leg from the toe to the hip, and pitch [rad] and pitch_rate [rad/s] the body's;
    a fixed body keeps them at 0.
    """

    t: float
    stride: int
    phase: Phase
    x: float
    y: float
    xdot: float
    ydot: float
    toe_x: float
    toe_y: float
    r: float
    theta: float
    rdot: float
    thetadot: float
    hip_torque: float
    energy: float
    grf_x: float
    grf_y: float
    ground_height: float = 0.0
    pitch: float = 0.0
    pitch_rate: float = 0.0


@dataclass(frozen=True)
class StrideEnergy:
    """Energy flows of one stance [J]: hip work int(tau thetadot dt) (int(tau (thetadot - phidot) dt) with a
    rigid body), damper loss int(c rdot^2 dt),
    and the spring energy k (r_lo - r0)^2 / 2 left in the massless leg at liftoff, which is lost."""

    hip_work: float
    damping_loss: float
    spring_loss: float

    @property
    def net_gain(self) -> float:
        """E_{k+1} - E_k, the apex energy change these flows imply."""
        return self.hip_work - self.damping_loss - self.spring_loss


@dataclass(frozen=True)
class Event:
    """A hybrid event at time t [s]; failure and reason are set for EventKind.FAILURE only."""

    kind: EventKind
    t: float
    stride: int
    state: HopperState
    failure: FailureKind | None = None
    reason: str = ""
