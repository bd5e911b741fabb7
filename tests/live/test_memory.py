"""Freed payload memory goes back to the OS (backend.live.memory; issue 21: after a flood by
admitted names the service's resident memory stayed ~300 MiB up)."""

from __future__ import annotations

import threading

import pytest

from backend.live.memory import _TRIM, release_free_memory


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
