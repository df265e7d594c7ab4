"""``tdslip recover RUN``: make a truncated or unfinalised recording readable again
(:func:`tdslip_ros.bag.recover.recover`; the original is kept as ``*.orig``) and say how much was lost:
messages recovered per topic (and missing, where the original states its counts), the bytes discarded and
why, and the log time of the last recovered message.
"""

from __future__ import annotations

import argparse
import sys
from datetime import UTC, datetime
from pathlib import Path

from tdslip_ros.bag.recover import RecoverError, RecoverInputError, Recovery, recover
from tdslip_ros.bag.writer import BagWriteError
from tdslip_ros.commands.options import command_parser

_NS_PER_S = 1_000_000_000


def _time(ns: int) -> str:
    return datetime.fromtimestamp(ns / _NS_PER_S, UTC).isoformat(timespec="milliseconds")


def report(recovery: Recovery) -> str:
    """The lines ``tdslip recover`` prints."""
    if recovery.original is None:
        total = sum(recovery.recovered.values())
        return f"{recovery.mcap_path} is finalised and intact ({total} messages); nothing to recover"
    scan = recovery.scan
    total = sum(recovery.recovered.values())
    lines = [f"recovered {recovery.mcap_path}: {total} messages on {len(recovery.recovered)} topics"]
    width = max((len(topic) for topic in recovery.recovered), default=5)
    for topic, count in sorted(recovery.recovered.items()):
        stated = recovery.expected.get(topic)
        of = (
            ""
            if stated is None
            else f" of {stated}" + (f" ({stated - count} lost)" if stated > count else "")
        )
        lines.append(f"  {topic:<{width}} {count:>9}{of}")
    if scan.last_log_time is not None and scan.first_log_time is not None:
        span = (scan.last_log_time - scan.first_log_time) / _NS_PER_S
        lines.append(f"last message logged at {_time(scan.last_log_time)} ({span:.3f} s after the first)")
    if not recovery.expected:
        lines.append("the original does not state how many messages it held: the messages lost are not known")
    lost = f"{scan.discarded_bytes} bytes discarded"
    causes = [
        f"{length} B damaged chunk at byte {offset} ({reason})"
        for offset, length, reason in scan.damaged_chunks
    ]
    if not scan.complete and scan.end < scan.size:
        causes.append(f"{scan.size - scan.end} B from byte {scan.end} on: {scan.stop_reason}")
    elif not scan.complete:
        causes.append("the file ends after a whole record but was not finalised")
    lines.append(lost + (": " + "; ".join(causes) if causes else ""))
    if scan.orphans:
        lines.append(f"{scan.orphans} messages of channels whose definition was lost were not kept")
    lines.extend(recovery.notes)
    lines.append(f"the original is kept as {recovery.original}")
    return "\n".join(lines)


DESCRIPTION = """\
Make a truncated or unfinalised recording readable again; the original is kept as *.orig.
Says how much was lost: messages recovered (and missing) per topic, the bytes discarded and why,
and the log time of the last recovered message."""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("recover", DESCRIPTION)
    parser.add_argument("run", type=Path, help="bag directory or .mcap file")
    return parser


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    try:
        recovery = recover(args.run)
    except RecoverInputError as error:  # no recording there: a usage error, exit status 2 as argparse's
        print(f"tdslip recover: {error}", file=sys.stderr)
        return 2
    except (RecoverError, BagWriteError) as error:
        print(f"tdslip recover: {error}", file=sys.stderr)
        return 1
    print(report(recovery))
    return 0
