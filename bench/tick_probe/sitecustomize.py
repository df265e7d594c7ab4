"""The tick process probed, for bench/bench_tick_trace.py (not part of the package).

Python imports ``sitecustomize`` at start-up from the path; the bench puts this directory on PYTHONPATH and
names a file prefix in TDSLIP_TICK_PROBE. In the tick process only (``python -m
tdslip_ros.nodes.tick_process``), :meth:`PlantRun.advance_to` and the calls that take the node's messages are
wrapped. Each firing that :class:`~tdslip_ros.nodes.realtime.TickTiming` would count as its own work (the
process busy past the deadline for half a period or more, on the CPU for half a period or more) is written as
one JSON line, with where the thread's CPU time went since the firing before: stepping that firing, the
messages taken, the garbage collector, the rest (the sink's flush and the wait for the next deadline), and
the thread's minor page faults and context switches in each. The firings whose misses the timing counted
unexplained in the end are written too.
"""

from __future__ import annotations

import os

if os.environ.get("TDSLIP_TICK_PROBE") and b"tick_process" in open("/proc/self/cmdline", "rb").read():
    import gc
    import json
    import resource
    import time

    from tdslip_ros.nodes import plant_run, realtime
    from tdslip_ros.nodes.torque_stream import TICK_NS

    HALF_PERIOD_NS = TICK_NS // 2  # TickTiming's threshold for a firing's own work
    _out = open(f"{os.environ['TDSLIP_TICK_PROBE']}.{os.getpid()}", "w", buffering=1)
    _since = {"messages_ns": 0, "gc_ns": 0, "gc_started": 0}
    _previous: dict[str, object] = {}

    def _thread_usage() -> tuple[int, int, int]:
        usage = resource.getrusage(resource.RUSAGE_THREAD)
        return usage.ru_minflt, usage.ru_nvcsw, usage.ru_nivcsw

    def _collected(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            _since["gc_started"] = time.thread_time_ns()
        else:
            _since["gc_ns"] += time.thread_time_ns() - _since["gc_started"]

    gc.callbacks.append(_collected)
    _advance_to = plant_run.PlantRun.advance_to

    def _probed_advance_to(
        self: plant_run.PlantRun, now_ns: int, busy_ns: int | None = None, busy_cpu_ns: int | None = None
    ) -> None:
        start, cpu, usage = time.monotonic_ns(), time.thread_time_ns(), _thread_usage()
        deadline, first = self.next_deadline_ns, self.ticks
        _advance_to(self, now_ns, busy_ns, busy_cpu_ns)
        end, cpu_end, usage_end = time.monotonic_ns(), time.thread_time_ns(), _thread_usage()
        firing = {
            "start_ns": start,
            "end_ns": end,
            "late_ns": now_ns - deadline,
            "busy_ns": busy_ns,
            "busy_cpu_ns": busy_cpu_ns,
            "ticks": self.ticks - first,
            "step_cpu_ns": cpu_end - cpu,
            "step_usage": [b - a for a, b in zip(usage, usage_end, strict=True)],
            "between_cpu_ns": cpu - _previous["cpu_end"] if _previous else None,
            "between_usage": [b - a for a, b in zip(_previous["usage_end"], usage, strict=True)]
            if _previous
            else None,
            "messages_cpu_ns": _since["messages_ns"],
            "gc_cpu_ns": _since["gc_ns"],
        }
        if (busy_ns or 0) >= HALF_PERIOD_NS and (busy_cpu_ns or 0) >= HALF_PERIOD_NS:
            _out.write(json.dumps({"previous": _previous.get("firing"), "firing": firing}) + "\n")
        _since["messages_ns"] = _since["gc_ns"] = 0
        _previous.update(firing=firing, cpu_end=time.thread_time_ns(), usage_end=_thread_usage())

    plant_run.PlantRun.advance_to = _probed_advance_to  # type: ignore[method-assign]

    def _timed(name: str) -> None:
        take = getattr(plant_run.PlantRun, name)

        def timed(self: plant_run.PlantRun, *args: object) -> object:
            cpu = time.thread_time_ns()
            try:
                return take(self, *args)
            finally:
                _since["messages_ns"] += time.thread_time_ns() - cpu

        setattr(plant_run.PlantRun, name, timed)

    for _name in ("take_command", "take_torque", "reset", "end", "start"):
        _timed(_name)

    # Which firings the timing counted unexplained in the end (a window with steal counts its misses as the
    # hypervisor's): each is written as {"unexplained": ticks missed, "at_ns": the firing's time}.
    _record, _close_window = realtime.TickTiming.record, realtime.TickTiming.close_window
    _window: list[tuple[int, int]] = []  # the open window's firings whose misses count as the process's own
    _recording: dict[str, int | None] = {"at_ns": None, "ours_before": 0}

    def _note_own_misses(timing: realtime.TickTiming) -> None:
        at_ns = _recording["at_ns"]
        if at_ns is not None and timing._window_ours > (_recording["ours_before"] or 0):
            _window.append((at_ns, timing._window_ours - (_recording["ours_before"] or 0)))
        _recording["at_ns"] = None

    def _probed_record(timing: realtime.TickTiming, now_ns: int, ticks: int, *args: int | None) -> None:
        _recording.update(at_ns=now_ns, ours_before=timing._window_ours)
        _record(timing, now_ns, ticks, *args)
        _note_own_misses(timing)  # unless the window closed within: then it was noted there

    def _probed_close_window(timing: realtime.TickTiming) -> None:
        _note_own_misses(timing)
        unexplained = timing.missed_unexplained
        _close_window(timing)
        if timing.missed_unexplained > unexplained:
            for at_ns, missed in _window:
                _out.write(json.dumps({"unexplained": missed, "at_ns": at_ns}) + "\n")
        _window.clear()

    realtime.TickTiming.record = _probed_record  # type: ignore[method-assign]
    realtime.TickTiming.close_window = _probed_close_window  # type: ignore[method-assign]
