"""Recorded runs over a lossy transport: the controller's ``min_subscribers`` at 2 (what ``tdslip run`` sets)
beside 0 (what it set before), alternating, in one run.

    .venv/bin/python bench/bench_lossy_discovery.py [--runs 20] [--strides 12]

Each run is ``tdslip run``'s (:func:`tdslip_ros.nodes.runner.run`, lockstep, the suite's controller and
recorder) under a Fast DDS profile that keeps discovery and data on UDP with 9 kB socket buffers and no
shared memory, so that the kernel drops datagrams under bursts: discovery announcements too, which makes
discovery lag in one direction for seconds. A recorder can then match the controller's command publisher
(and the plant starts) while that publisher has not matched the recorder: its answers reach the plant, not
the bag. Printed per arm: the runs whose recording was incomplete, with (published, recorded) by topic; the
load average and the CPU time the hypervisor stole beside them. Numbers: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from bench_nodes import load, steal_seconds

from tdslip_ros.nodes import isolation, run_options
from tdslip_ros.nodes.runner import run

LOSSY_PROFILE = f"""<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com">
  <profiles>
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>small_udp</transport_id>
        <type>UDPv4</type>
        <maxMessageSize>8192</maxMessageSize>
        <sendBufferSize>9216</sendBufferSize>
        <receiveBufferSize>9216</receiveBufferSize>
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="lossy" is_default_profile="true">
      <rtps>
        <userTransports><transport_id>small_udp</transport_id></userTransports>
        <useBuiltinTransports>false</useBuiltinTransports>
      </rtps>
    </participant>
    <data_writer profile_name="tdslip_ros_writer" is_default_profile="true">
      <times>
        <heartbeat_period><sec>0</sec><nanosec>{isolation.HEARTBEAT_PERIOD_NS}</nanosec></heartbeat_period>
      </times>
    </data_writer>
  </profiles>
</dds>
"""
ARMS = (2, 0)  # the controller's min_subscribers: tdslip run's, and none


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=20, help="runs per arm")
    parser.add_argument("--strides", type=int, default=12)
    arguments = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_lossy_") as scratch:
        profile = Path(scratch) / "lossy.xml"
        profile.write_text(LOSSY_PROFILE)
        os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = str(profile)  # read as each participant is made
        incomplete: dict[int, list[str]] = {arm: [] for arm in ARMS}
        print(f"start: {load()}", flush=True)
        steal = steal_seconds()
        for index in range(arguments.runs):
            for arm in ARMS:
                run_options.PLANT_AND_RECORDER = arm  # what controller_overrides gives the controller
                out = Path(scratch) / f"run_{index}_{arm}"
                report = run(run_options.RunOptions(out=out, strides=arguments.strides))
                if not report.recording_complete:
                    missed = {
                        topic: (published, report.recorded.get(topic, 0))
                        for topic, published in report.published.items()
                        if report.recorded.get(topic, 0) != published
                    }
                    incomplete[arm].append(f"run {index}: {missed}")
                print(f"run {index}, min_subscribers {arm}: complete {report.recording_complete}", flush=True)
        print(f"end: {load()}, steal {steal_seconds() - steal:.1f} s during the runs")
        for arm in ARMS:
            print(f"min_subscribers {arm}: {len(incomplete[arm])} of {arguments.runs} recordings incomplete")
            for line in incomplete[arm]:
                print(f"  {line}")


if __name__ == "__main__":
    main()
