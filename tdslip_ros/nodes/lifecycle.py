"""What the managed nodes share: the lifecycle transitions' common behaviour, autostart, ending with the run.

The plant, the controllers and the recorder are rclpy lifecycle nodes (the shape of ros2/demos'
lifecycle_py). Each declares what it does at each transition as a hook of :class:`ManagedNode`
(:meth:`~ManagedNode.configure`, :meth:`~ManagedNode.activate`, :meth:`~ManagedNode.deactivate`,
:meth:`~ManagedNode.cleanup`); this base declares, once, how every transition behaves:

* configure declares the node's parameters (so that a bad value fails the transition, not the process)
  and runs the hook; whatever the node created from then on (publishers, subscriptions, timers, services: in
  the hook, or later, as a controller's apex subscription) is destroyed again by cleanup, or at once when
  configure fails;
* a transition that cannot succeed (a refused parameter, an unwritable output: :data:`REFUSED`) logs one
  line naming the transition and the reason, and leaves the node in the state it was in; anything else a
  hook raises is logged the same way and takes the node, through rclpy's error processing, back to
  unconfigured;
* shutdown from active deactivates first, and from active or inactive cleans up;
* ``autostart`` (:data:`AUTOSTART`, default true) configures and activates the node as it is constructed,
  so an executable behaves as an unmanaged node would: the activate hook runs inside configure then (a
  message that arrives between the two transitions is not missed), and a refusal is raised (not logged), as
  an unmanaged node's constructor raised it; the executable says it in one line and exits with status 2;
* ``end_with_run`` (:data:`END_WITH_RUN`, on the nodes that serve a plant's run) watches ``tdslip/status``
  and sets :attr:`ManagedNode.run_ended` at the plant's fatal Status (the end of its run), which ends the
  node's executable (:func:`tdslip_ros.nodes.entry.run_node`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

from rclpy.exceptions import ParameterException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from tdslip_msgs.msg import Status

from tdslip_ros.model.params import ParameterError
from tdslip_ros.nodes import parameters, topics
from tdslip_ros.nodes.parameters import ParameterSpec, ParameterValue

REFUSED: tuple[type[Exception], ...] = (ParameterException, ParameterError, OSError)
"""What a transition that cannot succeed raises: a parameter refused, an output that cannot be written."""
AUTOSTART = ParameterSpec(
    "autostart",
    True,
    "configure and activate at start-up (false: wait for ros2 lifecycle set or a lifecycle manager)",
    read_only=True,
)
END_WITH_RUN = ParameterSpec(
    "end_with_run",
    False,
    "end this node when the plant's run ends (its fatal Status on tdslip/status), as under tdslip run",
    read_only=True,
)

_Hook = Callable[[], None]


class ManagedNode(LifecycleNode):
    """A lifecycle node whose transitions run the hooks below (see the module docstring). ``specs`` are the
    node's parameters: AUTOSTART and END_WITH_RUN among them are declared at once, the rest at configure."""

    def __init__(self, name: str, specs: Sequence[ParameterSpec], **node_options: object) -> None:
        super().__init__(name, **node_options)  # type: ignore[arg-type]
        self._specs = tuple(specs)
        self.refusal: Exception | None = None
        """Why the latest transition failed, if it did."""
        self.run_ended = False
        """end_with_run: the plant's run has ended (its fatal Status was heard)."""
        self._before_configure: set[int] | None = None  # the entities before configure (_entities)
        self.add_on_set_parameters_callback(lambda changed: parameters.validate(self._specs, changed))
        values = parameters.declare(self, [spec for spec in specs if spec in (AUTOSTART, END_WITH_RUN)])
        if values.get("end_with_run"):
            self.create_subscription(Status, topics.STATUS, self._on_status, topics.STREAM_QOS)
        self._autostarting = bool(values["autostart"])  # a refusal is raised then, not logged
        if self._autostarting:
            for transition in (self.trigger_configure, self.trigger_activate):
                if transition() != TransitionCallbackReturn.SUCCESS:
                    assert self.refusal is not None
                    raise self.refusal
            self._autostarting = False

    # --- the hooks: what each node does at each transition ----------------------------------------

    def configure(self, values: dict[str, ParameterValue]) -> None:
        """Check the parameters ``values`` and make what the node needs (raise one of REFUSED to refuse)."""

    def activate(self) -> None:
        """Start doing the node's work."""

    def deactivate(self) -> None:
        """Pause it, keeping what was configured."""

    def cleanup(self) -> None:
        """Undo configure beyond the entities it created (which the base destroys); must also undo a
        configure that failed part way."""

    # --- the transitions ---------------------------------------------------------------------------

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._before_configure = _entities(self)  # what is made from now on, cleanup destroys

        def configure() -> None:
            undeclared = [spec for spec in self._specs if not self.has_parameter(spec.name)]
            parameters.declare(self, undeclared)
            self.configure({spec.name: self.get_parameter(spec.name).value for spec in self._specs})
            if self._autostarting:  # at once: nothing that arrives between the two transitions is missed
                self.activate()

        result = self._transition("configure", configure)
        if result != TransitionCallbackReturn.SUCCESS:
            self._unconfigure()
        return result

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._autostarting:
            return TransitionCallbackReturn.SUCCESS  # the activate hook ran with configure
        return self._transition("activate", self.activate)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("deactivate", self.deactivate)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("cleanup", self._unconfigure)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        def shut_down() -> None:
            if state.label == "active":
                self.deactivate()
            if state.label in ("active", "inactive"):
                self._unconfigure()

        return self._transition("shutdown", shut_down)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("error processing", self._unconfigure)

    def _unconfigure(self) -> None:
        try:
            self.cleanup()
        finally:
            if self._before_configure is not None:
                for destroy in _destroyers(self, self._before_configure):
                    destroy()
                self._before_configure = None

    def _transition(self, name: str, hook: _Hook) -> TransitionCallbackReturn:
        """Run ``hook``; one log line and FAILURE (the node stays where it was) if it refuses, ERROR (rclpy's
        error processing, back to unconfigured) if it raises anything else."""
        try:
            hook()
        except REFUSED as error:
            self.refusal = error
            if not self._autostarting:
                self.get_logger().error(f"{name} failed: {error}")
            return TransitionCallbackReturn.FAILURE
        except Exception as error:
            self.refusal = error
            if not self._autostarting:
                self.get_logger().error(f"{name} failed: {error!r}")
            return TransitionCallbackReturn.ERROR
        self.refusal = None
        return TransitionCallbackReturn.SUCCESS

    def _on_status(self, status: Status) -> None:
        if status.fatal and not self.run_ended:
            self.run_ended = True
            self.get_logger().info(f"the plant's run ended ({status.kind}): ending with it (end_with_run)")


def _entities(node: Node) -> set[int]:
    """Identities of the node's publishers, subscriptions, timers, services and clients."""
    return {id(entity) for kind in _DESTROYERS for entity in getattr(node, kind)}


_DESTROYERS = {
    "publishers": "destroy_publisher",
    "subscriptions": "destroy_subscription",
    "timers": "destroy_timer",
    "services": "destroy_service",
    "clients": "destroy_client",
}


def _destroyers(node: Node, before: set[int]) -> list[Callable[[], None]]:
    """A call per entity the node has made since ``before`` (:func:`_entities`) that destroys it."""
    return [
        functools.partial(getattr(node, method), entity)
        for kind, method in _DESTROYERS.items()
        for entity in list(getattr(node, kind))
        if id(entity) not in before
    ]
