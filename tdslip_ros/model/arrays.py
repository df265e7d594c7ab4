"""The arrays the model's vectorised API speaks, and how a batch of them becomes the lanes of a compiled loop.

* :class:`ParamArrays`: hopper parameters as arrays that broadcast against states and commands;
* :class:`CommandArrays`: stance commands as arrays, with, per lane, the reason (:class:`NoCommand`) a
  policy has none there;
* :class:`Lanes` and :func:`elementwise`: inputs broadcast to one shape and flattened for a compiled lane
  loop, or mapped one lane at a time.

Everything is SI, as in :mod:`tdslip_ros.model.params`.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.events import FAILURE_KINDS, FailureKind
from tdslip_ros.model.params import (
    HUMAN_LIKE_LEG_LENGTH,
    HUMAN_LIKE_MASS,
    STANDARD_GRAVITY,
    HopperParams,
    ParameterError,
    StanceCommand,
)

Array = npt.NDArray[Any]
ArrayLike = npt.ArrayLike


@dataclass(frozen=True)
class ParamArrays:
    """Hopper parameters as arrays that broadcast against states and commands (SI, like HopperParams)."""

    m: Array
    k: Array
    r0: Array
    c: Array
    g: Array

    def __post_init__(self) -> None:
        for name in ("m", "k", "r0", "c", "g"):
            value = np.asarray(getattr(self, name), dtype=float)
            if not np.all(np.isfinite(value)):
                raise ParameterError(f"{name} must be finite everywhere")
            if name == "c":
                if np.any(value < 0.0):
                    raise ParameterError("c (damping) must be non-negative")
            elif np.any(value <= 0.0):
                raise ParameterError(f"{name} must be positive everywhere, got min {value.min()!r}")
            object.__setattr__(self, name, value)
        zeta0 = self.c / (2.0 * np.sqrt(self.m * self.k))
        if np.any(zeta0 >= 1.0):
            # zeta = c/(2 m wh) <= zeta0 for every stance, so zeta0 < 1 keeps every stance underdamped.
            raise ParameterError(
                "zeta0 = c/(2 sqrt(m k)) must be < 1 (underdamped leg) for the analytic map, "
                f"got max {zeta0.max()!r}"
            )

    @cached_property
    def column(self) -> Array | None:
        """m, k, r0, c, g as one (5, 1) column where they are scalars (one parameter set), else None: the
        compiled lane loops' parameter block for one lane, kept (a controller plans every apex with the same
        parameters). The loops only read it."""
        fields = (self.m, self.k, self.r0, self.c, self.g)
        if any(np.ndim(field) != 0 for field in fields):
            return None
        return np.array(fields, dtype=float).reshape(5, 1)

    @classmethod
    def of(cls, params: HopperParams | ParamArrays | Sequence[HopperParams]) -> ParamArrays:
        """Arrays from one parameter set (0-d arrays), several (1-d arrays) or an existing ParamArrays."""
        if isinstance(params, ParamArrays):
            return params
        if isinstance(params, HopperParams):
            params.require_fixed_body("the lane engines (analytic map, policies)")
            return _arrays_of_hopper(params)
        for each in params:
            each.require_fixed_body("the lane engines (analytic map, policies)")
        return cls(*(np.array([getattr(p, name) for p in params]) for name in ("m", "k", "r0", "c", "g")))

    @classmethod
    def from_dimensionless(
        cls,
        kbar: ArrayLike,
        zeta0: ArrayLike,
        m: ArrayLike = HUMAN_LIKE_MASS,
        r0: ArrayLike = HUMAN_LIKE_LEG_LENGTH,
        g: ArrayLike = STANDARD_GRAVITY,
    ) -> ParamArrays:
        """Arrays from the paper's kbar = k r0/(m g) and zeta0 = c/(2 sqrt(m k)) (eq. 24), broadcast."""
        m_, r0_, g_ = (np.asarray(v, dtype=float) for v in (m, r0, g))
        k = np.asarray(kbar, dtype=float) * m_ * g_ / r0_
        return cls(
            m=m_,
            k=k,
            r0=r0_,
            c=2.0 * np.asarray(zeta0, dtype=float) * np.sqrt(m_ * k),
            g=g_,
        )


@lru_cache(maxsize=64)
def _arrays_of_hopper(params: HopperParams) -> ParamArrays:
    """ParamArrays of one parameter set, kept: a controller plans every apex with the same parameters, and
    building and checking the arrays costs more than planning (their arrays are read-only, being shared)."""
    arrays = [np.array(getattr(params, name)) for name in ("m", "k", "r0", "c", "g")]
    for array in arrays:
        array.flags.writeable = False
    return ParamArrays(*arrays)


class NoCommand(enum.StrEnum):
    """Why a policy has no command for an apex (codes per lane: the index in NO_COMMAND_KINDS)."""

    LEG_PLACEMENT = "leg_placement"  # the leg cannot be placed at the angle (dynamics.can_place_leg)
    NO_LIFTOFF = "no_liftoff"  # the map the policy plans with predicts no liftoff
    PREDICTED_FALL = "predicted_fall"  # ... predicts a fall with the policy's command
    PREDICTED_REVERSAL = "predicted_reversal"  # ... predicts a reversal (or touchdown swings back)
    NO_SOLUTION = "no_solution"  # no torque solves the policy's equations with the body swinging forward

    def describe(self) -> str:
        return _NO_COMMAND_TEXT[self]


_NO_COMMAND_TEXT = {
    NoCommand.LEG_PLACEMENT: "the leg cannot be placed at the touchdown angle from this apex "
    "(dynamics.can_place_leg)",
    NoCommand.NO_LIFTOFF: "the map the policy plans with predicts no liftoff",
    NoCommand.PREDICTED_FALL: "the map the policy plans with predicts a fall with its command",
    NoCommand.PREDICTED_REVERSAL: "the map the policy plans with predicts a reversal with its command",
    NoCommand.NO_SOLUTION: "no torque solves the policy's equations with the body swinging forward",
}
NO_COMMAND_KINDS: tuple[NoCommand, ...] = tuple(NoCommand)
HAS_COMMAND = -1
"""no_command code of a lane that has its command."""
_NO_COMMAND_OF_FAILURE = {
    FailureKind.TOE_STUBBING: NoCommand.LEG_PLACEMENT,
    FailureKind.NO_LIFTOFF: NoCommand.NO_LIFTOFF,
    FailureKind.FALL: NoCommand.PREDICTED_FALL,
    FailureKind.REVERSAL: NoCommand.PREDICTED_REVERSAL,
}


def no_command_code(kind: NoCommand) -> int:
    return NO_COMMAND_KINDS.index(kind)


REASON_OF_FAILURE = np.array(
    [
        no_command_code(_NO_COMMAND_OF_FAILURE[kind]) if kind in _NO_COMMAND_OF_FAILURE else HAS_COMMAND
        for kind in FAILURE_KINDS
    ]
)
"""The no_command code for each failure code (HAS_COMMAND for the exact plant's other kinds)."""


class NoCommandError(ParameterError):
    """A policy has no command for the apex; ``reason`` says why."""

    def __init__(self, reason: NoCommand) -> None:
        super().__init__(f"no command ({reason.value}): {reason.describe()}")
        self.reason = reason


@dataclass(frozen=True, eq=False)
class CommandArrays:
    """The fields of :class:`StanceCommand` as broadcastable arrays (rad, N m, s).

    Iterates (and unpacks) as (touchdown_angle, tau0, t_f). ``no_command`` is set by the policies
    (:mod:`tdslip_ros.model.policies.controllers`): per lane HAS_COMMAND, or the code of the reason
    (:class:`NoCommand`) why the policy has none there, where the fields are NaN.
    """

    touchdown_angle: Array
    tau0: Array
    t_f: Array
    no_command: Array | None = None

    def __iter__(self) -> Iterator[Array]:
        return iter((self.touchdown_angle, self.tau0, self.t_f))

    def reason(self, index: int | tuple[int, ...] = ()) -> NoCommand | None:
        """Why lane ``index`` has no command, or None where it has one (or no reason was given)."""
        if self.no_command is None:
            return None
        code = int(np.asarray(self.no_command)[index])
        return None if code == HAS_COMMAND else NO_COMMAND_KINDS[code]

    def command(self, index: int | tuple[int, ...] = ()) -> StanceCommand:
        """One lane as a validated StanceCommand; NoCommandError (a ParameterError) where the policy has
        none."""
        reason = self.reason(index)
        if reason is not None:
            raise NoCommandError(reason)
        return StanceCommand(*(float(np.real(np.asarray(field)[index])) for field in self))


def command_arrays(command: CommandArrays | StanceCommand) -> CommandArrays:
    """A StanceCommand (or command arrays) as command arrays."""
    if isinstance(command, StanceCommand):
        return CommandArrays(
            np.asarray(command.touchdown_angle),
            np.asarray(command.tau0),
            np.asarray(command.t_f),
        )
    return CommandArrays(*(np.asarray(field) for field in command))


@dataclass(frozen=True)
class Lanes:
    """Inputs broadcast to one shape and flattened for a compiled lane loop: the hopper parameters as rows
    m, k, r0, c, g of one float64 block, the values as complex128 where any of them is complex (the complex
    step), else float64."""

    shape: tuple[int, ...]
    params: Array
    values: tuple[Array, ...]
    dtype: type

    @classmethod
    def of(cls, params: ParamArrays, *values: ArrayLike) -> Lanes:
        if params.column is not None and all(map(_is_scalar, values)):
            # One lane, the controller's call: nothing to broadcast, and the values in one array (at one
            # apex a time, this packaging costs about as much as the policies' kernels).
            together = np.array(values)
            kind: type = complex if together.dtype.kind == "c" else float
            together = together.astype(kind)
            return cls((), params.column, tuple(together[i : i + 1] for i in range(len(values))), kind)
        fields = (params.m, params.k, params.r0, params.c, params.g)
        arrays = [np.asarray(value) for value in values]
        dtype: type = complex if any(a.dtype.kind == "c" for a in arrays) else float
        shape = np.broadcast_shapes(*(np.shape(field) for field in fields), *(a.shape for a in arrays))

        def flat(value: Array, kind: type) -> Array:
            # Always a fresh, writable, C-ordered copy: numba compiles a loop once per array type, and a
            # read-only view (what broadcast_to gives) is another type than its copy.
            return np.array(np.broadcast_to(value, shape), dtype=kind, order="C").reshape(-1)

        block = np.stack([flat(field, float) for field in fields])
        return cls(shape, block, tuple(flat(a, dtype) for a in arrays), dtype)

    def run(self, loop: Callable[..., None], *arguments: Any) -> None:
        """Call a compiled lane loop with the parameters, the values and then ``arguments``."""
        loop(self.params, *self.values, *arguments)

    def rows(self, count: int) -> Array:
        """An output block of ``count`` rows, one column per lane."""
        return np.empty((count, math.prod(self.shape)), dtype=self.dtype)

    def shaped(self, row: Array) -> Array:
        return np.asarray(row.reshape(self.shape))

    def codes(self, row: Array) -> Array:
        """A row of integer codes (failure, no-command reason), held as numbers in the block."""
        return np.asarray(np.real(row).astype(int).reshape(self.shape))


def _is_scalar(value: ArrayLike) -> bool:
    return isinstance(value, (int, float, complex, np.number)) or (
        isinstance(value, np.ndarray) and value.ndim == 0
    )


def elementwise(function: Callable[..., Any], kinds: Sequence[type], *args: ArrayLike) -> tuple[Array, ...]:
    """``function`` (of one lane's scalars, returning len(kinds) scalars) over broadcast arrays, one Python
    call per lane: for the closed forms' API (checks, plots), not for batches. A kind of complex means the
    dtype of the arguments (complex128 if any is complex, else float64)."""
    dtype = complex if any(np.iscomplexobj(a) for a in args) else float
    otypes = [dtype if kind is complex else kind for kind in kinds]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # failed lanes: NaN, inf
        results = np.vectorize(function, otypes=otypes)(*args)
    return tuple(np.asarray(r) for r in (results if len(kinds) > 1 else (results,)))
