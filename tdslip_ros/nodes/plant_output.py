"""What the plant node publishes: its publishers, the messages it makes of the model's states and events, and
the count of what went out per topic (the recorder's flow control and the run's checks compare with it).

Every message goes out as bytes with no undefined byte (:mod:`tdslip_ros.nodes.wire`): the 1 kHz ones
(state, ground reaction force, /clock, applied torques) from fixed-layout encoders, since building message
objects cost the tick more than the bytes do; the event-rate ones serialised with their padding zeroed.

The 1 kHz state and force go to recorders in batches (tdslip/samples, :data:`SAMPLES_PER_BATCH` ticks, and
before every event) and live, a message per tick, only while someone subscribes to them: one reliable write a
tick to a recorder in another process costs the tick more than a batch every few ticks does (``bench_nodes.py
lockstep``; docs/benchmarks.md). Their counts in :attr:`PlantOutput.published` are of the samples that went
out in batches. /clock and the markers cost a publish even when nobody listens, so they too go out only while
someone subscribes (:meth:`PlantOutput.check_graph`). Each count is taken right after its publish, so that a
failing publish (rclpy's RCLError) leaves them exact.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from rclpy.node import Node
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock as ClockMsg
from tdslip_msgs.msg import ApexEvent, ContactEvent, HipTorque, Status

from tdslip_ros.interfaces import PITCH_FIELDS, STAMP_FIELDS
from tdslip_ros.model.events import Event, EventKind
from tdslip_ros.model.events import HopperState as ModelState
from tdslip_ros.nodes import topics
from tdslip_ros.nodes.markers import HopperMarkers
from tdslip_ros.nodes.plant_run import SAMPLES_PER_BATCH, ApexReport
from tdslip_ros.nodes.torque_stream import tick_stamp
from tdslip_ros.nodes.wire import (
    SAMPLE_FIELDS,
    fixed_layout_encoder,
    grf_encoder,
    sample_batch,
    serialized,
    set_stamp,
    stamp_of,
    state_encoder,
    state_values,
)

GRAPH_CHECK_TICKS = 50
"""Ticks between two looks at who subscribes to the live state and force, /clock and the markers (a graph
query is too dear to make every tick; docs/benchmarks.md); the plant also looks after every apex and touchdown
it publishes."""

APEX_FIELDS = (
    *STAMP_FIELDS,
    "epoch",
    "stride",
    "sim_time",
    "x",
    "height",
    "forward_speed",
    "energy",
    "ground_height",
    "measured_height",
    "measured_forward_speed",
    "hip_work",
    "damping_loss",
    "spring_loss",
    *PITCH_FIELDS,
)
"""The fields of an ApexEvent that the plant sets, in the message's order."""
CONTACT_FIELDS = (*STAMP_FIELDS, "kind", "epoch", "stride", "sim_time", "ground_height")
CONTACT_FIELDS += tuple(f"state.{field}" for field in SAMPLE_FIELDS)
"""The fields of a ContactEvent that the plant sets, in the message's order (its state's as a sample's)."""


_CONTACT_KINDS = {
    EventKind.TOUCHDOWN: ContactEvent.TOUCHDOWN,
    EventKind.BOTTOM: ContactEvent.BOTTOM,
    EventKind.LIFTOFF: ContactEvent.LIFTOFF,
}


class PlantOutput:
    """The plant's publishers on ``node`` (topics.PLANT_TOPICS, and /clock with ``publish_clock``) and what
    goes out on them; markers every ``marker_period_ticks`` ticks (0: never)."""

    def __init__(
        self, node: Node, *, publish_clock: bool, marker_period_ticks: int, rigid: bool = False
    ) -> None:
        # tdslip/samples first: a recorder that sees the plant's state publisher knows its batches too.
        published_topics = [topics.SAMPLES, *topics.PLANT_TOPICS, *((topics.CLOCK,) if publish_clock else ())]
        self._publishers: dict[str, Publisher[Any]] = {
            topic: node.create_publisher(topics.MESSAGE_TYPES[topic], topic, topics.STREAM_QOS)
            for topic in published_topics
        }
        self.topic_names = {topic: pub.topic_name for topic, pub in self._publishers.items()}
        """Fully qualified name of each published topic, by its relative name."""
        self.published: Counter[str] = Counter()
        """Messages published per topic, by relative name (topics.STATE, ...)."""
        self._samples_pub = self._publishers[topics.SAMPLES]
        self._batch = sample_batch()  # the samples not yet published on tdslip/samples
        self._state_pub = self._publishers[topics.STATE]
        self._grf_pub = self._publishers[topics.GRF]
        self._state_out: Publisher[Any] | None = None  # _state_pub while it has subscribers
        self._grf_out: Publisher[Any] | None = None  # _grf_pub while it has subscribers
        self._applied_torque_pub = self._publishers[topics.APPLIED_TORQUE]
        self._clock_pub = self._publishers.get(topics.CLOCK)
        self._clock_out: Publisher[Any] | None = None  # _clock_pub while it has subscribers
        self._markers_pub = self._publishers[topics.MARKERS]
        self._marker_period_ticks = marker_period_ticks
        self._markers_out = False  # markers are drawn while someone subscribes to them
        self._markers = HopperMarkers(topics.FRAME_ID, rigid)  # rigid: a rigid body's trunk is drawn
        self._state_encoder = state_encoder()
        self._grf_encoder = grf_encoder()
        self._clock_encoder = fixed_layout_encoder(ClockMsg, ("clock.sec", "clock.nanosec"))
        self._applied_torque_encoder = fixed_layout_encoder(
            HipTorque, (*STAMP_FIELDS, "epoch", "stride", "tick", "torque")
        )
        # The event messages too: building and serialising message objects costs the tick more than encoding
        # their bytes (docs/benchmarks.md).
        self._apex_pub = self._publishers[topics.APEX]
        self._apex_encoder = fixed_layout_encoder(ApexEvent, APEX_FIELDS)
        self._contact_pub = self._publishers[topics.CONTACT]
        contact = ContactEvent()
        contact.header.frame_id = contact.state.header.frame_id = topics.FRAME_ID
        self._contact_encoder = fixed_layout_encoder(ContactEvent, CONTACT_FIELDS, contact)

    def subscribers(self, topic: str) -> int:
        """Subscriptions matched with the publisher of ``topic`` (relative name)."""
        return self._publishers[topic].get_subscription_count()

    def listeners(self, topic: str) -> int:
        """:meth:`subscribers`, and for the state and the force also the recorders of their batches."""
        batched = self.subscribers(topics.SAMPLES) if topic in topics.BATCHED_TOPICS else 0
        return self.subscribers(topic) + batched

    @property
    def live(self) -> bool:
        """A tick's state, force or /clock goes out live: someone wants each tick at once."""
        return not (self._state_out is self._grf_out is self._clock_out is None)

    def check_graph(self) -> None:
        """Publish the live state and force, /clock and the markers from now on while someone subscribes to
        them (a graph query is too dear for every tick: the plant calls this every GRAPH_CHECK_TICKS ticks
        and at every apex)."""
        listened = self._clock_pub is not None and self._clock_pub.get_subscription_count() > 0
        self._clock_out = self._clock_pub if listened else None
        self._state_out = self._state_pub if self._state_pub.get_subscription_count() > 0 else None
        self._grf_out = self._grf_pub if self._grf_pub.get_subscription_count() > 0 else None
        self._markers_out = bool(self._marker_period_ticks) and self._markers_pub.get_subscription_count() > 0

    def _publish(self, topic: str, msg: object) -> None:
        self._publishers[topic].publish(serialized(msg))
        self.published[topic] += 1

    def sample(self, state: ModelState, t: float) -> None:
        """The 1 kHz state and ground reaction force (and /clock) of ``state`` stamped t [s]."""
        values = state_values(state, t)
        sec, nanosec = values[:2]
        self._batch.append((*values, state.grf_x, state.grf_y))
        if self._state_out is not None:
            self._state_out.publish(self._state_encoder.encode(values))
        if self._grf_out is not None:
            self._grf_out.publish(self._grf_encoder.encode((sec, nanosec, state.grf_x, state.grf_y)))
        if self._clock_out is not None:
            self._clock_out.publish(self._clock_encoder.encode((sec, nanosec)))
            self.published[topics.CLOCK] += 1
        if len(self._batch) >= SAMPLES_PER_BATCH:
            self.flush()

    def flush(self) -> None:
        """Publish the samples not yet batched on tdslip/samples (every event does, first; so does the end of
        a run)."""
        samples = len(self._batch)
        if samples:
            self._samples_pub.publish(self._batch.take())
            self.published[topics.STATE] += samples
            self.published[topics.GRF] += samples

    def markers(self, state: ModelState, t: float, tick: int) -> None:
        """The hopper drawn at ``state`` stamped t [s], if plant ``tick`` is one of the markers' and someone
        subscribes to them."""
        if self._markers_out and tick % self._marker_period_ticks == 0:
            self._markers_pub.publish(self._markers.encoded(state, t, state.ground_height))
            self.published[topics.MARKERS] += 1

    def applied_torque(self, epoch: int, stride: int, tick: int, torque: float) -> None:
        """A hip torque as held from plant ``tick`` on (stamped with the tick's time)."""
        values = (*tick_stamp(tick), epoch, stride, tick, torque)
        self._applied_torque_pub.publish(self._applied_torque_encoder.encode(values))
        self.published[topics.APPLIED_TORQUE] += 1

    def apex(self, report: ApexReport) -> None:
        """An apex event, after the samples before it."""
        self.flush()
        flows, state = report.flows, report.state
        energy = (0.0, 0.0, 0.0) if flows is None else (flows.hip_work, flows.damping_loss, flows.spring_loss)
        values = (
            *stamp_of(report.t),
            report.epoch,
            report.stride,
            report.t,
            state.x,
            state.y,
            state.xdot,
            state.energy,
            report.ground,
            *report.measured,
        )
        self._apex_pub.publish(self._apex_encoder.encode((*values, *energy, state.pitch, state.pitch_rate)))
        self.published[topics.APEX] += 1
        self.check_graph()  # after the apex is out (the controller waits for it), before the next sample

    def contact(self, epoch: int, event: Event, t: float) -> None:
        """A touchdown, bottom or liftoff at t [s], with its state."""
        self.flush()
        kind, state = _CONTACT_KINDS[event.kind], event.state
        values = (*stamp_of(t), kind, epoch, event.stride, t, state.toe_y, *state_values(state, t))
        self._contact_pub.publish(self._contact_encoder.encode(values))
        self.published[topics.CONTACT] += 1
        if event.kind is EventKind.TOUCHDOWN:  # a stance controller needs every sample of the stance
            self.check_graph()

    def status(self, epoch: int, stride: int, kind: str, reason: str, t: float, *, fatal: bool) -> None:
        self.flush()
        msg = Status(epoch=epoch, stride=stride, sim_time=t, kind=kind, reason=reason, fatal=fatal)
        msg.header.frame_id = topics.FRAME_ID
        set_stamp(msg.header.stamp, t)
        self._publish(topics.STATUS, msg)
