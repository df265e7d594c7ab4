"""How the figures of the commands look, defined once: resolution, the colours that mean the same in every
figure, the colouring of a basin by outcome and convergence stride, and how a figure is laid out and saved."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.text import Text

from tdslip_ros.model.arrays import Array
from tdslip_ros.model.stability import basins

DPI = 120
"""Dots per inch of every PNG the commands write."""

STABLE, UNSTABLE, EXACT, START = "black", "0.45", "tab:red", "tab:green"
"""The paper's figures: analytic fixed points (stable, unstable), the exact plant's, and start markers."""
CONTROLLER_STYLE = {
    "deadbeat": ("tab:blue", "-"),
    "stance_pd_speed_energy": ("tab:green", "--"),
    "apex_foot_placement": ("tab:orange", ":"),
}
"""Colour and line style of the controllers compared over target speeds: deadbeat and ref. 36's baseline as
the paper draws them in fig. 13 (solid blue, dashed green), and apex foot placement
(``tdslip compare --controllers``)."""
POLICY_COLOURS = {
    "open_loop": "tab:orange",
    "energy": "tab:blue",
    "energy_exact": "tab:purple",
    "deadbeat": "tab:red",
    "apex_foot_placement": "tab:green",
    "learned": "tab:brown",
}
"""Colour of each policy where policies are compared over perturbations (robustness, rough terrain)."""


def basin_colours(outcome: Array, convergence_stride: Array, strides: int) -> Array:
    """Colour index per lane (basins.OUTCOMES indices): convergence stride (0..strides) where converged,
    strides + 1 sustained, NaN for failures and impossible starts (drawn white)."""
    colour = np.where(outcome == basins.CONVERGED, convergence_stride, np.nan)
    return np.where(outcome == basins.SUSTAINED, strides + 1, colour)


def basin_colour_map(strides: int) -> ListedColormap:
    shades = matplotlib.colormaps["Blues_r"](np.linspace(0.15, 0.85, strides + 1))
    return ListedColormap(np.vstack([shades, [[0.85, 0.9, 0.95, 1.0]]]))


def titles(figure: Figure) -> list[Text]:
    """The figure's titles: its suptitle and every axes' title, where set."""
    found = [axes.title for axes in figure.axes]
    if figure._suptitle is not None:  # matplotlib keeps the suptitle's Text only there
        found.append(figure._suptitle)
    return [text for text in found if text.get_text()]


def lay_out(figure: Figure) -> None:
    """Lay ``figure`` out with every title wrapped to the figure's width: a title longer than its figure (one
    naming a long run directory, a basin's legend in words) would otherwise be cut at both edges."""
    for text in titles(figure):
        text.set_wrap(True)
    figure.tight_layout()


def save_figure(figure: Figure, path: Path) -> None:
    """Write ``figure`` to ``path`` as PNG at DPI, laid out (:func:`lay_out`)."""
    lay_out(figure)
    figure.savefig(path, dpi=DPI)
