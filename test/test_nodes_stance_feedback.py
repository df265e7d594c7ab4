"""Stance feedback through the plant's 1 kHz torque interface: the stance controller node (the baseline of
ref. 36) and hand-made torque streams, in a private in-process graph (lockstep unless said otherwise)."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from rclpy.node import Node
from rclpy.publisher import Publisher
from support.ros_harness import RosGraph, overrides
from tdslip_msgs.msg import ApexEvent, HipTorque, HopperState, StanceCommand, Status

from tdslip_ros.interfaces import hopper_parameters
from tdslip_ros.model.events import EventKind
from tdslip_ros.model.paper import UPRIGHT_TRUNK
from tdslip_ros.model.params import ApexState, HopperParams
from tdslip_ros.model.plant.stepper import FixedStepStepper
from tdslip_ros.model.policies.registry import (
    DEFAULT_APEX_HEIGHT,
    DEFAULT_APEX_SPEED,
    POSTURE,
    STANCE_PD_SPEED_ENERGY,
    PolicySpec,
)
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.parameters import PAPER_PARAMS as PARAMS
from tdslip_ros.nodes.plant_node import TICK_PERIOD, PlantNode
from tdslip_ros.nodes.stance_controller_node import StanceControllerNode
from tdslip_ros.nodes.torque_stream import tick_of

pytestmark = pytest.mark.nodes

START = ApexState(DEFAULT_APEX_HEIGHT, DEFAULT_APEX_SPEED)
REPO = Path(__file__).parents[1]


def model_apexes(
    policy: str, params: HopperParams, start: ApexState, strides: int
) -> tuple[list[tuple[float, ...]], list[tuple[float, float]]]:
    """(t, y, xdot, pitch, pitch rate) of apexes 0..strides and every torque held, of ``policy`` (at its
    defaults) answering each apex of the stepper, as the stance controller node answers the plant's."""
    spec = PolicySpec.default(policy)
    stepper = FixedStepStepper(params, start, spec.stance_feedback(params, start), dt=TICK_PERIOD)
    apexes: list[tuple[float, ...]] = [(0.0, *dataclasses.astuple(start))]
    torques: list[tuple[float, float]] = []
    while len(apexes) <= strides:
        for event in stepper.step():
            assert event.kind is not EventKind.FAILURE, event.reason
            if event.kind is EventKind.LIFTOFF:
                torques += stepper.stance_torques
            if event.kind is EventKind.APEX:
                state = event.state
                apex = ApexState(state.y, state.xdot, state.pitch, state.pitch_rate)
                apexes.append((event.t, *dataclasses.astuple(apex)))
                stepper.set_command(spec.stance_feedback(params, apex))
    return apexes, torques


def stance_feedback_node(ros: RosGraph, name: str) -> tuple[Node, Publisher[HipTorque]]:
    """A hand-made controller ``name`` that answers every apex with stance feedback at 22 deg, and its hip
    torque publisher (what it streams is the test's)."""
    node = ros.node(name)
    commands = node.create_publisher(StanceCommand, topics.COMMAND, 10)

    def answer(apex: ApexEvent) -> None:
        msg = StanceCommand(epoch=apex.epoch, stride=apex.stride, touchdown_angle=math.radians(22.0))
        msg.stance = StanceCommand.STANCE_FEEDBACK
        commands.publish(msg)

    node.create_subscription(ApexEvent, topics.APEX, answer, 10)
    return node, node.create_publisher(HipTorque, topics.HIP_TORQUE, 10)


def test_the_baseline_node_drives_the_plant_as_the_law_drives_the_stepper(ros: RosGraph) -> None:
    """Lockstep: the plant waits for each stance tick's torque, so the run is the model's own, bit for bit:
    the same apexes, and the torques applied (tdslip/applied_torque) are the law's."""
    strides = 4
    plant = ros.add(PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=strides)))
    controller = ros.add(StanceControllerNode(context=ros.context))
    apexes = ros.collect(ApexEvent, topics.APEX)
    applied = ros.collect(HipTorque, topics.APPLIED_TORQUE)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome is not None and plant.outcome.ok, plant.outcome
    ros.spin_until(lambda: len(apexes) == strides + 1, "every apex event")
    expected, torques = model_apexes(STANCE_PD_SPEED_ENERGY, PARAMS, START, strides)
    assert [(a.sim_time, a.height, a.forward_speed) for a in apexes] == [e[:3] for e in expected]
    ros.spin_until(lambda: len(applied) == len(torques), "every applied torque")
    assert [(a.tick, a.torque) for a in applied] == [(round(t / TICK_PERIOD), tau) for t, tau in torques]
    assert controller.torques == len(torques) and plant.counts.late_torques == plant.counts.stale_torques == 0
    assert plant.counts.rejected == 0


RIGID = dataclasses.replace(PARAMS, body=UPRIGHT_TRUNK)
RIGID_START = ApexState(1.2, 5.0)
"""The upright trunk's hip at 1 m (the centre of mass 0.2 m above it)."""


def test_the_posture_node_balances_a_rigid_body_as_the_policy_does_in_the_stepper(ros: RosGraph) -> None:
    """A rigid body on the wire: the plant publishes its pitch in every state and apex, the stance controller
    plans each stride from the apex's pitch and holds the lean from each sample's. Lockstep makes the run the
    model's own: the same apexes, pitch included, and the same torques held, to rounding (the law's ramp runs
    on the time since touchdown, which the node takes from the stamps: 1e-16 s apart)."""
    strides = 4
    plant = ros.add(
        PlantNode(
            context=ros.context,
            parameter_overrides=overrides(
                **hopper_parameters(RIGID), initial_height=RIGID_START.y, max_strides=strides
            ),
        )
    )
    controller = ros.add(
        StanceControllerNode(
            context=ros.context,
            parameter_overrides=overrides(**hopper_parameters(RIGID), stance_policy=POSTURE),
        )
    )
    apexes = ros.collect(ApexEvent, topics.APEX)
    applied = ros.collect(HipTorque, topics.APPLIED_TORQUE)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome is not None and plant.outcome.ok, plant.outcome
    ros.spin_until(lambda: len(apexes) == strides + 1, "every apex event")
    expected, torques = model_apexes(POSTURE, RIGID, RIGID_START, strides)
    recorded = [(a.sim_time, a.height, a.forward_speed, a.pitch, a.pitch_rate) for a in apexes]
    assert np.allclose(recorded, expected, rtol=1e-12, atol=1e-12)
    assert all(abs(pitch) > 0.3 for _, _, _, pitch, _ in expected[1:])  # it leans: a pitch, not zeros
    ros.spin_until(lambda: len(applied) == len(torques), "every applied torque")
    assert [a.tick for a in applied] == [round(t / TICK_PERIOD) for t, _ in torques]
    assert np.allclose([a.torque for a in applied], [tau for _, tau in torques], rtol=1e-12, atol=1e-9)
    assert controller.torques == len(torques) and plant.counts.rejected == 0


def test_bad_torques_are_refused_and_the_plant_waits_for_the_right_one(ros: RosGraph) -> None:
    """A hand-made stream: NaN, implausible, ahead of the plant and for another epoch are refused (a Status
    each) or counted late, and the plant holds the first valid one for the awaited tick."""
    plant = ros.add(PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=2)))
    node, torques = stance_feedback_node(ros, "hand")
    statuses = ros.collect(Status, topics.STATUS)
    stance_states: list[HopperState] = []
    sent: list[int] = []

    def stream(state: HopperState) -> None:
        if state.phase != HopperState.PHASE_STANCE:
            return
        tick = tick_of(state.header.stamp.sec, state.header.stamp.nanosec)
        if not stance_states:  # the first stance tick: everything wrong first
            for bad in (
                HipTorque(epoch=0, stride=state.stride, tick=tick, torque=math.nan),
                HipTorque(epoch=0, stride=state.stride, tick=tick, torque=1e9),
                HipTorque(epoch=0, stride=state.stride, tick=tick + 1, torque=-10.0),
                HipTorque(epoch=1, stride=state.stride, tick=tick, torque=-10.0),
                HipTorque(epoch=0, stride=state.stride + 1, tick=tick, torque=-10.0),
            ):
                torques.publish(bad)
        stance_states.append(state)
        sent.append(tick)
        torques.publish(HipTorque(epoch=0, stride=state.stride, tick=tick, torque=-50.0))

    node.create_subscription(HopperState, topics.STATE, stream, 10)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome is not None and plant.outcome.ok, plant.outcome
    refused = [s.reason for s in statuses if s.kind == Status.KIND_TORQUE_REJECTED]
    assert len(refused) == 5 and not any(s.fatal for s in statuses if s.kind == Status.KIND_TORQUE_REJECTED)
    for reason in ("not a plausible hip torque", "ahead of the plant", "the plant's latest state is tick"):
        assert any(reason in r for r in refused), (reason, refused)
    # Every stance tick held the valid -50 N m: each stance's first state holds zero only until its first
    # sample instant, the tick after touchdown; every later one holds -50.
    by_stride: dict[int, list[float]] = {}
    for state in stance_states:
        by_stride.setdefault(state.stride, []).append(state.hip_torque)
    assert len(by_stride) == 2 and all(set(held[1:]) == {-50.0} for held in by_stride.values()), by_stride
    assert plant.counts.late_torques == 0


def test_the_torque_of_the_tick_that_fails_is_recorded_too(ros: RosGraph) -> None:
    """A stream that brakes hard (+3000 N m, backward) ends the stance in a failure; every torque the plant
    held went out on tdslip/applied_torque, the one of the failing tick included (before: all but it)."""
    plant = ros.add(PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=2)))
    node, torques = stance_feedback_node(ros, "braking")
    applied = ros.collect(HipTorque, topics.APPLIED_TORQUE)
    sent: list[int] = []

    def stream(state: HopperState) -> None:
        if state.phase == HopperState.PHASE_STANCE:
            tick = tick_of(state.header.stamp.sec, state.header.stamp.nanosec)
            sent.append(tick)
            torques.publish(HipTorque(epoch=0, stride=state.stride, tick=tick, torque=3000.0))

    node.create_subscription(HopperState, topics.STATE, stream, 10)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome is not None and not plant.outcome.ok, plant.outcome
    ros.spin_until(lambda: len(applied) == plant.published[topics.APPLIED_TORQUE], "every applied torque")
    assert plant.counts.rejected == 0 and plant.received_torques == len(sent) > 10
    assert [(a.tick, a.torque) for a in applied] == [(tick, 3000.0) for tick in sent]


def test_a_silent_torque_stream_ends_a_lockstep_run_with_command_timeout(ros: RosGraph) -> None:
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=3, command_timeout=0.5))
    )
    stance_feedback_node(ros, "silent")  # streams nothing
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome is not None and plant.outcome.kind == Status.KIND_COMMAND_TIMEOUT
    assert "no valid hip torque for epoch 0, stride 0, tick" in plant.outcome.reason


def test_realtime_holds_the_stream_and_counts_stale_ticks(ros: RosGraph) -> None:
    """Realtime with the baseline node: the run completes, and the ticks that held zero (the controller's
    torques are never exactly zero) are the stale ticks the plant counts. On an idle machine there are few or
    none: test_nodes_torque_stream's PlantRun test counts stale ticks that surely happen."""
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides(max_strides=4, clock_mode="realtime"))
    )
    controller = ros.add(StanceControllerNode(context=ros.context))
    applied = ros.collect(HipTorque, topics.APPLIED_TORQUE)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run")
    assert plant.outcome is not None and plant.outcome.ok, plant.outcome
    # On a loaded machine a command may come after its touchdown (fresh2's suite, 2026-12-05): then it is
    # refused as late, and that is all it may be refused for (one answer per apex: one per late stride).
    assert controller.torques > 0 and plant.counts.rejected == plant.counts.late_commands, plant.counts
    ros.spin_until(lambda: len(applied) == plant.published[topics.APPLIED_TORQUE], "every applied torque")
    stale = sum(1 for a in applied if a.torque == 0.0)
    assert plant.counts.stale_torques == stale


def test_a_torque_controller_of_ones_own_with_default_qos_drives_the_plant(
    ros: RosGraph, tmp_path: Path
) -> None:
    """examples/my_torque_controller.py, a stranger's 1 kHz node (default QoS), in a process of its own:
    the lockstep plant holds every torque it sends, none late or refused, and the hopper settles where
    its docstring says; it ends by itself when the run ends."""
    strides = 6
    plant = ros.add(
        PlantNode(
            context=ros.context, parameter_overrides=overrides(max_strides=strides, command_timeout=60.0)
        )
    )
    apexes = ros.collect(ApexEvent, topics.APEX)
    applied = ros.collect(HipTorque, topics.APPLIED_TORQUE)
    log = tmp_path / "controller.log"
    controller = ros.start_process([sys.executable, str(REPO / "examples" / "my_torque_controller.py")], log)
    ros.spin_until(lambda: plant.outcome is not None, "the end of the run", timeout=90.0)
    assert plant.outcome is not None and plant.outcome.ok, (plant.outcome, log.read_text())
    assert controller.wait(30) == 0, log.read_text()  # the example ends with the plant's run
    ros.spin_until(lambda: len(apexes) == strides + 1, "every apex event")
    ros.spin_until(lambda: len(applied) == plant.published[topics.APPLIED_TORQUE], "every applied torque")
    assert plant.received_torques == len(applied) > 100 and plant.counts.rejected == 0
    assert plant.counts.late_torques == 0 and all(abs(a.torque) <= 400.0 for a in applied)
    assert apexes[-1].height == pytest.approx(1.01, abs=0.01)
    assert apexes[-1].forward_speed == pytest.approx(5.02, abs=0.01)
