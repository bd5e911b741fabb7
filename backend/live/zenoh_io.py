"""The service's one embedded Zenoh session: the subscription in, estimates and feedback out.

Samples arrive in a small bounded Zenoh channel. One receiving thread takes whatever has
arrived, all at once (then pauses ``RX_GATHER_S``), and only appends ``(key, payload bytes,
size, arrival time)`` to a bounded buffer and, when the buffer was empty, schedules one drain
on the asyncio loop with ``loop.call_soon_threadsafe``: no decoding, no Zenoh calls. A full
buffer drops and counts; ingest never blocks. (A Zenoh callback would take the GIL once per
sample; under load each of those handovers stalled the loop, which holds the GIL most of the
time.)
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from protocol import keys

log = logging.getLogger(__name__)

RawSample = tuple[str, bytes | None, int, float]

# Room for bursts while the loop is busy; bytes bound it too (payloads reach 1 MiB).
BUFFER_ITEMS = 1 << 16
BUFFER_BYTES = 32 << 20  # 256 MiB stayed resident after a flood (issue 21)
# Samples between Zenoh's network thread and ours: ~0.4 s at 50 devices while the loop holds
# the GIL (then Zenoh waits, the devices' own queues absorb it); the channel is drained at
# once, so it holds little, but each slot may hold a message up to RX_MAX_MESSAGE_BYTES
# (protocol.zenoh_config).
RX_CHANNEL = 1024
# After taking what has arrived, the receiving thread waits this long before it takes the
# GIL again. Without the pause it took the GIL about once per 3 samples (~900 times a second
# at 50 devices), and each time the loop let it go (in every Zenoh put, ~1250 a second) the
# loop then waited for it back: ~110 µs per put. With it: ~270 takes a second, ~75 µs per
# put, for at most 2 ms more on a sample's way in (the channel holds what arrives meanwhile).
RX_GATHER_S = 0.002
# A worker's subscription per held device (docs/scaling.md, "Device discovery"): samples
# wait in the device's channel until the receiving thread's next round (every RX_GATHER_S)
DEVICE_CHANNEL = 256


@dataclass
class DevicePublishers:
    estimate: zenoh.Publisher
    feedback: zenoh.Publisher
    event: zenoh.Publisher
    joints: zenoh.Publisher  # a wearable device's joint angles (contract §8)


class ZenohIO:
    def __init__(
        self,
        config: zenoh.Config,
        prefix: str,
        loop: asyncio.AbstractEventLoop,
        on_batch: Callable[[list[RawSample]], None],
        on_token: Callable[[str, bool], None],
        max_payload: int,
        accept: Callable[[str], bool] | None = None,
        subscribe: bool = True,
        per_device: bool = False,
    ) -> None:
        self._config = config
        self.prefix = prefix
        self._loop = loop
        self._on_batch = on_batch
        self._on_token = on_token
        self._max_payload = max_payload
        # a worker's filter on the key (the devices it holds), before any copy of the payload
        self._accept = accept
        self._subscribe = subscribe  # an API-only node takes no device data
        # a worker: one subscription per held device (subscribe_device), not all the data
        self._per_device = per_device
        self._device_subs: dict[str, zenoh.Subscriber[Any]] = {}
        # the receiving thread's view: replaced whole (never changed in place) on a change
        self._channels: tuple[zenoh.handlers.Handler[zenoh.Sample], ...] = ()
        self._closing = threading.Event()
        self._buf: deque[RawSample] = deque()
        self._buf_bytes = 0
        self._bytes_lock = threading.Lock()  # held for an addition only
        self._scheduled = False
        self.overflow = 0  # samples dropped because the loop fell behind
        self._session: zenoh.Session | None = None
        self._subs: list[zenoh.Subscriber[Any]] = []
        self._rx: threading.Thread | None = None
        self._pubs: dict[str, DevicePublishers] = {}

    # ------------------------------------------------------------------ lifecycle

    def open(self) -> None:
        self._session = zenoh.open(self._config)
        if self._subscribe:
            self._open_data()
        self._subs.append(
            self._session.liveliness().declare_subscriber(
                f"{self.prefix}/*/**", self._on_liveliness, history=True
            )
        )

    @property
    def session(self) -> zenoh.Session | None:
        return self._session

    def _open_data(self) -> None:
        assert self._session is not None
        if self._per_device:
            self._rx = threading.Thread(target=self._poll, name="zenoh-rx", daemon=True)
            self._rx.start()
            return
        data = self._session.declare_subscriber(
            keys.subscription(self.prefix),
            zenoh.handlers.FifoChannel(RX_CHANNEL),
            allowed_origin=zenoh.Locality.REMOTE,  # not our own estimates
        )
        self._subs.append(data)
        self._rx = threading.Thread(
            target=self._receive, args=(data.handler,), name="zenoh-rx", daemon=True
        )
        self._rx.start()

    def close(self) -> None:
        session, self._session = self._session, None
        if session is None:
            return
        self._closing.set()
        self._channels = ()
        for sub in self._device_subs.values():
            sub.undeclare()  # type: ignore[no-untyped-call]
        self._device_subs.clear()
        for sub in self._subs:
            sub.undeclare()  # type: ignore[no-untyped-call]
        if self._rx is not None:
            self._rx.join(5.0)  # its channel is closed: it returns
            self._rx = None
        for pubs in self._pubs.values():
            pubs.estimate.undeclare()  # type: ignore[no-untyped-call]
            pubs.feedback.undeclare()  # type: ignore[no-untyped-call]
            pubs.event.undeclare()  # type: ignore[no-untyped-call]
            pubs.joints.undeclare()  # type: ignore[no-untyped-call]
        self._subs.clear()
        self._pubs.clear()
        session.close()  # type: ignore[no-untyped-call]

    # ------------------------------------------------------------------ Zenoh threads

    def _receive(self, channel: zenoh.handlers.Handler[zenoh.Sample]) -> None:
        """Everything that has arrived per wake-up: the GIL once for a burst, then a pause
        of ``RX_GATHER_S`` for the next burst to gather."""
        try:
            while True:
                sample: zenoh.Sample | None = channel.recv()  # waits without the GIL
                while sample is not None:
                    self._on_sample(sample)
                    sample = channel.try_recv()
                time.sleep(RX_GATHER_S)
        except zenoh.ZError:  # the subscriber was undeclared: the session is closing
            return

    def _poll(self) -> None:
        """A worker's receiving thread: every ``RX_GATHER_S``, whatever waits in the held
        devices' channels (a ``try_recv`` is ~0.2 µs and keeps the GIL: one take per
        round, as with one channel)."""
        closing = self._closing
        while not closing.is_set():
            time.sleep(RX_GATHER_S)  # cheaper than an Event's timed wait, ~500 times a second
            for channel in self._channels:
                try:
                    sample = channel.try_recv()
                    while sample is not None:
                        self._on_sample(sample)
                        sample = channel.try_recv()
                except zenoh.ZError:  # undeclared meanwhile: the device was dropped
                    continue

    def subscribe_device(self, device: str) -> None:
        """Take ``device``'s data from now on (a worker that has just leased it). Declared
        on the loop, never in a Zenoh callback; the router learns of it before anything
        this session sends afterwards (one link, in order)."""
        if device in self._device_subs or self._session is None or not self._per_device:
            return
        sub = self._session.declare_subscriber(
            keys.device_data(device, self.prefix),
            zenoh.handlers.FifoChannel(DEVICE_CHANNEL),
            allowed_origin=zenoh.Locality.REMOTE,
        )
        self._device_subs[device] = sub
        self._channels = (*self._channels, sub.handler)

    def unsubscribe_device(self, device: str) -> None:
        sub = self._device_subs.pop(device, None)
        if sub is None:
            return
        self._channels = tuple(s.handler for s in self._device_subs.values())
        sub.undeclare()  # type: ignore[no-untyped-call]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        if self._accept is not None and not self._accept(str(sample.key_expr)):
            return
        size = len(sample.payload)
        keep = size <= self._max_payload  # too large: keep only the fact, not the bytes
        with self._bytes_lock:
            if len(self._buf) >= BUFFER_ITEMS or (keep and self._buf_bytes + size > BUFFER_BYTES):
                self.overflow += 1
                return
            if keep:
                self._buf_bytes += size
        data = sample.payload.to_bytes() if keep else None
        self._buf.append((str(sample.key_expr), data, size, time.time()))
        if not self._scheduled:
            self._scheduled = True
            with contextlib.suppress(RuntimeError):  # loop closed during shutdown
                self._loop.call_soon_threadsafe(self._drain)

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        pre = self.prefix.split("/")
        if len(parts) <= len(pre) or parts[: len(pre)] != pre:
            return
        device = parts[len(pre)]
        if not keys.DEVICE_RE.fullmatch(device):
            return
        alive = sample.kind == zenoh.SampleKind.PUT
        with contextlib.suppress(RuntimeError):
            self._loop.call_soon_threadsafe(self._on_token, device, alive)

    # ------------------------------------------------------------------ loop side

    def _drain(self) -> None:
        # reset first: a sample appended from now on schedules another drain
        self._scheduled = False
        buf = self._buf
        batch: list[RawSample] = []
        nbytes = 0
        while buf:
            item = buf.popleft()
            batch.append(item)
            if item[1] is not None:
                nbytes += item[2]
        with self._bytes_lock:
            self._buf_bytes -= nbytes
        if batch:
            self._on_batch(batch)

    def publishers(self, device: str) -> DevicePublishers | None:
        """Declared once per device, on its first output."""
        pubs = self._pubs.get(device)
        if pubs is None and self._session is not None:
            s = self._session

            def declare(key: str) -> zenoh.Publisher:
                return s.declare_publisher(
                    key,
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                    # a slow subscriber loses outputs; it never stalls the pipelines
                    congestion_control=zenoh.CongestionControl.DROP,
                    # batched with what else is queued: express (sent alone) cost ~40 µs of
                    # the loop per put against ~9, and saved < 0.1 ms of latency on loopback
                    express=False,
                    allowed_destination=zenoh.Locality.REMOTE,
                )

            pubs = DevicePublishers(
                estimate=declare(keys.estimate(device, self.prefix)),
                feedback=declare(keys.feedback(device, self.prefix)),
                event=declare(keys.event(device, self.prefix)),
                joints=declare(keys.joints(device, self.prefix)),
            )
            self._pubs[device] = pubs
        return pubs
