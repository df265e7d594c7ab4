"""``tdslip body``: the paper's future work, a freely rotating body (issue 36, docs/rotating_body.md).

    tdslip body [--out DIR] [--only body_map body_strides body_grf]
                [--distances 0.05 0.1 ...] [--radii 0.1 0.2 ...]

Writes DIR/NAME.png and DIR/NAME.json for each figure (:mod:`tdslip_ros.analysis.rotating_body`): the map of
stable regulated gaits over the hip's distance from the centre of mass and the body's radius of gyration,
with and without the posture law (about two minutes on one core at the default grid); pitch and energy over
strides from off the gait (seconds); the GRF of fig. 12's stance, fixed and rotating body (seconds). The
map's table is printed as well.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure

from tdslip_ros.analysis import rotating_body
from tdslip_ros.commands.options import command_parser
from tdslip_ros.model.params import ParameterError
from tdslip_ros.reporting.output import OutputError, output_directory, to_json, write_failed
from tdslip_ros.reporting.style import save_figure

DESCRIPTION = """\
A freely rotating body instead of the paper's fixed one: does energy regulation with a fixed touchdown angle
keep stable gaits, and what does the posture law change? Three figures, PNG and JSON, on the exact map."""


def parser() -> Any:
    parser = command_parser("body", DESCRIPTION)
    parser.add_argument("--out", type=Path, help="the directory to write (default: runs/body-<time>)")
    parser.add_argument(
        "--only",
        nargs="+",
        choices=("body_map", "body_strides", "body_grf"),
        help="just these figures (default: all three)",
    )
    parser.add_argument(
        "--distances",
        nargs="+",
        type=float,
        default=rotating_body.HIP_DISTANCES,
        help="the map's hip distances from the centre of mass [m]",
    )
    parser.add_argument(
        "--radii",
        nargs="+",
        type=float,
        default=rotating_body.GYRATION_RADII,
        help="the map's radii of gyration [m]",
    )
    return parser


def table(data: dict[str, Any]) -> str:
    """The map as text: the spectral radius per cell ('-' without a gait), and the work per metre."""
    lines = []
    header = "radius \\ |d| " + " ".join(f"{d:>6g}" for d in data["hip_distances"])
    for branch, by_policy in data["cells"].items():
        for name, rows in by_policy.items():
            lines += [f"{branch}, {name} (spectral radius):", header]
            for radius, row in zip(data["gyration_radii"], rows, strict=True):
                values = [cell["spectral_radius"] for cell in row]
                lines.append(
                    f"{radius:>12g} " + " ".join("     -" if math.isnan(v) else f"{v:6.2f}" for v in values)
                )
    lines.append(
        f"the fixed body's hip work per metre: {data['fixed_body_hip_work_per_metre']:.1f} J/m "
        "(each cell's is in body_map.json)"
    )
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    names = args.only or ["body_map", "body_strides", "body_grf"]
    out = args.out or Path("runs") / f"body-{datetime.now():%Y%m%d-%H%M%S}"
    started = time.monotonic()

    def progress(text: str) -> None:
        print(f"body: {text} ({time.monotonic() - started:.0f} s)", file=sys.stderr, flush=True)

    work: dict[str, tuple[Callable[[], dict[str, Any]], Callable[[dict[str, Any]], Figure]]] = {
        "body_map": (
            lambda: rotating_body.gait_map(tuple(args.distances), tuple(args.radii), progress),
            rotating_body.draw_map,
        ),
        "body_strides": (rotating_body.strides_data, rotating_body.draw_strides),
        "body_grf": (rotating_body.grf_data, rotating_body.draw_grf),
    }
    try:
        if any(value <= 0.0 for value in [*args.distances, *args.radii]):
            raise ParameterError("--distances and --radii must be positive")
        output_directory(out)
        for name in names:
            compute, draw = work[name]
            progress(f"{name} ...")
            data = compute()
            save_figure(draw(data), out / f"{name}.png")
            (out / f"{name}.json").write_text(to_json({"figure": name, **data}))
            if name == "body_map":
                print(table(data))
    except (ParameterError, OutputError) as error:
        print(f"tdslip body: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        print(f"tdslip body: {write_failed(error)}", file=sys.stderr)
        return 1
    print(f"figures: {out}")
    return 0
