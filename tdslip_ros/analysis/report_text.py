"""What ``tdslip analyze`` says of a run in words: the results block of ``report.md`` and the headline it
prints (:func:`headline`), the report's glossary of every term it uses (:func:`glossary`) and the Markdown
around them (:func:`markdown`). The numbers come from :mod:`.compare` and :mod:`.report`'s summary; each
figure has its caption here (FIGURES).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from tdslip_ros.analysis import plots
from tdslip_ros.analysis.compare import (
    CONVERGENCE_TOLERANCE,
    CORRECTIONS,
    KNOWN_POLICIES,
    Comparison,
    FixedPoint,
    dimensionless,
)
from tdslip_ros.analysis.records import Run
from tdslip_ros.analysis.stance_feedback import largest_errors, largest_pitch_errors
from tdslip_ros.interfaces import (
    RUN_COMPLETE,
    STOP_REQUESTED,
)
from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import ANALYTIC_MAPS, DEFAULT_ANALYTIC_MAP
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.plant.perturbations import Mismatch
from tdslip_ros.model.policies.registry import PolicySpec, settings_of
from tdslip_ros.reporting.output import DIMENSIONLESS_SUFFIXES, UNIT_SUFFIXES

FIGURES = {
    "apex_sequence": "apex height and speed per stride",
    "return_map": "return-map cobweb over the analytic map",
    "com_trajectory": "COM trajectory with GRF directions and virtual footfalls (fig. 12)",
    "energy_flows": "energy input against losses per stride",
    "terrain_path": "COM path over the ground, toe landings and saturated stances",
    "measured_apex": "true and measured apexes per stride, saturated strides",
    "body_pitch": "a rigid body's pitch and pitch rate per stride, recorded and replayed on the exact map",
}


RUN_ENDINGS = {
    "completed": f"the plant ended the run normally ({RUN_COMPLETE}): it reached its stride limit "
    "(max_strides) or the wall-time limit it was given",
    "stopped": f"the run was stopped on request before its limits ({RUN_COMPLETE}, '{STOP_REQUESTED}')",
    "failed": "the hopper failed: the run ended in a failure, named by its kind (toe_stubbing, no_liftoff, "
    "fall, reversal, state_limit, command_timeout, publish_failed)",
    "unknown": "the recording ends before the run did: it holds no final status",
}
"""How a run ended (``run.outcome.ended`` in summary.json), and what each way means."""


UNITLESS_KEYS = {
    "stride": "the index of a stride (of its apex)",
    "strides": "the number of strides compared",
    "failures": "the number of those a map predicted to fail",
    "apexes_recorded": "the number of recorded apexes",
    "samples": "the number of 1 kHz states recorded",
    "samples_kept": "the number of those the analysis kept (all of up to 10 minutes, FULL_RATE_SAMPLES)",
    "message_counts": "messages recorded, by topic",
    "saturated_strides": "the number of strides in which the hip saturated",
    "converged_at_stride": "the stride from which the run converged",
    "corrections": "correction iterations of the analytic map the policy plans with",
    "apex_noise_seed": "the seed of the sensor's noise",
    "angle_noise_seed": "the seed of the placement error",
    "zeta0": "the damping ratio c/(2 sqrt(m k))",
    "eigenvalues": "the eigenvalues lambda of a fixed point, as [real, imaginary]",
    "dominant_modulus": "|lambda|, the largest modulus of those",
}
"""The keys of summary.json whose numbers carry no unit suffix: counts, indices, seeds and dimensionless
numbers; every other number's key ends in its unit (reporting.output.UNIT_SUFFIXES) or in a dimensionless
suffix (DIMENSIONLESS_SUFFIXES)."""


def _body_lines(params: HopperParams) -> list[str]:
    body = params.body
    if body is None:
        return []
    return [
        f"body: rigid, J = {body.inertia:.4g} kg m^2, hip at ({body.hip_x:.4g}, {body.hip_y:.4g}) m from the "
        f"centre of mass at pitch 0, tips past {body.tip_limit:.4g} rad (docs/rotating_body.md); the "
        "analytic map is the fixed body's and predicts none of its strides"
    ]


def _outcome_text(run: Run) -> str:
    outcome, ended = run.outcome, run.ending
    if outcome is None:
        return "the recording ends before the run did"
    if ended == "failed":
        return f"failed at stride {outcome.stride}: {outcome.kind} ({outcome.reason})"
    return f"{ended} at stride {outcome.stride} ({outcome.reason})"


def _perturbation_lines(run: Run) -> list[str]:
    """What perturbed the run, the saturated strides, and where a run on uneven ground failed."""
    perturbations = replace(run.perturbations, mismatch=Mismatch(**(run.mismatch or {})))
    lines = [perturbations.summary()]
    if perturbations.saturates:
        lines.append(f"the hip saturated (|tau0| > tau_max) in {run.saturated_strides} stride(s)")
    where = run.failure_location
    if where is not None and not perturbations.terrain.is_flat and run.outcome is not None:
        stance = (
            f"; its stance's toe at x = {where['toe_x_m']:.3f} m on ground {where['stance_ground_m']:.4f} m"
            if math.isfinite(where["toe_x_m"])
            else ""
        )
        lines.append(
            f"failed on the terrain at x = {where['x_m']:.3f} m over ground "
            f"{where['ground_under_body_m']:.4f} m{stance}: {run.outcome.kind}: {run.outcome.reason}"
        )
    return lines


_IN_PAPER_TERMS: dict[str, Callable[[HopperParams, float], str]] = {
    "touchdown_angle": lambda params, value: f"{math.degrees(value):.2f} deg",
    "touchdown_power": lambda params, value: f"alpha {units.power_to_alpha(params, value):.4f}",
    "target_energy": lambda params, value: f"Ebar {units.energy_to_bar(params, value):.4f}",
}
"""What the report adds to a setting's SI value: the paper's dimensionless value (eq. 24), or degrees."""
ANALYTIC_MAP_SPEEDS = {"energy": "from the energy balance", "liftoff": "the liftoff velocity of eq. 7"}
"""The analytic maps' next apex speeds (analytic.SpeedSource) in words."""


def policy_settings_text(policy: PolicySpec, params: HopperParams) -> str:
    """The values of the settings ``policy`` uses (model.policies.POLICY_SETTINGS), each as name = value
    unit, with the paper's terms where the report has them."""
    parts = []
    for setting in settings_of(policy.name):
        value = getattr(policy, setting.name)
        unit = f" {setting.unit}" if setting.unit else ""
        in_paper_terms = _IN_PAPER_TERMS.get(setting.name)
        extra = f" ({in_paper_terms(params, value)})" if in_paper_terms else ""
        shown = value if setting.kind is str else f"{value:.6g}"
        parts.append(f"{setting.name} = {shown}{unit}{extra}")
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
            f"--policy {{{','.join(KNOWN_POLICIES)}}} and its settings (see --help)"
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


def _analytic_map_lines(comparison: Comparison) -> list[str]:
    """The analytic map of the predictions, said where it is not ours (the default)."""
    if comparison.analytic_map == DEFAULT_ANALYTIC_MAP:
        return []
    speed = ANALYTIC_MAPS[comparison.analytic_map]
    return [f"analytic map: {comparison.analytic_map} (next apex speed: {ANALYTIC_MAP_SPEEDS[speed]})"]


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
        *_body_lines(params),
        *_perturbation_lines(run),
        _policy_text(comparison),
        *_analytic_map_lines(comparison),
    ]
    rows = [
        (f"analytic map, {c} correction{'s' if c != 1 else ''}", comparison.errors[c]) for c in CORRECTIONS
    ]
    rows.append(("exact map (DOP853)", comparison.exact_errors))
    if comparison.exact_errors.strides:  # none in a run whose every stance was under stance feedback
        lines += [
            f"next-apex prediction error, dimensionless, over {comparison.exact_errors.strides} strides:",
            f"  {'':<30} {'height max':>10} {'mean':>9} {'speed max':>10} {'mean':>9}",
        ]
    else:
        rows = []
    for label, stats in rows:
        failures = f"  ({stats.failures} predicted to fail)" if stats.failures else ""
        lines.append(
            f"  {label:<30} {stats.max_height:>10.2e} {stats.mean_height:>9.2e} "
            f"{stats.max_speed:>10.2e} {stats.mean_speed:>9.2e}{failures}"
        )
    replay = comparison.stance_feedback
    if len(replay.stride):
        largest = largest_errors(replay)
        errors = (
            "no apex" if largest is None else f"next-apex error max {largest[0]:.2e} m, {largest[1]:.2e} m/s"
        )
        pitch = largest_pitch_errors(replay)
        if params.body is not None and pitch is not None:
            errors += f", pitch {pitch[0]:.2e} rad, pitch rate {pitch[1]:.2e} rad/s"
        failures = sum(f is not None for f in replay.failures)
        lines.append(
            f"stance feedback, its recorded torques replayed on the exact map over {len(replay.stride)} "
            f"strides: {errors}" + (f"; {failures} replayed to a failure" if failures else "")
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


_TOLERANCE_TEXT = f"{CONVERGENCE_TOLERANCE:.0e}".replace("e-0", "e-")  # 1e-4, as the headline writes it

GLOSSARY: tuple[tuple[str, str], ...] = (
    (
        "SI units; ybar, xdotbar, Ebar, alpha (eq. 24)",
        "numbers are in SI units (m, kg, s, N, J, W, rad) unless they are dimensionless; the bars are the "
        "dimensionless units of eq. 24 of the paper (Ankarali & Saranli, Chaos 2010): ybar = y/r0, "
        "xdotbar = xdot/sqrt(g r0), Ebar = E/(m g r0), and alpha = C/(m g sqrt(g r0)) for a hip power C",
    ),
    (
        "m, k, r0, c, g; kbar, zeta0",
        "the hopper: body mass m, leg stiffness k, leg rest length r0, leg damping c, gravity g; "
        "kbar = k r0/(m g) the dimensionless stiffness, zeta0 = c/(2 sqrt(m k)) the damping ratio; "
        "after them, where they come from (stored in the recording by tdslip run, given with --params, "
        "or inferred from the recorded events)",
    ),
    (
        "apex, stride",
        "apex k: the top of the k-th flight (vertical speed ydot = 0; apex 0 the start), at height y above "
        "the ground of the stance before it (summary.json: y_m the world height, ground_m that ground), "
        "forward speed xdot, energy E = m (g y + xdot^2/2); stride k: from apex k through touchdown (the toe "
        "lands), stance and liftoff to apex k + 1",
    ),
    (
        "completed, stopped, failed; max_strides",
        "how the run ended (run.outcome.ended in summary.json): "
        + "; ".join(f"{name}: {meaning}" for name, meaning in RUN_ENDINGS.items())
        + "; max_strides: the plant's stride limit",
    ),
    (
        "command: beta, tau0, t_f",
        "what the controller sends at each apex for the next stance: the touchdown angle beta of the leg "
        "from the vertical, and the hip torque ramp tau = tau0 (1 - t/t_f) from touchdown, over t_f or "
        "until liftoff (tau0 < 0 drives forward); saturated: a stride whose |tau0| exceeds the hip's torque "
        "limit tau_max (a perturbation), its ramp cut at +-tau_max",
    ),
    (
        "policy; replaying, max rel. dev.",
        "the controller's rule from apex to command (" + ", ".join(KNOWN_POLICIES) + "); replaying it: "
        "running it offline on the apexes the controller was given; max rel. dev.: the largest relative "
        "difference of the replayed commands from the applied ones (angle, tau0, t_f each relative to its "
        "own size; a stance-feedback policy's torques, its law run on the recorded stance states, relative "
        "to the largest applied)",
    ),
    (
        "analytic map, corrections",
        "the paper's approximate apex return map: the next apex in closed form from an apex and a command "
        "(the stance linearised about the rest length, at constant angular momentum); corrections: how "
        "often the stance is re-evaluated with the angular momentum corrected for the impulse of the hip "
        "torque and of gravity (eqs. 19-22): 0 keeps the angular momentum of touchdown, 1 corrects it "
        "once (the policies' default)",
    ),
    (
        "exact map (DOP853)",
        "the exact plant (the TD-SLIP equations of motion, with the run's terrain, torque limit, pushes "
        "and placement errors) integrated over one stride by DOP853, an adaptive 8th-order Runge-Kutta "
        "method; the recorded 1 kHz plant integrates the same equations by fixed-step RK4, so the exact "
        "map's error is the plant's own integration error and the analytic map's error beyond it is its "
        "approximation",
    ),
    (
        "next-apex prediction error, predicted to fail",
        "|predicted - recorded| of the next apex, predicted from each recorded apex with the command "
        "applied there, in ybar (height) and xdotbar (speed), max and mean over the strides with a "
        "recorded next apex; predicted to fail: of those, how many the map predicted to end in a failure",
    ),
    (
        "converged",
        f"from apex n on every apex-to-apex change of ybar and xdotbar is below {_TOLERANCE_TEXT} "
        "(the paper's tolerance) and the changes shrink (|lambda| < 1)",
    ),
    (
        "fixed point (fixed pt), lambda, |lambda|; recorded, analytic",
        "an apex that the closed-loop return map (apex to command by the policy, command to next apex) "
        "maps onto itself; lambda: an eigenvalue of that map's Jacobian there, |lambda| the largest "
        "modulus; |lambda| < 1: stable, a small deviation shrinks by about |lambda| per stride. recorded: "
        "fitted to the recorded apexes (changes D_{k+1} = A D_k, A by least squares, lambda its "
        "eigenvalues, the fixed point extrapolated from the last apex); analytic: of the closed-loop "
        "analytic map with the policy (Newton's method; Jacobian in ybar, xdotbar and the previous xdotbar, "
        "by central differences)",
    ),
    (
        "energy balance residual",
        "the largest |E_{k+1} - E_k - (hip work - damping loss - spring loss + push work)| / E_k over the "
        "strides: how well the recorded energy flows account for the apex energies",
    ),
    (
        "hip work, damping loss, spring energy left at liftoff (losses)",
        "the energy flows of a stance: the energy the hip torque puts in, the energy the leg damper "
        "dissipates, and the energy left in the leg spring at liftoff (lost with the massless leg)",
    ),
    (
        "COM, GRF, toe, virtual footfalls",
        "COM: the body's centre of mass (a point mass on a massless leg); GRF: the ground reaction force; "
        "toe: the leg's end, fixed on the ground in stance; virtual footfall: where the line through the "
        "COM along the GRF meets y = 0, x - y fx/fy (x from the stride's toe, (fx, fy) the GRF), drawn "
        f"every {plots.GRF_LINE_PERIOD}th 1 kHz stance sample while the leg pushes up (fy > 0); the hip "
        "torque turns the GRF off the leg, so it need not point at the toe (paper fig. 12)",
    ),
    (
        "cobweb",
        "the return-map figure: ybar_k+1 against ybar_k, the recorded apexes stepping between the diagonal "
        "y' = y and the closed-loop analytic height map drawn on the energy level Ebar of the fixed point",
    ),
)
"""The terms of every report, each with its definition: what the code computes (see compare.py, plots.py)."""

PERTURBATION_TERMS = (
    "perturbations: terrain, apex noise, angle noise, tau_max, pushes, mismatch",
    "terrain: the ground the toe lands on (flat; step: a step of height at x; blocks: blocks of length "
    "whose heights are Gaussian with std sigma, from start on, drawn with seed; profile: a polyline from a "
    "file); apex noise: the std of the Gaussian errors of the apex height [m] and speed [m/s] the "
    "controller's sensor reports (measured; true: the plant's apex); angle noise: the std [rad] of the "
    "Gaussian error of the leg's placed angle (the commanded angle plus the error); tau_max: the hip's "
    "torque limit [N m] (saturated: see command); "
    "pushes: forward speed changes [m/s] right after an apex, STRIDE:DV at chosen strides, random: of "
    "size, with probability rate per stride, drawn with seed; mismatch: the factors by which the "
    "controller's model (mass, stiffness, damping, rest_length) differs from the plant's",
)
"""The glossary entry of a perturbed run."""

FAILURE_TERMS = (
    "failure kinds",
    "toe_stubbing: the toe is below the ground when the leg is placed at the apex; no_liftoff: the stance "
    "lasts too long; fall: the body reaches height 0 in stance, or lifts off moving down; reversal: the "
    "body swings back over the toe, or lifts off moving backwards; state_limit: the motion leaves the "
    "plausibility limits; command_timeout: no valid command in time; publish_failed: the plant could not "
    "publish",
)
"""The glossary entry of a failed run."""


def glossary(comparison: Comparison) -> list[tuple[str, str]]:
    """The glossary of the report of ``comparison``: GLOSSARY, the settings of its policy (from
    POLICY_SETTINGS), the perturbations if the run has any, the failure kinds if it failed, and the
    conventions of summary.json."""
    run = comparison.run
    entries = list(GLOSSARY)
    if comparison.policy is not None:
        settings = settings_of(comparison.policy.name)
        entries.append(
            (
                f"settings of {comparison.policy.name}: " + ", ".join(setting.name for setting in settings),
                "; ".join(
                    f"{setting.name}: {setting.description}" + (f" [{setting.unit}]" if setting.unit else "")
                    for setting in settings
                ),
            )
        )
    if run.perturbations.active or run.mismatch is not None:
        entries.append(PERTURBATION_TERMS)
    if run.ending == "failed":
        entries.append(FAILURE_TERMS)
    dimensionless = "; ".join(f"{suffix}: {meaning}" for suffix, meaning in DIMENSIONLESS_SUFFIXES.items())
    entries.append(
        (
            "summary.json keys",
            f"the key of a number ends in its SI unit ({', '.join(UNIT_SUFFIXES.values())}) or says it is "
            f"dimensionless ({dimensionless}); without a suffix: "
            + ", ".join(UNITLESS_KEYS)
            + " (counts, indices, seeds, and zeta0, eigenvalues [re, im] and their largest modulus |lambda|)",
        )
    )
    return entries


def glossary_markdown(entries: list[tuple[str, str]]) -> str:
    return "\n".join(f"- **{terms}**: {definition}." for terms, definition in entries)


def markdown(comparison: Comparison, summary: dict[str, Any]) -> str:
    figures = "\n".join(f"![{FIGURES[name]}]({file})\n" for name, file in summary["figures"].items())
    omitted = "; ".join(f"{name} ({reason})" for name, reason in summary["figures_omitted"].items())
    not_drawn = f"\nNot drawn: {omitted}.\n" if omitted else ""
    return (
        f"# Run analysis: {comparison.run.path.name}\n\n"
        "A recorded run of the TD-SLIP hopper against the analytic apex return map of the paper "
        "(Ankarali & Saranli, Chaos 2010). Numbers: `summary.json`; the terms it uses are defined at the end."
        "\n\n"
        f"## Results\n\n```\n{headline(comparison)}\n```\n\n{figures}{not_drawn}\n"
        f"## Terms\n\n{glossary_markdown(glossary(comparison))}\n"
    )
