"""What the study commands (``tdslip sweep``, ``tdslip robustness``) do with what can go wrong: one line on
stderr and an exit status, never a traceback; an interrupted study keeps its written chunks for --resume."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from tdslip_ros.model.params import ParameterError
from tdslip_ros.reporting.output import OutputError, write_failed
from tdslip_ros.studies import engine, table
from tdslip_ros.studies.design import StudyError

USAGE_ERRORS = (StudyError, ParameterError, OutputError, table.StudyDirectoryError, engine.EngineError)


def run_study_command(command: str, out: Path, produce: Callable[[], None]) -> int:
    """Call ``produce`` (which writes the study's results to ``out``); 0 when it did, else the status of
    what stopped it (1: an error, said in one line; 130: Ctrl-C)."""
    try:
        produce()
    except USAGE_ERRORS as error:
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
