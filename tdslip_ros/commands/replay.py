"""``tdslip replay RUN [--rate R]``: re-publish a recording on its original topics with its timing
(:mod:`tdslip_ros.nodes.replay`). The recording and the rate are checked before ROS starts; SIGINT or
SIGTERM stops the replay between two messages.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import rclpy
from rclpy.signals import SignalHandlerOptions

from tdslip_ros.commands.options import command_parser
from tdslip_ros.nodes.entry import stop_on_signals
from tdslip_ros.nodes.replay import ReplayError, check_rate, checked_bag, replay

DESCRIPTION = """\
Re-publish a recording on its original topics with its timing (or faster, --rate).
The recording and the rate are checked before ROS starts (exit status 2 if unusable);
SIGINT or SIGTERM stops the replay between two messages."""


def parser() -> argparse.ArgumentParser:
    parser = command_parser("replay", DESCRIPTION)
    parser.add_argument("run", type=Path, help="bag directory or .mcap file")
    parser.add_argument("--rate", type=float, default=1.0, help="speed factor (default: 1; inf: no delays)")
    parser.add_argument("--topics", nargs="+", help="replay only these topics (default: all)")
    parser.add_argument(
        "--wait-for-subscribers",
        type=int,
        default=0,
        metavar="N",
        help="first wait for N subscribers per topic",
    )
    parser.add_argument(
        "--wait-for-recorder",
        action="store_true",
        help="first wait until a recorder_node reports every replayed topic matched",
    )
    return parser


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    try:
        check_rate(args.rate, checked_bag(args.run))  # before ROS starts and takes the signals
    except (ReplayError, ValueError) as error:  # a usage error: exit status 2, as argparse's
        print(f"tdslip replay: {error}", file=sys.stderr)
        return 2
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = stop_on_signals()
    try:
        result = replay(
            args.run,
            args.rate,
            topics=args.topics,
            wait_for_subscribers=args.wait_for_subscribers,
            wait_for_recorder=args.wait_for_recorder,
            stop=stop.is_set,
        )
    except (ReplayError, ValueError) as error:
        print(f"tdslip replay: {error}", file=sys.stderr)
        return 1
    finally:
        rclpy.try_shutdown()
    counts = ", ".join(f"{topic} {count}" for topic, count in result.published.items())
    state = "stopped" if result.stopped else "done"
    print(f"replay {state} in {result.duration:.3f} s: {counts}")
    if not result.acknowledged:
        print("warning: not every reliable subscriber acknowledged every message", file=sys.stderr)
    return 0
