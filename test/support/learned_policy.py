"""Files of the ``learned`` policy for the tests: a linear residual on energy regulation at its default
settings, around the default apex, with the environments' default action scaling."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from tdslip_ros.envs.config import DEFAULT_COMMAND_HIGH, DEFAULT_COMMAND_LOW, DEFAULT_RESIDUAL_HALF_WIDTH
from tdslip_ros.model.policies import learned
from tdslip_ros.model.policies.registry import DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED

WEIGHTS = np.array([[-0.3, 0.2, 0.1], [0.4, -0.2, 0.05], [0.0, 0.1, -0.2]])
"""W | b of a residual that moves every command field at and around the default apex."""


def learned_file(path: Path, weights: npt.ArrayLike = WEIGHTS) -> str:
    """Write the residual of ``weights`` on energy regulation to ``path``; the path, as the setting is."""
    residual = learned.LinearResidual(
        weights=np.asarray(weights, dtype=np.float64),
        apex=np.array([DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED]),
        scale=np.array([0.1, 0.5]),
        base_policy="energy",
        base_settings={},
        half_width=np.asarray(DEFAULT_RESIDUAL_HALF_WIDTH),
        command_low=np.asarray(DEFAULT_COMMAND_LOW),
        command_high=np.asarray(DEFAULT_COMMAND_HIGH),
    )
    learned.save(residual, path)
    return str(path)


def malformed_file(directory: Path, **changes: Any) -> Path:
    """A copy of :func:`learned_file`'s file in ``directory`` with the top-level fields ``changes`` (default:
    a base policy that is the learned policy itself, which would plan with itself for ever)."""
    data = json.loads(Path(learned_file(directory / "good.json")).read_text())
    data.update(changes or {"base": {"policy": "learned", "settings": {}}})
    path = directory / "malformed.json"
    path.write_text(json.dumps(data))
    return path
