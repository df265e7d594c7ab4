"""The apex controller node: answers every apex event with a stance command from a model policy.

The policy is the parameter ``policy``, one of :data:`~tdslip_ros.model.policies.registry.POLICIES`; what each
does and plans on: docs/policies.md. Each setting of the policies
(:data:`tdslip_ros.model.policies.registry.POLICY_SETTINGS`) is the parameter of the same name, with its
default, range (or choices) and description. Policy, targets and gains are read at every apex, so ``ros2 param
set`` changes them at runtime (values are checked against their ranges and choices first; a value outside them
is refused, at start-up too). How long planning takes: ``bench/bench_controllers.py`` (docs/benchmarks.md).

The controller plans with its own SI hopper parameters (``mass``, ``stiffness``, ``rest_length``,
``damping``, ``gravity``): the plant's, as config/controller.yaml has them for the defaults, or other
values to study model mismatch (``tdslip run --mismatch`` scales the plant's by factors).

The controller is blind to the terrain and sees the apex through the plant's sensor: it plans with the
*measured* apex (ApexEvent ``measured_height``, ``measured_forward_speed``, equal to the true apex without
sensing noise), its height taken above ``ground_height``, the ground of the stance it last stood on.
"""

from __future__ import annotations

import contextlib
import sys
import time

from tdslip_msgs.msg import ApexEvent, StanceCommand

from tdslip_ros.interfaces import hopper_from_parameters
from tdslip_ros.model.limits import check_hopper
from tdslip_ros.model.params import ParameterError
from tdslip_ros.model.params import StanceCommand as ModelCommand
from tdslip_ros.model.policies import controllers
from tdslip_ros.model.policies.registry import (
    DEFAULT_POLICY,
    LEARNED,
    POLICIES,
    POLICY_SETTINGS,
    PolicyError,
    PolicySetting,
    PolicySpec,
)
from tdslip_ros.nodes import parameters, topics
from tdslip_ros.nodes.answers import (
    ANSWER_SUBSCRIBERS,
    MATCH_TIMEOUT,
    ApexAnswers,
    subscribe_when_heard,
    wait_to_answer,
)
from tdslip_ros.nodes.diagnostics import CONTROLLER_THRESHOLDS, specs_of
from tdslip_ros.nodes.entry import run_node
from tdslip_ros.nodes.lifecycle import AUTOSTART, END_WITH_RUN, ManagedNode
from tdslip_ros.nodes.node_status import PlanningTimes, controller_diagnostics
from tdslip_ros.nodes.parameters import ParameterSpec, ParameterValue
from tdslip_ros.nodes.wire import command_encoder


def setting_parameter(setting: PolicySetting) -> ParameterSpec:
    """The parameter of a policy setting: its name, default, range or choices, and one-line text."""
    return ParameterSpec(
        setting.name, setting.default, setting.text, setting.lower, setting.upper, choices=setting.choices
    )


TUNABLE: tuple[ParameterSpec, ...] = (
    ParameterSpec("policy", DEFAULT_POLICY, "stance policy answering each apex", choices=POLICIES),
    *map(setting_parameter, POLICY_SETTINGS),
)
SPECS: tuple[ParameterSpec, ...] = (
    AUTOSTART,
    END_WITH_RUN,
    ANSWER_SUBSCRIBERS,
    *parameters.HOPPER,
    *TUNABLE,
    *specs_of(CONTROLLER_THRESHOLDS),
)


class ControllerNode(ManagedNode):
    """Subscribes tdslip/apex, publishes one tdslip/command per apex it can answer while active
    (:mod:`tdslip_ros.nodes.lifecycle`: configure loads the policies' kernels, activate answers)."""

    def __init__(self, **node_options: object) -> None:
        self.published = 0
        self.unanswered = 0
        self.planning_times = PlanningTimes()
        self._answering = False
        self._answers = ApexAnswers()
        self._configured = False
        super().__init__("controller", SPECS, **node_options)
        self.add_post_set_parameters_callback(self._parameters_changed)

    def configure(self, values: dict[str, ParameterValue]) -> None:
        self.hopper = hopper_from_parameters(values)
        check_hopper(self.hopper)
        self._previous_speed: float | None = None
        self._policy: PolicySpec | None = None
        """The policy with the current parameters; built again at the first apex after a parameter changed."""
        self._publisher = self.create_publisher(StanceCommand, topics.COMMAND, topics.COMMAND_QOS)
        # The policies' compiled kernels load (or compile) before the first apex can arrive, not at it.
        controllers.warm_up(self.hopper, complex_step=False, exact_plant=False)
        self.exact_plant_ready = False
        """energy_exact's compiled exact stride is loaded (see :meth:`_ready_exact_plant`)."""
        self._ready_exact_plant()
        self._apex_topic = self.resolve_topic_name(topics.APEX)
        subscribe_when_heard(
            self,
            [self._publisher],
            int(values[ANSWER_SUBSCRIBERS.name]),
            lambda: self.create_subscription(ApexEvent, topics.APEX, self._on_apex, topics.STREAM_QOS),
        )
        self.diagnostics = controller_diagnostics(self, self)
        self._configured = True

    def activate(self) -> None:
        self._answering = True

    def deactivate(self) -> None:
        self._answering = False

    def cleanup(self) -> None:
        self._configured = False

    def _parameters_changed(self, changed: object) -> None:
        self._policy = None
        self._answers.forget()
        if self._configured:
            self._ready_exact_plant()

    def _ready_exact_plant(self) -> None:
        """Load energy_exact's compiled exact stride once the policy plans on it, directly or as a learned
        policy's base: at the start, or as the parameters change to it, not at the next apex (loading, or a
        compilation, would make its answer late). Only then: it brings scipy.integrate's import to the start
        (docs/benchmarks.md).
        """
        if self.exact_plant_ready:
            return
        spec = self.policy_spec(str(self.get_parameter("policy").value))
        planned = {spec.name}
        if spec.name == LEARNED:
            with contextlib.suppress(PolicyError):  # a bad file is reported at the apex it cannot answer
                planned.add(spec.learned_residual()[1].name)
        if "energy_exact" in planned:
            controllers.warm_up(self.hopper, complex_step=False, exact_plant=True)
            self.exact_plant_ready = True

    def plan(self, y: float, xdot: float, policy: PolicySpec | None = None) -> ModelCommand:
        """The command of ``policy`` (default: the current one) for the apex (y [m], xdot [m/s]);
        ParameterError if the policy has none (e.g. the leg cannot be placed from this apex), PolicyError if
        its settings cannot serve (the learned policy's file unreadable)."""
        previous = xdot if self._previous_speed is None else self._previous_speed
        spec = self.current_policy() if policy is None else policy
        return spec.commands(self.hopper, y, xdot, previous).command()

    def current_policy(self) -> PolicySpec:
        """The parameter ``policy`` with the current values of the settings (PolicyError if they cannot make
        one); kept until a parameter changes, as an apex's answer is due within a millisecond or two."""
        if self._policy is None:
            self._policy = self.policy_spec(str(self.get_parameter("policy").value))
        return self._policy

    def policy_spec(self, policy: str) -> PolicySpec:
        """``policy`` with the current values of the settings."""
        settings = PolicySpec.settings()
        return PolicySpec.of(
            policy, {parameter.name: parameter.value for parameter in self.get_parameters(settings)}
        )

    def _on_apex(self, apex: ApexEvent) -> None:
        if not self._answering or self._answers.repeated(apex, self._publisher):
            return
        if apex.stride == 0:
            self._previous_speed = None  # a new run: no previous apex for the PD's derivative term
        # What the controller can know: the measured apex, its height above the ground it last stood on.
        height, speed = apex.measured_height - apex.ground_height, apex.measured_forward_speed
        started_ns = time.perf_counter_ns()
        try:
            policy = self.current_policy()  # once: the command and its label come from the same policy
            command = self.plan(height, speed, policy)
        except (ParameterError, PolicyError) as error:
            self.unanswered += 1
            name = self.get_parameter("policy").value
            self.get_logger().error(
                f"{name}: no command for apex {apex.stride} (y = {height:.6g} m above the ground, "
                f"xdot = {speed:.6g} m/s): {error}"
            )
            return
        finally:
            self._previous_speed = speed
            self.planning_times.add(time.perf_counter_ns() - started_ns)
        stamp = apex.header.stamp
        encoder = command_encoder(policy.name, apex.header.frame_id)  # in the apex's frame
        data = encoder.encode(
            (
                stamp.sec,
                stamp.nanosec,
                apex.epoch,
                apex.stride,
                command.touchdown_angle,
                command.tau0,
                command.t_f,
            )
        )
        # A recorder or plant this publisher has not matched (or discovered) yet would miss it.
        wait_to_answer(self, self._publisher, self._apex_topic, first=apex.stride == 0, timeout=MATCH_TIMEOUT)
        self._publisher.publish(data)
        self._answers.answered(data)
        self.published += 1


def main(argv: list[str] | None = None) -> int:
    """``controller_node [--ros-args ...]``: serve until SIGINT/SIGTERM (or the run's end, ``end_with_run``),
    config/controller.yaml by default."""
    return run_node(
        ControllerNode,
        "controller.yaml",
        sys.argv if argv is None else argv,
        lambda node: node.run_ended,
        specs=SPECS,
    )


if __name__ == "__main__":
    sys.exit(main())
