"""Device events that change a running session, in the audit log with their source.

``shoulder_reference`` and ``nominal_reset`` move the nominal shoulder the compensation is
judged against; ``cycle_start`` cuts the cycles. Each accepted one during a session becomes an
audit row ``device.<type>`` on ``session:<id>``, actor ``device:<name>``, with the Zenoh key,
the event's stamp and point, and the identity the transport proved: with the clinic's mutual
TLS and access control (``REHAB_ZENOH_CONFIG``) only the holder of the certificate whose
common name is the device name can publish under that key; without it the source is only
the key (``unauthenticated``).

A device flooding events must not flood the audit table: at most ``RATE`` rows per second
and device (a token bucket); the rows left out are counted and the next row says how many.
"""

from __future__ import annotations

import time
from typing import Any

from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.audit import audit
from backend.live.store import DbWriter
from protocol import wire

RATE = 5.0  # audit rows per second and device, sustained
BURST = 20.0


class EventAuditor:
    def __init__(self, db: DbWriter, authenticated: bool) -> None:
        self._db = db
        self.identity = "tls-certificate-cn" if authenticated else "unauthenticated"
        self._buckets: dict[str, tuple[float, float]] = {}  # device -> (tokens, at)
        self._skipped: dict[str, int] = {}
        self.suppressed = 0

    def __call__(self, device: str, session_id: int, ev: wire.EventMessage, key: str) -> None:
        now = time.monotonic()
        tokens, at = self._buckets.get(device, (BURST, now))
        tokens = min(BURST, tokens + (now - at) * RATE)
        if tokens < 1.0:
            self._buckets[device] = (tokens, now)
            self._skipped[device] = self._skipped.get(device, 0) + 1
            self.suppressed += 1
            return
        self._buckets[device] = (tokens - 1.0, now)
        details: dict[str, Any] = {
            "key": key,
            "t": ev.t,
            "source": self.identity,
            "identity": f"CN={device}" if self.identity != "unauthenticated" else None,
        }
        if ev.point is not None:
            details["point"] = [float(x) for x in ev.point]
        skipped = self._skipped.pop(device, 0)
        if skipped:
            details["suppressed_before"] = skipped
        action = f"device.{ev.type}"

        async def op(db: AsyncSession) -> None:
            audit(db, f"device:{device}", action, f"session:{session_id}", details)

        self._db.submit(f"audit of {action} on session {session_id}", op)
