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
engine); :func:`tdslip_ros.model.plant.batch.simulate_strides` keeps each lane's apex times itself.

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

* the baseline of the paper's ref. 36, a policy:
:class:`tdslip_ros.model.policies.stance_pd.StancePDSpeedEnergy`;
* :class:`RecordedTorques`, the held torques of a recording, replayed: the exact map reproduces a
  recorded stride from its apex, its apex time and these;
* :class:`TorqueStream`: the torques come from outside, one per sample, through
  :meth:`.stepper.FixedStepStepper.hold_torque` (the plant node's torque topic); only the stepper runs it.

The maths of a law is written once, in arithmetic that takes floats (the scalar engines) and arrays over
lanes (the batched engine) alike; a law's fields may be arrays over the lanes of a batched stride.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.body_dynamics import RIGID_STANCE_STATE_SIZE
from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.params import ParameterError

DEFAULT_SAMPLE_PERIOD = 1e-3
"""s: the plant node's tick, the period at which a ROS controller sends torques."""
RECORD_TIME_TOLERANCE = 1e-9
"""s: a recorded torque stamped this little after a sample instant counts as held from it (a recording's
clock may be rounded, e.g. to nanoseconds)."""


class StanceSample(NamedTuple):
    """What a law sees at a sample instant (floats, or arrays over lanes): the absolute time t and the
    time since touchdown s [s], the polar state (r [m], theta [rad], rdot [m/s], thetadot [rad/s]), the
    torque held until this instant, ``held`` [N m], and a rigid body's pitch [rad] and pitch rate [rad/s]
    (0 for the paper's fixed body)."""

    t: Any
    s: Any
    r: Any
    theta: Any
    rdot: Any
    thetadot: Any
    held: Any
    pitch: Any = 0.0
    pitch_rate: Any = 0.0


class StanceLaw(Protocol):
    """A sampled stance law: the torque [N m] to hold from a sample on (before clipping). ``lanes``, for
    the batched engine, indexes the law's per-lane fields by the lanes of ``sample``; None: scalars."""

    def torque(self, sample: StanceSample, lanes: npt.NDArray[np.int64] | None = None) -> Any: ...


def lane_values(value: Any, lanes: npt.NDArray[np.int64] | None) -> Any:
    """A law's field for the sampled lanes: itself when scalar, else indexed by ``lanes``."""
    if np.ndim(value) == 0:
        return value
    if lanes is None:
        raise ParameterError("a law with per-lane fields runs only on the batched engine")
    return np.asarray(value, dtype=np.float64)[lanes]


def finite_field(name: str, value: Any) -> Any:
    """A law's numeric field, a float or an array of floats; ParameterError naming it."""
    array = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise ParameterError(f"{name} must be finite, got {value!r}")
    return float(array) if array.ndim == 0 else array


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
        angle = finite_field("touchdown_angle", self.touchdown_angle)
        if not 0.0 < angle < math.pi / 2:
            raise ParameterError(f"touchdown_angle must lie in (0, pi/2) rad, got {angle!r}")
        period = finite_field("sample_period", self.sample_period)
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
        the law's torque (``streamed`` for a TorqueStream), clipped, is held from now on; returned. A rigid
        body's state holds its pitch and rate at y[6], y[7] (:func:`~.rigid_stance_derivatives`)."""
        t, s = self._index * self._period, self.next_sample()
        if isinstance(self._law, TorqueStream):
            tau = streamed
        else:
            pitch, pitch_rate = (y[6], y[7]) if len(y) == RIGID_STANCE_STATE_SIZE else (0.0, 0.0)
            seen = StanceSample(t, s, y[0], y[1], y[2], y[3], self.held, pitch, pitch_rate)
            tau = float(self._law.torque(seen))
        self.saturated |= self._tau_max is not None and abs(tau) > self._tau_max
        self.held = float(clip_torque(tau, self._limit))
        self.record.append((t, self.held))
        self._index += 1.0
        return self.held
