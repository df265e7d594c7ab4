"""Study designs: which trajectories a study runs, each one's parameters a pure function of its index.

A :class:`Study` is a grid (axes, the first outermost) and, optionally, a Monte Carlo design on top of it:
``samples`` trajectories per grid cell, each drawing the ``draws`` parameters from its own random stream.
Trajectory ``i`` belongs to cell ``i // samples``; its draws come from ``SeedSequence(seed,
spawn_key=(i, DESIGN_STREAM))``, so they depend on the seed and the index only, never on how the study is
chunked or which worker runs it. Parameters named in neither the grid nor the draws take ``fixed`` values or
the :data:`DEFAULTS`.

The parameters (SI, the names of :data:`~tdslip_ros.model.policies.registry.POLICY_SETTINGS` where they are a
policy's settings):

* ``policy``: one of :data:`~tdslip_ros.model.policies.registry.POLICIES`;
* the hopper, ``kbar`` and ``zeta0`` (eq. 24; m, r0 and g are the study's ``mass``, ``rest_length`` and
  ``gravity``). The batched engine runs one hopper per call, so these are grid axes or fixed, never drawn;
* the policy's settings (:data:`POLICY_PARAMETERS`, each with its unit and default from the declaration),
  but for ``corrections``, one per study (:attr:`Study.corrections`); ``target_energy`` NaN: the
  trajectory's initial energy, the paper's goal regulator of section IV.B. A setting of text choices
  (:data:`CHOICE_SETTINGS`: ``analytic_map``) is, like ``policy``, a grid axis or fixed, never drawn;
* the initial apex ``y0`` [m] with, by the study's ``start`` rule, ``xdot0`` [m/s] (``speed``), ``energy0``
  [J] (``energy``), or neither (``open_loop_fixed_point``: energy0 is the open loop's energy fixed point
  E*(y0) of eq. 27 at the trajectory's touchdown angle and power on its analytic map, fig. 7's start).

Chunks are consecutive runs of ``chunk_size`` trajectories; a chunk is the unit of work, of retry and of
the table's files. Keep the hopper axes outermost so that a chunk holds few hoppers (each is one call of
the batched engine).
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import ANALYTIC_MAPS
from tdslip_ros.model.dynamics import speed_from_energy
from tdslip_ros.model.paper import PAPER_KBAR, PAPER_PARAMS, PAPER_ZETA0
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.policies.registry import DEFAULT_POLICY, POLICIES, POLICY_SETTINGS, SETTING_DEFAULTS
from tdslip_ros.model.stability import analytic_fixed_points
from tdslip_ros.studies import perturbed

HOPPER_PARAMETERS = ("kbar", "zeta0")
POLICY_PARAMETERS = tuple(setting.name for setting in POLICY_SETTINGS if setting.name != "corrections")
"""The policies' settings, a value per trajectory (corrections: one per study, Study.corrections)."""
CHOICE_SETTINGS = tuple(setting.name for setting in POLICY_SETTINGS if setting.kind is str)
"""The policies' text settings (analytic_map, and the free policy_file): string columns, one value per engine
call."""
CHOICES: dict[str, tuple[str, ...]] = {
    "policy": POLICIES,
    **{setting.name: setting.choices for setting in POLICY_SETTINGS if setting.kind is str},
}
"""The text parameters, with their choices (none for a free text): ``policy`` and CHOICE_SETTINGS."""
START_PARAMETERS = ("y0", "xdot0", "energy0")
NUMERIC_PARAMETERS = (
    HOPPER_PARAMETERS
    + tuple(name for name in POLICY_PARAMETERS if name not in CHOICES)
    + START_PARAMETERS
    + perturbed.PERTURBATION_PARAMETERS
)
PARAMETERS = (*CHOICES, *NUMERIC_PARAMETERS)
GROUP_PARAMETERS = (*CHOICES, *HOPPER_PARAMETERS, *perturbed.MISMATCH_PARAMETERS)
"""Parameters with one value per call of the batched engine: grid axes or fixed, never drawn."""
UNITS = {
    "kbar": "",
    "zeta0": "",
    **{setting.name: setting.unit for setting in POLICY_SETTINGS if setting.name in POLICY_PARAMETERS},
    "y0": "m",
    "xdot0": "m/s",
    "energy0": "J",
    **perturbed.UNITS,
}
DEFAULTS: dict[str, str | float] = {
    "policy": DEFAULT_POLICY,
    "kbar": PAPER_KBAR,
    "zeta0": PAPER_ZETA0,
    **{name: SETTING_DEFAULTS[name] for name in POLICY_PARAMETERS},
    # The studies' own: the figures' angle, and the goal regulator.
    "touchdown_angle": math.radians(26.0),
    "touchdown_power": math.nan,  # set it (or the study's alpha) for the open loop
    "target_energy": math.nan,  # the initial energy
    **perturbed.DEFAULTS,
}
"""The paper's hopper (figs. 8-13), the policies' declared settings but beta = 26 deg (figs. 7, 10) and the
goal regulator."""
StartRule = Literal["speed", "energy", "open_loop_fixed_point"]
START_RULES: dict[str, tuple[str, ...]] = {
    "speed": ("y0", "xdot0"),
    "energy": ("y0", "energy0"),
    "open_loop_fixed_point": ("y0",),
}
"""The initial-apex parameters each start rule needs (the others are derived)."""
DESIGN_STREAM = 0
"""spawn_key (index, DESIGN_STREAM): the stream of a trajectory's design draws (others: perturbations)."""


def analytic_map_fixed(analytic_map: str) -> dict[str, str]:
    """The fixed value that puts a study's policies on the analytic map ``analytic_map``: none for the
    default, so that a study on it keeps the design and digest, and so the chunks on disk, that it had
    before the setting existed (--resume)."""
    return {} if analytic_map == DEFAULTS["analytic_map"] else {"analytic_map": analytic_map}


class StudyError(ValueError):
    """The study design is inconsistent; the message says what to change."""


@dataclass(frozen=True)
class Uniform:
    """A Monte Carlo parameter drawn uniformly from [low, high]."""

    low: float
    high: float


def _grid_value(value: Any) -> Any:
    if isinstance(value, str):
        return value
    if isinstance(value, tuple | list | np.ndarray):
        return tuple(float(v) for v in value)
    return float(value)


Lanes = dict[str, np.ndarray]
"""Columns of a run of trajectories: ``trajectory`` (index), the CHOICES (str) and NUMERIC_PARAMETERS."""


@dataclass(frozen=True)
class Study:
    """A study: grid axes (name, values), Monte Carlo draws (name, Uniform) with ``samples`` per grid
    cell, fixed values, the start rule, strides per trajectory, chunk size, seed, the policies' map
    corrections and the hopper's m [kg], r0 [m], g [m/s^2]. Build it with :meth:`of`."""

    grid: tuple[tuple[str, tuple[Any, ...]], ...] = ()
    draws: tuple[tuple[str, Uniform], ...] = ()
    samples: int = 1
    fixed: tuple[tuple[str, str | float], ...] = ()
    start: StartRule = "energy"
    strides: int = 50
    chunk_size: int = 1000
    seed: int = 0
    corrections: int = 1
    hold_commands: bool = False
    mass: float = PAPER_PARAMS.m
    rest_length: float = PAPER_PARAMS.r0
    gravity: float = PAPER_PARAMS.g

    @classmethod
    def of(
        cls,
        grid: Mapping[str, Sequence[Any] | np.ndarray] | None = None,
        draws: Mapping[str, Uniform] | None = None,
        fixed: Mapping[str, str | float] | None = None,
        **settings: Any,
    ) -> Study:
        """A study from mappings (the grid's order is the axes' order, the first outermost). An axis
        "a,b" links parameters: its values are (a, b) pairs, taken together."""
        return cls(
            grid=tuple(
                (name, tuple(_grid_value(v) for v in values)) for name, values in (grid or {}).items()
            ),
            draws=tuple((draws or {}).items()),
            fixed=tuple((name, v if isinstance(v, str) else float(v)) for name, v in (fixed or {}).items()),
            **settings,
        )

    def __post_init__(self) -> None:
        named = (
            [name for axis, _ in self.grid for name in axis.split(",")]
            + [name for name, _ in self.draws]
            + [name for name, _ in self.fixed]
        )
        for name in named:
            if name not in PARAMETERS:
                raise StudyError(f"unknown study parameter {name!r}; one of {', '.join(PARAMETERS)}")
        repeated = sorted({name for name in named if named.count(name) > 1})
        if repeated:
            raise StudyError(f"parameter {repeated[0]!r} is given more than once (grid, draws, fixed)")
        for name, _ in self.draws:
            if name in GROUP_PARAMETERS:
                raise StudyError(
                    f"{name} is a grid axis or fixed, not drawn (one hopper, policy and model per call)"
                )
        for name, distribution in self.draws:
            if not (math.isfinite(distribution.low) and math.isfinite(distribution.high)):
                raise StudyError(f"the range of {name} must be finite, got {distribution}")
            if distribution.low > distribution.high:
                raise StudyError(
                    f"the range of {name} is empty: low {distribution.low} > high {distribution.high}"
                )
            for end in (distribution.low, distribution.high):
                self._check_value(name, end)
        for name, values in self.grid:
            if not values:
                raise StudyError(f"grid axis {name} has no values")
            width = len(name.split(","))
            if width > 1 and any(not isinstance(v, tuple) or len(v) != width for v in values):
                raise StudyError(f"the values of the linked axis {name} must be {width}-tuples")
        for name, value in self._values():
            self._check_value(name, value)
        if self.start not in START_RULES:
            raise StudyError(f"unknown start rule {self.start!r}; one of {', '.join(START_RULES)}")
        given = set(named)
        for name in START_PARAMETERS:
            needed = name in START_RULES[self.start]
            if needed and name not in given:
                raise StudyError(f"the start rule {self.start!r} needs {name} (grid, draws or fixed)")
            if not needed and name in given:
                raise StudyError(f"the start rule {self.start!r} derives {name}: do not set it")
        for name, least in (("strides", 1), ("chunk_size", 1), ("samples", 1), ("corrections", 0)):
            if getattr(self, name) < least:
                raise StudyError(f"{name} must be at least {least}, got {getattr(self, name)!r}")
        if not 0 <= self.seed < 2**31:
            raise StudyError(f"seed must be in [0, 2**31), got {self.seed!r}")
        self._check_perturbations(set(named))
        for kbar, zeta0 in self.hoppers():
            self.params(kbar, zeta0)

    def _values(self) -> list[tuple[str, str | float]]:
        return [pair for name in self._grid_names() for pair in self._grid_values(name)] + list(self.fixed)

    def _grid_names(self) -> list[str]:
        return [name for axis, _ in self.grid for name in axis.split(",")]

    def _grid_values(self, name: str) -> list[tuple[str, str | float]]:
        """(name, value) for every value of a parameter on a grid axis (alone, or linked with others)."""
        for axis, values in self.grid:
            names = axis.split(",")
            if name in names:
                position = names.index(name)
                return [(name, value[position] if len(names) > 1 else value) for value in values]
        return []

    def _check_value(self, name: str, value: str | float) -> None:
        if name in CHOICES:
            if not isinstance(value, str) or (CHOICES[name] and value not in CHOICES[name]):
                raise StudyError(f"unknown {name} {value!r}; one of {', '.join(CHOICES[name])}")
            return
        if isinstance(value, str):
            raise StudyError(f"{name} must be a number, got {value!r}")
        if name in perturbed.PERTURBATION_PARAMETERS:
            requirement = perturbed.check_value(name, value)
            if requirement is not None:
                raise StudyError(f"{name} must be {requirement}, got {value!r}")
        elif not math.isfinite(value) and name != "target_energy":
            raise StudyError(f"{name} must be a finite number, got {value!r}")

    def _check_perturbations(self, named: set[str]) -> None:
        """Perturbations need the closed loop that holds commands; one terrain per trajectory."""
        given = named & set(perturbed.PERTURBATION_PARAMETERS)
        if given and not self.hold_commands:
            raise StudyError(
                f"perturbations ({', '.join(sorted(given))}) need hold_commands: the perturbed closed loop "
                "keeps the command in force where the policy has none, as the plant does"
            )
        if self._may_be_nonzero("terrain_sigma") and self._may_be_nonzero("step_height"):
            raise StudyError(
                "a trajectory has one terrain: random blocks (terrain_sigma) or a step, not both"
            )

    def _may_be_nonzero(self, name: str) -> bool:
        drawn = dict(self.draws).get(name)
        if drawn is not None:
            return drawn.low != 0.0 or drawn.high != 0.0
        return any(value != 0.0 for value in self.values_of(name))

    def values_of(self, name: str) -> tuple[str | float, ...]:
        """The values a grid axis or fixed parameter takes (the default when neither names it)."""
        on_grid = self._grid_values(name)
        if on_grid:
            return tuple(value for _, value in on_grid)
        return (dict(self.fixed).get(name, DEFAULTS.get(name, math.nan)),)

    def hoppers(self) -> list[tuple[float, float]]:
        """Every (kbar, zeta0) of the study."""
        return [(float(k), float(z)) for k in self.values_of("kbar") for z in self.values_of("zeta0")]

    def params(self, kbar: float, zeta0: float) -> HopperParams:
        """The hopper of (kbar, zeta0) with the study's m, r0 and g."""
        if not 0.0 <= zeta0 < 1.0:
            raise StudyError(f"zeta0 must be in [0, 1) (an underdamped leg), got {zeta0!r}")
        try:
            return HopperParams.from_dimensionless(kbar, zeta0, self.mass, self.rest_length, self.gravity)
        except ParameterError as error:
            raise StudyError(str(error)) from None

    @property
    def cells(self) -> int:
        return math.prod(len(values) for _, values in self.grid)

    @property
    def size(self) -> int:
        """Trajectories in the study."""
        return self.cells * self.samples

    @property
    def chunks(self) -> int:
        return -(-self.size // self.chunk_size)

    def chunk_range(self, index: int) -> tuple[int, int]:
        """The trajectories [start, stop) of chunk ``index``."""
        if not 0 <= index < self.chunks:
            raise StudyError(f"chunk {index} is not in the study's {self.chunks} chunks")
        return index * self.chunk_size, min((index + 1) * self.chunk_size, self.size)

    def document(self) -> dict[str, Any]:
        """The design as JSON-ready data (the study directory's manifest)."""
        data = asdict(self)
        data["grid"] = [[name, list(values)] for name, values in self.grid]
        data["draws"] = [[name, [d.low, d.high]] for name, d in self.draws]
        data["fixed"] = [[name, value] for name, value in self.fixed]
        return data

    @property
    def digest(self) -> str:
        """A short hash of the design: names a study's chunks (and their Dask keys)."""
        text = json.dumps(self.document(), sort_keys=True, allow_nan=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def lanes(self, start: int, stop: int) -> Lanes:
        """The parameters of trajectories [start, stop), initial apex derived by the start rule (xdot0 NaN
        where no such apex exists, energy below m g y0) and NaN target energies set to the initial ones."""
        index = np.arange(start, stop, dtype=np.int64)
        cell = index // self.samples
        columns: Lanes = {"trajectory": index}
        shape = tuple(len(values) for _, values in self.grid)
        positions = np.unravel_index(cell, shape) if shape else ()
        for (axis, _), position in zip(self.grid, positions, strict=True):
            for name in axis.split(","):
                values = [value for _, value in self._grid_values(name)]
                columns[name] = np.asarray(values, dtype=object if name in CHOICES else float)[position]
        if self.draws:
            drawn = np.array([self._draw(int(i)) for i in index]).reshape(index.size, len(self.draws))
            for column, (name, _) in enumerate(self.draws):
                columns[name] = drawn[:, column]
        for name in PARAMETERS:
            if name not in columns:
                value = self.values_of(name)[0]
                columns[name] = np.full(index.size, value, dtype=object if name in CHOICES else float)
        for name in CHOICES:
            columns[name] = columns[name].astype(str)
        kinds = zip(columns["terrain_sigma"], columns["step_height"], strict=True)
        columns["terrain"] = np.array([perturbed.terrain_kind(sigma, step) for sigma, step in kinds])
        self._derive_start(columns)
        energy = columns["energy0"]
        columns["target_energy"] = np.where(
            np.isnan(columns["target_energy"]), energy, columns["target_energy"]
        )
        return columns

    def _draw(self, index: int) -> list[float]:
        generator = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(index, DESIGN_STREAM)))
        return [float(generator.uniform(d.low, d.high)) for _, d in self.draws]

    def _derive_start(self, columns: Lanes) -> None:
        """xdot0 and energy0 from the start rule, per hopper."""
        y0 = columns["y0"]
        for kbar, zeta0 in self.hoppers():
            mask = (columns["kbar"] == kbar) & (columns["zeta0"] == zeta0)
            if not mask.any():
                continue
            params = self.params(kbar, zeta0)
            if self.start == "speed":
                xdot = columns["xdot0"][mask]
                columns["energy0"][mask] = params.m * (params.g * y0[mask] + 0.5 * xdot**2)
                continue
            if self.start == "open_loop_fixed_point":
                angles, maps = columns["touchdown_angle"], columns["analytic_map"]
                for beta, name in sorted(set(zip(angles[mask], maps[mask], strict=True))):
                    lanes = mask & (angles == beta) & (maps == name)
                    alpha = units.power_to_alpha(params, columns["touchdown_power"][lanes])
                    columns["energy0"][lanes] = analytic_fixed_points.energy_fixed_point(
                        params,
                        float(beta),
                        alpha,
                        y0[lanes],
                        self.corrections,
                        speed=ANALYTIC_MAPS[str(name)],
                    )
            with np.errstate(invalid="ignore"):
                columns["xdot0"][mask] = speed_from_energy(params, y0[mask], columns["energy0"][mask])
