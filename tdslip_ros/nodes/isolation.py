"""The suite's DDS environment: a private domain per run or test, localhost discovery, prompt acks,
synchronous publication.

* A domain id is reserved by holding an exclusive ``flock`` on ``<tmp>/tdslip_ros_domains/<id>.lock``
  for as long as it is in use, so concurrent runs and test processes (also of other users of this
  scheme on the machine) never share one, and a crashed holder frees its id at once. The pool,
  :data:`DOMAIN_POOL`, avoids the default domain 0 and stays below Fast DDS's highest usable id (232).
* ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` keeps discovery off the network.
* A Fast DDS profile (:data:`FASTDDS_PROFILE`) shortens the reliable writers' heartbeat period from
  Fast DDS's 3 s to 50 ms. Subscribers acknowledge on heartbeats, so this is how soon a publisher
  learns that everything arrived: ``wait_for_all_acked`` at the end of a run returns in tens of ms
  instead of up to 3 s, and a KEEP_ALL history holds ~50 ms of messages instead of seconds.
  It is used unless ``FASTDDS_DEFAULT_PROFILES_FILE`` is set already.
* ``RMW_FASTRTPS_PUBLICATION_MODE=SYNCHRONOUS`` (unless set already): ``publish`` hands the message
  to the transport itself instead of to a sender thread of normal priority. The realtime tick then
  never waits for that thread, and misses fewer ticks for it (``bench_nodes.py realtime``;
  docs/benchmarks.md).

These must be in the environment before a process creates its first participant (rclpy.init
and the first node): :func:`isolated_environment` for child processes, :func:`process_settings`
into ``os.environ`` for the current one. The node executables take only the Fast DDS profile
(:func:`dds_settings`): discovery stays the user's choice when they run on their own.
"""

from __future__ import annotations

import fcntl
import os
import random
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

VALID_DOMAIN_IDS = range(0, 233)
"""The ids Fast DDS can use: its port arithmetic runs out of ports above 232."""
DOMAIN_POOL = range(120, 230)
DOMAIN_COOL_DOWN = 60.0  # s after its release before a pool id is handed out again
DISCOVERY_RANGE = "LOCALHOST"
HEARTBEAT_PERIOD_NS = 50_000_000
FASTDDS_PROFILE = f"""<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com">
  <profiles>
    <data_writer profile_name="tdslip_ros_writer" is_default_profile="true">
      <times>
        <heartbeat_period>
          <sec>0</sec>
          <nanosec>{HEARTBEAT_PERIOD_NS}</nanosec>
        </heartbeat_period>
      </times>
    </data_writer>
  </profiles>
</dds>
"""
_STATE_DIRECTORY = Path(tempfile.gettempdir()) / "tdslip_ros_domains"


@contextmanager
def reserved_domain(domain_id: int | None = None) -> Iterator[int]:
    """Hold a free domain id from DOMAIN_POOL (or exactly ``domain_id``) for the with-block.

    An id from the pool is also one not released in the last DOMAIN_COOL_DOWN seconds: processes of
    the previous holder (a node child still shutting down, an orphan) must not meet the next run.
    """
    _STATE_DIRECTORY.mkdir(exist_ok=True)
    if domain_id is not None:
        candidates: list[int] = [domain_id]
    else:
        # A random start spreads concurrent reservations over the pool instead of racing for one id.
        start = random.randrange(len(DOMAIN_POOL))
        rotated = [*DOMAIN_POOL[start:], *DOMAIN_POOL[:start]]
        cool = [candidate for candidate in rotated if not _recently_released(candidate)]
        candidates = cool or rotated
    for candidate in candidates:
        lock = _STATE_DIRECTORY / f"{candidate}.lock"
        descriptor = os.open(lock, os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(descriptor)
            continue
        try:
            yield candidate
        finally:
            os.utime(descriptor)  # the release time, for the cool-down
            os.close(descriptor)  # releases the lock
        return
    raise RuntimeError(
        f"ROS domain {domain_id} is in use by another run (choose another --domain-id, or none)"
        if domain_id is not None
        else "every domain id of the pool is in use"
    )


def _recently_released(domain_id: int) -> bool:
    try:
        released = (_STATE_DIRECTORY / f"{domain_id}.lock").stat().st_mtime
    except FileNotFoundError:
        return False
    return time.time() - released < DOMAIN_COOL_DOWN


def fastdds_profile_file() -> Path:
    """FASTDDS_PROFILE as a file in the temp directory (rewritten atomically when it differs)."""
    _STATE_DIRECTORY.mkdir(exist_ok=True)
    path = _STATE_DIRECTORY / "fastdds_profile.xml"
    if not path.is_file() or path.read_text() != FASTDDS_PROFILE:
        staging = path.with_suffix(f".{os.getpid()}.tmp")
        staging.write_text(FASTDDS_PROFILE)
        os.replace(staging, path)
    return path


def dds_settings() -> dict[str, str]:
    """The Fast DDS profile file and publication mode: the caller's where set, else the suite's."""
    return {
        "FASTDDS_DEFAULT_PROFILES_FILE": os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE")
        or str(fastdds_profile_file()),
        "RMW_FASTRTPS_PUBLICATION_MODE": os.environ.get("RMW_FASTRTPS_PUBLICATION_MODE") or "SYNCHRONOUS",
    }


def process_settings() -> dict[str, str]:
    """The environment the suite's processes run in, domain id aside (see the module docstring)."""
    return {"ROS_AUTOMATIC_DISCOVERY_RANGE": DISCOVERY_RANGE, **dds_settings()}


def isolated_environment(domain_id: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """An environment for child processes on ``domain_id`` (see :func:`configure_process`)."""
    environment = dict(os.environ if base is None else base)
    environment.update(process_settings())
    environment["ROS_DOMAIN_ID"] = str(domain_id)
    environment.pop("ROS_STATIC_PEERS", None)
    return environment
