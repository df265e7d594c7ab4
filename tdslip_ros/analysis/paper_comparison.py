"""The paper's claims beside ours: the table ``tdslip figures`` prints and writes as comparison.md.

Each row is one claim or figure of the paper: the paper's value, ours on the analytic map and on the exact
plant, the command that reproduces ours, and where they differ a pointer to the explanation in
docs/paper.md (which shows the exact-plant evidence). Ours come from the figure documents of the same run
(:mod:`.figure_claims`) or, for the rows that read no figure, from the model alone (:mod:`.model_claims`, the
full run's); a run holds only the rows it computed. Which parameters each figure uses, and which of them the
paper gives: :mod:`.figure_parameters`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from tdslip_ros.analysis import figure_claims, model_claims
from tdslip_ros.analysis.figure_claims import Documents
from tdslip_ros.model.params import HopperParams


@dataclass(frozen=True)
class Row:
    claim: str
    paper: str
    analytic: str
    exact: str
    figures: tuple[str, ...]
    """The figures whose documents the row reads (``tdslip figures --only ...``)."""
    explanation: str
    """The section of docs/paper.md that explains a difference ("" where there is none)."""

    @property
    def command(self) -> str:
        return (
            f"tdslip figures --out DIR --only {' '.join(self.figures)}" if self.figures else "tdslip figures"
        )


RowSpec = tuple[str, str, tuple[str, ...], str, Callable[[Documents, HopperParams], tuple[str, str]]]
ROWS: tuple[RowSpec, ...] = (
    (
        "stable Ebar range, beta = 20 deg (IV.C)",
        "[1.1, 3.4]",
        ("ranges",),
        "stable-ranges",
        lambda documents, params: figure_claims.stable_ranges(documents, "20"),
    ),
    (
        "stable Ebar range, beta = 22 deg (figs 8, 9)",
        "figure only",
        ("ranges",),
        "stable-ranges",
        lambda documents, params: figure_claims.stable_ranges(documents, "22"),
    ),
    (
        "stable Ebar range, beta = 26 deg (fig. 10)",
        "figure only",
        ("ranges",),
        "stable-ranges",
        lambda documents, params: figure_claims.stable_ranges(documents, "26"),
    ),
    (
        "stable Ebar range, beta = 30 deg (IV.C)",
        "[3.45, 11.9]",
        ("ranges",),
        "stable-ranges",
        lambda documents, params: figure_claims.stable_ranges(documents, "30"),
    ),
    (
        "fig. 11: the range grows with beta",
        "grows",
        ("fig11",),
        "",
        lambda documents, params: figure_claims.trend(documents, "beta_deg"),
    ),
    (
        "fig. 11: the range grows with stiffness kbar",
        "grows",
        ("fig11",),
        "",
        lambda documents, params: figure_claims.trend(documents, "kbar"),
    ),
    (
        "fig. 11: more damping zeta0 slightly shrinks the range",
        "shrinks slightly",
        ("fig11",),
        "damping",
        lambda documents, params: figure_claims.trend(documents, "zeta0"),
    ),
    (
        "open loop, beta = 26 deg: a robust ~2 r0 family and a realistic marginal one (III.B)",
        "(i) ~2 r0, |lambda| well below 1; (ii) realistic, |lambda| ~ 1",
        ("fig04",),
        "",
        lambda documents, params: figure_claims.families(documents),
    ),
    (
        "open loop, beta = 32 deg (fig. 6b)",
        "no region with three fixed points",
        ("fig06",),
        "beta-32",
        lambda documents, params: figure_claims.three_fixed_points(documents),
    ),
    (
        "eq. 27 has exactly one solution E*(y) (III.A)",
        "always a single solution",
        (),
        "eq-27",
        lambda documents, params: model_claims.eq27_solutions(params),
    ),
    (
        "fig. 5: one fixed point, but for a narrow region of two stable and one unstable (III.B)",
        "generally a single fixed point, except a narrow parameter range with two stable and one unstable",
        ("fig05",),
        "fig-5",
        lambda documents, params: figure_claims.fig05_counts(documents),
    ),
    (
        "fig. 5: fixed points unstable for beta too large or too small (III.B)",
        "unstable once beta becomes either too large or too small",
        ("fig05",),
        "fig-5",
        lambda documents, params: figure_claims.fig05_beta_band(documents),
    ),
    (
        "fig. 6a, beta = 26 deg: two saddle-nodes bound the three fixed points (III.B)",
        "two saddle node bifurcations at the boundaries of the middle section; the single point unstable "
        "outside",
        ("fig06",),
        "",
        lambda documents, params: figure_claims.saddle_nodes(documents),
    ),
    (
        "fig. 7: fast convergence at alpha = 1, slow at alpha = 1.5 (III.B)",
        "(b) fast and (c) slow convergence",
        ("fig07",),
        "",
        lambda documents, params: figure_claims.fig07_speed(documents),
    ),
    (
        "fig. 7: the realistic fixed points' domain of attraction (III.B)",
        '"only marginal stability with an extremely small domain of attraction"',
        ("fig07",),
        "fig-7-basin",
        lambda documents, params: figure_claims.fig07_basin(documents),
    ),
    (
        "open loop: t_f = the predicted liftoff time (II.D, III.A)",
        "t_f = t_lo",
        ("fig07",),
        "open-loop-tf",
        figure_claims.open_loop_tf,
    ),
    (
        "fig. 10: exact fixed points match the analytic ones",
        "almost exact, except near the low-energy saddle node",
        ("fig10",),
        "stable-ranges",
        lambda documents, params: figure_claims.fig10_match(documents),
    ),
    (
        "figs 8, 9: unstable fixed points beside the stable ones (IV.B)",
        "stable and unstable fixed points",
        ("fig08",),
        "unstable-fixed-points",
        lambda documents, params: figure_claims.fig08_unstable(documents),
    ),
    (
        "fig. 10: unstable fixed points beside the stable ones, a saddle node at low energy (IV.B)",
        "stable and unstable fixed points; a saddle node bifurcation at low energy levels",
        ("fig10",),
        "unstable-fixed-points",
        lambda documents, params: figure_claims.fig10_unstable(documents),
    ),
    (
        "fig. 10: the basin covers the region between the unstable and stable fixed points (IV.B)",
        '"almost exactly covers the region between the unstable and stable fixed points"',
        ("fig10",),
        "unstable-fixed-points",
        lambda documents, params: figure_claims.fig10_basin(documents),
    ),
    (
        "fig. 10: its cavities come from the leg-placement gap (IV.B)",
        "apex too low to place the leg at beta; reproduced by the approximations and the plant",
        ("fig10",),
        "unstable-fixed-points",
        figure_claims.fig10_cavities,
    ),
    (
        "convergence of the regulated exact plant (IV.B)",
        "at most ~8 strides from most initial conditions",
        ("fig10",),
        "convergence",
        lambda documents, params: figure_claims.convergence(documents),
    ),
    (
        "deadbeat towards an apex below r0 (V, issue 9)",
        "-",
        ("fig13",),
        "deadbeat-edge",
        lambda documents, params: figure_claims.deadbeat_edge(documents),
    ),
    (
        "fig. 13: deadbeat reaches more target speeds xdotbar* and tracks better (speed, height %) than "
        "ref. 36's stance PD (V.B)",
        "a significantly wider range of velocity goals; better tracking of apex speed and height",
        ("fig13",),
        "fig-13",
        lambda documents, params: figure_claims.tracking(documents),
    ),
    (
        "fig. 12: TD-SLIP's GRF and virtual footfalls at 3 m/s against the SLIP's (IV.D)",
        "large braking early; footfalls behind the toe, meeting it at liftoff; SLIP's at the toe",
        ("fig12",),
        "fig-12",
        lambda documents, params: figure_claims.ground_reaction(documents),
    ),
    (
        "analytic map's next-apex error (II.C)",
        "no number",
        (),
        "prediction-error",
        lambda documents, params: model_claims.prediction_error(params),
    ),
    (
        "analytic map's accuracy domain (II.C)",
        '"accurate for leg compressions up to %75 of the spring rest length as well as deviations of up to '
        '30 deg away from the vertical"',
        (),
        "accuracy-domain",
        lambda documents, params: model_claims.accuracy_domain(params),
    ),
    (
        "corrections (eqs. 19-22) converge; one iteration suffices (II.D)",
        "convergence for all but the most extreme initial conditions; a single iteration usually "
        "sufficiently accurate",
        (),
        "",
        lambda documents, params: model_claims.corrections(params),
    ),
    (
        "xdotbar = 1.5 (IV.B)",
        "about 4.7 m/s",
        (),
        "",
        lambda documents, params: model_claims.speed_scale(params),
    ),
)


def rows(documents: Documents, params: HopperParams, *, model_rows: bool) -> list[Row]:
    """The rows this run computes: those whose figures are all among ``documents``, and, with ``model_rows``
    (the run of every figure, their command), those that read no figure."""
    return [
        Row(claim, paper, *compute(documents, params), figures, explanation)
        for claim, paper, figures, explanation, compute in ROWS
        if (set(figures) <= set(documents) if figures else model_rows)
    ]


NO_ROWS = "No claim reads only the figures of this run: `tdslip figures` (every figure) computes them all.\n"
"""What the table says where a run computes none of its rows (``--only fig09``)."""


def markdown(table: list[Row]) -> str:
    """The table as Markdown (comparison.md; docs/paper.md quotes it); :data:`NO_ROWS` without rows."""
    if not table:
        return NO_ROWS
    lines = [
        "| claim | paper | ours, analytic map | ours, exact plant | reproduce | explained |",
        "|---|---|---|---|---|---|",
    ]
    for row in table:
        where = f"docs/paper.md#{row.explanation}" if row.explanation else ""
        cells = (row.claim, row.paper, row.analytic, row.exact, f"`{row.command}`", where)
        lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |")
    return "\n".join(lines) + "\n"


def text(table: list[Row]) -> str:
    """The table as plain text for the terminal: one block per claim; :data:`NO_ROWS` without rows."""
    if not table:
        return NO_ROWS
    blocks = []
    for row in table:
        blocks.append(
            f"{row.claim}\n  paper:    {row.paper}\n  analytic: {row.analytic}\n  exact:    {row.exact}\n"
            f"  command:  {row.command}"
            + (f"\n  see:      docs/paper.md#{row.explanation}" if row.explanation else "")
        )
    return "\n".join(blocks) + "\n"
