"""The hopper as a robot for RViz and Foxglove: its URDF on ``robot_description``, its leg on ``joint_states``
and its frames on ``/tf``, as robot_state_publisher would publish them.

The URDF (``urdf/tdslip_hopper.urdf`` beside this module, installed into ``share/tdslip_ros/urdf/``) has the
links ``body``, ``leg`` and ``toe``: the revolute joint ``hip_angle`` (body to leg) is the model's leg angle
theta about the axis -y, the prismatic joint ``leg_length`` (leg to toe) the leg's length r along the leg.
``joint_states`` carries their positions, rates and efforts (the hip torque; the leg's axial force, zero in
flight), ``/tf`` world -> body -> leg -> toe. This module is the one place where the model's plane (x
forward, y up) becomes REP 103's axes (x forward, y left, z up): :func:`rep103_position` and
:func:`hip_rotation`. In a namespace the frames are prefixed with it (``h1/body``), as robot_state_publisher's
``frame_prefix`` does.

Cost: the joint states and the frames go out at ``marker_rate`` Hz of simulated time, and each only while
someone subscribes to it (looked at every GRAPH_CHECK_TICKS ticks, as the plant's other optional topics):
with nobody listening a tick costs one comparison (``bench/bench_diagnostics.py``; docs/benchmarks.md).
Their bytes come from fixed-layout encoders (:mod:`tdslip_ros.nodes.wire`). ``/tf`` needs ``tf2_msgs``
(every ROS 2 install has it; here the ``../shared`` tools build it); without, the plant says so once in its
log.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from importlib.resources import files
from typing import Any

from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from rclpy.publisher import Publisher
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from tdslip_ros.model.dynamics import leg_force
from tdslip_ros.model.events import HopperState, Phase
from tdslip_ros.model.params import HopperParams
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.wire import fixed_layout_encoder, stamp_of

URDF_NAME = "tdslip_hopper.urdf"
URDF = files(__package__).joinpath("urdf", URDF_NAME)
"""The hopper's URDF, as the package holds it (setup.py also installs it into share/tdslip_ros/urdf/)."""
BODY, LEG, TOE = "body", "leg", "toe"
HIP_ANGLE, LEG_LENGTH = "hip_angle", "leg_length"
JOINTS = (HIP_ANGLE, LEG_LENGTH)
"""The joints of the URDF that joint_states names, in its order."""

_STAMP = ("header.stamp.sec", "header.stamp.nanosec")
JOINT_FIELDS = (*_STAMP, "position[0]", "position[1]", "velocity[0]", "velocity[1]", "effort[0]", "effort[1]")
TF_FIELDS = (
    *(f"transforms[0].{field}" for field in (*_STAMP, "transform.translation.x", "transform.translation.z")),
    *(f"transforms[1].{field}" for field in (*_STAMP, "transform.rotation.y", "transform.rotation.w")),
    *(f"transforms[2].{field}" for field in (*_STAMP, "transform.translation.z")),
)
"""What changes between two /tf messages: the stamps, the body's position, the hip's rotation, the leg's
length (every other field is the template's: y = 0, the body's and the toe's rotation the identity)."""


def rep103_position(x: float, height: float) -> tuple[float, float, float]:
    """A point of the model's plane (x forward, height up) in REP 103's axes (x forward, y left, z up)."""
    return (x, 0.0, height)


def hip_rotation(theta: float) -> tuple[float, float, float, float]:
    """The quaternion (x, y, z, w) of the leg's frame in the body's: theta [rad] about -y, so that a
    positive theta (the model's: the toe ahead of the body) puts the toe at +x."""
    return (0.0, -math.sin(theta / 2), 0.0, math.cos(theta / 2))


def robot_description(rest_length: float) -> str:
    """The URDF with the leg drawn at ``rest_length`` [m]."""
    robot = ET.fromstring(URDF.read_text())
    leg_visual = robot.find(f"link[@name='{LEG}']/visual")
    assert leg_visual is not None
    leg_visual.find("origin").set("xyz", f"0 0 {-rest_length / 2:.17g}")  # type: ignore[union-attr]
    leg_visual.find("geometry/cylinder").set("length", f"{rest_length:.17g}")  # type: ignore[union-attr]
    return ET.tostring(robot, encoding="unicode")


def joint_values(hopper: HopperParams, state: HopperState) -> tuple[float, ...]:
    """Positions, rates and efforts of :data:`JOINTS` (theta, r; thetadot, rdot; the hip torque, the leg's
    axial force: the spring-damper's in stance, none in flight, where the leg is massless)."""
    force = leg_force(hopper, state.r, state.rdot) if state.phase is Phase.STANCE else 0.0
    return (state.theta, state.r, state.thetadot, state.rdot, state.hip_torque, force)


def _tf_message_class() -> type | None:
    try:
        from tf2_msgs.msg import TFMessage  # optional: not every environment has it
    except ImportError:
        return None
    return TFMessage  # type: ignore[no-any-return]


class RobotModelPublisher:
    """The plant's robot_description (at once), joint_states and /tf (:meth:`publish` at every tick, every
    ``period_ticks``-th going out while someone subscribes; 0: never) for ``hopper``."""

    def __init__(self, node: Node, hopper: HopperParams, period_ticks: int) -> None:
        self._node = node
        self._hopper = hopper
        self._period_ticks = period_ticks
        namespace = node.get_namespace().strip("/")
        self.frame_prefix = f"{namespace}/" if namespace else ""
        self._description = node.create_publisher(
            String, topics.ROBOT_DESCRIPTION, topics.ROBOT_DESCRIPTION_QOS
        )
        self._description.publish(String(data=robot_description(hopper.r0)))
        self._joints = node.create_publisher(JointState, topics.JOINT_STATES, topics.STREAM_QOS)
        self._joint_encoder = fixed_layout_encoder(
            JointState,
            JOINT_FIELDS,
            JointState(name=list(JOINTS), position=[0.0] * 2, velocity=[0.0] * 2, effort=[0.0] * 2),
        )
        self._joints_out = False
        self._tf: Publisher[Any] | None = None
        self._tf_out = False
        tf_message = _tf_message_class()
        if tf_message is None:
            node.get_logger().info(
                "no /tf: tf2_msgs is not installed (joint_states and robot_description are)"
            )
            return
        self._tf = node.create_publisher(tf_message, topics.TF, topics.TF_QOS)
        self._tf_encoder = fixed_layout_encoder(tf_message, TF_FIELDS, self._tf_template(tf_message))

    def _tf_template(self, tf_message: type) -> object:
        chain = [(topics.FRAME_ID, BODY), (BODY, LEG), (LEG, TOE)]
        transforms = []
        for parent, child in chain:
            transform = TransformStamped()
            prefix = "" if parent == topics.FRAME_ID else self.frame_prefix
            transform.header.frame_id = prefix + parent
            transform.child_frame_id = self.frame_prefix + child
            transform.transform.rotation.w = 1.0
            transforms.append(transform)
        return tf_message(transforms=transforms)

    def check_graph(self) -> None:
        """Publish joint_states and /tf from now on while someone subscribes to them."""
        listening = bool(self._period_ticks)
        self._joints_out = listening and self._joints.get_subscription_count() > 0
        self._tf_out = listening and self._tf is not None and self._tf.get_subscription_count() > 0

    def publish(self, state: HopperState, t: float, tick: int) -> None:
        """The joints and frames of ``state`` stamped t [s], if ``tick`` is one of theirs and someone
        listens."""
        if not (self._joints_out or self._tf_out) or tick % self._period_ticks:
            return
        stamp = stamp_of(t)
        if self._joints_out:
            self._joints.publish(self._joint_encoder.encode((*stamp, *joint_values(self._hopper, state))))
        if self._tf_out:
            assert self._tf is not None
            x, _, z = rep103_position(state.x, state.y)
            _, rotation_y, _, rotation_w = hip_rotation(state.theta)
            self._tf.publish(
                self._tf_encoder.encode((*stamp, x, z, *stamp, rotation_y, rotation_w, *stamp, -state.r))
            )

    def destroy(self) -> None:
        for publisher in (self._description, self._joints, self._tf):
            if publisher is not None:
                self._node.destroy_publisher(publisher)
