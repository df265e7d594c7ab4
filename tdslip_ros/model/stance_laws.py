"""Stance feedback: a hip torque that a sampled law decides during stance, instead of the ramp of eq. 18.

**Sampling.** A ROS controller answers the 1 kHz plant with one torque per tick, and the plant holds it
until the next tick (zero-order hold). A law here is therefore *sampled*: at each sample instant it maps
what it sees (:class:`StanceSample`) to a torque that the hip holds until the next sample instant. Every
engine (the exact map, the 1 kHz stepper, the batched engine) integrates the stance piecewise between
sample instants, each one a kink of the torque like the ramp's end t_f.

**The sample grid** is the plant's tick grid in absolute time: the sample instants are the integer
multiples ``n * sample_period`` of the clock on which the run's first apex is at t = 0 (the stepper's
``t``, the plant node's simulated time less its offset after a reset). Touchdown falls inside a tick;
the first sample is the first grid instant at or after it (:func:`first_sample`), and the hip holds
**zero torque from touchdown to the first sample**: the torque of the tick in which the leg touches down
was decided while the body flew, where the hip moves a massless leg, so no stance torque can have been
decided for it (a touchdown exactly on a grid instant is sampled at once). A one-stride engine is put on
the grid by the absolute time of the apex it starts from (``apex_time`` of the exact map and the batched
engine); :func:`tdslip_ros.model.batch.simulate_strides` keeps each lane's apex times itself.

**What a law sees** at a sample: the absolute time t and the time since touchdown s [s], the leg's polar
state about the toe (r [m], theta [rad], rdot [m/s], thetadot [rad/s], in the convention of
:mod:`.params`), and the torque the hip held until that instant [N m] (a controller knows its last
command). Targets and gains are the law's own fields. Cartesian quantities (xdot, ydot, the energy above
the stance's ground) follow from the polar state through :mod:`.dynamics`.

**Perturbations** (:mod:`.perturbations`) reach a law as they reach the ramp's policies. The torque limit
tau_max clips each sample's torque, and so does the plausibility limit max_torque (:mod:`.limits`): a
law cannot be refused at touchdown as a ramp's tau0 is, so the actuator saturates instead, which keeps
every stance within the limits' energy bound. A stride one of whose samples tau_max clipped is
*saturated*. Model mismatch reaches the law through its ``model``, the hopper the law computes with:
build it with ``perturbations.mismatch.controller_params(params)``, as the policies plan with them.
Sensing noise does not reach a law: the package's sensor (:class:`.perturbations.SensingNoise`) reads the
apex only, and a noisy stance sensor would be a perturbation kind of its own.

**Laws.**

* :class:`StancePDSpeedEnergy`, the baseline of the paper's ref. 36 (below);
* :class:`RecordedTorques`, the held torques of a recording, replayed: the exact map reproduces a
  recorded stride from its apex, its apex time and these;
* :class:`TorqueStream`: the torques come from outside, one per sample, through
  :meth:`.stepper.FixedStepStepper.hold_torque` (the plant node's torque topic); only the stepper runs it.

The maths of a law is written once, in arithmetic that takes floats (the scalar engines) and arrays over
lanes (the batched engine) alike; a law's fields may be arrays over the lanes of a batched stride.

**The baseline of ref. 36.** What the paper says of it (section V, fig. 13), all we have of it:

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
  (``test/test_stance_laws.py``). Sampled, the law's apexes jitter by some 5e-5 m from stride to stride
  about that point, as the touchdown's phase in the tick changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np
import numpy.typing as npt

from tdslip_ros.model import dynamics
from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.params import HopperParams, ParameterError

DEFAULT_SAMPLE_PERIOD = 1e-3
"""s: the plant node's tick, the period at which a ROS controller sends torques."""
DEFAULT_ENERGY_GAIN = 3.0
"""N m/J: k_E of :func:`pd_speed_energy_torque`; 100 J below the target pushes with 300 N m."""
DEFAULT_SPEED_GAIN = 3000.0
"""N m/(m/s) = N s: k_p; 0.1 m/s too slow pushes with 300 N m."""
DEFAULT_SPEED_RATE_GAIN = 20.0
"""N m/(m/s^2) = N s^2: k_d. The sampled law feeds its held torque back through xddot with the gain
k_d cos(theta) / (m r) per sample (0.25 on the paper's hopper); below 1 that loop decays."""
RECORD_TIME_TOLERANCE = 1e-9
"""s: a recorded torque stamped this little after a sample instant counts as held from it (a recording's
clock may be rounded, e.g. to nanoseconds)."""


class StanceSample(NamedTuple):
    """What a law sees at a sample instant (floats, or arrays over lanes): the absolute time t and the
    time since touchdown s [s], the polar state (r [m], theta [rad], rdot [m/s], thetadot [rad/s]) and
    the torque held until this instant, ``held`` [N m]."""

    t: Any
    s: Any
    r: Any
    theta: Any
    rdot: Any
    thetadot: Any
    held: Any


class StanceLaw(Protocol):
    """A sampled stance law: the torque [N m] to hold from a sample on (before clipping). ``lanes``, for
    the batched engine, indexes the law's per-lane fields by the lanes of ``sample``; None: scalars."""

    def torque(self, sample: StanceSample, lanes: npt.NDArray[np.int64] | None = None) -> Any: ...


def _lane_values(value: Any, lanes: npt.NDArray[np.int64] | None) -> Any:
    """A law's field for the sampled lanes: itself when scalar, else indexed by ``lanes``."""
    if np.ndim(value) == 0:
        return value
    if lanes is None:
        raise ParameterError("a law with per-lane fields runs only on the batched engine")
    return np.asarray(value, dtype=np.float64)[lanes]


def _finite(name: str, value: Any) -> Any:
    """A law's numeric field, a float or an array of floats; ParameterError naming it."""
    array = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise ParameterError(f"{name} must be finite, got {value!r}")
    return float(array) if array.ndim == 0 else array


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
            object.__setattr__(self, name, _finite(name, getattr(self, name)))

    def torque(self, sample: StanceSample, lanes: npt.NDArray[np.int64] | None = None) -> Any:
        model = self.model
        target_y, target_xdot = _lane_values(self.target_y, lanes), _lane_values(self.target_xdot, lanes)
        target_energy = model.m * (model.g * target_y + 0.5 * target_xdot * target_xdot)
        if isinstance(sample.theta, float):  # the scalar engines: math is faster than numpy on floats
            sin_t, cos_t = math.sin(sample.theta), math.cos(sample.theta)
        else:
            sin_t, cos_t = np.sin(sample.theta), np.cos(sample.theta)
        return pd_speed_energy_torque(
            model,
            target_energy,
            target_xdot,
            _lane_values(self.energy_gain, lanes),
            _lane_values(self.speed_gain, lanes),
            _lane_values(self.speed_rate_gain, lanes),
            sample.r,
            sin_t,
            cos_t,
            sample.rdot,
            sample.thetadot,
            sample.held,
        )


@dataclass(frozen=True, eq=False)
class RecordedTorques:
    """Held torques as a recording gives them: ``torques[i]`` [N m] held from ``times[i]`` [s, the sample
    clock, increasing] on. At a sample instant t the law holds the latest torque recorded at or before t
    (within RECORD_TIME_TOLERANCE), zero before the first record: replayed on the same grid it reproduces
    the torques as applied."""

    times: FloatArray
    torques: FloatArray

    def __post_init__(self) -> None:
        times = np.array(self.times, dtype=np.float64).reshape(-1)
        torques = np.array(self.torques, dtype=np.float64).reshape(-1)
        if times.shape != torques.shape:
            raise ParameterError(f"{times.size} record times for {torques.size} torques")
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(torques))):
            raise ParameterError("recorded times and torques must be finite")
        if np.any(np.diff(times) <= 0.0):
            raise ParameterError("recorded times must increase")
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "torques", torques)

    def torque(self, sample: StanceSample, lanes: npt.NDArray[np.int64] | None = None) -> Any:
        index = np.searchsorted(self.times, np.asarray(sample.t) + RECORD_TIME_TOLERANCE, side="right") - 1
        held = np.where(index >= 0, self.torques[np.maximum(index, 0)], 0.0)
        return float(held) if held.ndim == 0 else held


@dataclass(frozen=True)
class TorqueStream:
    """The torques come from outside, one per sample (:meth:`.stepper.FixedStepStepper.hold_torque`): the
    plant node's stream. It has no maths; the exact map and the batched engine refuse it (to predict a
    streamed stride, replay its recorded torques with :class:`RecordedTorques`)."""

    def torque(self, sample: StanceSample, lanes: npt.NDArray[np.int64] | None = None) -> Any:
        raise ParameterError("a torque stream has no law to evaluate: its torques come from hold_torque")


@dataclass(frozen=True)
class StanceFeedback:
    """A stance under feedback: the leg lands at touchdown_angle [rad] in (0, pi/2), and the hip holds the
    torques ``law`` decides at the sample instants, sample_period [s] apart (module docstring)."""

    touchdown_angle: float
    law: StanceLaw
    sample_period: float = DEFAULT_SAMPLE_PERIOD

    def __post_init__(self) -> None:
        angle = _finite("touchdown_angle", self.touchdown_angle)
        if not 0.0 < angle < math.pi / 2:
            raise ParameterError(f"touchdown_angle must lie in (0, pi/2) rad, got {angle!r}")
        period = _finite("sample_period", self.sample_period)
        if not period > 0.0:
            raise ParameterError(f"sample_period must be positive, got {period!r}")
        object.__setattr__(self, "touchdown_angle", angle)
        object.__setattr__(self, "sample_period", period)


def first_sample(t_touchdown: Any, period: float) -> Any:
    """Grid index n (a float, or an array of them) of the first sample instant n * period at or after the
    touchdown at absolute time t_touchdown [s]; the hip holds zero torque before it."""
    index = np.ceil(np.asarray(t_touchdown) / period)
    index = np.where(index * period < t_touchdown, index + 1.0, index)  # a quotient rounded down
    return float(index) if index.ndim == 0 else index


def torque_limit(tau_max: Any, max_torque: float) -> Any:
    """The torque [N m] a law's output is clipped at: the perturbation's tau_max (None: none; a float, or
    an array over lanes) or the plausibility limit max_torque, whichever is smaller."""
    if tau_max is None:
        return max_torque
    return min(tau_max, max_torque) if isinstance(tau_max, float) else np.minimum(tau_max, max_torque)


def clip_torque(tau: Any, limit: Any) -> Any:
    """tau clipped into [-limit, limit] (floats stay floats: the stepper's path)."""
    if isinstance(tau, float):
        return min(max(tau, -limit), float(limit))
    clipped: FloatArray = np.clip(tau, -limit, limit)
    return clipped


class HeldTorque:
    """The zero-order hold of one stance under feedback in a scalar engine (the exact map, the stepper):
    the torque held now, the grid index of the next sample instant, the samples taken so far and whether
    tau_max clipped one of them. Created at touchdown (absolute time t_touchdown [s]); a touchdown on the
    grid is sampled at once, from the touchdown state y (r, theta, rdot, thetadot, ...)."""

    def __init__(
        self,
        command: StanceFeedback,
        t_touchdown: float,
        limit: float,
        tau_max: float | None,
        y: tuple[float, ...],
        streamed: float = 0.0,
    ) -> None:
        self._law, self._period, self._t_touchdown = command.law, command.sample_period, t_touchdown
        self._limit, self._tau_max = limit, tau_max
        self._index: float = first_sample(t_touchdown, self._period)
        self.held = 0.0
        self.record: list[tuple[float, float]] = []
        self.saturated = False
        if self.next_sample() == 0.0:
            self.sample(y, streamed)

    def next_sample(self) -> float:
        """Time since touchdown [s] of the next sample instant."""
        return self._index * self._period - self._t_touchdown

    def sample(self, y: tuple[float, ...], streamed: float = 0.0) -> float:
        """Sample at the next sample instant, the stance state there being y (r, theta, rdot, thetadot, ...):
        the law's torque (``streamed`` for a TorqueStream), clipped, is held from now on; returned."""
        t, s = self._index * self._period, self.next_sample()
        if isinstance(self._law, TorqueStream):
            tau = streamed
        else:
            tau = float(self._law.torque(StanceSample(t, s, y[0], y[1], y[2], y[3], self.held)))
        self.saturated |= self._tau_max is not None and abs(tau) > self._tau_max
        self.held = float(clip_torque(tau, self._limit))
        self.record.append((t, self.held))
        self._index += 1.0
        return self.held
