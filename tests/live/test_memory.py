"""Freed payload memory goes back to the OS (backend.live.memory; issue 21: after a flood by
admitted names the service's resident memory stayed ~300 MiB up)."""

from __future__ import annotations

import subprocess
import sys
import threading

import pytest
import zenoh

from backend.live.memory import _TRIM, release_free_memory
from protocol.zenoh_config import make_config
from tests.live.conftest import free_port, wait_for


def _rss_mib() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


@pytest.mark.skipif(_TRIM is None, reason="glibc's malloc_trim only")
def test_a_floods_freed_payloads_are_given_back() -> None:
    # as Zenoh's receiving thread does: ~100 kB payloads (under glibc's mmap threshold),
    # allocated in a thread, freed by another, interleaved with small survivors
    held: list[bytes] = []
    keep: list[bytes] = []

    def receive() -> None:
        for i in range(2000):
            held.append(bytes([i % 251]) * 100_000)
            keep.append(bytes(64))

    t = threading.Thread(target=receive)
    t.start()
    t.join()
    before = _rss_mib()
    held.clear()
    freed = _rss_mib()
    assert release_free_memory()
    after = _rss_mib()
    assert before - after > 100, (before, freed, after)  # ~190 MiB were freed
    assert len(keep) == 2000


# a stranger on the same machine: Zenoh's defaults (shared memory on), messages over 3 kB
_SENDER = """
import sys, time, zenoh
cfg = zenoh.Config()
cfg.insert_json5("mode", '"peer"')
cfg.insert_json5("connect/endpoints", '["' + sys.argv[1] + '"]')
cfg.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(cfg)
pub = s.declare_publisher("rehab/shm01/imu/upperarm")
time.sleep(1.0)
for i in range(int(sys.argv[2])):
    pub.put(bytes([i % 251]) * 100_000)
time.sleep(1.0)
s.close()
"""


def _shared_mappings() -> list[str]:
    with open("/proc/self/maps") as fh:
        return [line.split()[-1] for line in fh if line.rstrip().endswith(".zenoh")]


def test_other_processes_shared_memory_is_never_mapped() -> None:
    """The service's Zenoh takes no shared memory from other processes (issue 21: a flood
    from a new local process left that process's 16 MiB pools resident in the API node and
    each worker, every time): large payloads arrive whole, over the link."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(make_config(listen=endpoint, mode="peer"))
    got: list[bytes] = []
    sub = session.declare_subscriber("rehab/*/imu/*", lambda s: got.append(s.payload.to_bytes()))
    n = 40
    try:
        subprocess.run([sys.executable, "-c", _SENDER, endpoint, str(n)], check=True, timeout=60)
        wait_for(lambda: len(got) == n, timeout=10, what="every payload")
        assert [p[:1] * len(p) == p and len(p) == 100_000 for p in got] == [True] * n
        assert _shared_mappings() == []
    finally:
        sub.undeclare()
        session.close()
