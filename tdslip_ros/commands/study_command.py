"""What the commands running on the study engine (``tdslip figures``, ``tdslip sweep``, ``tdslip robustness``)
share on the command line: where they run (``--scheduler`` or ``--workers``), ``--resume``, positive counts,
and what they do with what can go wrong: one line on stderr and an exit status, never a traceback; an
interrupted study keeps its written chunks for --resume."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from tdslip_ros.model.params import ParameterError
from tdslip_ros.reporting.output import OutputError, write_failed
from tdslip_ros.studies import engine, table
from tdslip_ros.studies.design import StudyError

USAGE_ERRORS = (StudyError, ParameterError, OutputError, table.StudyDirectoryError)
"""What a study refuses to start with (its design, the hopper, --out, --resume): exit status 2, as
argparse's."""


def add_engine_arguments(parser: argparse.ArgumentParser, resume: bool = True) -> None:
    """The options of the commands that run on the engine: where, and (for studies) --resume."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="an existing Dask cluster's scheduler (default: a local cluster)",
    )
    where.add_argument(
        "--workers", type=positive_int, help="worker processes of the local cluster (default: one per core)"
    )
    if resume:
        parser.add_argument(
            "--resume",
            action="store_true",
            help="complete an interrupted run in the same --out, computing only missing chunks",
        )


def positive_int(text: str) -> int:
    """A positive integer option (argparse type)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def where_of(args: argparse.Namespace) -> engine.Where:
    return engine.Where(scheduler=args.scheduler, workers=args.workers)


def run_study_command(command: str, out: Path, produce: Callable[[], None]) -> int:
    """Call ``produce`` (which writes the study's results to ``out``); 0 when it did, else the status of
    what stopped it (2: a usage error, 1: another error, each said in one line; 130: Ctrl-C)."""
    try:
        produce()
    except USAGE_ERRORS as error:
        print(f"tdslip {command}: {error}", file=sys.stderr)
        return 2
    except engine.EngineError as error:  # the cluster: unreachable, or a task failed
        print(f"tdslip {command}: {error}", file=sys.stderr)
        return 1
    except OSError as error:
        print(f"tdslip {command}: {write_failed(error)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(
            f"\ntdslip {command}: interrupted; the chunks written stay in {out}: --resume completes it",
            file=sys.stderr,
        )
        return 130
    return 0
