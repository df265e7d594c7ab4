"""The hopper drawn as a ``visualization_msgs/MarkerArray`` for Foxglove's 3D panel and RViz.

The plant publishes it on ``tdslip/markers`` at ``marker_rate`` Hz of simulated time. The drawing is
in the x-z plane of the ``world`` frame (the model's y, the height, is drawn as z, the up axis of
both viewers): the body (a sphere at the centre of mass), the leg from hip to toe (a line; in flight the leg
shown at rest length and the commanded touchdown angle, as the model states it), the toe (a small sphere),
the ground under the hopper (a line over a window around the body), the ground reaction force (an arrow from
the toe, 1 m per ``GRF_SCALE`` N) and, for a rigid body (docs/rotating_body.md), its trunk: a line through the
centre of mass along the body's axis (up at pitch 0), ``TRUNK_HALF_LENGTH`` each way, and the leg from the hip
(the toe plus the leg), which no longer sits at the centre of mass. The fixed body's trunk is deleted.

The message is built once; each publication packs only its stamps and coordinates into the bytes of
that message (:func:`~tdslip_ros.nodes.wire.fixed_layout_encoder`), so a drawing costs the plant's tick
about 10 us instead of the 60-170 us of serialising the message object.
"""

from __future__ import annotations

import math

from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from tdslip_ros.model.events import HopperState
from tdslip_ros.nodes.wire import fixed_layout_encoder, stamp_of

NAMESPACE = "tdslip"
BODY, LEG, TOE, GROUND, GRF, TRUNK = range(6)
"""Marker ids."""
BODY_DIAMETER = 0.2  # m
TOE_DIAMETER = 0.05  # m
LEG_WIDTH = 0.03  # m
GROUND_WIDTH = 0.02  # m
GROUND_HALF_WINDOW = 3.0  # m of ground drawn behind and ahead of the body
GRF_SCALE = 2000.0  # N per metre of arrow: a body weight of 785 N is a 0.4 m arrow
GRF_SHAFT_DIAMETER = 0.03  # m
TRUNK_HALF_LENGTH = 0.35  # m of trunk drawn each way from the centre of mass
TRUNK_WIDTH = 0.06  # m

_STAMP = ("header.stamp.sec", "header.stamp.nanosec")
_POSITION = ("pose.position.x", "pose.position.z")
_POINTS = ("points[0].x", "points[0].z", "points[1].x", "points[1].z")


def _fields(marker: int, *names: str) -> tuple[str, ...]:
    return tuple(f"markers[{marker}].{name}" for name in names)


DRAWN_FIELDS = (
    *_fields(BODY, *_STAMP, *_POSITION),
    *_fields(LEG, *_STAMP, *_POINTS),
    *_fields(TOE, *_STAMP, *_POSITION),
    *_fields(GROUND, *_STAMP, *_POINTS),
    *_fields(GRF, *_STAMP, "action", *_POINTS),
    *_fields(TRUNK, *_STAMP, "action", *_POINTS),
)
"""What changes from one drawing to the next, in the message's order (:meth:`HopperMarkers.drawn`)."""


def _color(red: float, green: float, blue: float) -> ColorRGBA:
    return ColorRGBA(r=red, g=green, b=blue, a=1.0)


def _marker(marker_id: int, kind: int, color: ColorRGBA, frame_id: str) -> Marker:
    marker = Marker(id=marker_id, type=kind, action=Marker.ADD, ns=NAMESPACE, color=color)
    marker.header.frame_id = frame_id
    marker.pose.orientation.w = 1.0
    marker.lifetime = Duration()  # forever: each publication replaces the markers of the same id
    return marker


class HopperMarkers:
    """The hopper's MarkerArray for hopper states; :meth:`encoded` serialises it for one state."""

    def __init__(self, frame_id: str, rigid: bool = False) -> None:
        self._rigid = rigid
        body = _marker(BODY, Marker.SPHERE, _color(0.2, 0.4, 0.9), frame_id)
        body.scale.x = body.scale.y = body.scale.z = BODY_DIAMETER
        leg = _marker(LEG, Marker.LINE_STRIP, _color(0.3, 0.3, 0.3), frame_id)
        leg.scale.x = LEG_WIDTH
        leg.points = [Point(), Point()]
        toe = _marker(TOE, Marker.SPHERE, _color(0.9, 0.5, 0.1), frame_id)
        toe.scale.x = toe.scale.y = toe.scale.z = TOE_DIAMETER
        ground = _marker(GROUND, Marker.LINE_STRIP, _color(0.4, 0.3, 0.2), frame_id)
        ground.scale.x = GROUND_WIDTH
        ground.points = [Point(), Point()]
        grf = _marker(GRF, Marker.ARROW, _color(0.1, 0.7, 0.2), frame_id)
        grf.scale.x, grf.scale.y, grf.scale.z = GRF_SHAFT_DIAMETER, 2 * GRF_SHAFT_DIAMETER, 0.05
        grf.points = [Point(), Point()]
        trunk = _marker(TRUNK, Marker.LINE_STRIP, _color(0.2, 0.4, 0.9), frame_id)
        trunk.scale.x = TRUNK_WIDTH
        trunk.points = [Point(), Point()]
        template = MarkerArray(markers=[body, leg, toe, ground, grf, trunk])
        self._encoder = fixed_layout_encoder(MarkerArray, DRAWN_FIELDS, template)

    def drawn(self, state: HopperState, t: float, ground_height: float = 0.0) -> tuple[int | float, ...]:
        """The values of :data:`DRAWN_FIELDS` for ``state`` (SI, world frame) over ground at
        ``ground_height`` [m], stamped t [s]."""
        sec, nanosec = stamp_of(t)
        hip_x, hip_z = state.x, state.y  # the fixed body's hip is its centre of mass
        trunk = Marker.DELETE, state.x, state.y, state.x, state.y
        if self._rigid:
            hip_x = state.toe_x - state.r * math.sin(state.theta)
            hip_z = state.toe_y + state.r * math.cos(state.theta)
            axis_x = -TRUNK_HALF_LENGTH * math.sin(state.pitch)
            axis_z = TRUNK_HALF_LENGTH * math.cos(state.pitch)
            trunk = Marker.ADD, state.x - axis_x, state.y - axis_z, state.x + axis_x, state.y + axis_z
        head_x = state.toe_x + state.grf_x / GRF_SCALE
        head_z = state.toe_y + state.grf_y / GRF_SCALE
        # In flight there is no force: the arrow is hidden (DELETE) rather than drawn with zero length.
        action = Marker.ADD if state.grf_x or state.grf_y else Marker.DELETE
        left, right = state.x - GROUND_HALF_WINDOW, state.x + GROUND_HALF_WINDOW
        return (
            *(sec, nanosec, state.x, state.y),
            *(sec, nanosec, hip_x, hip_z, state.toe_x, state.toe_y),
            *(sec, nanosec, state.toe_x, state.toe_y),
            *(sec, nanosec, left, ground_height, right, ground_height),
            *(sec, nanosec, action, state.toe_x, state.toe_y, head_x, head_z),
            *(sec, nanosec, *trunk),
        )

    def encoded(self, state: HopperState, t: float, ground_height: float = 0.0) -> bytes:
        """The markers of :meth:`drawn`, serialised (CDR, every padding byte zero)."""
        return self._encoder.encode(self.drawn(state, t, ground_height))
