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
from rclpy.subscription import Subscription
from rclpy.timer import Timer

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


def _wait_until(condition: Callable[[], bool], timeout: float) -> bool:
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
    return _wait_until(
        lambda: all(p.get_subscription_count() >= node.count_subscribers(p.topic_name) for p in publishers),
        timeout,
    )


def wait_to_answer(
    node: Node, answers: Publisher[Any], question_topic: str, *, first: bool, timeout: float
) -> None:
    """Before an answer to a message of ``question_topic`` (an apex) goes out on ``answers`` (the commands):
    :func:`wait_for_matching`, and at the ``first`` question of a run also until every node that asks (the
    plant) subscribes to the answers in this node's view of the graph. Discovery is not symmetric: a plant
    may have matched this publisher, started and asked before this node has discovered the plant's
    subscription, and a volatile answer published then reaches everyone but the plant. A warning after
    ``timeout`` s (a node that asks without listening, such as a replay, costs that at each run's start)."""

    def askers_listen() -> bool:
        askers = {(i.node_namespace, i.node_name) for i in node.get_publishers_info_by_topic(question_topic)}
        listeners = {
            (i.node_namespace, i.node_name) for i in node.get_subscriptions_info_by_topic(answers.topic_name)
        }
        return askers <= listeners

    heard = not first or _wait_until(askers_listen, timeout)
    if not wait_for_matching(node, [answers], timeout) or not heard:
        node.get_logger().warning(f"{answers.topic_name}: not every subscriber matched in time")


class ApexAnswers:
    """A controller's answer to the latest apex, sent again, not planned anew, when that apex comes again: a
    lockstep plant publishes an apex no command reached again (``PlantRun.repeat_apex``), and planning twice
    would log a refusal twice or move a policy's memory (the PD's previous speed) on."""

    def __init__(self) -> None:
        self._apex: Any = None
        self._answer: bytes | None = None

    def repeated(self, apex: Any, publisher: Publisher[Any]) -> bool:
        """Whether ``apex`` is the latest one again; if so, its answer (if it had one) is published again."""
        if apex != self._apex:
            self._apex, self._answer = apex, None
            return False
        if self._answer is not None:
            publisher.publish(self._answer)
        return True

    def answered(self, data: bytes) -> None:
        """``data`` (a serialised command) answers the latest apex."""
        self._answer = data

    def forget(self) -> None:
        """The settings changed: an equal apex (of a new run) is planned anew."""
        self._apex = self._answer = None


ANSWER_SUBSCRIBERS = ParameterSpec(
    "min_subscribers",
    0,
    "subscribe to tdslip/apex once each answer publisher has matched this many subscriptions "
    "(the plant's and a recorder's: 2), so that no answer misses one of them",
    0,
    1000,
    read_only=True,
)
"""A controller's parameter: discovery is not symmetric, and a recorder that has matched the controller's
publisher (so the plant starts) may not yet be matched by it: a volatile answer published then is lost to
the recorder. A controller not yet subscribed to the apex is one the plant does not start on."""
PLANT_AND_RECORDER = 2
"""The ``min_subscribers`` of a controller whose answers a recorder records (tdslip run, the launch files)."""
MATCH_CHECK_PERIOD = 0.01  # s between two looks at the answer publishers' matches (QuestionsWhenHeard)


class QuestionsWhenHeard:
    """A controller's subscription to the questions (the apex), made once each of its answer publishers has
    matched ``minimum`` subscriptions (:data:`ANSWER_SUBSCRIBERS`): at once if they have, else from a timer.
    Made after configure, it is not among the entities the lifecycle destroys: :meth:`destroy` at cleanup."""

    def __init__(
        self,
        node: Node,
        answers: Sequence[Publisher[Any]],
        minimum: int,
        subscribe: Callable[[], Subscription[Any]],
    ) -> None:
        self._node, self._answers, self._minimum, self._subscribe = node, answers, minimum, subscribe
        self.subscription: Subscription[Any] | None = None
        self._timer: Timer | None = None
        if not self._check():
            self._timer = node.create_timer(MATCH_CHECK_PERIOD, self._check)

    def _check(self) -> bool:
        if self.subscription is None and all(
            p.get_subscription_count() >= self._minimum for p in self._answers
        ):
            self.subscription = self._subscribe()
            if self._timer is not None:
                self._node.destroy_timer(self._timer)
        return self.subscription is not None

    def destroy(self) -> None:
        """Destroy the timer and the subscription (either may be gone already: rclpy then does nothing)."""
        if self._timer is not None:
            self._node.destroy_timer(self._timer)
        if self.subscription is not None:
            self._node.destroy_subscription(self.subscription)


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
