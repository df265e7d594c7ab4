"""Uneven ground: the ground height h(x) under the hopper, and where the toe of a falling leg meets it.

Every terrain is a sequence of *pieces* indexed by integers in the order of x: on piece i, for x in
[lo_i, hi_i), the ground is the line h(x) = level_i + slope_i (x - lo_i) (slope 0 on every piece of a
flat, step or block terrain; the first and the last piece reach to -inf and +inf). A change of level
between two pieces is a vertical edge; h is continuous from the right there (x = lo_i lies on piece i).

* :class:`Flat`: h = 0 everywhere;
* :class:`Step`: h = 0 before x_step, ``height`` from it on (a step up or down);
* :class:`Blocks`: h = 0 before ``start``, then blocks of ``length`` whose heights are ``sigma`` times
  independent standard normals. Block j's normal is a function of (``seed``, j) only
  (:func:`block_normals`): every lane with the same seed hops over the same terrain, scaled by its sigma;
* :class:`Profile`: the polyline through (x, height) points (a CSV file, :meth:`Profile.from_csv`),
  constant beyond its ends; a repeated x is a vertical edge (the height jumps from the first to the last
  point at that x).

The numeric fields of Flat, Step and Blocks may be arrays over lanes (the batched engine's per-lane
perturbations; :meth:`Terrain.take` selects lanes); a Profile is one ground for every lane.

**Touchdown** (:func:`touchdown`). In flight the massless leg is held at the commanded angle theta_td and
rest length r0, its toe at (x + r0 sin(theta_td), y - r0 cos(theta_td)). From the apex on (the leg is
placed there), the toe falls on a parabola and moves forward with the body. Touchdown is the first instant
at which it meets the ground: it lands on the piece under it, or, if it reaches the vertical face of a
higher piece first (a step up met on the way forward and down), on that face, at the height where it
met it. The toe stays where it landed for the whole stance; the stance's ground height is the toe's height.
If the toe is already below the ground under it when the leg is placed, touchdown is impossible: that is
toe stubbing. Only the toe touches the ground (the leg and the body pass through terrain in the model).
"""

from __future__ import annotations

import abc
import bisect
import csv
import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from tdslip_ros.model import dynamics
from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.params import ParameterError

IntArray = npt.NDArray[np.int64]

BLOCK_CHUNK = 64
"""Block normals are drawn in chunks of this many consecutive blocks (one random stream each; 32 m of
blocks 0.5 m long, some 20 strides at 5 m/s)."""
BLOCK_CACHE = 65536
"""Chunks kept in memory (512 bytes each): a batch whose lanes each have their own terrain seed draws each
chunk once."""
TERRAIN_STREAM = 0
"""Last spawn-key word of the block-height streams: SeedSequence(seed, spawn_key=(chunk, TERRAIN_STREAM)).
The per-trajectory streams of :mod:`.perturbations` end in other words, so no two streams coincide."""
MAX_TOUCHDOWN_PIECES = 1_000_000
"""Bound on the pieces one fall may cross (a safeguard: a bounded flight crosses a bounded number)."""


@dataclass(frozen=True)
class Pieces:
    """Pieces of a terrain, one per lane: [lo, hi), h(x) = level + slope (x - lo) (slope 0: level)."""

    lo: FloatArray
    hi: FloatArray
    level: FloatArray
    slope: FloatArray

    def select(self, mask: npt.NDArray[np.bool_]) -> Pieces:
        return Pieces(self.lo[mask], self.hi[mask], self.level[mask], self.slope[mask])

    def height(self, x: FloatArray) -> FloatArray:
        """h at x on each lane's piece (x need not lie on it: the piece's line is extended)."""
        with np.errstate(invalid="ignore"):  # lo = -inf on the first piece, whose slope is 0
            sloped = self.level + self.slope * (x - self.lo)
        return np.where(self.slope == 0.0, self.level, sloped)


class Terrain(abc.ABC):
    """Ground height h(x) [m] (world frame: flat ground lies at 0), cut into pieces (module docstring)."""

    kind: ClassVar[str]

    @abc.abstractmethod
    def piece_index(self, x: FloatArray) -> IntArray:
        """Index of the piece holding x (broadcast with the terrain's lane arrays)."""

    @abc.abstractmethod
    def pieces(self, index: IntArray) -> Pieces:
        """The pieces of the given indices (broadcast with the terrain's lane arrays)."""

    @abc.abstractmethod
    def spec(self) -> str:
        """Canonical text of this terrain (``kind:key=value,...``); :func:`parse_terrain` reads it back."""

    @abc.abstractmethod
    def take(self, lanes: IntArray | int) -> Terrain:
        """This terrain for the given lanes (per-lane fields indexed; a shared terrain is returned as is)."""

    @property
    def is_flat(self) -> bool:
        """True when h = 0 everywhere: the engines then take their flat-ground path, bit for bit."""
        return False

    def height(self, x: npt.ArrayLike) -> FloatArray:
        """h(x) [m], vectorised (broadcast with the terrain's lane arrays)."""
        x = np.asarray(x, dtype=np.float64)
        return self.pieces(self.piece_index(x)).height(x)

    def height_at(self, x: float) -> float:
        """h(x) [m] at one x, for a terrain whose fields are scalars: the value of :meth:`height`, bit for
        bit (the plant asks for it at every tick, so the terrains compute it without numpy's overhead)."""
        return float(self.height(x))


def _as_field(name: str, value: npt.ArrayLike, check: Callable[[FloatArray], Any], requirement: str) -> Any:
    """A numeric field as a float, or a float array for per-lane values; ParameterError naming it."""
    array = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(array) & check(array)):
        raise ParameterError(f"{name} must be {requirement}, got {value!r}")
    return float(array) if array.ndim == 0 else array


def _finite(name: str, value: npt.ArrayLike) -> Any:
    return _as_field(name, value, lambda a: np.ones(a.shape, dtype=bool), "finite")


def _non_negative(name: str, value: npt.ArrayLike) -> Any:
    return _as_field(name, value, lambda a: a >= 0.0, "finite and >= 0")


def _positive(name: str, value: npt.ArrayLike) -> Any:
    return _as_field(name, value, lambda a: a > 0.0, "finite and > 0")


def _take(value: Any, lanes: IntArray | int) -> Any:
    return value if np.ndim(value) == 0 else np.asarray(value)[lanes]


def _number(value: Any) -> str:
    if np.ndim(value) != 0:
        raise ParameterError("a terrain with per-lane values has no single spec")
    return repr(float(value))


def _constant_pieces(lo: FloatArray, hi: FloatArray, level: FloatArray) -> Pieces:
    lo, hi, level = np.broadcast_arrays(lo, hi, level)
    return Pieces(lo, hi, level, np.zeros(lo.shape))


@dataclass(frozen=True, eq=False)
class Flat(Terrain):
    """h = 0 everywhere (the paper's ground)."""

    kind: ClassVar[str] = "flat"

    def piece_index(self, x: FloatArray) -> IntArray:
        return np.zeros(np.shape(x), dtype=np.int64)

    def pieces(self, index: IntArray) -> Pieces:
        shape = np.shape(index)
        return _constant_pieces(np.full(shape, -np.inf), np.full(shape, np.inf), np.zeros(shape))

    def spec(self) -> str:
        return "flat"

    def height_at(self, x: float) -> float:
        return 0.0

    def take(self, lanes: IntArray | int) -> Terrain:
        return self

    @property
    def is_flat(self) -> bool:
        return True


FLAT = Flat()


@dataclass(frozen=True, eq=False)
class Step(Terrain):
    """h = 0 for x < ``x`` [m], ``height`` [m] from x on (negative: a step down)."""

    kind: ClassVar[str] = "step"
    height_change: Any
    x: Any

    def __post_init__(self) -> None:
        object.__setattr__(self, "height_change", _finite("step height", self.height_change))
        object.__setattr__(self, "x", _finite("step x", self.x))

    def piece_index(self, x: FloatArray) -> IntArray:
        return np.asarray(x >= self.x).astype(np.int64)

    def pieces(self, index: IntArray) -> Pieces:
        upper = index >= 1
        edge = np.broadcast_to(self.x, np.shape(index))
        return _constant_pieces(
            np.where(upper, edge, -np.inf),
            np.where(upper, np.inf, edge),
            np.where(upper, self.height_change, 0.0),
        )

    def spec(self) -> str:
        return f"step:height={_number(self.height_change)},x={_number(self.x)}"

    def height_at(self, x: float) -> float:
        return float(self.height_change) if x >= self.x else 0.0

    def take(self, lanes: IntArray | int) -> Terrain:
        return Step(_take(self.height_change, lanes), _take(self.x, lanes))


@functools.lru_cache(maxsize=BLOCK_CACHE)
def _normal_chunk(seed: int, chunk: int) -> FloatArray:
    stream = np.random.SeedSequence(seed, spawn_key=(chunk, TERRAIN_STREAM))
    values = np.random.Generator(np.random.PCG64(stream)).standard_normal(BLOCK_CHUNK)
    values.setflags(write=False)
    return values


def block_normals(seed: npt.ArrayLike, index: npt.ArrayLike) -> FloatArray:
    """The standard normals of blocks ``index`` (>= 0) of terrain ``seed`` (broadcast): a function of
    (seed, index) only. Chunk c of BLOCK_CHUNK blocks comes from SeedSequence(seed, spawn_key=(c, 0))."""
    seed_array, index_array = np.broadcast_arrays(
        np.asarray(seed, dtype=np.int64), np.asarray(index, dtype=np.int64)
    )
    chunk, offset = np.divmod(index_array.ravel(), BLOCK_CHUNK)
    seeds = seed_array.ravel()
    if np.any(seeds >= 2**31) or np.any(chunk >= 2**32):
        raise ParameterError("block terrain seeds must be below 2**31 (and blocks within 2**38 of the start)")
    keys, inverse = np.unique(seeds * 2**32 + chunk, return_inverse=True)
    out = np.empty(index_array.size)
    if keys.size == 1:
        out[:] = _normal_chunk(int(keys[0] >> 32), int(keys[0] & 0xFFFFFFFF))[offset]
        return out.reshape(index_array.shape)
    order = np.argsort(inverse, kind="stable")
    starts = np.searchsorted(inverse[order], np.arange(keys.size + 1))
    for key, (begin, end) in zip(keys.tolist(), zip(starts[:-1], starts[1:], strict=True), strict=True):
        lanes = order[begin:end]
        out[lanes] = _normal_chunk(key >> 32, key & 0xFFFFFFFF)[offset[lanes]]
    return out.reshape(index_array.shape)


@dataclass(frozen=True, eq=False)
class Blocks(Terrain):
    """Random blocks: h = 0 for x < ``start`` [m]; block j >= 0 covers [start + j length, start + (j+1)
    length) at height sigma * N_j [m], N_j = block_normals(seed, j) a standard normal."""

    kind: ClassVar[str] = "blocks"
    sigma: Any
    length: Any
    seed: Any = 0
    start: Any = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma", _non_negative("blocks sigma", self.sigma))
        object.__setattr__(self, "length", _positive("blocks length", self.length))
        object.__setattr__(self, "start", _finite("blocks start", self.start))
        seed = np.asarray(self.seed)
        if not (np.issubdtype(seed.dtype, np.integer) and np.all(seed >= 0)):
            raise ParameterError(f"blocks seed must be a non-negative integer, got {self.seed!r}")
        object.__setattr__(self, "seed", int(seed) if seed.ndim == 0 else seed.astype(np.int64))

    def piece_index(self, x: FloatArray) -> IntArray:
        index: IntArray = np.maximum(np.floor((x - self.start) / self.length), -1.0).astype(np.int64)
        return index

    def pieces(self, index: IntArray) -> Pieces:
        block = np.maximum(index, 0)
        lo = self.start + block * self.length
        hi = self.start + (block + 1) * self.length
        level = np.where(index >= 0, self.sigma * block_normals(self.seed, block), 0.0)
        before = index < 0
        return _constant_pieces(
            np.where(before, -np.inf, lo), np.where(before, np.broadcast_to(self.start, lo.shape), hi), level
        )

    def height_at(self, x: float) -> float:
        block = math.floor((x - self.start) / self.length)
        if block < 0:
            return 0.0
        chunk, offset = divmod(block, BLOCK_CHUNK)
        return float(self.sigma * _normal_chunk(int(self.seed), chunk)[offset])

    def spec(self) -> str:
        return (
            f"blocks:sigma={_number(self.sigma)},length={_number(self.length)},"
            f"seed={int(np.asarray(self.seed))},start={_number(self.start)}"
        )

    def take(self, lanes: IntArray | int) -> Terrain:
        return Blocks(*(_take(getattr(self, name), lanes) for name in ("sigma", "length", "seed", "start")))


@dataclass(frozen=True, eq=False)
class Profile(Terrain):
    """The polyline through the points (x [m], height [m]), x non-decreasing; constant beyond its ends; a
    repeated x is a vertical edge. One ground for every lane."""

    kind: ClassVar[str] = "profile"
    x: tuple[float, ...]
    heights: tuple[float, ...]
    breaks: FloatArray = field(init=False, repr=False)
    _levels: FloatArray = field(init=False, repr=False)
    _slopes: FloatArray = field(init=False, repr=False)
    _break_list: list[float] = field(init=False, repr=False)
    _level_list: list[float] = field(init=False, repr=False)
    _slope_list: list[float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        xs = np.asarray(self.x, dtype=np.float64)
        hs = np.asarray(self.heights, dtype=np.float64)
        if xs.ndim != 1 or xs.shape != hs.shape or xs.size == 0:
            raise ParameterError("a terrain profile needs one height per x and at least one point")
        if not (np.all(np.isfinite(xs)) and np.all(np.isfinite(hs))):
            raise ParameterError("a terrain profile's x and heights must be finite numbers")
        if np.any(np.diff(xs) < 0.0):
            raise ParameterError("a terrain profile's x must not decrease (a repeated x is a vertical edge)")
        if np.any(np.unique(xs, return_counts=True)[1] > 2):
            raise ParameterError("a terrain profile may repeat an x once (a vertical edge), not more")
        object.__setattr__(self, "x", tuple(xs.tolist()))
        object.__setattr__(self, "heights", tuple(hs.tolist()))
        breaks, first = np.unique(xs, return_index=True)
        last = np.searchsorted(xs, breaks, side="right") - 1
        left, right = hs[first], hs[last]  # the height arriving at a break from the left, leaving it
        # Piece 0 before the first break, piece i in 1..n-1 from break i-1 to break i, piece n after.
        levels = np.concatenate([[left[0]], right])
        slopes = np.concatenate([[0.0], (left[1:] - right[:-1]) / np.diff(breaks), [0.0]])
        object.__setattr__(self, "breaks", breaks)
        object.__setattr__(self, "_levels", levels)
        object.__setattr__(self, "_slopes", slopes)
        object.__setattr__(self, "_break_list", breaks.tolist())
        object.__setattr__(self, "_level_list", levels.tolist())
        object.__setattr__(self, "_slope_list", slopes.tolist())

    @classmethod
    def from_csv(cls, path: Path | str) -> Profile:
        """Read a profile from a CSV file of rows ``x, height`` [m] (a header row is skipped)."""
        points: list[tuple[float, float]] = []
        try:
            with open(path, newline="") as stream:
                for number, row in enumerate(csv.reader(stream), start=1):
                    if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                        continue
                    try:
                        if len(row) != 2:
                            raise ValueError(f"{len(row)} columns")
                        points.append((float(row[0]), float(row[1])))
                    except ValueError as error:
                        if number == 1 and not points:
                            continue  # a header
                        raise ParameterError(f"{path}, line {number}: not 'x, height' ({error})") from None
        except OSError as error:
            raise ParameterError(f"terrain profile {path}: {error.strerror or error}") from None
        if not points:
            raise ParameterError(f"terrain profile {path}: no 'x, height' rows")
        xs, hs = zip(*points, strict=True)
        try:
            return cls(tuple(xs), tuple(hs))
        except ParameterError as error:
            raise ParameterError(f"terrain profile {path}: {error}") from None

    def piece_index(self, x: FloatArray) -> IntArray:
        index: IntArray = np.searchsorted(self.breaks, x, side="right").astype(np.int64)
        return index

    def pieces(self, index: IntArray) -> Pieces:
        bounds = np.concatenate([[-np.inf], self.breaks, [np.inf]])
        return Pieces(bounds[index], bounds[index + 1], self._levels[index], self._slopes[index])

    def height_at(self, x: float) -> float:
        index = bisect.bisect_right(self._break_list, x)
        level, slope = self._level_list[index], self._slope_list[index]
        if slope == 0.0:
            return level
        return level + slope * (x - self._break_list[index - 1])

    def spec(self) -> str:
        points = ";".join(f"{x!r}/{h!r}" for x, h in zip(self.x, self.heights, strict=True))
        return f"profile:points={points}"

    def take(self, lanes: IntArray | int) -> Terrain:
        return self


# --- the text form -----------------------------------------------------------------------------------


def spec_fields(text: str, what: str, keys: Mapping[str, Callable[[str], Any]]) -> dict[str, Any]:
    """``key=value,key=value`` parsed with the converter of each key; ParameterError naming ``what``,
    the key and the allowed keys for anything else."""
    values: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, equals, value = item.partition("=")
        key = key.strip()
        if not equals or key not in keys:
            raise ParameterError(f"{what}: {item!r} is not one of {', '.join(f'{k}=...' for k in keys)}")
        if key in values:
            raise ParameterError(f"{what}: {key} is given twice")
        try:
            values[key] = keys[key](value.strip())
        except ValueError:
            raise ParameterError(
                f"{what}: {key}={value.strip()!r} is not a valid {keys[key].__name__}"
            ) from None
    return values


def _required(values: dict[str, Any], what: str, *names: str) -> None:
    missing = [name for name in names if name not in values]
    if missing:
        raise ParameterError(f"{what}: missing {', '.join(f'{name}=...' for name in missing)}")


def _profile_points(text: str) -> Profile:
    try:
        pairs = [item.split("/") for item in text.split(";") if item.strip()]
        return Profile(tuple(float(x) for x, _ in pairs), tuple(float(h) for _, h in pairs))
    except ValueError:
        raise ParameterError(f"profile points {text!r} are not 'x/height;x/height;...'") from None


TERRAIN_KINDS = ("flat", "step", "blocks", "profile")
TERRAIN_FORMS = "flat | step:height=H,x=X | blocks:sigma=S,length=L,seed=N[,start=X] | profile:file=PATH.csv"


def parse_terrain(text: str) -> Terrain:
    """A terrain from its text (the form of :data:`TERRAIN_FORMS`, or a Terrain's :meth:`~Terrain.spec`);
    ParameterError with one line naming what is wrong."""
    text = text.strip()
    kind, _, rest = text.partition(":")
    what = f"terrain {text!r}"
    if kind == "flat" and not rest.strip():
        return FLAT
    if kind == "step":
        values = spec_fields(rest, what, {"height": float, "x": float})
        _required(values, what, "height", "x")
        return _built(what, lambda: Step(values["height"], values["x"]))
    if kind == "blocks":
        values = spec_fields(rest, what, {"sigma": float, "length": float, "seed": int, "start": float})
        _required(values, what, "sigma", "length", "seed")
        return _built(what, lambda: Blocks(**values))
    if kind == "profile":
        if rest.startswith("points="):
            return _built(what, lambda: _profile_points(rest[len("points=") :]))
        values = spec_fields(rest, what, {"file": str})
        _required(values, what, "file")
        return Profile.from_csv(values["file"])
    raise ParameterError(f"{what} is not one of: {TERRAIN_FORMS}")


def _built(what: str, build: Callable[[], Terrain]) -> Terrain:
    try:
        return build()
    except ParameterError as error:
        raise ParameterError(f"{what}: {error}") from None


# --- touchdown -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Touchdown:
    """Where a leg placed at an apex lands, per lane (arrays).

    stubbed: the toe was below the ground under it at placement (no touchdown; the other fields are NaN
    there); t [s]: time from the apex to touchdown; toe_x, toe_y [m]: the toe's landing point, toe_y the
    stance's ground height; edge: it landed on a vertical face; placement_ground [m]: h under the toe at
    placement.
    """

    stubbed: npt.NDArray[np.bool_]
    t: FloatArray
    toe_x: FloatArray
    toe_y: FloatArray
    edge: npt.NDArray[np.bool_]
    placement_ground: FloatArray


def touchdown(
    terrain: Terrain,
    x_apex: FloatArray,
    y_apex: FloatArray,
    xdot: FloatArray,
    sin_td: FloatArray,
    cos_td: FloatArray,
    r0: float,
    g: float,
) -> Touchdown:
    """Touchdown of legs placed at theta_td at apexes (x_apex, y_apex [world frame], forward speed xdot)
    on ``terrain`` (module docstring); 1-D arrays over lanes, the terrain's lane fields aligned with them.

    On each piece the toe meets the ground line where the body, falling from its apex, reaches the line
    plus r0 cos(theta_td): :func:`.dynamics.fall_time` with the line's rise per second along the path as
    the body's vertical speed (on a level piece exactly the flat-ground touchdown). A toe that leaves the
    piece first is checked against the next piece's height at the boundary: at or below it, it lands on
    that piece's face.
    """
    lanes = x_apex.shape[0]
    y_td = r0 * cos_td
    toe_x0 = x_apex + r0 * sin_td
    index = np.array(np.broadcast_to(terrain.piece_index(toe_x0), (lanes,)), dtype=np.int64)
    ground0 = terrain.pieces(index).height(toe_x0)
    stubbed = np.asarray(y_apex < ground0 + y_td)
    t_out, toe_x, toe_y = (np.full(lanes, np.nan) for _ in range(3))
    edge = np.zeros(lanes, dtype=bool)
    step = np.sign(xdot).astype(np.int64)  # the next piece along the toe's path
    active = np.flatnonzero(~stubbed)
    t_enter = np.zeros(lanes)
    for _ in range(MAX_TOUCHDOWN_PIECES):
        if active.size == 0:
            break
        lane_terrain = terrain.take(active)
        piece = lane_terrain.pieces(index[active])
        x0, ya, v, ytd = toe_x0[active], y_apex[active], xdot[active], y_td[active]
        # The body reaches the piece's line (raised by r0 cos(theta_td)) along the toe's path; NaN only
        # where rounding put the toe a hair below the line it enters: it lands there at once.
        t_hit = dynamics.fall_time(ya, -piece.slope * v, piece.height(x0) + ytd, g)
        t_hit = np.where(np.isnan(t_hit), t_enter[active], t_hit)
        boundary = np.where(v > 0.0, piece.hi, piece.lo)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_exit = np.where(np.isfinite(boundary) & (v != 0.0), (boundary - x0) / v, np.inf)
        landed = t_hit <= t_exit
        done = active[landed]
        t_out[done] = t_hit[landed]
        toe_x[done] = x0[landed] + v[landed] * t_hit[landed]
        toe_y[done] = piece.select(landed).height(toe_x[done])
        # The others reach the end of their piece, where the next piece's face is.
        moving = ~landed
        ahead = active[moving]
        next_index = index[ahead] + step[ahead]
        face = lane_terrain.take(np.flatnonzero(moving)).pieces(next_index).height(boundary[moving])
        t_b = t_exit[moving]
        toe_y_b = (ya[moving] - 0.5 * g * t_b * t_b) - ytd[moving]
        on_face = toe_y_b <= face
        hit = ahead[on_face]
        t_out[hit], toe_x[hit], toe_y[hit] = t_b[on_face], boundary[moving][on_face], toe_y_b[on_face]
        edge[hit] = True
        index[ahead], t_enter[ahead] = next_index, t_b
        active = ahead[~on_face]
    else:
        raise RuntimeError(f"a fall crossed more than {MAX_TOUCHDOWN_PIECES} terrain pieces")
    return Touchdown(stubbed, t_out, toe_x, toe_y, edge, ground0)
