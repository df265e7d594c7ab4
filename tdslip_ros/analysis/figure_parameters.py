"""Which parameters each of the paper's figures uses here, and which of them the paper gives: the table
``tdslip figures`` writes under the claims in comparison.md, and docs/paper.md quotes."""

from __future__ import annotations

FIGURE_PARAMETERS: tuple[tuple[str, str, str], ...] = (
    (
        "fig. 4",
        "kbar 36, zeta0 0.08, m 80 kg, r0 1 m; beta 26 deg; (a) alpha 1.5, (b) alpha 1-2, (c) alpha 0.5-2.5",
        "beta 26 deg, alpha 1.5 for (a); m 80 kg and r0 1 m (III.A); not kbar or zeta0",
    ),
    (
        "fig. 5",
        "kbar 36, zeta0 0.08; beta 20-32 deg, alpha 0.5-2.5",
        "beta in [20, 32] deg, alpha in [0.5, 2.5]; not kbar or zeta0",
    ),
    (
        "fig. 6",
        "kbar 36, zeta0 0.08; beta 26 and 32 deg, alpha 0.5-2.5",
        "beta 26 and 32 deg; not kbar or zeta0",
    ),
    (
        "fig. 7",
        "kbar 36, zeta0 0.08; beta 26 deg; alpha 0.5-2.5, ybar0 from cos(beta) to 2.4 on E*(y0); 150 "
        "strides; crosses (alpha, ybar0) (1, 2.0), (1.5, 1.05)",
        "beta 26 deg, 150 strides, alpha 1 and 1.5 for (b), (c); not kbar, zeta0, the grid or the crosses' "
        "heights",
    ),
    (
        "figs 8, 9",
        "kbar 36, zeta0 0.08; beta 22 and 30 deg; Ebar 1-8",
        "all of them (the captions; m and r0 in III.A)",
    ),
    (
        "fig. 10",
        "kbar 36, zeta0 0.08; beta 26 deg; Ebar 2-6; ybar0 from cos(beta) to 2.4; 50 strides, tolerance 1e-4",
        "all but the grid of initial heights (the caption and IV.B; m and r0 in III.A)",
    ),
    (
        "fig. 11",
        "beta 20-30 deg, kbar 20-52, zeta0 0.04-0.16; the others kept at 26 deg, 36, 0.08",
        "none: neither the values varied nor those kept constant (the text quotes the ranges at 20 and 30 "
        "deg)",
    ),
    (
        "fig. 12",
        "m 65.4 kg, r0 1 m, 3.0 m/s; kbar 36, zeta0 0.08; TD-SLIP at beta 17 deg",
        "m 65.4 kg, r0 1 m, about 3 m/s; not kbar, zeta0 or beta (tuned by hand)",
    ),
    (
        "fig. 13",
        "kbar 36, zeta0 0.08; ybar 1 at 5 m/s to ybar* 1, xdotbar* 0.25-3.5; 50 strides; ref. 36 as our "
        "stance law at 1 kHz, its angle matched per speed",
        "50 steps; IV.B's parameters (kbar 36, zeta0 0.08 by reference); not the start, target height, "
        "speeds, or ref. 36's equations, gains, angle",
    ),
)
"""Per figure: the parameters it uses here, and which of them the paper gives."""


def parameters_markdown() -> str:
    """FIGURE_PARAMETERS as Markdown (comparison.md; docs/paper.md quotes it)."""
    lines = ["| figure | uses | the paper gives |", "|---|---|---|"]
    lines += [f"| {figure} | {uses} | {given} |" for figure, uses, given in FIGURE_PARAMETERS]
    return "\n".join(lines) + "\n"
