"""Rows (tdslip_ros.nodes.rows), what a run keeps of each stride: the numbers of each message as they were
sent, at a small fraction of the memory of the messages themselves (issue 35's soak grew 3.6 MiB in ten
minutes keeping them). No node, no ROS context."""

from __future__ import annotations

import pickle
import tracemalloc

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from tdslip_msgs.msg import ApexEvent

from tdslip_ros.nodes.rows import Rows

KEPT = 5_000  # apexes: about two realtime runs of ten minutes


def random_apexes(count: int, seed: int = 7) -> list[ApexEvent]:
    rng = np.random.default_rng(seed)
    fields = [name for name in ApexEvent.get_fields_and_field_types() if name != "header"]
    apexes = []
    for stride in range(count):
        apex = ApexEvent(epoch=int(rng.integers(0, 2**32)), stride=stride)
        for name in fields[2:]:
            setattr(apex, name, float(rng.normal(scale=1e3)))
        apexes.append(apex)
    return apexes


def test_each_row_has_the_fields_of_its_message_bit_for_bit() -> None:
    apexes = random_apexes(200)
    rows = Rows.of_message(ApexEvent)
    for apex in apexes:
        rows.append_message(apex)
    assert len(rows) == len(apexes)
    names = [name for name in ApexEvent.get_fields_and_field_types() if name != "header"]
    assert list(rows[0]._fields) == names
    for row, apex in zip(rows, apexes, strict=True):
        assert tuple(row) == tuple(getattr(apex, name) for name in names)
    assert rows[-1] == rows[len(rows) - 1] and rows[3:7] == [rows[i] for i in range(3, 7)]
    with pytest.raises(IndexError):
        rows[len(rows)]
    assert list(pickle.loads(pickle.dumps(rows))) == list(rows)  # a RunReport is pickled whole


def test_rows_of_values_unpack_as_they_were_appended() -> None:
    latencies = Rows("CommandLatency", {"epoch": "I", "stride": "I", "latency_ns": "q"})
    appended = [(1, stride, -(2**40) + stride) for stride in range(10)]
    for values in appended:
        latencies.append(*values)
    assert [tuple(row) for row in latencies] == appended
    assert [row.latency_ns for row in latencies] == [values[2] for values in appended]
    with pytest.raises(OverflowError):  # an epoch beyond uint32, as the message could not carry it either
        latencies.append(2**32, 0, 0)


def test_rows_keep_an_apex_in_a_fifth_of_the_memory_of_its_message() -> None:
    """13 numeric fields at 4-8 bytes: about 100 bytes an apex with the columns' spare room, where a kept
    message, as a subscription delivers it, takes about 600 (a Python object per field; 100 and 601 measured
    with tracemalloc on CPython 3.11)."""
    apexes = random_apexes(KEPT)

    def allocated(keep: object) -> int:
        tracemalloc.start()
        try:
            before = tracemalloc.get_traced_memory()[0]
            kept = keep()
            after = tracemalloc.get_traced_memory()[0]
        finally:
            tracemalloc.stop()
        assert len(kept) == KEPT
        return after - before

    sent = [serialize_message(apex) for apex in apexes]

    def as_messages() -> list[ApexEvent]:  # as a subscription delivers them to the monitor
        return [deserialize_message(data, ApexEvent) for data in sent]

    def as_rows() -> Rows:
        rows = Rows.of_message(ApexEvent)
        for apex in apexes:
            rows.append_message(apex)
        return rows

    per_message, per_row = allocated(as_messages) / KEPT, allocated(as_rows) / KEPT
    assert per_row < 150 and per_message > 5 * per_row, (per_row, per_message)
