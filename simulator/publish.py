"""Publish a simulation or a recording over Zenoh, as devices would, timed by the messages'
own timestamps: ``speed`` 1 is real time, 20 is twenty times faster, 0 as fast as possible.

    python -m simulator.publish recording.jsonl.gz --connect tcp/127.0.0.1:7447 --speed 1

A message is released when its newest sample is taken (an IMU batch when its last sample
is in, a robot sample at its stamp, an event at its time), the order of the recording is
kept. Each device also holds a Zenoh liveliness token ``<prefix>/<device>`` while
publishing, so the service shows it online before its first message. Publishers block
rather than drop when the network pushes back: a recording arrives complete.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson
import zenoh
import zenoh.ext as zenoh_ext

from protocol import keys, recording, wire
from protocol.zenoh_config import make_config

log = logging.getLogger(__name__)
READY_TIMEOUT_S = 60.0  # a DeviceThread waits this long for its ready() at most


@dataclass(frozen=True, slots=True)
class Outgoing:
    at: float  # release time on the sample clock (s)
    key: str
    payload: bytes


def _release_time(obj: Any) -> float | None:
    if not isinstance(obj, dict):
        return None
    t = obj.get("t")
    if isinstance(t, list) and t and all(isinstance(x, (int, float)) for x in t):
        return float(max(t))
    if isinstance(t, (int, float)) and not isinstance(t, bool):
        return float(t)
    return None


def prepare(messages: Iterable[tuple[str | None, Any]]) -> list[Outgoing]:
    """``(key, payload)`` pairs (payload objects, JSON bytes, or the raw payloads of
    :func:`protocol.recording.read`) → what to send and when. Messages without a usable
    time go out with the one before them; times never run backwards."""
    out: list[Outgoing] = []
    last = None
    for key, payload in messages:
        if key is None:
            continue  # a recording line that is not a message
        if isinstance(payload, dict):
            data, obj = wire.dumps(payload), payload
        else:
            data = payload.encode("utf-8") if isinstance(payload, str) else bytes(payload)
            try:
                obj = orjson.loads(data)
            except orjson.JSONDecodeError:
                obj = None
        t = _release_time(obj)
        at = t if t is not None else last
        if at is None:
            at = 0.0
        if last is not None and at < last:
            at = last
        last = at
        out.append(Outgoing(at, key, data))
    return out


def devices_of(outgoing: Iterable[Outgoing], prefix: str = keys.DEFAULT_PREFIX) -> list[str]:
    found: dict[str, None] = {}
    for m in outgoing:
        with contextlib.suppress(keys.KeyError_):
            found[keys.parse(m.key, prefix).device] = None
    return list(found)


def _matching(pub: Any) -> bool:
    if not hasattr(pub, "matching_status"):
        return True  # an AdvancedPublisher: a late subscriber gets its cache
    status: object = pub.matching_status  # a MatchingStatus object at runtime (stub: bool)
    return bool(getattr(status, "matching", status))


class Publisher:
    """Publishers declared once per key, a liveliness token per device.

    ``cache``: a publication cache of that many messages per key (zenoh-ext's
    ``AdvancedPublisher``, with publisher detection). A worker that takes the device over
    queries it and records the messages published while no worker held the device (see
    docs/scaling.md, "Seconds lost"). Device makers: the same two settings on a real
    device's publishers (``cache`` sized for a few seconds of its messages, and
    ``timestamping`` enabled in its Zenoh configuration, which the cache requires).
    """

    def __init__(
        self, session: zenoh.Session, prefix: str = keys.DEFAULT_PREFIX, cache: int = 0
    ) -> None:
        self.session = session
        self.prefix = prefix
        self.cache = cache
        self._pubs: dict[str, Any] = {}  # zenoh.Publisher, or zenoh.ext.AdvancedPublisher
        self._tokens: dict[str, zenoh.LivelinessToken] = {}

    @classmethod
    def connect(cls, endpoint: str, prefix: str = keys.DEFAULT_PREFIX, cache: int = 0) -> Publisher:
        config = make_config(connect=endpoint, mode="peer")
        if cache:
            config.insert_json5("timestamping/enabled", "true")  # the cache needs them
        return cls(zenoh.open(config), prefix, cache)

    def declare(self, outgoing: Sequence[Outgoing]) -> None:
        for m in outgoing:
            self.declare_key(m.key)
        for device in devices_of(outgoing, self.prefix):
            self.announce(device)

    def announce(self, device: str) -> None:
        if device not in self._tokens:
            self._tokens[device] = self.session.liveliness().declare_token(
                f"{self.prefix}/{device}"
            )

    def declare_key(self, key: str) -> Any:
        """The key's publisher, declared once (zenoh.Publisher or AdvancedPublisher)."""
        return self._publisher(key)

    def _publisher(self, key: str) -> Any:
        pub = self._pubs.get(key)
        if pub is None:
            if self.cache:
                pub = zenoh_ext.declare_advanced_publisher(
                    self.session,
                    key,
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    cache=zenoh_ext.CacheConfig(max_samples=self.cache),
                    publisher_detection=True,
                )
            else:
                pub = self.session.declare_publisher(
                    key,
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
            self._pubs[key] = pub
        return pub

    def wait_for_subscribers(self, timeout: float = 10.0) -> bool:
        """Until every declared key has a subscriber (what is sent before is lost)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(_matching(p) for p in self._pubs.values()):
                return True
            time.sleep(0.01)
        return False

    def put(self, key: str, payload: bytes) -> None:
        self._publisher(key).put(payload)

    def close(self) -> None:
        for tok in self._tokens.values():
            tok.undeclare()  # type: ignore[no-untyped-call]
        for pub in self._pubs.values():
            pub.undeclare()
        self._tokens.clear()
        self._pubs.clear()
        self.session.close()  # type: ignore[no-untyped-call]

    def __enter__(self) -> Publisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def play(
    publisher: Publisher,
    outgoing: Sequence[Outgoing],
    speed: float = 1.0,
    *,
    stop: threading.Event | None = None,
    on_sent: Callable[[Outgoing, float], None] | None = None,
    start: float | None = None,
) -> int:
    """Send ``outgoing`` in order, message ``m`` at ``start + (m.at - first.at) / speed``
    (monotonic clock; ``speed`` ≤ 0: no waiting). ``on_sent(m, wall time)`` after each
    put. Returns how many were sent (fewer if ``stop`` was set)."""
    if not outgoing:
        return 0
    base = time.monotonic() if start is None else start
    t0 = outgoing[0].at
    n = 0
    for m in outgoing:
        if speed > 0:
            delay = base + (m.at - t0) / speed - time.monotonic()
            if delay > 0:
                if stop is not None:
                    if stop.wait(delay):
                        break
                else:
                    time.sleep(delay)
        if stop is not None and stop.is_set():
            break
        publisher.put(m.key, m.payload)
        n += 1
        if on_sent is not None:
            on_sent(m, time.time())
    return n


def publish(
    endpoint: str,
    messages: Iterable[tuple[str | None, Any]],
    speed: float = 1.0,
    *,
    prefix: str = keys.DEFAULT_PREFIX,
    wait_s: float = 10.0,
    stop: threading.Event | None = None,
    cache: int = 0,
) -> int:
    """Connect, declare, wait for the service's subscription, play, disconnect.
    ``cache``: a publication cache of that many messages per key (:class:`Publisher`)."""
    outgoing = prepare(messages)
    with Publisher.connect(endpoint, prefix, cache) as pub:
        pub.declare(outgoing)
        if not pub.wait_for_subscribers(wait_s):
            log.warning("no subscriber on %s after %.0f s: publishing anyway", endpoint, wait_s)
        return play(pub, outgoing, speed, stop=stop)


class DeviceThread(threading.Thread):
    """A simulated device publishing ``outgoing`` from a background thread, as a real one
    would: once ``ready()`` (if given: e.g. a worker holds the device, polled from this
    thread), ``head_s`` seconds in real time (so the service knows the device), then, if
    ``gated``, a wait for :meth:`go` (a session has started), then everything up to
    ``fast_until_s`` (seconds after the first message) at ``fast`` times real time (the
    heading calibration, shortened) and the rest in real time until the end or :meth:`stop`.

    An exception in the thread is kept in ``error`` for its owner to report.
    """

    def __init__(
        self,
        endpoint: str,
        outgoing: Sequence[Outgoing],
        *,
        name: str,
        head_s: float = 0.0,
        fast_until_s: float = 0.0,
        fast: float = 1.0,
        gated: bool = False,
        ready: Callable[[], bool] | None = None,
        prefix: str = keys.DEFAULT_PREFIX,
    ) -> None:
        super().__init__(name=f"sim-{name}", daemon=True)
        self.ready = ready
        self.endpoint, self.outgoing, self.prefix = endpoint, list(outgoing), prefix
        self.head_s, self.fast_until_s, self.fast = head_s, fast_until_s, fast
        self._go = threading.Event()
        if not gated:
            self._go.set()
        self.stop_event = threading.Event()
        self.realtime = threading.Event()  # set once the fast part is over
        self.error: BaseException | None = None
        self.sent = 0

    def go(self) -> None:
        self._go.set()

    def stop(self, timeout_s: float = 10.0) -> None:
        self.stop_event.set()
        self._go.set()
        self.join(timeout_s)

    def run(self) -> None:
        try:
            with Publisher.connect(self.endpoint, self.prefix) as pub:
                pub.declare(self.outgoing)
                pub.wait_for_subscribers(10.0)
                if not self.outgoing:
                    return
                if self.ready is not None:
                    deadline = time.monotonic() + READY_TIMEOUT_S
                    while not self.ready():
                        if time.monotonic() > deadline:
                            raise TimeoutError(f"not ready after {READY_TIMEOUT_S:.0f} s")
                        if self.stop_event.wait(0.05):
                            return
                at = [m.at for m in self.outgoing]  # never decreasing (prepare)
                n_head = bisect.bisect_left(at, at[0] + self.head_s)
                n_fast = max(n_head, bisect.bisect_left(at, at[0] + self.fast_until_s))
                self.sent += play(pub, self.outgoing[:n_head], 1.0, stop=self.stop_event)
                while not self._go.wait(0.2):
                    if self.stop_event.is_set():
                        return
                fast, rest = self.outgoing[n_head:n_fast], self.outgoing[n_fast:]
                self.sent += play(pub, fast, self.fast, stop=self.stop_event)
                self.realtime.set()
                self.sent += play(pub, rest, 1.0, stop=self.stop_event)
        except BaseException as exc:  # reported by the owner of the device
            self.error = exc


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="X",
        help="1 = real time (default), 20 = twenty times faster, 0 = no waiting",
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m simulator.publish",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("recording", type=Path, help="contract recording (.jsonl or .jsonl.gz)")
    ap.add_argument(
        "--connect",
        default="tcp/127.0.0.1:7447",
        metavar="ENDPOINT",
        help="Zenoh endpoint of the service or router (default %(default)s)",
    )
    ap.add_argument("--prefix", default=keys.DEFAULT_PREFIX)
    ap.add_argument(
        "--cache",
        type=int,
        default=0,
        metavar="N",
        help="keep a publication cache of N messages per key (zenoh-ext AdvancedPublisher): "
        "a worker taking the device over recovers what it missed (default 0: none)",
    )
    add_arguments(ap)
    args = ap.parse_args(argv)
    if not args.recording.is_file():
        print(f"publish: no such recording: {args.recording}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    n = publish(
        args.connect,
        recording.read(args.recording),
        args.speed,
        prefix=args.prefix,
        cache=args.cache,
    )
    print(f"published {n} messages to {args.connect} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
