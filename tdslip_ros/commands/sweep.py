"""``tdslip sweep``: the exact plant's basins (figs. 7 and 10) and parameter dependence (fig. 11) at any
resolution, on the study engine (a local Dask cluster, or ``--scheduler``).

    tdslip sweep fig07|fig10|fig11 --out DIR [--grid AxB] [--strides N] [--chunk-size N] [--map ours|paper]
                 [--scheduler tcp://HOST:PORT | --workers N] [--resume]

* fig07: open loop at beta = 26 deg, a grid of touchdown powers alpha in [0.5, 2.5] x initial heights ybar0
  from r0 cos(beta) + 5 mm to 2.4, each starting on the energy fixed point E*(y0) of eq. 27 (fig. 7(a));
  150 strides. ``--grid`` is alphas x heights (default 17x20, ``tdslip figures``' resolution).
* fig10: the goal regulator (each trajectory's initial energy is its goal) at beta = 26 deg, initial
  energies Ebar0 in [2, 6] x heights ybar0 from r0 cos(beta) + 2 mm to 2.4; 50 strides. ``--grid`` is
  energies x heights (default 21x20; 1000x1000 is a million trajectories).
* fig11: the fixed points the goal regulator's exact plant reaches as beta (20..30 deg), kbar (20..52) and
  zeta0 (0.04..0.16) vary, fig. 11's values: one study per parameter (DIR/beta_deg, DIR/kbar, DIR/zeta0),
  each a grid of goal energies Ebar in [0.8, 14] x initial heights ybar0 in [1, 2] per value; 50 strides.
  ``--grid`` is energies x heights (default 57x3).

The policies (and fig. 7's start E*(y0)) plan on the analytic map ``--map``: ours, or the paper's as printed
(the table's ``analytic_map`` column; the exact plant is the same). Each study directory holds the table
(``table/``, Parquet, one row per trajectory: see :mod:`tdslip_ros.studies.table`) and ``study.json``; DIR
gets the figure (``fig07.png``, ...) and ``summary.json`` (the map, outcome counts, and the fixed points
reached: per grid row, the median over the converged trajectories, dimensionless). ``--resume`` completes
an interrupted sweep, computing only missing chunks.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tdslip_ros.commands.options import add_analytic_map, command_parser
from tdslip_ros.commands.study_command import add_engine_arguments, positive_int, run_study_command, where_of
from tdslip_ros.studies.sweep import SWEEPS, write_sweep


def grid_size(text: str) -> tuple[int, int]:
    """``AxB`` as two positive ints (argparse type)."""
    parts = text.lower().split("x")
    try:
        sizes = tuple(int(part) for part in parts)
    except ValueError:
        sizes = ()
    if len(sizes) != 2 or min(sizes) < 1:
        raise argparse.ArgumentTypeError(f"expected two positive counts like 1000x1000, got {text!r}")
    return sizes[0], sizes[1]


DESCRIPTION = """\
The exact plant's basins (figs 7 and 10) and parameter dependence (fig 11) at any resolution, in
parallel on a local Dask cluster (or --scheduler). fig07: open loop, touchdown powers x initial heights;
fig10: the goal regulator, initial energies x heights; fig11: fixed points as beta, kbar, zeta0 vary.
Writes per study a Parquet table and study.json; DIR gets the figure and summary.json."""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("sweep", DESCRIPTION)
    parser.add_argument("sweep", choices=list(SWEEPS), help="which figure's sweep")
    parser.add_argument("--out", type=Path, required=True, help="directory for the table, figure and summary")
    parser.add_argument(
        "--grid",
        type=grid_size,
        metavar="AxB",
        help="resolution: fig07 alphas x heights, fig10/fig11 energies x heights (default: "
        + ", ".join(f"{name} {sweep.grid[0]}x{sweep.grid[1]}" for name, sweep in SWEEPS.items())
        + ")",
    )
    parser.add_argument(
        "--strides",
        type=positive_int,
        help="strides per trajectory (default: "
        + ", ".join(f"{name} {sweep.strides}" for name, sweep in SWEEPS.items())
        + ")",
    )
    parser.add_argument(
        "--chunk-size", type=positive_int, help="trajectories per chunk (default: from the size)"
    )
    add_analytic_map(parser, what=", the one the policies plan on")
    add_engine_arguments(parser)
    return parser


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)

    def produce() -> None:
        write_sweep(
            args.sweep,
            args.out,
            args.grid,
            args.strides,
            args.chunk_size,
            where_of(args),
            args.resume,
            args.map,
        )

    status = run_study_command("sweep", args.out, produce)
    if status:
        return status
    print(
        f"tdslip sweep: {args.out / (args.sweep + '.png')}, {args.out / 'summary.json'}, tables in {args.out}"
    )
    return 0
