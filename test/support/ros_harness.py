"""Launch-free ROS 2 test harness: nodes spun in-process, a private graph per test.

Each :func:`ros_graph` has its own ``rclpy.Context`` initialised on a domain id reserved for it
alone (:mod:`tdslip_ros.nodes.isolation`: localhost discovery, prompt acknowledgements), its own
EventsExecutor, and tears everything down in ``finally`` (child processes, executor, nodes,
context), as rclpy's own tests do. Tests therefore run in any order and in parallel processes
without seeing each other's messages.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import rclpy
from rclpy.context import Context
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from tdslip_ros.nodes import isolation, topics
from tdslip_ros.nodes.entry import SPIN_SLICE

NodeT = TypeVar("NodeT", bound=Node)
RECORDER = "tdslip_ros.nodes.recorder_node"
"""The recorder node's module, run as a child process (as ``tdslip run`` runs it)."""
DEFAULT_TIMEOUT = 20.0  # s; generous for a loaded 2-core machine, never reached when things work


def overrides(**values: object) -> list[Parameter]:
    """``parameter_overrides`` for a node constructor."""
    return [Parameter(name, value=value) for name, value in values.items()]


@dataclass
class RosGraph:
    """One test's ROS graph: context, domain, executor, and what was added to them."""

    context: Context
    domain_id: int
    executor: Any  # rclpy's EventsExecutor (a pybind11 class without type information)
    nodes: list[Node] = field(default_factory=list)
    processes: list[subprocess.Popen[bytes]] = field(default_factory=list)

    def add(self, node: NodeT) -> NodeT:
        """Spin ``node`` (constructed with ``context=graph.context``) in this graph's executor."""
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def node(self, name: str) -> Node:
        """A plain node for probes and publishers of the test itself."""
        return self.add(Node(name, context=self.context))

    def collect(self, message_class: type, topic: str, node: Node | None = None) -> list[Any]:
        """A list that fills with every message on ``topic`` (suite QoS)."""
        received: list[Any] = []
        (node or self.node(f"collect_{len(self.nodes)}")).create_subscription(
            message_class, topic, received.append, topics.STREAM_QOS
        )
        return received

    def spin_until(self, condition: Callable[[], bool], what: str, timeout: float = DEFAULT_TIMEOUT) -> None:
        """Spin until ``condition()``; fail the test naming ``what`` after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            self.executor.spin_once(timeout_sec=SPIN_SLICE)

    @property
    def environment(self) -> dict[str, str]:
        """Environment of child processes in this graph."""
        return isolation.isolated_environment(self.domain_id)

    def start_process(self, command: list[str], log: Path) -> subprocess.Popen[bytes]:
        """A child process in this graph, output to ``log``; killed at teardown if still running."""
        with log.open("wb") as output:
            process = subprocess.Popen(command, env=self.environment, stdout=output, stderr=subprocess.STDOUT)
        self.processes.append(process)
        return process

    def start_module(self, module: str, ros_arguments: list[str], log: Path) -> subprocess.Popen[bytes]:
        return self.start_process([sys.executable, "-m", module, "--ros-args", *ros_arguments], log)

    def start_recorder(self, bag: Path, log: Path, **parameters: object) -> subprocess.Popen[bytes]:
        """A recorder node child writing ``bag``, given its other ROS ``parameters`` (booleans spelled as
        ROS reads them)."""
        arguments = ["-p", f"output:={bag}"]
        for name, value in parameters.items():
            arguments += ["-p", f"{name}:={str(value).lower() if isinstance(value, bool) else value}"]
        return self.start_module(RECORDER, arguments, log)


def stop_process(process: subprocess.Popen[bytes], signum: int = signal.SIGINT, timeout: float = 30.0) -> int:
    """Send ``signum`` and wait for the exit status."""
    process.send_signal(signum)
    return process.wait(timeout)


def stop_example(process: subprocess.Popen[bytes], grace: float = 10.0) -> None:
    """End an example controller (examples/) once its run is over: SIGINT, then SIGKILL after ``grace`` s;
    its exit status is not the test's business. The examples rely on rclpy's own signal handlers, which now
    and then lose a signal that arrives while rclpy starts (about 1 in 30 at 0.5-0.8 s after launch here;
    the process then spins on), or, in a node taking 1 kHz messages, turn one that arrives inside
    ``take_message`` into a RuntimeError traceback: upstream races, not the run under test."""
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


@contextmanager
def ros_graph() -> Iterator[RosGraph]:
    """A private ROS graph for the with-block (see the module docstring). The process environment
    must hold :func:`tdslip_ros.nodes.isolation.process_settings` already (the ``ros`` fixture)."""
    with isolation.reserved_domain() as domain_id:
        context = Context()
        rclpy.init(context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        graph = RosGraph(context, domain_id, EventsExecutor(context=context))
        try:
            yield graph
        finally:
            try:
                for process in graph.processes:
                    if process.poll() is None:
                        process.kill()
                    process.wait()
                graph.executor.shutdown()
                for node in reversed(graph.nodes):
                    node.destroy_node()
            finally:
                rclpy.try_shutdown(context=context)
