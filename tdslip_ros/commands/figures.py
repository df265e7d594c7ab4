"""``tdslip figures``: the paper's figures 4-13 from the model core, as PNG plus the numbers as JSON.

    tdslip figures --out DIR [--only fig04 fig10 ranges ...] [--fine] [--resolution energies=101 ...]
                   [--scheduler tcp://HOST:PORT | --workers N]

Each figure is named after the paper's (fig04.png with fig04.json, ...); the JSON holds the numbers drawn
(dimensionless, eq. 24; NaN as null) and the settings. Parameters: kbar = 36, zeta0 = 0.08, m = 80 kg,
r0 = 1 m (figs 8-11, 13 and the paper's section V); the open-loop figures 4-7 use them too. Fig. 12 uses
the paper's m = 65.4 kg (its JSON's params say so), and its JSON is in SI units, which its keys name.

Every analytic fixed point drawn (figs 4-6, 8, 9) is checked on the exact plant
(:mod:`tdslip_ros.model.stability.exact_fixed_points`, the open-loop rule with the paper's t_f, or the ideal
regulator energy_exact for the energy-regulated map): red markers are the exact plant's fixed points (filled
where stable, by their eigenvalues), a red cross marks an analytic fixed point the exact plant does not have.
At the end the command prints the paper's claims beside ours (:mod:`.paper_comparison`) and writes them to
DIR/comparison.md: the rows of the figures drawn, and, on a run of every figure, the rows the model alone
answers (some seconds); docs/paper.md explains the differences.

* fig04: open loop, beta = 26 deg: (a) energy map E' vs E at alpha = 1.5 for several heights, with the
  energy fixed points E*(y) (eq. 27); (b) the height section y' vs y on E*(y) for several alpha (eq. 28);
  (c) the fixed points over alpha with the saddle-node bifurcations.
* fig05: open-loop fixed points over (alpha, beta): apex height (a), energy (b) and largest eigenvalue
  modulus (c) of the most stable fixed point; dark green where it is unstable, hatched where there are
  three.
* fig06: largest eigenvalue modulus at every open-loop fixed point over alpha, beta = 26 and 32 deg.
* fig07: exact plant, open loop, beta = 26 deg, up to 150 strides from initial heights y0 on the energy
  fixed point E*(y0) of eq. 27: outcome per (alpha, y0), analytic fixed points (black: solid stable,
  dashed unstable), the fixed points the exact plant reaches (red dots) and its fixed points by
  eigenvalue with the paper's t_f and with t_f = the stance it produces (squares); (b), (c) convergence
  at alpha = 1 and 1.5 from the green crosses.
* fig08: energy-regulated height map y' vs y for Ebar = 1..8 and its fixed points over Ebar, beta = 22
  and 30 deg; grey: kinematically infeasible heights (y < r0 cos beta).
* fig09: the eigenvalue dy'/dy at those fixed points.
* fig10: beta = 26 deg, Ebar in [2, 6]: fixed points of the analytic map (black) and of the exact plant
  under the paper's goal-energy regulator (red line: reached in the basin; markers: by eigenvalue) in apex
  height (a) and speed (b); blue: the exact plant's basin after 50 strides, lighter for slower
  convergence.
* fig11: stable regulated fixed points (xdotbar*, ybar*) as beta, kbar or zeta0 vary (one curve over Ebar
  per value, circles at its ends, the arrow from the smallest value to the largest); the legend gives each
  value's stable Ebar range, analytic and on the exact plant (energy_exact).
* ranges: the stable Ebar ranges at beta = 20, 22, 26, 30 deg: the paper's, the analytic map's, and the
  exact plant's under the paper's goal regulator (energy) and the ideal one (energy_exact).
* fig12: ground reaction forces over one stance at 3 m/s, m = 65.4 kg: TD-SLIP at its energy_exact fixed point
  (beta = 17 deg) beside the lossless SLIP from the same apex (the touchdown angle that maps it onto itself):
  the centre of mass with the GRF lines down to the virtual footfalls, F_x, F_y and the footfall relative to
  the toe over stance time. The paper's human-data panel cannot be reproduced. Computed in the process
  (about two seconds), not on the study engine.
* fig13: deadbeat against the baseline of ref. 36 (a stance law: energy term and PD on speed, 1 kHz, its
  touchdown angle matched per target speed) on the exact plant, 50 strides per desired speed from the apex
  (1 m, 5 m/s) towards (1 m, xdot*): final speed and height errors in percent; crosses where a controller
  loses stability (fails, does not converge to 1e-4, or, the baseline, has no angle). The JSON adds deadbeat
  towards y* = 0.95 m.

The sweeps that take the time (the exact plant's stable ranges, fixed points and basins: the @shared
computations of :func:`shared_work`) run first, as tasks on the study engine
(:mod:`tdslip_ros.studies.engine`: a local cluster of one worker process per core, or ``--scheduler``), the
longest first; the figures then draw from their results. Each task is the very call the figure would make,
so the numbers do not depend on where it ran. Defaults take some ten minutes of CPU (the exact-plant checks
and ranges most of it); ``--fine`` uses the paper's resolutions, and ``--resolution NAME=N ...`` changes
single grid sizes of either (the fields of :class:`~tdslip_ros.analysis.figures.common.Resolution`). Progress
goes to stderr.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Sequence
from pathlib import Path

from tdslip_ros.analysis import figure_parameters, paper_comparison
from tdslip_ros.analysis.figures.catalogue import FIGURES, compute_shared, shared_work, write_figure
from tdslip_ros.analysis.figures.common import DEFAULT, FINE, PARAMS, Resolution
from tdslip_ros.analysis.figures.shared import SHARED
from tdslip_ros.commands.options import add_analytic_map, analytic_map_speed, command_parser
from tdslip_ros.commands.study_command import add_engine_arguments, where_of
from tdslip_ros.model.analytic.apex_map import SpeedSource
from tdslip_ros.reporting.output import OutputError, output_directory, write_failed
from tdslip_ros.studies import engine


def precompute(names: Sequence[str], resolution: Resolution, speed: SpeedSource, where: engine.Where) -> None:
    """Run the figures' sweeps (:func:`~tdslip_ros.analysis.figures.catalogue.shared_work`) as tasks on the
    study engine, in parallel; the figures then draw from their results. Each task brings back every shared
    result it made."""
    work = shared_work(names, resolution, speed)
    if not work:
        return
    calls: list[engine.Call] = [(name, compute_shared, (name, args)) for name, args in work]
    with engine.connect(where) as client:
        for entries in engine.compute(client, calls, engine.Progress("figures", "sweeps")):
            SHARED.store(entries)


DESCRIPTION = """\
The paper's figures 4-13 from the model (no ROS): DIR/figNN.png, with the numbers drawn in
DIR/figNN.json, and "ranges" (the stable Ebar ranges). The slow sweeps run first, in parallel on a local
Dask cluster (or --scheduler); the defaults take some ten minutes of CPU, --fine much longer.
Prints the paper's claims beside ours (also DIR/comparison.md); docs/paper.md explains the differences."""


def resolution_setting(text: str) -> tuple[str, float]:
    """``NAME=N``: a grid size of :class:`Resolution` (a positive count; speed_step a positive step) (argparse
    type)."""
    name, equals, value = text.partition("=")
    sizes = {field.name: type(getattr(DEFAULT, field.name)) for field in dataclasses.fields(Resolution)}
    if not equals or name not in sizes:
        raise argparse.ArgumentTypeError(f"expected NAME=N with NAME one of {', '.join(sizes)}, got {text!r}")
    try:
        number = sizes[name](value)
    except ValueError:
        number = 0
    if not 0 < number < math.inf:
        kind = "a positive count" if sizes[name] is int else "a positive number"
        raise argparse.ArgumentTypeError(f"{name} must be {kind}, got {value!r}")
    return name, number


def parser() -> argparse.ArgumentParser:
    parser = command_parser("figures", DESCRIPTION)
    parser.add_argument("--out", type=Path, required=True, help="directory for the PNG and JSON files")
    parser.add_argument("--only", nargs="+", choices=list(FIGURES), help="just these figures (default: all)")
    parser.add_argument("--fine", action="store_true", help="the paper's resolutions (much slower)")
    parser.add_argument(
        "--resolution",
        nargs="+",
        type=resolution_setting,
        metavar="NAME=N",
        help="grid sizes that differ from the default's or --fine's: "
        + ", ".join(f"{name}={value:g}" for name, value in vars(DEFAULT).items())
        + " by default",
    )
    add_analytic_map(parser)
    add_engine_arguments(parser, resume=False)
    return parser


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    try:
        output_directory(args.out)
    except OutputError as error:  # a usage error: exit status 2, as argparse's
        print(f"tdslip figures: {error}", file=sys.stderr)
        return 2
    try:
        resolution = dataclasses.replace(FINE if args.fine else DEFAULT, **dict(args.resolution or []))
        names = args.only or list(FIGURES)
        speed = analytic_map_speed(args)
        precompute(names, resolution, speed, where_of(args))
        documents = {name: write_figure(name, args.out, resolution, speed) for name in names}
        # The claims the model alone answers cost seconds: the full run's (their command), not each --only's.
        table = paper_comparison.rows(documents, PARAMS, model_rows=set(names) >= set(FIGURES))
        (args.out / "comparison.md").write_text(
            paper_comparison.markdown(table) + "\n" + figure_parameters.parameters_markdown()
        )
    except (OutputError, engine.EngineError) as error:
        print(f"tdslip figures: {error}", file=sys.stderr)
        return 1
    except OSError as error:
        print(f"tdslip figures: {write_failed(error)}", file=sys.stderr)
        return 1
    print(paper_comparison.text(table), end="")
    return 0
