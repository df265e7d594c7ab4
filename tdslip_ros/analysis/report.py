"""A recorded run against the analytic map, as numbers and pictures: what ``tdslip analyze RUN --out DIR``
writes and prints.

Writes ``DIR/summary.json`` (run, how it ended, hopper parameters, policy, per-stride records and
predictions, convergence, fixed points, eigenvalues; each number's key says its unit, see
``report_text.UNITLESS_KEYS``),
the PNG figures that show something (:func:`omitted_figures`) and ``DIR/report.md``, which leads with the
results and ends with a glossary of every term it uses (:mod:`.report_text`), and prints the headline numbers.
Policy settings that the recording does not show can be given on the command line (see
:func:`tdslip_ros.analysis.compare.policy_for_run`); so can the hopper parameters (``--params``, a ROS
parameter file such as config/plant.yaml), which otherwise come from the bag's custom_data (``tdslip run``
stores them) or are inferred from the recording. A run of a controller of the user's
own is analysed without a policy unless ``--policy`` names one; the report says what that skips.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs

from tdslip_ros.analysis import plots
from tdslip_ros.analysis.compare import (
    CORRECTIONS,
    Comparison,
    compare_run,
    comparison_summary,
    policy_for_run,
)
from tdslip_ros.analysis.decoding import RunReadError
from tdslip_ros.analysis.records import Run
from tdslip_ros.analysis.report_text import FIGURES, markdown
from tdslip_ros.interfaces import (
    hopper_from_parameters,
    perturbation_parameters,
)
from tdslip_ros.model.params import HopperParams, ParameterError, StanceCommand
from tdslip_ros.reporting.output import to_json, unit_key


@dataclass(frozen=True)
class Analysis:
    comparison: Comparison
    summary: dict[str, Any]
    files: dict[str, Path]


def hopper_params_from_yaml(path: Path) -> HopperParams:
    """The hopper block (mass, stiffness, rest_length, damping, gravity) of a ROS parameter file."""
    try:
        document = yaml.safe_load(Path(path).read_text())
        return hopper_from_parameters(next(iter(document.values()))["ros__parameters"])
    except (OSError, yaml.YAMLError, AttributeError, StopIteration, KeyError, TypeError, ValueError) as error:
        raise RunReadError(f"{path}: no hopper parameters (mass, stiffness, ...) in it: {error!r}") from None
    except ParameterError as error:
        raise RunReadError(f"{path}: {error}") from None


def command_summary(command: StanceCommand | None) -> dict[str, float] | None:
    """JSON-ready stance command: touchdown angle, the hip torque ramp's tau0 and duration t_f."""
    if command is None:
        return None
    return {
        "touchdown_angle_rad": command.touchdown_angle,
        "tau0_N_m": command.tau0,
        "t_f_s": command.t_f,
    }


def _apex(apex: npt.ArrayLike) -> dict[str, float]:
    y, xdot = np.asarray(apex, dtype=float).tolist()
    return {"y_m": y, "xdot_m_per_s": xdot}


def stride_table(comparison: Comparison) -> list[dict[str, Any]]:
    """One JSON row per recorded stride: apex, applied command, energy flows, failure, predictions."""
    run, predictions = comparison.run, comparison.predictions
    row_of = {int(k): i for i, k in enumerate(predictions.stride)}
    rows = []
    for stride in run.strides:
        row: dict[str, Any] = {
            "stride": stride.stride,
            "t_s": stride.t,
            "y_m": stride.y,
            "xdot_m_per_s": stride.xdot,
            "energy_J": stride.energy,
            "command": command_summary(stride.command),
            "policy": stride.policy or None,
            "hip_work_J": stride.hip_work,
            "damping_loss_J": stride.damping_loss,
            "spring_loss_J": stride.spring_loss,
            "failure": stride.failure,
            "failure_reason": stride.failure_reason or None,
            "ground_m": stride.ground,
            "stance_ground_m": stride.stance_ground,
            "measured_y_m": stride.measured_y,
            "measured_xdot_m_per_s": stride.measured_xdot,
            "placed_angle_rad": stride.placed_angle,
            "push_m_per_s": stride.push,
            "saturated": stride.saturated,
        }
        i = row_of.get(stride.stride)
        if i is not None:
            row["next_apex_predicted"] = {
                **{f"analytic_{c}_corrections": _apex(predictions.analytic[c][i]) for c in CORRECTIONS},
                "exact_map": _apex(predictions.exact[i]),
            }
            row["analytic_failure"] = {
                f"analytic_{c}_corrections": predictions.analytic_failures[c][i] for c in CORRECTIONS
            }
        rows.append(row)
    return rows


def outcome_summary(run: Run) -> dict[str, Any]:
    """How the run ended (RUN_ENDINGS), whether it failed (None: unknown), and the final Status's kind,
    reason, stride and time."""
    ended, outcome = run.ending, run.outcome
    return {
        "ended": ended,
        "failed": None if outcome is None else ended == "failed",
        "kind": None if outcome is None else outcome.kind,
        "reason": None if outcome is None else outcome.reason,
        "stride": None if outcome is None else outcome.stride,
        "t_s": None if outcome is None else outcome.t,
    }


def run_summary(run: Run) -> dict[str, Any]:
    params = run.params
    return {
        "path": str(run.path),
        "apexes_recorded": len(run.strides),
        "sim_time_s": float(run.samples.t[-1]) if len(run.samples) else run.strides[-1].t,
        "samples": run.samples_recorded,
        "samples_kept": len(run.samples),
        "outcome": outcome_summary(run),
        "message_counts": run.message_counts,
        "params": {
            **hopper_summary(params),
            "kbar": params.kbar,
            "zeta0": params.zeta0,
            "source": run.params_source,
        },
        "controller_params": None if run.controller_params is None else hopper_summary(run.controller_params),
        "perturbations": perturbation_summary(run),
        "failure_location": run.failure_location,
    }


HOPPER_UNITS = {"m": "kg", "k": "N/m", "r0": "m", "c": "N s/m", "g": "m/s^2"}
"""The SI unit of each HopperParams field."""
PERTURBATION_UNITS = {
    "apex_height_noise": "m",
    "apex_speed_noise": "m/s",
    "angle_noise": "rad",
    "tau_max": "N m",
}
"""The SI unit of each numeric perturbation parameter of the plant (interfaces.PERTURBATION_PARAMETERS) but
the seeds; the others are text (terrain, pushes)."""


BODY_UNITS = {"inertia": "kg m^2", "hip_x": "m", "hip_y": "m", "tip_limit": "rad"}
"""The units of a RigidBody's fields."""


def hopper_summary(params: HopperParams) -> dict[str, Any]:
    """JSON-ready hopper parameters, each key with its unit, and ``body``: null for the paper's fixed body,
    else the rigid body's."""
    body = None
    if params.body is not None:
        body = {unit_key(name, unit): getattr(params.body, name) for name, unit in BODY_UNITS.items()}
    return {
        **{unit_key(name, unit): getattr(params, name) for name, unit in HOPPER_UNITS.items()},
        "body": body,
    }


def perturbation_summary(run: Run) -> dict[str, Any]:
    """JSON-ready perturbations of ``run`` (the plant's parameters, each key with its unit; tau_max null
    without a torque limit), the mismatch factors and the saturated strides."""
    values = perturbation_parameters(run.perturbations)
    if not run.perturbations.saturates:
        values["tau_max"] = None  # the parameter's 0: no limit
    return {
        **{unit_key(name, PERTURBATION_UNITS.get(name, "")): value for name, value in values.items()},
        "mismatch": _mismatch_summary(run),
        "saturated_strides": run.saturated_strides,
    }


def _mismatch_summary(run: Run) -> dict[str, float] | None:
    mismatch = run.mismatch
    return None if mismatch is None else {f"{name}_factor": factor for name, factor in mismatch.items()}


def omitted_figures(run: Run, stride: int | None = None) -> dict[str, str]:
    """The FIGURES not drawn for ``run``, each with the reason: those with nothing to draw (no complete
    stride, no recorded state), and those that would show nothing the others do not: the path over the
    ground on flat ground (the centre of mass is in com_trajectory, the apexes in apex_sequence), the
    measured apexes where the sensor reported the true ones and the hip never saturated. ``stride``: the
    stride com_trajectory is asked to draw (None: the last complete one)."""
    omitted = {}
    if run.params.body is None:
        omitted["body_pitch"] = "the paper's fixed body: its pitch is 0"
    else:
        omitted["return_map"] = "the analytic map is the fixed body's: it predicts no stride of a rigid body"
    if plots.last_complete_stride(run) is None:
        omitted["com_trajectory"] = omitted["energy_flows"] = (
            "no complete stride: the run failed in its first"
        )
    elif len(run.samples) == 0 and stride is None:
        omitted["com_trajectory"] = "no 1 kHz state recorded: no path to draw"
    if len(run.samples) == 0:
        omitted["terrain_path"] = "no 1 kHz state recorded: no path to draw"
    elif run.perturbations.terrain.is_flat and not np.any(run.samples.ground_height != 0.0):
        omitted["terrain_path"] = "flat ground: nothing beyond com_trajectory and apex_sequence"
    true = run.apex_array()
    measured = np.array([(s.measured_y - s.ground, s.measured_xdot) for s in run.strides]).reshape(-1, 2)
    differs = np.isfinite(measured) & (measured != true)
    if not np.any(differs) and run.saturated_strides == 0:
        omitted["measured_apex"] = "the sensor reported the true apexes and the hip never saturated"
    return omitted


def analyze(
    run: Run, out: Path, policy_overrides: dict[str, Any] | None = None, stride: int | None = None
) -> Analysis:
    """Compare ``run``, write the summary JSON, the figures and the Markdown report into ``out``. An
    ``analytic_map`` among ``policy_overrides`` is the map of the predictions too, policy or none."""
    out.mkdir(parents=True, exist_ok=True)
    overrides = policy_overrides or {}
    comparison = compare_run(run, policy_for_run(run, **overrides), overrides.get("analytic_map"))
    omitted = omitted_figures(run, stride)
    files = {name: out / f"{name}.png" for name in FIGURES if name not in omitted}
    drawers = {
        "apex_sequence": lambda path: plots.apex_sequence(comparison, path),
        "return_map": lambda path: plots.return_map(comparison, path),
        "com_trajectory": lambda path: plots.com_trajectory(run, path, stride),
        "energy_flows": lambda path: plots.energy_flows(comparison, path),
        "terrain_path": lambda path: plots.terrain_path(run, path),
        "measured_apex": lambda path: plots.measured_apex(comparison, path),
        "body_pitch": lambda path: plots.body_pitch(comparison, path),
    }
    for name, path in files.items():
        drawers[name](path)
    summary = {
        "run": run_summary(run),
        "comparison": comparison_summary(comparison),
        "figures": {name: path.name for name, path in files.items()},
        "figures_omitted": omitted,
        "strides": stride_table(comparison),
    }
    files["summary"] = out / "summary.json"
    files["summary"].write_text(to_json(summary))
    files["report"] = out / "report.md"
    files["report"].write_text(markdown(comparison, summary))
    return Analysis(comparison, summary, files)
