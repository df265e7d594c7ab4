"""What /diagnostics and the hopper's robot model (joint_states, /tf) cost the plant, side by side in one run.

    .venv/bin/python bench/bench_diagnostics.py [--rounds 5] [--strides 40] [--realtime-duration 20]

Three settings, interleaved round by round so that the machine's drift falls on each alike:

* ``off``: every node with ``diagnostics:=false``, nobody subscribed to joint_states or /tf;
* ``diagnostics``: the nodes' default, /diagnostics at 1 Hz; nobody on joint_states or /tf (the plant then
  only looks at their subscription counts every 50 ticks);
* ``diagnostics + viewer``: also a viewer process subscribed to joint_states and /tf (they go out at
  ``marker_rate``, 60 Hz of simulated time). /tf needs tf2_msgs, which ``./run.sh`` builds only where
  ``../shared/ros2-tools`` is; without it the plant publishes no /tf, the viewer takes joint_states alone, and
  the bench says so.

Lockstep: plant and controller in this process (one executor), strides per second of wall time from the
plant's start to the end of its run (median and spread over the rounds); realtime: missed ticks in
``--realtime-duration`` s per setting. The load average and the CPU time the hypervisor stole during each run
are printed beside them. Target: diagnostics cost under 2 % of lockstep speed.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from tdslip_ros.nodes import isolation, topics
from tdslip_ros.nodes.controller_node import ControllerNode
from tdslip_ros.nodes.entry import SPIN_SLICE
from tdslip_ros.nodes.plant_node import PlantNode

SETTINGS = ("off", "diagnostics", "diagnostics + viewer")
COST_TARGET = 0.02  # of lockstep speed
RUN_TIMEOUT = 120.0  # s a step of a run may take before the bench gives up
HAS_TF = importlib.util.find_spec("tf2_msgs") is not None
VIEWER = f"""
import rclpy
from sensor_msgs.msg import JointState
from tdslip_ros.nodes import topics
rclpy.init()
node = rclpy.create_node("viewer")
node.create_subscription(JointState, topics.JOINT_STATES, lambda message: None, topics.STREAM_QOS)
if {HAS_TF}:
    from tf2_msgs.msg import TFMessage
    node.create_subscription(TFMessage, topics.TF, lambda message: None, topics.TF_QOS)
rclpy.spin(node)  # until the bench kills it
"""


def load() -> str:
    return "load average " + " ".join(f"{value:.2f}" for value in os.getloadavg())


def steal_seconds() -> float:
    """CPU time the hypervisor gave to others while this VM wanted it (Linux /proc/stat, all CPUs)."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    return int(fields[8]) / os.sysconf("SC_CLK_TCK")


def one_run(
    setting: str, domain_id: int, *, realtime: bool, strides: int, duration: float
) -> tuple[PlantNode, float]:
    """A run of plant and controller in ``setting`` (with its viewer process, if any), lockstep for
    ``strides`` or realtime for ``duration`` s; the plant after it ended and the CPU time stolen [s]
    meanwhile."""
    viewer = None
    if setting.endswith("viewer"):
        environment = isolation.isolated_environment(domain_id)
        viewer = subprocess.Popen([sys.executable, "-c", VIEWER], env=environment)
    context = Context()
    rclpy.init(context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
    executor = EventsExecutor(context=context)
    switch = Parameter("diagnostics", value=setting != "off")
    mode = Parameter("clock_mode", value="realtime" if realtime else "lockstep")
    ends = Parameter("max_strides", value=0 if realtime else strides)
    # Started by the bench once the viewer is matched: a plant that started by itself could finish its
    # 40 lockstep strides before the viewer matched, and the bench would wait for a run already over.
    plant = PlantNode(context=context, start_when_ready=False, parameter_overrides=[switch, mode, ends])
    controller = ControllerNode(context=context, parameter_overrides=[switch])
    try:
        for node in (plant, controller):
            executor.add_node(node)

        def spin_until(condition: Callable[[], bool]) -> None:
            deadline = time.monotonic() + RUN_TIMEOUT
            while not condition():
                if time.monotonic() > deadline:
                    sys.exit(f"{setting}: no progress in {RUN_TIMEOUT:g} s")
                executor.spin_once(timeout_sec=SPIN_SLICE)

        if viewer is not None:  # matched before the run starts, as RViz would be
            spin_until(
                lambda: (
                    plant.count_subscribers(topics.JOINT_STATES)
                    and (not HAS_TF or plant.count_subscribers(topics.TF))
                )
            )
        spin_until(plant.ready_to_start)
        plant.start()
        steal = steal_seconds()
        if realtime:
            spin_until(lambda: time.monotonic_ns() - plant.start_wall_ns > duration * 1e9)
            plant.end_run("the bench's duration")
            spin_until(lambda: plant.tick_timing is not None)
        else:
            spin_until(lambda: plant.outcome is not None)
        return plant, steal_seconds() - steal
    finally:
        executor.shutdown()
        plant.destroy_node()
        controller.destroy_node()
        rclpy.try_shutdown(context=context)
        if viewer is not None:
            viewer.kill()  # a throwaway subscriber: no clean shutdown to wait for
            viewer.wait()


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5, help="lockstep runs per setting, interleaved")
    parser.add_argument("--strides", type=int, default=40, help="strides of each lockstep run")
    parser.add_argument("--realtime-duration", type=float, default=20.0, help="s of each realtime run")
    arguments = parser.parse_args(argv)
    os.environ.update(isolation.process_settings())
    if not HAS_TF:
        print(
            "no tf2_msgs here (./run.sh builds it from ../shared/ros2-tools): "
            "the viewer takes joint_states alone"
        )
    print(f"lockstep: {arguments.rounds} rounds of {arguments.strides} strides per setting ({load()})")
    speeds: dict[str, list[float]] = {setting: [] for setting in SETTINGS}
    stolen = dict.fromkeys(SETTINGS, 0.0)
    with isolation.reserved_domain() as domain_id:
        one_run("off", domain_id, realtime=False, strides=2, duration=0.0)  # kernels loaded, caches warm
        for _ in range(arguments.rounds):
            for setting in SETTINGS:
                plant, steal = one_run(
                    setting, domain_id, realtime=False, strides=arguments.strides, duration=0
                )
                assert plant.outcome is not None and plant.outcome.ok, plant.outcome
                speeds[setting].append(arguments.strides / plant.outcome.wall_time)
                stolen[setting] += steal
        off = float(np.median(speeds["off"]))
        for setting in SETTINGS:
            values = np.asarray(speeds[setting])
            median = float(np.median(values))
            print(
                f"  {setting:<22} {median:7.2f} strides/s (min {values.min():.2f}, max {values.max():.2f}); "
                f"{median / off - 1:+.1%} against off; stolen {stolen[setting]:.2f} s"
            )
        print(f"  target: diagnostics cost < {COST_TARGET:.0%} of lockstep speed ({load()})")
        print(f"realtime: {arguments.realtime_duration:g} s per setting ({load()})")
        for setting in SETTINGS:
            plant, steal = one_run(
                setting, domain_id, realtime=True, strides=0, duration=arguments.realtime_duration
            )
            timing = plant.tick_timing
            assert timing is not None
            print(
                f"  {setting:<22} missed {timing.missed:6d} of {timing.ticks} ticks "
                f"({timing.missed / max(timing.ticks, 1):.3%}; {timing.missed_stolen} while the hypervisor "
                f"stole, {timing.missed_waiting} waiting for a CPU, {timing.missed_unexplained} unexplained);"
                f" "
                f"stolen {steal:.2f} s; {load()}"
            )


if __name__ == "__main__":
    main()
