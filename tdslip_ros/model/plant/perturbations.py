"""What a locomotion researcher tests a controller against: one description for every engine.

:class:`Perturbations` bundles, all SI:

* ``terrain`` (:mod:`.terrain`): the ground h(x) the toe lands on;
* ``sensing`` (:class:`SensingNoise`): the controller's sensor reports the apex height and speed with
  Gaussian noise; the engines keep the true and the measured apex. The controller is blind: it plans
  with the measured height above the ground it last stood on (the true ground of the last stance) and the
  measured speed;
* ``placement`` (:class:`PlacementNoise`): the leg lands at the commanded touchdown angle plus a Gaussian
  error (:func:`placed_angle`);
* ``tau_max`` [N m]: the hip torque saturates, tau(s) = clip(tau0 (1 - s/t_f), -tau_max, tau_max)
  (:func:`.dynamics.hip_torque`); a stride whose |tau0| exceeds it is *saturated*;
* ``pushes`` (:class:`Pushes`): horizontal velocity changes at the apex, at chosen strides or at random.
  A push acts right after the apex is measured: the controller plans without knowing it;
* ``mismatch`` (:class:`Mismatch`): the controller plans with hopper parameters that differ from the
  plant's by factors (:meth:`Mismatch.controller_params`); the engines themselves use the plant's.

Every numeric field may be an array over lanes (the batched engine's lanes; :meth:`Perturbations.take`
selects lanes); the single-trajectory engines take scalars. The description is small, frozen and
picklable, so a study can ship it to its workers.

**Random draws** (:meth:`Perturbations.draws`) are a function of (seed, trajectory index, stride) only,
never of call order or of how lanes are split into calls: stride k of trajectory i takes row k mod 64 of
block k // 64 of the stream SeedSequence(seed, spawn_key=(i, stream, k // 64)), the stream being 1 for
sensing, 2 for placement and 3 for pushes (terrain blocks use (chunk, 0), :mod:`.terrain`). Equal seeds in
two kinds therefore still give independent draws. Turning one kind on does not change the draws of another.

With every field at its default (no perturbation) :attr:`Perturbations.active` is False and every engine
takes its flat-ground path, bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.arrays import ParamArrays
from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.limits import PlausibilityLimits
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.plant.terrain import FLAT, IntArray, Terrain, spec_fields

SENSING_STREAM, PLACEMENT_STREAM, PUSH_STREAM = 1, 2, 3
DRAW_BLOCK = 64
"""Strides per block of random draws (one SeedSequence per block, trajectory and stream)."""
Built = TypeVar("Built")
PLACEMENT_MARGIN = 1e-9
"""rad kept inside (0, pi/2) by a placement error: the leg never lands behind the body or horizontal."""


def _field(name: str, value: npt.ArrayLike, valid: Callable[[FloatArray], Any], requirement: str) -> Any:
    """A numeric field as a float, or a float array for per-lane values; ParameterError naming it."""
    array = np.asarray(value, dtype=np.float64)
    if not np.all(valid(array)):
        raise ParameterError(f"{name} must be {requirement}, got {value!r}")
    return float(array) if array.ndim == 0 else array


def _size(name: str, value: npt.ArrayLike) -> Any:
    return _field(name, value, lambda a: np.isfinite(a) & (a >= 0.0), "finite and >= 0")


def _seed(name: str, value: npt.ArrayLike) -> Any:
    array = np.asarray(value)
    if not (np.issubdtype(array.dtype, np.integer) and np.all(array >= 0)):
        raise ParameterError(f"{name} must be a non-negative integer, got {value!r}")
    return int(array) if array.ndim == 0 else array.astype(np.int64)


def _take(value: Any, lanes: IntArray | int) -> Any:
    return value if np.ndim(value) == 0 else np.asarray(value)[lanes]


def _scalar(value: Any) -> float:
    if np.ndim(value) != 0:
        raise ParameterError("perturbations with per-lane values have no single text form")
    return float(value)


def _is_zero(value: Any) -> bool:
    return bool(np.all(np.asarray(value) == 0.0))


@dataclass(frozen=True, eq=False)
class SensingNoise:
    """Standard deviations of the measured apex height [m] and speed [m/s], and their seed."""

    height: Any = 0.0
    speed: Any = 0.0
    seed: Any = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "height", _size("height noise", self.height))
        object.__setattr__(self, "speed", _size("speed noise", self.speed))
        object.__setattr__(self, "seed", _seed("sensing noise seed", self.seed))

    @property
    def active(self) -> bool:
        return not (_is_zero(self.height) and _is_zero(self.speed))

    def spec(self) -> str:
        return f"height={_scalar(self.height)!r},speed={_scalar(self.speed)!r},seed={int(self.seed)}"

    @classmethod
    def parse(cls, text: str) -> SensingNoise:
        """From ``height=M,speed=M_PER_S,seed=N`` (each optional)."""
        values = spec_fields(text, f"apex noise {text!r}", {"height": float, "speed": float, "seed": int})
        return _built(f"apex noise {text!r}", lambda: cls(**values))


@dataclass(frozen=True, eq=False)
class PlacementNoise:
    """Standard deviation [rad] of the touchdown angle's error, and its seed."""

    sigma: Any = 0.0
    seed: Any = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma", _size("angle noise", self.sigma))
        object.__setattr__(self, "seed", _seed("angle noise seed", self.seed))

    @property
    def active(self) -> bool:
        return not _is_zero(self.sigma)

    @classmethod
    def parse_degrees(cls, text: str) -> PlacementNoise:
        """From ``sigma=DEG,seed=N``, sigma in degrees (as the command line gives angles)."""
        values = spec_fields(text, f"angle noise {text!r}", {"sigma": float, "seed": int})
        if "sigma" in values:
            values["sigma"] = math.radians(values["sigma"])
        return _built(f"angle noise {text!r}", lambda: cls(**values))


@dataclass(frozen=True, eq=False)
class Pushes:
    """Horizontal velocity changes at the apex: ``at`` holds (stride, dv [m/s]) pairs; besides, each stride
    gets a push of magnitude ``size`` [m/s], forward or backward with equal odds, with probability ``rate``
    (0 to 1), drawn with ``seed``."""

    at: tuple[tuple[int, float], ...] = ()
    size: Any = 0.0
    rate: Any = 0.0
    seed: Any = 0

    def __post_init__(self) -> None:
        chosen = []
        for stride, dv in self.at:
            if not (isinstance(stride, int | np.integer) and stride >= 0):
                raise ParameterError(f"a push's stride must be a non-negative integer, got {stride!r}")
            if not math.isfinite(dv):
                raise ParameterError(f"a push's velocity change must be finite, got {dv!r}")
            chosen.append((int(stride), float(dv)))
        object.__setattr__(self, "at", tuple(sorted(chosen)))
        object.__setattr__(self, "size", _size("push size", self.size))
        object.__setattr__(
            self, "rate", _field("push rate", self.rate, lambda a: (a >= 0.0) & (a <= 1.0), "in [0, 1]")
        )
        object.__setattr__(self, "seed", _seed("push seed", self.seed))

    @property
    def random(self) -> bool:
        return not (_is_zero(self.size) or _is_zero(self.rate))

    @property
    def active(self) -> bool:
        return bool(self.at) or self.random

    def largest(self) -> float:
        """The largest |dv| [m/s] any push can have."""
        chosen = max((abs(dv) for _, dv in self.at), default=0.0)
        return max(chosen, float(np.max(self.size)))

    def spec(self) -> str:
        items = [f"{stride}:{dv!r}" for stride, dv in self.at]
        if self.random:
            items.append(
                f"random:size={_scalar(self.size)!r},rate={_scalar(self.rate)!r},seed={int(self.seed)}"
            )
        return ";".join(items)

    @classmethod
    def parse(cls, text: str) -> Pushes:
        """From items separated by ';': ``STRIDE:DV`` (a push of DV m/s at the apex of STRIDE) and at most one
        ``random:size=DV,rate=P,seed=N``; an empty text has no push."""
        at: list[tuple[int, float]] = []
        random: dict[str, Any] = {}
        for item in filter(None, (part.strip() for part in text.split(";"))):
            head, _, rest = item.partition(":")
            what = f"push {item!r}"
            if head.strip() == "random":
                if random:
                    raise ParameterError(f"{what}: only one random push series is allowed")
                random = spec_fields(rest, what, {"size": float, "rate": float, "seed": int})
                missing = [key for key in ("size", "rate") if key not in random]
                if missing:
                    raise ParameterError(f"{what}: missing {', '.join(f'{k}=...' for k in missing)}")
                continue
            try:
                at.append((int(head), float(rest)))
            except ValueError:
                raise ParameterError(
                    f"{what} is neither STRIDE:DV (e.g. 5:0.3) nor random:size=DV,rate=P,seed=N"
                ) from None
        return _built(f"push {text!r}", lambda: cls(tuple(at), **random))


MISMATCH_FIELDS = {"mass": "m", "stiffness": "k", "damping": "c", "rest_length": "r0"}
"""Mismatch factors by name, and the HopperParams field each scales."""


@dataclass(frozen=True, eq=False)
class Mismatch:
    """Factors by which the controller's model differs from the plant's: mass, stiffness, damping and
    rest length."""

    mass: Any = 1.0
    stiffness: Any = 1.0
    damping: Any = 1.0
    rest_length: Any = 1.0

    def __post_init__(self) -> None:
        for name in MISMATCH_FIELDS:
            value = _field(
                f"{name} mismatch factor",
                getattr(self, name),
                lambda a: np.isfinite(a) & (a > 0.0),
                "finite and > 0",
            )
            object.__setattr__(self, name, value)

    @property
    def active(self) -> bool:
        return any(not np.all(np.asarray(getattr(self, name)) == 1.0) for name in MISMATCH_FIELDS)

    def controller_params(self, params: HopperParams) -> HopperParams | ParamArrays:
        """The hopper the controller plans with: the plant's parameters times the factors (a ParamArrays for
        per-lane factors); ParameterError if they leave the model's range."""
        scaled = {
            field_name: getattr(params, field_name) * np.asarray(getattr(self, name))
            for name, field_name in MISMATCH_FIELDS.items()
        }
        if all(np.ndim(value) == 0 for value in scaled.values()):
            m, k, r0, c = (float(scaled[name]) for name in ("m", "k", "r0", "c"))
            return HopperParams(m=m, k=k, r0=r0, c=c, g=params.g, body=params.body)
        return ParamArrays(**scaled, g=np.asarray(params.g))

    def spec(self) -> str:
        return ",".join(f"{name}={_scalar(getattr(self, name))!r}" for name in MISMATCH_FIELDS)

    @classmethod
    def parse(cls, text: str) -> Mismatch:
        """From ``mass=F,stiffness=F,damping=F,rest_length=F`` (each optional, default 1)."""
        values = spec_fields(text, f"mismatch {text!r}", dict.fromkeys(MISMATCH_FIELDS, float))
        return _built(f"mismatch {text!r}", lambda: cls(**values))


def _built(what: str, build: Callable[[], Built]) -> Built:
    try:
        return build()
    except ParameterError as error:
        raise ParameterError(f"{what}: {error}") from None


@dataclass(frozen=True)
class Draws:
    """The random perturbations of ``strides`` strides of some lanes, arrays (strides, lanes): sensor errors
    of the apex height [m] and speed [m/s], the touchdown angle's error [rad], the push at the apex [m/s]."""

    height_error: FloatArray
    speed_error: FloatArray
    angle_error: FloatArray
    push: FloatArray


def _stream_rows(
    seeds: Any,
    trajectories: IntArray,
    stream: int,
    first: int,
    count: int,
    draw: Callable[[np.random.Generator], Any],
) -> FloatArray:
    """Rows first..first+count-1 of each lane's stream (module docstring): (count, lanes, *row shape)."""
    blocks = range(first // DRAW_BLOCK, (first + count - 1) // DRAW_BLOCK + 1)
    seed_of = np.broadcast_to(np.asarray(seeds, dtype=np.int64), trajectories.shape)
    per_lane = []
    for seed, trajectory in zip(seed_of.tolist(), trajectories.tolist(), strict=True):
        rows = [
            draw(
                np.random.Generator(
                    np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(trajectory, stream, block)))
                )
            )
            for block in blocks
        ]
        start = first - blocks.start * DRAW_BLOCK
        per_lane.append(np.concatenate(rows)[start : start + count])
    return np.stack(per_lane, axis=1) if per_lane else np.empty((count, 0))


@dataclass(frozen=True, eq=False)
class Perturbations:
    """The perturbations of a run or of the lanes of a batch (module docstring)."""

    terrain: Terrain = FLAT
    sensing: SensingNoise = field(default_factory=SensingNoise)
    placement: PlacementNoise = field(default_factory=PlacementNoise)
    tau_max: Any = math.inf
    pushes: Pushes = field(default_factory=Pushes)
    mismatch: Mismatch = field(default_factory=Mismatch)

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "tau_max",
            _field("tau_max", self.tau_max, lambda a: a > 0.0, "> 0 N m (inf: no saturation)"),
        )

    @property
    def saturates(self) -> bool:
        return not bool(np.all(np.isinf(self.tau_max)))

    @property
    def random(self) -> bool:
        """Some perturbation is drawn per stride."""
        return self.sensing.active or self.placement.active or self.pushes.random

    @property
    def active(self) -> bool:
        """Some perturbation acts on the plant or the sensor (not mismatch: only the controller sees it)."""
        return (
            not self.terrain.is_flat
            or self.sensing.active
            or self.placement.active
            or self.saturates
            or self.pushes.active
        )

    def check_limits(self, limits: PlausibilityLimits) -> None:
        """Refuse pushes larger than the hopper's speed bound (an input beyond the limits, :mod:`.limits`)."""
        if self.pushes.largest() > limits.max_apex_speed:
            raise ParameterError(
                f"a push of {self.pushes.largest()!r} m/s exceeds max_apex_speed = "
                f"{limits.max_apex_speed:.6g} m/s"
            )

    def summary(self) -> str:
        """One line naming the perturbations that act (``no perturbations`` when none do)."""
        parts = []
        if not self.terrain.is_flat:
            parts.append(f"terrain {self.terrain.spec() if self.terrain.kind != 'profile' else 'profile'}")
        if self.sensing.active:
            parts.append(f"apex noise {self.sensing.spec()}")
        if self.placement.active:
            parts.append(
                f"angle noise {_scalar(self.placement.sigma):g} rad (seed {int(self.placement.seed)})"
            )
        if self.saturates:
            parts.append(f"tau_max {_scalar(self.tau_max):g} N m")
        if self.pushes.active:
            parts.append(f"pushes {self.pushes.spec()}")
        if self.mismatch.active:
            parts.append(f"mismatch {self.mismatch.spec()}")
        return "perturbations: " + "; ".join(parts) if parts else "no perturbations"

    def take(self, lanes: IntArray | int) -> Perturbations:
        """These perturbations for the given lanes (per-lane fields indexed; an int: one lane's scalars)."""

        def taken(part: Any) -> Any:
            names = [name for name in vars(part) if not name.startswith("_") and name != "at"]
            return replace(part, **{name: _take(getattr(part, name), lanes) for name in names})

        return Perturbations(
            terrain=self.terrain.take(lanes),
            sensing=taken(self.sensing),
            placement=taken(self.placement),
            tau_max=_take(self.tau_max, lanes),
            pushes=taken(self.pushes),
            mismatch=taken(self.mismatch),
        )

    def draws(self, trajectories: npt.ArrayLike, first_stride: int, strides: int) -> Draws:
        """The random perturbations of strides first_stride .. first_stride + strides - 1 of the trajectories
        (1-D indices, one per lane); zeros for kinds that are off. Chosen pushes are included."""
        lanes = np.asarray(trajectories, dtype=np.int64).reshape(-1)
        if np.any(lanes < 0):
            raise ParameterError("trajectory indices must be non-negative")
        shape = (strides, lanes.size)
        height = np.zeros(shape)
        speed = np.zeros(shape)
        angle = np.zeros(shape)
        push = np.zeros(shape)
        if strides <= 0:
            return Draws(height, speed, angle, push)
        sensing, placement, pushes = self.sensing, self.placement, self.pushes
        if sensing.active:
            normals = _stream_rows(
                sensing.seed,
                lanes,
                SENSING_STREAM,
                first_stride,
                strides,
                lambda g: g.standard_normal((DRAW_BLOCK, 2)),
            )
            height = normals[..., 0] * np.asarray(sensing.height)
            speed = normals[..., 1] * np.asarray(sensing.speed)
        if placement.active:
            normals = _stream_rows(
                placement.seed,
                lanes,
                PLACEMENT_STREAM,
                first_stride,
                strides,
                lambda g: g.standard_normal(DRAW_BLOCK),
            )
            angle = normals * np.asarray(placement.sigma)
        if pushes.random:
            uniforms = _stream_rows(
                pushes.seed, lanes, PUSH_STREAM, first_stride, strides, lambda g: g.random((DRAW_BLOCK, 2))
            )
            happens = uniforms[..., 0] < np.asarray(pushes.rate)
            push = np.where(
                happens, np.where(uniforms[..., 1] < 0.5, -1.0, 1.0) * np.asarray(pushes.size), 0.0
            )
        for stride, dv in pushes.at:
            if first_stride <= stride < first_stride + strides:
                push[stride - first_stride] += dv
        return Draws(height, speed, angle, push)

    def scalars(self) -> dict[str, str | float | int]:
        """These perturbations of one trajectory as scalars by field (``sensing.height``, ...): the terrain
        and the pushes in their text forms, tau_max inf where the hip does not saturate; the mismatch aside
        (only the controller plans with it). ParameterError for per-lane values, which have no single form."""
        return {
            "terrain": self.terrain.spec(),
            "sensing.height": _scalar(self.sensing.height),
            "sensing.speed": _scalar(self.sensing.speed),
            "sensing.seed": int(self.sensing.seed),
            "placement.sigma": _scalar(self.placement.sigma),
            "placement.seed": int(self.placement.seed),
            "tau_max": math.inf if not self.saturates else _scalar(self.tau_max),
            "pushes": self.pushes.spec(),
        }


def placed_angle(angle: Any, error: Any) -> Any:
    """The touchdown angle the leg lands at: the commanded one plus its error, kept PLACEMENT_MARGIN inside
    (0, pi/2); exactly the commanded one where the error is 0 (floats or arrays)."""
    placed = np.clip(np.asarray(angle) + error, PLACEMENT_MARGIN, math.pi / 2 - PLACEMENT_MARGIN)
    result = np.where(np.asarray(error) == 0.0, angle, placed)
    return float(result) if result.ndim == 0 else result


@dataclass(frozen=True)
class StrideConditions:
    """What a stride is hopped under, besides the apex and the command: the per-stride conditions that the
    exact map (floats), the batched engine (floats or arrays broadcast with the lanes) and the compiled
    stride (tau_max alone) take as one value. The defaults are flat ground and no perturbation.

    x [m]: where the apex is; ground [m, world frame]: the ground under the apex that its height is above
    (None: the terrain's height at x); terrain: where the toe lands (:func:`.terrain.touchdown`); tau_max
    [N m]: the hip torque's saturation (inf: none); push [m/s]: a change of the forward speed right after the
    apex; angle_error [rad]: the leg lands at the commanded angle plus this (:func:`placed_angle`). The
    engines check the values per lane and name the first bad one.
    """

    x: Any = 0.0
    ground: Any = None
    terrain: Terrain = FLAT
    tau_max: Any = math.inf
    push: Any = 0.0
    angle_error: Any = 0.0


UNPERTURBED = StrideConditions()
"""Flat ground, no saturation, no push, no placement error: the engines' default conditions."""
