"""Byte budgets of the live side: what all devices together may hold in memory waiting to be
processed, what one session may write to its recording, and how long one scheduling round
may hold the event loop.

One global ingest budget, not one per device: a device's own queue bound alone let twenty
flooding names hold twenty times as much (memory went from 370 to 965 MiB and stayed). Each
device keeps a small floor outside the global budget, so a flood by others never starves it.
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)

DEVICE_FLOOR_BYTES = 1 << 20  # a device may always queue this much, whatever the others do
ROUND_S = 0.01  # one scheduling round stops after this much loop time; the rest waits a turn
POLL_SAMPLES = 1000  # samples fed without a poll before the worker polls (~20 ms of work)
TURN_BYTES = 64 << 10  # payload bytes one device's turn processes at most (at least one message)
REST_MAX_S = 0.1  # the longest pause after a cut round (a turn that overran by far)


def rest_after(round_s: float) -> float:
    """The loop's free time after a scheduling round that ran ``round_s`` and left work:
    as long as the round (ingest gets at most half of a saturated loop, requests the rest),
    at least ``ROUND_S``, at most ``REST_MAX_S``."""
    return min(max(round_s, ROUND_S), REST_MAX_S)


class IngestBudget:
    """Bytes of payloads queued for all devices' workers."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self.used = 0
        self.refused = 0  # messages dropped because the budget was spent

    def take(self, size: int, device_queued: int) -> bool:
        """Room for ``size`` more bytes of a device holding ``device_queued`` bytes?"""
        if self.used + size <= self.max_bytes or device_queued + size <= DEVICE_FLOOR_BYTES:
            self.used += size
            return True
        self.refused += 1
        return False

    def give(self, size: int) -> None:
        self.used -= size


class RecordingBudget:
    """Bytes one session may record from its device; beyond, its messages are refused
    (neither recorded nor fed, so that the session's outputs stay those of its recording)."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self.used = 0
        self.refused = 0

    def take(self, size: int, session_id: int | None) -> bool:
        if self.used + size <= self.max_bytes:
            self.used += size
            return True
        if not self.refused:
            log.error(
                "session %s: recording budget of %d bytes reached (REHAB_RECORDING_MAX_BYTES);"
                " further device messages are refused and counted as recording_full",
                session_id,
                self.max_bytes,
            )
        self.refused += 1
        return False
