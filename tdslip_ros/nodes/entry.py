"""What the node executables share: their default parameter files, stop signals and spinning.

``plant_node``, ``controller_node`` and ``recorder_node`` load ``share/tdslip_ros/config/<node>.yaml``
(installed from ``config/``) unless the command line gives a ``--params-file`` of its own; ``-p``
overrides apply on top either way.

Nodes are spun by rclpy's C++ EventsExecutor, which costs a fraction of the Python executors' time
per callback (what makes 1 kHz affordable in Python). SIGINT and SIGTERM do not tear the context
down under a running callback (rclpy's own handler is off): they ask the spin loop to stop, after
which the node's publications are delivered (acknowledged by every reliable subscriber) before
it is destroyed. A second signal interrupts at once. A node started by a supervisor that set
``TDSLIP_PARENT_PID`` stops the same way when that process is gone.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import Any, TypeVar

import rclpy
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.signals import SignalHandlerOptions

from tdslip_ros.interfaces import config_file
from tdslip_ros.model.params import ParameterError
from tdslip_ros.nodes import isolation, parameters
from tdslip_ros.nodes.parameters import ParameterSpec

SPIN_SLICE = 0.1
"""s, longest a spin call blocks: how soon signal handlers and exit checks get to run."""
DELIVERY_TIMEOUT = 5.0  # s
MATCH_POLL = 0.001  # s between two looks at a publisher's matched subscriptions
PARENT_PID_VARIABLE = "TDSLIP_PARENT_PID"
"""Set by a supervising process (``tdslip run``): its node children stop when it is gone."""
BAD_PARAMETERS = 2  # exit status of a node executable refusing its parameters

NodeT = TypeVar("NodeT", bound=Node)


def with_default_params_file(argv: list[str], config_name: str) -> list[str]:
    """argv with ``--ros-args --params-file <installed config> --`` first, unless it names a params
    file itself; first, because rcl lets later parameter arguments win, so ``-p`` still overrides."""
    if "--params-file" in argv:
        return argv
    return [*argv[:1], "--ros-args", "--params-file", str(config_file(config_name)), "--", *argv[1:]]


def stop_on_signals() -> threading.Event:
    """An event set by the first SIGINT or SIGTERM; a second one raises KeyboardInterrupt."""
    stop = threading.Event()

    def handler(signum: int, frame: FrameType | None) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def spin_until(executor: Executor, condition: Callable[[], bool], timeout: float | None = None) -> bool:
    """Spin in short slices until ``condition()`` holds (True) or ``timeout`` seconds pass (False)."""
    deadline = None if timeout is None else time.monotonic() + timeout
    while not condition():
        if deadline is not None and time.monotonic() >= deadline:
            return False
        executor.spin_once(timeout_sec=SPIN_SLICE)
    return True


def wait_until(condition: Callable[[], bool], timeout: float) -> bool:
    """Sleep in MATCH_POLL steps until ``condition()`` holds (True) or ``timeout`` s pass (False)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(MATCH_POLL)
    return True


def wait_for_matching(node: Node, publishers: Sequence[Publisher[Any]], timeout: float) -> bool:
    """Wait (sleeping, without spinning: DDS matches on threads of its own) until each publisher
    has matched every subscription the graph shows on its topic; False after ``timeout`` s.
    A volatile publisher sends nothing to a subscriber it has not matched yet, even one the graph
    already shows: this is how a node makes sure a recorder that started first hears it."""
    return wait_until(
        lambda: all(p.get_subscription_count() >= node.count_subscribers(p.topic_name) for p in publishers),
        timeout,
    )


def wait_for_delivery(node: Node, timeout: float = DELIVERY_TIMEOUT) -> bool:
    """Wait until each of ``node``'s publishers has matched every subscription the graph shows on
    its topic and every reliable subscriber has acknowledged everything published (False if not
    within ``timeout`` s)."""
    deadline = time.monotonic() + timeout
    if not wait_for_matching(node, node.publishers, timeout):
        return False

    def acknowledged(publisher: Publisher[Any]) -> bool:
        left = Duration(nanoseconds=max(0, round((deadline - time.monotonic()) * 1e9)))
        return bool(publisher.wait_for_all_acked(left))

    return all(acknowledged(publisher) for publisher in node.publishers)


def orphaned() -> bool:
    """True once the supervisor named by PARENT_PID_VARIABLE is no longer this process's parent."""
    supervisor = os.environ.get(PARENT_PID_VARIABLE)
    return supervisor is not None and os.getppid() != int(supervisor)


def _delivered_to_every_subscriber(node: Node, executor: Executor) -> None:
    if not wait_for_delivery(node):
        node.get_logger().warning("not every subscriber acknowledged every message before exit")


def run_node(
    factory: Callable[[], NodeT],
    config_name: str,
    argv: list[str],
    finished: Callable[[NodeT], bool],
    exit_status: Callable[[NodeT], int] = lambda node: 0,
    on_stop: Callable[[NodeT, Executor], None] = lambda node, executor: None,
    *,
    specs: Sequence[ParameterSpec] = (),
    deliver: Callable[[NodeT, Executor], None] = _delivered_to_every_subscriber,
) -> int:
    """Main of a node executable: check the command line (params files exist, ``-p`` values of
    ``specs`` have their types), init with the default params file, spin until ``finished(node)``
    or a stop signal, run ``on_stop``, ``deliver`` what was published, shut down; returns
    ``exit_status(node)``, or BAD_PARAMETERS if the node refused its parameters or output."""
    name = Path(argv[0]).stem
    try:
        argv = parameters.check_command_line(argv, specs)
    except ParameterError as error:
        print(f"{name}: {error}", file=sys.stderr)
        return BAD_PARAMETERS
    os.environ.update(isolation.dds_settings())
    rclpy.init(
        args=with_default_params_file(argv, config_name), signal_handler_options=SignalHandlerOptions.NO
    )
    stop = stop_on_signals()
    try:
        try:
            node = factory()
        except (ParameterException, ParameterError, OSError) as error:
            print(f"{name}: {error}", file=sys.stderr)
            return BAD_PARAMETERS
        executor = EventsExecutor()
        executor.add_node(node)
        try:
            spin_until(executor, lambda: stop.is_set() or finished(node) or orphaned())
            on_stop(node, executor)
            deliver(node, executor)
        finally:
            executor.shutdown()
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return exit_status(node)
