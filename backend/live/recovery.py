"""Recovery of the takeover gap from a device's publication cache.

Between a holder's death and the next holder's lease, a device's messages reach no one who
records them. A device that publishes through zenoh-ext's ``AdvancedPublisher`` with a cache
(``python -m simulator.publish --cache N``; docs/scaling.md) still holds its last messages:
the new holder declares an ``AdvancedSubscriber`` with history on the device's keys when it
takes the session over, and :func:`gap` picks out of that history, per key, the messages
after the last one the recording holds and before the first one that reached the holder's
own queue. They go in front of the queue, in the device's publication order (the samples'
HLC timestamps), and are recorded and processed like any other: the recording has no gap.
Without a cache the history is empty and the gap is counted in data quality as before.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterable
from typing import Any

import orjson
import zenoh
import zenoh.ext as zenoh_ext

from backend.live.ingest import RawMessage, recorded_form
from protocol import keys

MIN_WAIT_S = 0.3  # the history query's replies (~10 ms on loopback) arrive before this


def release_time(payload: bytes) -> float | None:
    """The newest sample time of a contract payload (what orders a device's messages)."""
    try:
        obj = orjson.loads(payload)
    except orjson.JSONDecodeError:
        return None
    t = obj.get("t") if isinstance(obj, dict) else None
    if isinstance(t, list) and t and all(isinstance(x, (int, float)) for x in t):
        return float(max(t))
    if isinstance(t, (int, float)) and not isinstance(t, bool):
        return float(t)
    return None


class CacheHistory:
    """The history of one device's publication cache, collected from declaration until
    :meth:`close` (Zenoh's thread only appends)."""

    def __init__(self, session: zenoh.Session, prefix: str, device: str, max_age_s: float):
        self.prefix = prefix
        self.samples: list[tuple[int, int, str, bytes]] = []  # (HLC time, index, key, payload)
        self._lock = threading.Lock()
        self.opened = time.monotonic()
        self._sub: Any = zenoh_ext.declare_advanced_subscriber(
            session,
            f"{prefix}/{device}/**",
            self._on,
            history=zenoh_ext.HistoryConfig(max_age=max_age_s),
        )

    def _on(self, sample: zenoh.Sample) -> None:
        ts = sample.timestamp
        with self._lock:
            self.samples.append(
                (
                    ts.get_time_as_ntp64().as_nanos() if ts is not None else 0,
                    len(self.samples),
                    str(sample.key_expr),
                    sample.payload.to_bytes(),
                )
            )

    def close(self) -> list[tuple[int, int, str, bytes]]:
        self._sub.undeclare()
        with self._lock:
            return sorted(self.samples)


def gap(
    history: Iterable[tuple[int, int, str, bytes]],
    recorded: Iterable[tuple[str, bytes]],
    queued: Iterable[RawMessage],
    prefix: str,
) -> list[RawMessage]:
    """The device's input messages in ``history`` that the recording (its last lines,
    ``recorded``) and the holder's queue both miss: per key, released after the last
    recorded and before the first queued message, in the history's order."""
    after: dict[str, float] = {}
    for key, payload in recorded:
        t = release_time(payload)
        if t is not None:
            after[key] = t
    before: dict[str, float] = {}
    for m in queued:
        if m.payload is not None and m.key not in before:
            t = release_time(m.payload)
            if t is not None:
                before[m.key] = t
    out: list[RawMessage] = []
    seen: set[tuple[str, float]] = set()
    for _, _, key, payload in history:
        try:
            kind = keys.parse(key, prefix).kind
        except keys.KeyError_:
            continue
        if kind not in keys.INPUT_KINDS:
            continue
        form = recorded_form(payload)
        t = release_time(form)
        if t is None or (key, t) in seen:
            continue
        if after.get(key, -math.inf) < t < before.get(key, math.inf):
            seen.add((key, t))
            out.append(RawMessage(key, payload, len(payload), time.time(), kind))
    return out
