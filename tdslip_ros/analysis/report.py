"""A recorded run against the analytic map, as numbers and pictures: what ``tdslip analyze RUN --out DIR``
writes and prints.

Writes ``DIR/summary.json`` (run, hopper parameters, policy, per-stride records and predictions,
convergence, fixed points, eigenvalues), four PNG figures and ``DIR/report.md``, and prints the
headline numbers. Policy settings that the recording does not show can be given on the command line
(see :func:`tdslip_ros.analysis.compare.policy_for_run`); so can the hopper parameters (``--params``,
a ROS parameter file such as config/plant.yaml), which otherwise come from the bag's custom_data
(``tdslip run`` stores them) or are inferred from the recording. A run of a controller of the user's
own is analysed without a policy unless ``--policy`` names one; the report says what that skips.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no type stubs

from tdslip_ros.analysis import plots
from tdslip_ros.analysis.compare import (
    CORRECTIONS,
    Comparison,
    FixedPoint,
    compare_run,
    comparison_summary,
    dimensionless,
    policy_for_run,
)
from tdslip_ros.analysis.reader import FAILURE_KINDS, Run, RunReadError
from tdslip_ros.interfaces import hopper_from_parameters, perturbation_parameters
from tdslip_ros.model import units
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.perturbations import MISMATCH_FIELDS, Mismatch
from tdslip_ros.model.policies import POLICIES, PolicySpec, settings_of
from tdslip_ros.reporting.output import to_json

FIGURES = {
    "apex_sequence": "apex height and speed per stride",
    "return_map": "return-map cobweb over the analytic map",
    "com_trajectory": "COM trajectory with GRF directions and virtual footfalls (fig. 12)",
    "energy_flows": "energy input against losses per stride",
    "terrain_path": "COM path over the ground, toe landings and saturated stances",
    "measured_apex": "true and measured apexes per stride, saturated strides",
}


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


def stride_table(comparison: Comparison) -> list[dict[str, Any]]:
    """One JSON row per recorded stride: apex, applied command, energy flows, failure, predictions."""
    run, predictions = comparison.run, comparison.predictions
    row_of = {int(k): i for i, k in enumerate(predictions.stride)}
    rows = []
    for stride in run.strides:
        row: dict[str, Any] = {
            "stride": stride.stride,
            "t": stride.t,
            "y": stride.y,
            "xdot": stride.xdot,
            "energy": stride.energy,
            "command": None if stride.command is None else asdict(stride.command),
            "policy": stride.policy or None,
            "hip_work": stride.hip_work,
            "damping_loss": stride.damping_loss,
            "spring_loss": stride.spring_loss,
            "failure": stride.failure,
            "failure_reason": stride.failure_reason or None,
            "ground": stride.ground,
            "stance_ground": stride.stance_ground,
            "measured_y": stride.measured_y,
            "measured_xdot": stride.measured_xdot,
            "placed_angle": stride.placed_angle,
            "push": stride.push,
            "saturated": stride.saturated,
        }
        i = row_of.get(stride.stride)
        if i is not None:
            row["next_apex_predicted"] = {
                **{f"analytic_{c}_corrections": predictions.analytic[c][i].tolist() for c in CORRECTIONS},
                "exact_map": predictions.exact[i].tolist(),
            }
            row["analytic_failure"] = {
                f"analytic_{c}_corrections": predictions.analytic_failures[c][i] for c in CORRECTIONS
            }
        rows.append(row)
    return rows


def run_summary(run: Run) -> dict[str, Any]:
    params = run.params
    outcome = None if run.outcome is None else asdict(run.outcome)
    return {
        "path": str(run.path),
        "apexes_recorded": len(run.strides),
        "sim_time": float(run.samples.t[-1]) if len(run.samples) else run.strides[-1].t,
        "samples": len(run.samples),
        "outcome": outcome,
        "message_counts": run.message_counts,
        "params": {**asdict(params), "kbar": params.kbar, "zeta0": params.zeta0, "source": run.params_source},
        "controller_params": None if run.controller_params is None else asdict(run.controller_params),
        "perturbations": {
            **perturbation_parameters(run.perturbations),
            "mismatch": _mismatch(run),
            "saturated_strides": run.saturated_strides,
        },
        "failure_location": failure_location(run),
    }


def _mismatch(run: Run) -> dict[str, float] | None:
    """The factors by which the controller's model differs from the plant's (None: it does not)."""
    planner = run.planner
    if planner == run.params:
        return None
    return {
        name: getattr(planner, field) / getattr(run.params, field) for name, field in MISMATCH_FIELDS.items()
    }


def failure_location(run: Run) -> dict[str, float] | None:
    """Where a failed run failed: the body's x and the ground under it at the last sample, and the toe
    and ground of the failed stride's stance if it touched down (None for a run that did not fail)."""
    if run.outcome is None or run.outcome.kind not in FAILURE_KINDS:
        return None
    failed = next((s for s in run.strides if s.failure is not None), run.strides[-1])
    touchdown = next((c for c in run.contacts if c.kind == "touchdown" and c.stride == failed.stride), None)
    samples = run.samples
    return {
        "x": float(samples.x[-1]) if len(samples) else failed.x,
        "ground_under_body": float(samples.ground_height[-1]) if len(samples) else failed.ground,
        "toe_x": math.nan if touchdown is None else touchdown.state.toe_x,
        "stance_ground": math.nan if touchdown is None else touchdown.ground,
    }


def analyze(
    run: Run, out: Path, policy_overrides: dict[str, Any] | None = None, stride: int | None = None
) -> Analysis:
    """Compare ``run``, write the summary JSON, the figures and the Markdown report into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    comparison = compare_run(run, policy_for_run(run, **(policy_overrides or {})))
    files = {name: out / f"{name}.png" for name in FIGURES}
    drawers = {
        "apex_sequence": lambda path: plots.apex_sequence(comparison, path),
        "return_map": lambda path: plots.return_map(comparison, path),
        "com_trajectory": lambda path: plots.com_trajectory(run, path, stride),
        "energy_flows": lambda path: plots.energy_flows(comparison, path),
        "terrain_path": lambda path: plots.terrain_path(run, path),
        "measured_apex": lambda path: plots.measured_apex(comparison, path),
    }
    if len(run.samples) == 0:  # no state recorded: no path to draw
        del files["terrain_path"]
    if plots.last_complete_stride(run) is None:  # failed in its first stride: nothing per stride to draw
        del files["com_trajectory"], files["energy_flows"]
    elif len(run.samples) == 0 and stride is None:
        del files["com_trajectory"]
    for name, path in files.items():
        drawers[name](path)
    summary = {
        "run": run_summary(run),
        "comparison": comparison_summary(comparison),
        "figures": {name: path.name for name, path in files.items()},
        "strides": stride_table(comparison),
    }
    files["summary"] = out / "summary.json"
    files["summary"].write_text(to_json(summary))
    files["report"] = out / "report.md"
    files["report"].write_text(markdown(comparison, summary))
    return Analysis(comparison, summary, files)


# --- text ---------------------------------------------------------------------------------------


def _outcome_text(run: Run) -> str:
    if run.outcome is None:
        return "the recording ends before the run did"
    return f"ended {run.outcome.kind} at stride {run.outcome.stride} ({run.outcome.reason})"


def _perturbation_lines(run: Run) -> list[str]:
    """What perturbed the run, the saturated strides, and where a run on uneven ground failed."""
    perturbations = replace(run.perturbations, mismatch=Mismatch(**(_mismatch(run) or {})))
    lines = [perturbations.summary()]
    if perturbations.saturates:
        lines.append(f"the hip saturated (|tau0| > tau_max) in {run.saturated_strides} stride(s)")
    where = failure_location(run)
    if where is not None and not perturbations.terrain.is_flat and run.outcome is not None:
        stance = (
            f"; its stance's toe at x = {where['toe_x']:.3f} m on ground {where['stance_ground']:.4f} m"
            if math.isfinite(where["toe_x"])
            else ""
        )
        lines.append(
            f"failed on the terrain at x = {where['x']:.3f} m over ground {where['ground_under_body']:.4f} m"
            f"{stance}: {run.outcome.kind}: {run.outcome.reason}"
        )
    return lines


_IN_PAPER_TERMS: dict[str, Callable[[HopperParams, float], str]] = {
    "touchdown_angle": lambda params, value: f"{math.degrees(value):.2f} deg",
    "touchdown_power": lambda params, value: f"alpha {units.power_to_alpha(params, value):.4f}",
    "target_energy": lambda params, value: f"Ebar {units.energy_to_bar(params, value):.4f}",
}
"""What the report adds to a setting's SI value: the paper's dimensionless value (eq. 24), or degrees."""


def policy_settings_text(policy: PolicySpec, params: HopperParams) -> str:
    """The values of the settings ``policy`` uses (model.policies.POLICY_SETTINGS), each as name = value
    unit, with the paper's terms where the report has them."""
    parts = []
    for setting in settings_of(policy.name):
        value = getattr(policy, setting.name)
        unit = f" {setting.unit}" if setting.unit else ""
        in_paper_terms = _IN_PAPER_TERMS.get(setting.name)
        extra = f" ({in_paper_terms(params, value)})" if in_paper_terms else ""
        parts.append(f"{setting.name} = {value:.6g}{unit}{extra}")
    return ", ".join(parts)


def _policy_text(comparison: Comparison) -> str:
    policy, params, deviation = comparison.policy, comparison.run.params, comparison.command_deviation
    if policy is None or deviation is None:  # None together: no policy to replay
        shown = comparison.run.policies
        what = f"polic{'y' if len(shown) == 1 else 'ies'} {', '.join(shown)}" if shown else "no command"
        return (
            f"policy not replayed: the recording shows {what}, not one policy tdslip_ros knows; checking "
            "that it reproduces the recorded commands and the analytic fixed point are skipped, the "
            "predictions use the applied commands. To compare with a known policy: "
            f"--policy {{{','.join(POLICIES)}}} and its settings (see --help)"
        )
    detail = policy_settings_text(policy, params)
    if math.isnan(deviation):
        replay = "no command was applied, so there is nothing to check it against"
    elif comparison.policy_reproduced:
        replay = f"replaying it reproduces the recorded commands (max rel. dev. {deviation:.1e})"
    else:
        replay = (
            "WARNING: replaying it does NOT reproduce the recorded commands (max rel. dev. "
            f"{deviation:.1e}); give the run's settings (--target-..., see --help)"
        )
    return f"policy {policy.name} ({detail}); {replay}"


def _fixed_point_row(
    label: str, params: HopperParams, fixed: FixedPoint | None, converged: bool = True
) -> str:
    if fixed is None:
        return f"  {label:<9} {'-':>9} {'-':>9} {'-':>9}"
    bar = dimensionless(params, (fixed.y, fixed.xdot))
    point = f"{bar[0]:>9.5f} {bar[1]:>9.5f}" if converged else f"{'-':>9} {'-':>9}"
    return f"  {label:<9} {point} {abs(fixed.dominant):>9.4f}"


def headline(comparison: Comparison) -> str:
    """The compact summary ``tdslip analyze`` prints."""
    run = comparison.run
    params = run.params
    apexes = f"{len(run.strides)} apex{'es' if len(run.strides) != 1 else ''}"
    simulated = run.samples.t[-1] if len(run.samples) else 0.0
    lines = [
        f"run {run.path}: {apexes}, {simulated:.2f} s simulated, {_outcome_text(run)}",
        f"hopper: m = {params.m:.4g} kg, k = {params.k:.6g} N/m, r0 = {params.r0:.4g} m, "
        f"c = {params.c:.5g} N s/m, g = {params.g:.4g} m/s^2 "
        f"(kbar {params.kbar:.4g}, zeta0 {params.zeta0:.4g}; {run.params_source})",
        *_perturbation_lines(run),
        _policy_text(comparison),
        f"next-apex prediction error, dimensionless, over {comparison.exact_errors.strides} strides:",
        f"  {'':<30} {'height max':>10} {'mean':>9} {'speed max':>10} {'mean':>9}",
    ]
    rows = [
        (f"analytic map, {c} correction{'s' if c != 1 else ''}", comparison.errors[c]) for c in CORRECTIONS
    ]
    rows.append(("exact map (DOP853)", comparison.exact_errors))
    for label, stats in rows:
        failures = f"  ({stats.failures} predicted to fail)" if stats.failures else ""
        lines.append(
            f"  {label:<30} {stats.max_height:>10.2e} {stats.mean_height:>9.2e} "
            f"{stats.max_speed:>10.2e} {stats.mean_speed:>9.2e}{failures}"
        )
    failed = next((s.stride for s in run.strides if s.failure is not None), None)
    predictions = comparison.predictions
    if failed is not None and failed in predictions.stride:
        foreseen = predictions.analytic_failures[1][list(predictions.stride).index(failed)] or "a next apex"
        lines.append(f"the analytic map (1 correction) predicted {foreseen} for stride {failed}")
    converged, recorded = comparison.converged_at, comparison.recorded_fixed_point
    if converged is not None:
        lines.append(f"converged (apex change < 1e-4) from stride {converged}")
    elif recorded is not None:
        lines.append(
            "not converged: the apex changes are below 1e-4 but grow "
            f"(|lambda| = {abs(recorded.dominant):.4f})"
        )
    else:
        lines.append(
            "not converged: the last apex change is not below 1e-4"
            if run.outcome is None or run.outcome.kind == "run_complete"
            else "not converged: the run failed"
        )
    lines.append(f"  {'fixed pt':<9} {'ybar':>9} {'xdotbar':>9} {'|lambda|':>9}")
    lines.append(_fixed_point_row("recorded", params, recorded, converged is not None))
    lines.append(_fixed_point_row("analytic", params, comparison.analytic_fixed_point))
    lines.append(
        f"energy balance per stride: largest residual {comparison.energy_balance_residual:.1e} (relative)"
    )
    return "\n".join(lines)


def markdown(comparison: Comparison, summary: dict[str, Any]) -> str:
    figures = "\n".join(f"![{FIGURES[name]}]({file})\n" for name, file in summary["figures"].items())
    return (
        f"# Run analysis: {comparison.run.path.name}\n\n"
        "Recorded run against the analytic apex return map of the paper (dimensionless units of eq. 24 "
        "unless marked). Numbers: `summary.json`.\n\n"
        f"```\n{headline(comparison)}\n```\n\n{figures}"
    )
