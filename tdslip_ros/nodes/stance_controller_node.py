"""The stance controller node: a stance-feedback policy at 1 kHz on the plant's torque interface.

Its policy (``stance_policy``) is one of :data:`~tdslip_ros.model.policies.registry.STANCE_FEEDBACK_POLICIES`:
the baseline of the paper's ref. 36 (``stance_pd_speed_energy``,
:class:`~tdslip_ros.model.policies.stance_pd.StancePDSpeedEnergy`: an energy term toward the target apex, PD
on forward speed), or, for a rigid body, ``posture``
(:class:`~tdslip_ros.model.policies.posture.PostureRegulation`: energy regulation planned on the hip at each
apex, and a PD holding the balancing lean). It answers every apex with stance feedback (StanceCommand
``stance`` STANCE_FEEDBACK) at the policy's fixed touchdown angle ``stance_touchdown_angle``, and every state
sample in stance (``tdslip/state``, phase STANCE) with the law's torque for that sample's tick on
``tdslip/hip_torque`` (:mod:`tdslip_ros.nodes.torque_stream`). All maths is the model's; this node only
converts messages.

What the law sees is what the model's engines give it: at the apex, the measured height above the ground of
the last stance, the measured speed and the pitch; in stance, the sampled leg state, the pitch and the torque
held until the sample (the sample's ``hip_torque``); the sample's time t is the plant's simulated time, and s
the time since the touchdown event of the stride (``tdslip/contact``; NaN until it is heard, which neither
law reads). The torque is clipped at this hopper's plausible torque, as the engines clip a law's
output (the plant refuses a torque beyond it).

Parameters: the hopper the law computes with (``mass``, ...: the plant's, or others for model mismatch) and
the policy's settings (:data:`~tdslip_ros.model.policies.registry.POLICY_SETTINGS`, those of the policy),
read at every apex, so ``ros2 param set`` changes them at runtime. Defaults: config/controller.yaml.
"""

from __future__ import annotations

import dataclasses
import math
import sys

from tdslip_msgs.msg import ApexEvent, ContactEvent, HipTorque, HopperState, StanceCommand

from tdslip_ros.interfaces import STAMP_FIELDS, hopper_from_parameters
from tdslip_ros.model.limits import PlausibilityLimits, check_hopper
from tdslip_ros.model.params import ApexState, ParameterError
from tdslip_ros.model.plant.stance_laws import StanceFeedback, StanceSample, clip_torque
from tdslip_ros.model.policies import controllers
from tdslip_ros.model.policies.registry import (
    POLICY_SETTINGS,
    SETTING_DEFAULTS,
    STANCE_FEEDBACK_POLICIES,
    STANCE_PD_SPEED_ENERGY,
    PolicyError,
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
from tdslip_ros.nodes.controller_node import setting_parameter
from tdslip_ros.nodes.diagnostics import specs_of
from tdslip_ros.nodes.entry import run_node
from tdslip_ros.nodes.lifecycle import AUTOSTART, END_WITH_RUN, ManagedNode
from tdslip_ros.nodes.node_status import stance_controller_diagnostics
from tdslip_ros.nodes.parameters import ParameterSpec, ParameterValue
from tdslip_ros.nodes.torque_stream import tick_of
from tdslip_ros.nodes.wire import fixed_layout_encoder, serialized

STANCE_POLICY = ParameterSpec(
    "stance_policy",
    STANCE_PD_SPEED_ENERGY,
    "the stance controller's policy (stance feedback at each tick of the stance)",
    choices=STANCE_FEEDBACK_POLICIES,
)
SETTINGS = tuple(s for s in POLICY_SETTINGS if set(s.policies) & set(STANCE_FEEDBACK_POLICIES))
"""The settings of the stance-feedback policies, in POLICY_SETTINGS' order."""
SPECS: tuple[ParameterSpec, ...] = (
    AUTOSTART,
    END_WITH_RUN,
    ANSWER_SUBSCRIBERS,
    *parameters.HOPPER,
    STANCE_POLICY,
    *map(setting_parameter, SETTINGS),
    *specs_of(()),
)


class StanceControllerNode(ManagedNode):
    """Subscribes tdslip/apex, tdslip/contact and tdslip/state; while active, publishes a tdslip/command per
    apex and a tdslip/hip_torque per stance sample (:mod:`tdslip_ros.nodes.lifecycle`)."""

    def __init__(self, **node_options: object) -> None:
        self.commands = 0
        self.torques = 0
        self.unanswered = 0
        self._answering = False
        self._answers = ApexAnswers()
        super().__init__("stance_controller", SPECS, **node_options)
        self.add_post_set_parameters_callback(lambda _: self._answers.forget())

    def configure(self, values: dict[str, ParameterValue]) -> None:
        self.hopper = hopper_from_parameters(values)
        check_hopper(self.hopper)
        self._max_torque = PlausibilityLimits.for_hopper(self.hopper).max_torque
        # posture plans on the analytic map: its kernels load before the first apex (0.24 s), not at it
        point_mass = dataclasses.replace(self.hopper, body=None)
        controllers.warm_up(point_mass, complex_step=False, exact_plant=False)
        self._epoch = 0
        self._feedback: StanceFeedback | None = None  # the answer to the latest apex
        self._touchdown = (-1, math.nan)  # (stride, simulated time [s]) of the latest touchdown heard
        self._command_publisher = self.create_publisher(StanceCommand, topics.COMMAND, topics.COMMAND_QOS)
        self._torque_publisher = self.create_publisher(HipTorque, topics.HIP_TORQUE, topics.STREAM_QOS)
        self._torque_encoder = fixed_layout_encoder(
            HipTorque, (*STAMP_FIELDS, "epoch", "stride", "tick", "torque")
        )
        self._apex_topic = self.resolve_topic_name(topics.APEX)
        subscribe_when_heard(
            self,
            [self._command_publisher, self._torque_publisher],
            int(values[ANSWER_SUBSCRIBERS.name]),
            lambda: self.create_subscription(ApexEvent, topics.APEX, self._on_apex, topics.STREAM_QOS),
        )
        self.create_subscription(ContactEvent, topics.CONTACT, self._on_contact, topics.STREAM_QOS)
        self.create_subscription(HopperState, topics.STATE, self._on_state, topics.STREAM_QOS)
        self.diagnostics = stance_controller_diagnostics(self, self)

    def activate(self) -> None:
        self._answering = True

    def deactivate(self) -> None:
        self._answering = False
        self._feedback = None  # no torque for a stance whose apex this node did not answer

    @property
    def policy(self) -> str:
        """The policy answering the next apex (``stance_policy``)."""
        return str(self.get_parameter(STANCE_POLICY.name).value)

    def feedback(self, policy: str, apex: ApexState) -> StanceFeedback:
        """``policy``'s stance feedback to ``apex`` (as the controller sees it), with the parameters now."""
        values = {**SETTING_DEFAULTS}
        values |= {setting.name: self.get_parameter(setting.name).value for setting in SETTINGS}
        return PolicySpec.of(policy, values).stance_feedback(self.hopper, apex)

    def _on_apex(self, apex: ApexEvent) -> None:
        if not self._answering or self._answers.repeated(apex, self._command_publisher):
            return
        policy = self.policy
        seen = ApexState(
            apex.measured_height - apex.ground_height,
            apex.measured_forward_speed,
            apex.pitch,
            apex.pitch_rate,
        )
        try:
            feedback = self.feedback(policy, seen)  # the command and its label of one policy
        except (ParameterError, PolicyError) as error:  # no command: the plant's timeout says so
            self.unanswered += 1
            self._feedback = None
            self.get_logger().error(
                f"{policy}: no command for apex {apex.stride} (y = {seen.y:.6g} m above the ground, "
                f"xdot = {seen.xdot:.6g} m/s, pitch = {seen.pitch:.6g} rad): {error}"
            )
            return
        self._epoch, self._feedback = apex.epoch, feedback
        msg = StanceCommand(
            epoch=apex.epoch,
            stride=apex.stride,
            touchdown_angle=self._feedback.touchdown_angle,
            policy=policy,
            stance=StanceCommand.STANCE_FEEDBACK,
        )
        msg.header = apex.header
        # A recorder or plant this publisher has not matched (or discovered) yet would miss it.
        wait_to_answer(
            self, self._command_publisher, self._apex_topic, first=apex.stride == 0, timeout=MATCH_TIMEOUT
        )
        data = serialized(msg)
        self._command_publisher.publish(data)
        self._answers.answered(data)
        self.commands += 1

    def _on_contact(self, contact: ContactEvent) -> None:
        if contact.kind == ContactEvent.TOUCHDOWN:
            self._touchdown = (contact.stride, contact.sim_time)

    def _on_state(self, state: HopperState) -> None:
        if state.phase != HopperState.PHASE_STANCE or self._feedback is None or not self._answering:
            return
        sec, nanosec = state.header.stamp.sec, state.header.stamp.nanosec
        t = sec + nanosec * 1e-9
        stride, touchdown = self._touchdown
        sample = StanceSample(
            t,
            t - touchdown if stride == state.stride else math.nan,
            state.leg_length,
            state.leg_angle,
            state.leg_length_rate,
            state.leg_angle_rate,
            state.hip_torque,
            state.pitch,
            state.pitch_rate,
        )
        torque = clip_torque(float(self._feedback.law.torque(sample)), self._max_torque)
        values = (sec, nanosec, self._epoch, state.stride, tick_of(sec, nanosec), torque)
        self._torque_publisher.publish(self._torque_encoder.encode(values))
        self.torques += 1


def main(argv: list[str] | None = None) -> int:
    """``stance_controller_node [--ros-args ...]``: serve until SIGINT/SIGTERM (or the run's end,
    ``end_with_run``), config/controller.yaml by default."""
    return run_node(
        StanceControllerNode,
        "controller.yaml",
        sys.argv if argv is None else argv,
        lambda node: node.run_ended,
        specs=SPECS,
    )


if __name__ == "__main__":
    sys.exit(main())
