"""The hopper drawn as a ``visualization_msgs/MarkerArray`` for Foxglove's 3D panel and RViz.

The plant publishes it on ``tdslip/markers`` at ``marker_rate`` Hz of simulated time. The drawing is
in the x-z plane of the ``world`` frame (the model's y, the height, is drawn as z, the up axis of
both viewers): the body (a sphere), the leg from hip to toe (a line; in flight the leg shown at
rest length and the commanded touchdown angle, as the model states it), the toe (a small sphere),
the ground under the hopper (a line over a window around the body) and the ground reaction force
(an arrow from the toe, 1 m per ``GRF_SCALE`` N).

The messages are built once and only their coordinates change per publication, so a marker costs
the plant's tick a few tens of microseconds.
"""

from __future__ import annotations

from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from tdslip_ros.model.events import HopperState

NAMESPACE = "tdslip"
BODY, LEG, TOE, GROUND, GRF = range(5)
"""Marker ids."""
BODY_DIAMETER = 0.2  # m
TOE_DIAMETER = 0.05  # m
LEG_WIDTH = 0.03  # m
GROUND_WIDTH = 0.02  # m
GROUND_HALF_WINDOW = 3.0  # m of ground drawn behind and ahead of the body
GRF_SCALE = 2000.0  # N per metre of arrow: a body weight of 785 N is a 0.4 m arrow
GRF_SHAFT_DIAMETER = 0.03  # m


def _color(red: float, green: float, blue: float) -> ColorRGBA:
    return ColorRGBA(r=red, g=green, b=blue, a=1.0)


def _marker(marker_id: int, kind: int, color: ColorRGBA, frame_id: str) -> Marker:
    marker = Marker(id=marker_id, type=kind, action=Marker.ADD, ns=NAMESPACE, color=color)
    marker.header.frame_id = frame_id
    marker.pose.orientation.w = 1.0
    marker.lifetime = Duration()  # forever: each publication replaces the markers of the same id
    return marker


class HopperMarkers:
    """A reusable MarkerArray for hopper states; :meth:`update` fills it for one state."""

    def __init__(self, frame_id: str) -> None:
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
        self.message = MarkerArray(markers=[body, leg, toe, ground, grf])
        self._markers = (body, leg, toe, ground, grf)

    def update(self, state: HopperState, stamp: Time, ground_height: float = 0.0) -> MarkerArray:
        """The markers for ``state`` (SI, world frame) over ground at ``ground_height`` [m], stamped
        ``stamp``; returns the shared message."""
        body, leg, toe, ground, grf = self._markers
        for marker in self._markers:
            marker.header.stamp = stamp
        body.pose.position.x, body.pose.position.z = state.x, state.y
        toe.pose.position.x, toe.pose.position.z = state.toe_x, state.toe_y
        hip, foot = leg.points
        hip.x, hip.z, foot.x, foot.z = state.x, state.y, state.toe_x, state.toe_y
        left, right = ground.points
        left.x, left.z = state.x - GROUND_HALF_WINDOW, ground_height
        right.x, right.z = state.x + GROUND_HALF_WINDOW, ground_height
        tail, head = grf.points
        tail.x, tail.z = state.toe_x, state.toe_y
        head.x, head.z = state.toe_x + state.grf_x / GRF_SCALE, state.toe_y + state.grf_y / GRF_SCALE
        # In flight there is no force: the arrow is hidden (DELETE) rather than drawn with zero length.
        grf.action = Marker.ADD if state.grf_x or state.grf_y else Marker.DELETE
        return self.message
