"""The ``tdslip`` command: one entry point, one sub-command per job.

Each sub-command lives in its own module of this package, named after it, as
``main(argv: list[str]) -> int``; they are imported
only when chosen, so ``tdslip --help`` stays fast and a missing optional dependency of one job
does not break the others. A closed output pipe ends every one of them the same way, here.
"""

from __future__ import annotations

import difflib
import importlib
import os
import signal
import sys

BROKEN_PIPE = 128 + signal.SIGPIPE
"""Exit status when the output's reader went away, as a shell reports a command killed by SIGPIPE."""
SUBCOMMANDS: dict[str, str] = {
    "simulate": "plant-only simulation from the model core, printed as a table",
    "run": "run the plant, controller and recorder nodes for one hop, recorded",
    "analyze": "compare a recorded run with the analytic map: summary JSON, figures, report",
    "identify": "estimate the hopper (k, c, r0, m) from a recording's stances: a hopper file and a report",
    "compare": "deadbeat vs apex foot placement over desired speeds, recorded and analysed (fig. 13 errors)",
    "replay": "re-publish a recording on its topics with its timing (or --rate R)",
    "recover": "make a truncated or unfinalised recording readable again (the original is kept as *.orig)",
    "figures": "the paper's figures 4-13 from the model (PNG + JSON)",
    "sweep": (
        "basins (figs 7, 10) and parameter dependence (fig 11) at any resolution, on Dask (Parquet + PNG)"
    ),
    "robustness": (
        "survival against terrain, sensor noise, model mismatch and step-downs, per policy, on Dask"
    ),
    "viability": "viability kernels: the states and commands that keep the hopper running, on Dask",
    "terrain": "energy regulation against open loop over rough ground: COM paths and apex energies (PNG)",
    "body": "a freely rotating body: stable regulated gaits over hip offset and inertia, posture law (PNG)",
}
"""Every subcommand by name, with its one-line summary; ``tdslip NAME`` runs ``tdslip_ros.commands.NAME``."""


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] in ("-h", "--help"):
        print("usage: tdslip <command> [options]\n\ncommands:")
        for name, summary in SUBCOMMANDS.items():
            print(f"  {name:<10} {summary}")
        return 0 if args else 2
    name, rest = args[0], args[1:]
    if name not in SUBCOMMANDS:
        closest = difflib.get_close_matches(name, SUBCOMMANDS, n=1)
        hint = f"did you mean '{closest[0]}'? " if closest else ""
        print(f"tdslip: unknown command {name!r}; {hint}try 'tdslip --help'", file=sys.stderr)
        return 2
    module = importlib.import_module(f"{__package__}.{name}")
    try:
        code = int(module.main(rest))
        sys.stdout.flush()
    except BrokenPipeError:
        # Whoever read the output is gone (``tdslip analyze RUN | head``): end quietly with the status
        # of a command killed by SIGPIPE, and spare Python's second error when it flushes at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return BROKEN_PIPE
    return code


if __name__ == "__main__":
    sys.exit(main())
