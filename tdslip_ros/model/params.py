"""Physical parameters, apex states and stance commands of the TD-SLIP hopper.

Everything here is SI. The dimensionless quantities of the paper (eq. 24) are
produced only by :mod:`tdslip_ros.model.units`, the single conversion boundary.

Sign convention (the one of the paper's eqs. 2, 6, 7; see shared/paper/NOTES.md):

* body position relative to the toe: ``(x_b - x_toe, y_b) = (-r sin(theta), r cos(theta))``;
* forward running (+x) touches down with ``theta_td = beta > 0`` and theta *decreases*
  through stance (``thetadot < 0``);
* hip power is ``tau * thetadot``, so forward thrust needs ``tau < 0``.

A rigid body (:class:`RigidBody`, docs/rotating_body.md) adds the body's pitch ``phi``, counter-clockwise in
the same plane (x forward, y up) as theta: the hip motor's torque acts on the leg and, reversed, on the body,
and its power is ``tau * (thetadot - phidot)``. Without one the body is held level (the paper's fixed body).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterator
from dataclasses import dataclass

_SQRT_MAX_FLOAT = math.sqrt(sys.float_info.max)
STANDARD_GRAVITY = 9.81
"""m/s^2, the value the paper's human-like examples use."""
HUMAN_LIKE_MASS = 80.0
"""kg, the body mass of the paper's human-like examples (figs 4-11)."""
HUMAN_LIKE_LEG_LENGTH = 1.0
"""m, the leg's rest length r0 of the paper's examples."""


class ParameterError(ValueError):
    """A parameter, state or command value is out of its domain; the message names the field."""


def _require_finite(name: str, value: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise ParameterError(f"{name} must be a finite number, got {value!r}")
    return value


def _require_positive(name: str, value: float) -> float:
    value = _require_finite(name, value)
    if value <= 0.0:
        raise ParameterError(f"{name} must be positive, got {value!r}")
    return value


def _derived_scales(m: float, k: float, r0: float, g: float) -> Iterator[tuple[str, float]]:
    """The products and ratios of the equations of motion and the unit conversions, one at a time, so
    that a product found to underflow to 0 is refused before a division by it is reached."""
    yield "m g r0 (the energy and torque scale)", m * g * r0
    yield "k/m (omega0^2)", k / m
    yield "m k", m * k
    yield "m g", m * g
    yield "m r0^2 (the leg's inertia)", m * r0 * r0
    yield "g/r0", g / r0
    yield "k r0/(m g) (kbar)", k * r0 / (m * g)


@dataclass(frozen=True)
class RigidBody:
    """A body that rotates freely in pitch instead of the paper's fixed body (docs/rotating_body.md).

    inertia [kg m^2] is the pitch inertia J about the centre of mass. (hip_x, hip_y) [m] is the hip's offset
    from the centre of mass in the body's frame, which is the world's (x forward, y up) at pitch 0: an upright
    trunk with its hip below the centre of mass has hip_y < 0, a horizontal body with its hip behind it
    hip_x < 0. tip_limit [rad] bounds |pitch|: a body that tips past it fails (``tipped``).

    Refused (ParameterError naming the field): non-numbers, non-finite values, inertia <= 0, and a tip_limit
    outside (0, pi].
    """

    inertia: float
    hip_x: float = 0.0
    hip_y: float = 0.0
    tip_limit: float = math.pi / 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "inertia", _require_positive("body inertia", self.inertia))
        for name in ("hip_x", "hip_y"):
            object.__setattr__(self, name, _require_finite(f"body {name}", getattr(self, name)))
        tip_limit = _require_positive("body tip_limit", self.tip_limit)
        if tip_limit > math.pi:
            raise ParameterError(f"body tip_limit must lie in (0, pi] rad, got {tip_limit!r}")
        object.__setattr__(self, "tip_limit", tip_limit)

    @classmethod
    def from_gyration(
        cls, m: float, radius: float, hip_x: float = 0.0, hip_y: float = 0.0, tip_limit: float = math.pi / 2
    ) -> RigidBody:
        """The body of mass m [kg] with radius of gyration ``radius`` [m]: inertia m radius^2."""
        return cls(
            _require_positive("m", m) * _require_positive("radius of gyration", radius) ** 2,
            hip_x,
            hip_y,
            tip_limit,
        )


@dataclass(frozen=True)
class HopperParams:
    """Mass m [kg], leg stiffness k [N/m], rest length r0 [m], damping c [N s/m], gravity g [m/s^2], and the
    body: None for the paper's fixed body (a point mass at the hip), else a :class:`RigidBody`.

    Refused (ParameterError naming the field): non-numbers, non-finite values, m, k, r0, g <= 0, c < 0,
    and values whose products and ratios in the equations of motion and the unit conversions leave the
    range of normal doubles (m = k = 1e-300 makes m k = 0, and zeta0 a division by zero). What is legal
    but implausible (an overdamped leg) is for :mod:`tdslip_ros.model.limits` to judge.
    """

    m: float
    k: float
    r0: float
    c: float
    g: float = STANDARD_GRAVITY
    body: RigidBody | None = None

    def __post_init__(self) -> None:
        if self.body is not None and not isinstance(self.body, RigidBody):
            raise ParameterError(f"body must be a RigidBody or None, got {self.body!r}")
        for name in ("m", "k", "r0", "g"):
            object.__setattr__(self, name, _require_positive(name, getattr(self, name)))
        c = _require_finite("c", self.c)
        if c < 0.0:
            raise ParameterError(f"c (damping) must be non-negative, got {c!r}")
        object.__setattr__(self, "c", c)
        m, k, r0, g = self.m, self.k, self.r0, self.g
        for what, value in _derived_scales(m, k, r0, g):
            if not sys.float_info.min <= value < math.inf:
                raise ParameterError(
                    f"m = {m!r}, k = {k!r}, r0 = {r0!r}, g = {g!r} are out of the floating-point range: "
                    f"{what} = {value!r}"
                )
        if not math.isfinite(self.zeta0):
            raise ParameterError(f"c = {c!r} N s/m is out of the floating-point range: zeta0 = {self.zeta0}")

    @classmethod
    def from_dimensionless(
        cls,
        kbar: float,
        zeta0: float,
        m: float = HUMAN_LIKE_MASS,
        r0: float = HUMAN_LIKE_LEG_LENGTH,
        g: float = STANDARD_GRAVITY,
        body: RigidBody | None = None,
    ) -> HopperParams:
        """Build from the paper's kbar = k r0/(m g) and zeta0 = c/(2 sqrt(m k)) (eq. 24)."""
        kbar = _require_positive("kbar", kbar)
        zeta0 = _require_finite("zeta0", zeta0)
        if zeta0 < 0.0:
            raise ParameterError(f"zeta0 (damping ratio) must be non-negative, got {zeta0!r}")
        m = _require_positive("m", m)
        r0 = _require_positive("r0", r0)
        g = _require_positive("g", g)
        k = kbar * m * g / r0
        return cls(m=m, k=k, r0=r0, c=2.0 * zeta0 * math.sqrt(m * k), g=g, body=body)

    @property
    def kbar(self) -> float:
        """Dimensionless stiffness k r0 / (m g)."""
        return self.k * self.r0 / (self.m * self.g)

    @property
    def zeta0(self) -> float:
        """Damping ratio c / (2 sqrt(m k))."""
        return self.c / (2.0 * math.sqrt(self.m * self.k))

    @property
    def omega0(self) -> float:
        """Natural frequency sqrt(k/m) of the leg spring [rad/s]."""
        return math.sqrt(self.k / self.m)

    def require_fixed_body(self, engine: str) -> None:
        """ParameterError if this hopper has a rigid body, which ``engine`` does not run yet."""
        if self.body is not None:
            raise ParameterError(
                f"{engine} runs the paper's fixed body only; a rigid body runs on the exact map "
                f"(tdslip_ros.model.plant.exact_map), the 1 kHz stepper and the batched engine's "
                f"batch_apex_return_map for now"
            )


@dataclass(frozen=True)
class ApexState:
    """Apex of flight: height y [m] and forward speed xdot [m/s] (vertical speed is zero); with a rigid body
    (:class:`RigidBody`) also its pitch [rad] and pitch_rate [rad/s], which a fixed body keeps at 0."""

    y: float
    xdot: float
    pitch: float = 0.0
    pitch_rate: float = 0.0

    def __post_init__(self) -> None:
        y = _require_positive("apex height y", self.y)
        xdot = _require_finite("apex speed xdot", self.xdot)
        # Energies must stay finite for any hopper: xdot^2 and y are bounded by the square root of the
        # largest double. What is implausible for a given hopper, the hopper's PlausibilityLimits judge
        # where the apex meets it: every map and the stepper refuse an apex beyond them.
        for name, value, unit in (("apex height y", y, "m"), ("apex speed xdot", xdot, "m/s")):
            if not abs(value) < _SQRT_MAX_FLOAT:
                raise ParameterError(
                    f"{name} = {value!r} {unit} is out of the floating-point range (|{name.split()[-1]}| < "
                    f"{_SQRT_MAX_FLOAT:.3g})"
                )
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "xdot", xdot)
        for name in ("pitch", "pitch_rate"):
            value = _require_finite(f"apex {name}", getattr(self, name))
            if not abs(value) < _SQRT_MAX_FLOAT:
                raise ParameterError(f"apex {name} = {value!r} is out of the floating-point range")
            object.__setattr__(self, name, value)

    def energy(self, params: HopperParams) -> float:
        """Total mechanical energy m xdot^2/2 + m g y [J] (the spring is at rest in flight), plus the body's
        J pitch_rate^2 / 2 with a rigid body."""
        energy = 0.5 * params.m * self.xdot**2 + params.m * params.g * self.y
        return energy if params.body is None else energy + 0.5 * params.body.inertia * self.pitch_rate**2

    @classmethod
    def from_height_energy(cls, params: HopperParams, y: float, energy: float) -> ApexState:
        """The forward-running apex state with height y [m] and total energy [J] (eq. 23 coordinates)."""
        y = _require_positive("apex height y", y)
        energy = _require_finite("apex energy", energy)
        kinetic = energy - params.m * params.g * y
        if kinetic < 0.0:
            raise ParameterError(
                f"apex energy {energy!r} J is below the potential energy m g y = "
                f"{params.m * params.g * y!r} J at height {y!r} m"
            )
        return cls(y=y, xdot=math.sqrt(2.0 * kinetic / params.m))


@dataclass(frozen=True)
class StanceCommand:
    """What the hip does in the coming stance.

    touchdown_angle [rad] is theta_td in (0, pi/2); the ramp torque of eq. 18 is
    tau(t) = tau0 (1 - t/t_f) for 0 <= t <= t_f and 0 afterwards, tau0 in N m (negative
    for forward thrust), t_f in s.
    """

    touchdown_angle: float
    tau0: float
    t_f: float

    def __post_init__(self) -> None:
        angle = _require_finite("touchdown_angle", self.touchdown_angle)
        if not 0.0 < angle < math.pi / 2:
            raise ParameterError(f"touchdown_angle must lie in (0, pi/2) rad, got {angle!r}")
        object.__setattr__(self, "touchdown_angle", angle)
        object.__setattr__(self, "tau0", _require_finite("tau0", self.tau0))
        object.__setattr__(self, "t_f", _require_positive("t_f", self.t_f))
