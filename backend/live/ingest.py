"""From Zenoh samples to device queues: key routing, global counters, the recorded form.

Routing is cheap and never blocks: a sample whose key is not a contract input is counted
here (globally, it has no device), everything else goes to its device's bounded queue.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import orjson

from protocol import keys, wire

if TYPE_CHECKING:
    from backend.live.worker import DeviceWorker

log = logging.getLogger(__name__)


class RawMessage(NamedTuple):
    """One sample as received. ``payload`` is None when it was too large to keep.
    (A named tuple: a frozen dataclass cost three times as much to create, per message.)"""

    key: str
    payload: bytes | None
    size: int
    arrival: float  # wall time, for presence and latency only
    kind: str


def recorded_form(payload: bytes) -> bytes:
    """The payload as it goes into a recording line: byte for byte when it is one JSON
    value (line breaks, only possible as whitespace there, become spaces); otherwise the
    received text as a JSON string, so a hostile payload can never forge a line.

    The live pipeline is fed by decoding this form, exactly as ``rehab analyze`` decodes
    the recording: rejections and their reasons match offline by construction.
    """
    try:
        orjson.loads(payload)
    except orjson.JSONDecodeError:
        return orjson.dumps(payload.decode("utf-8", "replace"))
    if b"\n" in payload or b"\r" in payload:
        return payload.replace(b"\n", b" ").replace(b"\r", b" ")
    return payload


class Ingest:
    """Routes raw samples to device workers; counts what belongs to no device."""

    def __init__(self, prefix: str, worker_for: Callable[[str], DeviceWorker | None]) -> None:
        self.prefix = prefix
        self._worker_for = worker_for
        self.counters: dict[str, int] = {}

    def count(self, reason: str, n: int = 1) -> None:
        self.counters[reason] = self.counters.get(reason, 0) + n

    def route(self, batch: list[tuple[str, bytes | None, int, float]]) -> None:
        for key, payload, size, arrival in batch:
            try:
                pk = keys.parse(key, self.prefix)
            except keys.KeyError_:
                self.count("unknown_key")
                continue
            if pk.kind not in keys.INPUT_KINDS:
                continue  # estimates and feedback of another service on the same network
            worker = self._worker_for(pk.device)
            if worker is None:
                continue  # counted there: not admitted, or too many devices
            worker.offer(RawMessage(key, payload, size, arrival, pk.kind))


MAX_PAYLOAD_BYTES = wire.MAX_PAYLOAD_BYTES
