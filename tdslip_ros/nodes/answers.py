"""How the controllers answer the plant: the apex is the question, a command (and a stance's hip torques) the
answer. Discovery is not symmetric, so an answer waits until it can reach everyone who must hear it
(:func:`subscribe_when_heard` before the run, :func:`wait_to_answer` at its first apex), and an apex the
plant publishes again gets the same answer again (:class:`ApexAnswers`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from rclpy.node import Node
from rclpy.publisher import Publisher

from tdslip_ros.nodes.entry import wait_for_matching, wait_until
from tdslip_ros.nodes.parameters import ParameterSpec

MATCH_TIMEOUT = 1.0  # s an answer waits for its publisher to match a subscriber the graph already shows


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

    heard = not first or wait_until(askers_listen, timeout)
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
MATCH_CHECK_PERIOD = 0.01  # s between two looks at the answer publishers' matches (subscribe_when_heard)


def subscribe_when_heard(
    node: Node, answers: Sequence[Publisher[Any]], minimum: int, subscribe: Callable[[], object]
) -> None:
    """``subscribe()`` to the questions once each of ``answers`` has matched ``minimum`` subscriptions
    (:data:`ANSWER_SUBSCRIBERS`): at once if they have, else from a timer of ``node``. Made after configure,
    the subscription is still the node's to destroy at cleanup (:mod:`tdslip_ros.nodes.lifecycle`)."""

    def heard() -> bool:
        return all(publisher.get_subscription_count() >= minimum for publisher in answers)

    if heard():
        subscribe()
        return

    def check() -> None:
        if heard() and not timer.is_canceled():
            timer.cancel()
            subscribe()

    timer = node.create_timer(MATCH_CHECK_PERIOD, check)
