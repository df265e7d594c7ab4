"""A progress that kills a Dask worker mid-run: the tests of the study engine and of the viability Q-maps on
a cluster use it to show that a killed worker's chunk runs again elsewhere and changes nothing."""

from __future__ import annotations

import os
import signal

from tdslip_ros.studies import engine


class KillAWorker(engine.Progress):
    """After a chunk arrives, SIGKILL a worker process that is running one (the first time one is)."""

    def __init__(self, client) -> None:
        super().__init__("test", "trajectories", stream=open(os.devnull, "w"))
        self.client, self.killed = client, None

    def advance(self, count: int) -> None:
        super().advance(count)
        if self.killed is None:
            busy = [worker for worker, keys in self.client.processing().items() if keys]
            if busy:  # between two chunks none may be running (an IndexError here once): the next chunk then
                victim = busy[0]
                self.killed = self.client.run(os.getpid, workers=[victim])[victim]
                os.kill(self.killed, signal.SIGKILL)
