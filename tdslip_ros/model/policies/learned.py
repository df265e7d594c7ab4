"""A learned linear residual on a base policy: the one evaluation shared by the environments' residual mode
(``tdslip_ros.envs``), the trainer (``examples/learn_cem.py``) and the ``learned`` policy
(:class:`~tdslip_ros.model.policies.registry.PolicySpec`) that the controller node and the studies run.

At a measured apex (y [m], xdot [m/s]) the residual acts

    f = ((y - apex_y) / scale_y, (xdot - apex_xdot) / scale_xdot, 1)
    a = clip(W f, -1, 1)                                  (one row of W per command field)
    command = clip(base + half_width * a, command_low, command_high)

with ``base`` the base policy's command (touchdown angle [rad], tau0 [N m], t_f [s]) at the same apex. The
features are the apex only: the node suite senses no ground ahead, so a policy the controller node runs cannot
use it.

**File format** (JSON, :func:`save` and :func:`load`)::

    {"format": "tdslip_ros.linear_residual/1",
     "features": ["apex_height", "apex_speed"],       # the observation layout of f, before the bias
     "apex": [y, xdot], "scale": [m, m/s],            # the features' centre and unit
     "weights": [[...], [...], [...]],                # W | b: 3 rows (angle, tau0, t_f), 3 columns
     "base": {"policy": "energy", "settings": {...}}, # PolicySpec.of(policy, defaults | settings)
     "half_width": [rad, N m, s], "command_low": [...], "command_high": [...]}
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.arrays import CommandArrays

FORMAT = "tdslip_ros.linear_residual/1"
FEATURES = ("apex_height", "apex_speed")
COMMAND_ROWS = 3
"""The residual acts on every field of the ramp command: touchdown angle, tau0, t_f."""


def residual_command(
    centre: npt.ArrayLike,
    half_width: npt.ArrayLike,
    action: npt.ArrayLike,
    low: npt.ArrayLike,
    high: npt.ArrayLike,
) -> np.ndarray:
    """(3, lanes): the command centre + half_width * action (rows the command fields), clipped to [low, high]
    (each (3, 1) or (3, lanes))."""
    command: np.ndarray = np.clip(np.asarray(centre) + np.asarray(half_width) * np.asarray(action), low, high)
    return command


def linear_action(weights: npt.ArrayLike, features: npt.ArrayLike) -> np.ndarray:
    """(lanes, rows): clip(W f, -1, 1) for features (lanes, F + 1, the bias last) and weights (rows, F + 1)
    shared by all lanes or (lanes, rows, F + 1), one per lane (the trainer's candidates)."""
    w, f = np.asarray(weights, dtype=np.float64), np.asarray(features, dtype=np.float64)
    product = np.einsum("af,lf->la", w, f) if w.ndim == 2 else np.einsum("laf,lf->la", w, f)
    action: np.ndarray = np.clip(product, -1.0, 1.0)
    return action


def apex_features(
    y: npt.ArrayLike, xdot: npt.ArrayLike, apex: npt.ArrayLike, scale: npt.ArrayLike
) -> np.ndarray:
    """(lanes, 3): the measured apex's deviation from ``apex`` in units of ``scale``, and the bias 1."""
    y, xdot = np.broadcast_arrays(np.atleast_1d(np.asarray(y, dtype=np.float64)), np.asarray(xdot))
    centre, unit = np.asarray(apex, dtype=np.float64), np.asarray(scale, dtype=np.float64)
    return np.stack([(y - centre[0]) / unit[0], (xdot - centre[1]) / unit[1], np.ones(y.shape)], axis=1)


@dataclass(frozen=True, eq=False)
class LinearResidual:
    """A linear residual on a base policy (the module docstring); every array SI."""

    weights: np.ndarray
    apex: np.ndarray
    scale: np.ndarray
    base_policy: str
    base_settings: Mapping[str, float | str]
    half_width: np.ndarray
    command_low: np.ndarray
    command_high: np.ndarray
    features: tuple[str, ...] = field(default=FEATURES)

    def __post_init__(self) -> None:
        if self.features != FEATURES:
            raise ValueError(f"features {self.features} are not {FEATURES}")
        if np.shape(self.weights) != (COMMAND_ROWS, len(FEATURES) + 1):
            raise ValueError(
                f"weights must be {COMMAND_ROWS} x {len(FEATURES) + 1}, got {np.shape(self.weights)}"
            )
        for name in ("apex", "scale"):
            if np.shape(getattr(self, name)) != (len(FEATURES),):
                raise ValueError(f"{name} must have {len(FEATURES)} entries")
        for name in ("half_width", "command_low", "command_high"):
            if np.shape(getattr(self, name)) != (COMMAND_ROWS,):
                raise ValueError(f"{name} must have {COMMAND_ROWS} entries")
        for name in ("weights", "apex", "scale", "half_width", "command_low", "command_high"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"{name} must be finite numbers")
        if not np.all(self.scale > 0.0):
            raise ValueError(f"scale must be positive, got {self.scale.tolist()}")
        if not np.all(self.half_width >= 0.0):
            raise ValueError(f"half_width must not be negative, got {self.half_width.tolist()}")
        if not np.all(self.command_low < self.command_high):
            raise ValueError("command_low must lie below command_high in every field")

    def action(self, y: npt.ArrayLike, xdot: npt.ArrayLike) -> np.ndarray:
        """(lanes, 3): the normalised residual at measured apexes."""
        return linear_action(self.weights, apex_features(y, xdot, self.apex, self.scale))

    def commands(self, base: CommandArrays, y: npt.ArrayLike, xdot: npt.ArrayLike) -> CommandArrays:
        """The residual added to the base policy's commands ``base`` at the apexes (y, xdot); NaN (and the
        base's no_command) where the base has no command."""
        shape = np.broadcast_shapes(np.shape(y), np.shape(xdot), *(np.shape(row) for row in base))
        # evaluated flat, answered in the apexes' shape (a scalar for one apex, as the other policies)
        action = self.action(np.broadcast_to(y, shape).ravel(), np.broadcast_to(xdot, shape).ravel())
        centre = np.stack([np.broadcast_to(np.asarray(row, dtype=np.float64), shape).ravel() for row in base])
        command = residual_command(
            centre, self.half_width[:, None], action.T, self.command_low[:, None], self.command_high[:, None]
        ).reshape(COMMAND_ROWS, *shape)
        return CommandArrays(command[0], command[1], command[2], base.no_command)

    def to_json(self) -> dict[str, object]:
        return {
            "format": FORMAT,
            "features": list(self.features),
            "apex": self.apex.tolist(),
            "scale": self.scale.tolist(),
            "weights": self.weights.tolist(),
            "base": {"policy": self.base_policy, "settings": dict(self.base_settings)},
            "half_width": self.half_width.tolist(),
            "command_low": self.command_low.tolist(),
            "command_high": self.command_high.tolist(),
        }


def save(residual: LinearResidual, path: Path) -> None:
    """Write ``residual`` to ``path`` (the module docstring's format)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(residual.to_json(), indent=1) + "\n")


def load(path: str | Path) -> LinearResidual:
    """The residual in the file ``path``, read once per version of the file (the controller answers every
    apex with it)."""
    stat = os.stat(path)
    return _load(str(path), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=8)
def _load(path: str, mtime_ns: int, size: int) -> LinearResidual:
    """OSError if the file cannot be read, ValueError (saying what is wrong) if it is not a residual."""
    del mtime_ns, size  # the cache key: a rewritten file is read again
    data = json.loads(Path(path).read_text())
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"not a {FORMAT} file")
    try:
        base = data["base"]
        if not isinstance(base, dict) or not isinstance(base.get("policy"), str):
            raise ValueError('"base" must be {"policy": NAME, "settings": {...}}')
        return LinearResidual(
            weights=np.asarray(data["weights"], dtype=np.float64),
            apex=np.asarray(data["apex"], dtype=np.float64),
            scale=np.asarray(data["scale"], dtype=np.float64),
            base_policy=base["policy"],
            base_settings=dict(base["settings"]),
            half_width=np.asarray(data["half_width"], dtype=np.float64),
            command_low=np.asarray(data["command_low"], dtype=np.float64),
            command_high=np.asarray(data["command_high"], dtype=np.float64),
            features=tuple(data["features"]),
        )
    except KeyError as error:
        raise ValueError(f"no field {error}") from None
    except TypeError as error:  # a field of the wrong kind (a number where a list belongs, ...)
        raise ValueError(f"a field of the wrong kind: {error}") from None
