"""WebSocket fan-out: per-client bounded queues, estimates decimated per device.

Each message is serialised once and handed to every interested client as text. A client
that cannot keep up loses messages (counted), it never slows the pipelines. Estimate rows
are kept as numpy blocks between sends and serialised once per send, so a client sees every
row even at the 30 Hz cap; state
changes and cycle verdicts bypass the cap. A state change can therefore arrive up to one
decimation interval before the rows that led to it.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import orjson

from backend.live.feed import Block, join
from backend.live.feed import dumps as dumps_numpy

log = logging.getLogger(__name__)


@dataclass(eq=False)
class Client:
    """One WebSocket. ``overlay`` = (device, session id) for a game overlay."""

    queue: asyncio.Queue[str | None]
    devices: frozenset[str] | None = None  # None: every device
    overlay: tuple[str, int] | None = None
    dropped: int = 0
    # How the socket closes when ``None`` comes out of the queue (revoke() makes it 1008).
    close_code: int = 1000
    close_reason: str = "session ended"

    def wants(self, device: str, session_id: int | None) -> bool:
        if self.overlay is not None:
            return self.overlay == (device, session_id)
        return self.devices is None or device in self.devices

    def send(self, text: str | None) -> None:
        try:
            self.queue.put_nowait(text)
        except asyncio.QueueFull:
            self.dropped += 1
            if text is None:  # the end must get through: make room for it
                self.queue.get_nowait()
                self.queue.put_nowait(None)

    def revoke(self, reason: str) -> None:
        """The viewer's login ended (logout, password change, deactivation): close 1008."""
        self.close_code, self.close_reason = 1008, reason
        self.send(None)


@dataclass
class _Pending:
    session_id: int | None = None
    kind: str = "estimate"  # the message type of the rows: estimate, or joints (wearable)
    display: list[Block] = field(default_factory=list)
    overlay: list[Block] = field(default_factory=list)
    last_sent: float = -1e9
    timer: asyncio.TimerHandle | None = None


def dumps(msg: Mapping[str, Any]) -> str:
    return orjson.dumps(msg).decode("utf-8")


def _estimate_text(device: str, blocks: list[Block], kind: str = "estimate") -> str:
    rows = join(blocks).columns()
    return dumps_numpy({"type": kind, "device": device, "rows": rows}).decode("utf-8")


class Hub:
    def __init__(self, max_rate_hz: float, queue_size: int) -> None:
        self.min_interval = 1.0 / max_rate_hz
        self.queue_size = queue_size
        self.clients: set[Client] = set()
        self._pending: dict[str, _Pending] = {}

    def connect(
        self, devices: Iterable[str] | None = None, overlay: tuple[str, int] | None = None
    ) -> Client:
        client = Client(
            asyncio.Queue(self.queue_size),
            frozenset(devices) if devices is not None else None,
            overlay,
        )
        self.clients.add(client)
        return client

    def disconnect(self, client: Client) -> None:
        self.clients.discard(client)

    def interest(self, device: str, session_id: int | None) -> tuple[bool, bool]:
        """(a therapist watches ``device``, an overlay of this session watches it)."""
        therapist = overlay = False
        for c in self.clients:
            if c.overlay is None:
                therapist = therapist or c.wants(device, session_id)
            elif c.wants(device, session_id):
                overlay = True
        return therapist, overlay

    def _send(
        self,
        device: str,
        session_id: int | None,
        msg: Mapping[str, Any],
        overlay_msg: Mapping[str, Any] | None,
    ) -> None:
        text = otext = None
        for c in list(self.clients):
            if not c.wants(device, session_id):
                continue
            if c.overlay is None:
                text = text or dumps(msg)
                c.send(text)
            elif overlay_msg is not None:
                otext = otext or dumps(overlay_msg)
                c.send(otext)

    def event(self, device: str, session_id: int | None, msg: Mapping[str, Any]) -> None:
        """``state`` and ``cycle``: immediately, to therapists and the session's overlay
        (rows pending under the rate cap follow at their time)."""
        self._send(device, session_id, msg, msg)

    def status(
        self,
        device: str,
        session_id: int | None,
        msg: Mapping[str, Any],
        overlay_msg: Mapping[str, Any],
    ) -> None:
        self._send(device, session_id, msg, overlay_msg)

    def rows(
        self,
        device: str,
        session_id: int | None,
        display: Block | None,
        overlay: Block | None,
        kind: str = "estimate",
    ) -> None:
        p = self._pending.get(device)
        if p is None:
            p = self._pending[device] = _Pending(session_id, kind)
        elif p.session_id != session_id or p.kind != kind:
            self.flush(device)
            p.session_id = session_id
            p.kind = kind
        if display is not None:
            p.display.append(display)
        if overlay is not None:
            p.overlay.append(overlay)
        wait = p.last_sent + self.min_interval - time.monotonic()
        if wait <= 0:
            self.flush(device)
        elif p.timer is None:
            p.timer = asyncio.get_running_loop().call_later(wait, self.flush, device)

    def flush(self, device: str) -> None:
        p = self._pending.get(device)
        if p is None:
            return
        if p.timer is not None:
            p.timer.cancel()
            p.timer = None
        if not p.display and not p.overlay:
            return
        display, overlay = p.display, p.overlay
        p.display, p.overlay = [], []
        p.last_sent = time.monotonic()
        text = otext = None
        for c in list(self.clients):
            if not c.wants(device, p.session_id):
                continue
            if c.overlay is None and display:
                text = text or _estimate_text(device, display, p.kind)
                c.send(text)
            elif c.overlay is not None and overlay:
                otext = otext or _estimate_text(device, overlay)
                c.send(otext)

    def end_session(self, session_id: int) -> None:
        """The session stopped: its overlay links are dead, close their sockets."""
        for c in list(self.clients):
            if c.overlay is not None and c.overlay[1] == session_id:
                c.send(None)

    def close_all(self) -> None:
        for c in list(self.clients):
            c.send(None)
