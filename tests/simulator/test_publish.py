"""simulator.publish's device thread over a real Zenoh session on loopback."""

from __future__ import annotations

import queue
import time
from collections.abc import Iterator

import pytest
import zenoh

from backend.cli_live import free_port
from protocol import keys
from protocol.zenoh_config import make_config
from simulator import SimConfig, simulate
from simulator.publish import DeviceThread, prepare


@pytest.fixture
def listener() -> Iterator[tuple[str, queue.Queue[tuple[float, str]]]]:
    """A session listening on loopback; what reaches it is queued as (arrival, key)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    got: queue.Queue[tuple[float, str]] = queue.Queue()
    session = zenoh.open(make_config(listen=endpoint))
    sub = session.declare_subscriber(
        f"{keys.DEFAULT_PREFIX}/**", lambda s: got.put((time.monotonic(), str(s.key_expr)))
    )
    try:
        yield endpoint, got
    finally:
        sub.undeclare()  # type: ignore[no-untyped-call]
        session.close()  # type: ignore[no-untyped-call]


def _drain(got: queue.Queue[tuple[float, str]], quiet_s: float) -> list[tuple[float, str]]:
    out: list[tuple[float, str]] = []
    while True:
        try:
            out.append(got.get(timeout=quiet_s))
        except queue.Empty:
            return out


def test_head_then_gate_then_fast_then_real_time(
    listener: tuple[str, queue.Queue[tuple[float, str]]],
) -> None:
    endpoint, got = listener
    outgoing = prepare(simulate(SimConfig(seed=4, duration_s=12.0, device="pub01")).messages)
    t0 = outgoing[0].at
    n_head = sum(m.at < t0 + 1.0 for m in outgoing)
    n_fast_end = sum(m.at < t0 + 9.0 for m in outgoing)
    dev = DeviceThread(
        endpoint, outgoing, name="pub01", head_s=1.0, fast_until_s=9.0, fast=16.0, gated=True
    )
    dev.start()
    try:
        # The head, in real time (about 1 s), then nothing while the gate is closed.
        head = _drain(got, quiet_s=1.5)
        assert len(head) == n_head, (len(head), n_head)
        assert head[-1][0] - head[0][0] > 0.6  # real time, not a burst
        assert not dev.realtime.is_set() and dev.sent == n_head
        dev.go()
        # 8 s of data at 16x: about half a second; then the rest in real time.
        assert dev.realtime.wait(5.0)
        fast = []
        while len(fast) < n_fast_end - n_head:
            fast.append(got.get(timeout=5.0))
        assert fast[-1][0] - fast[0][0] < 0.5 * (8.0 - 0.1)  # far faster than real time
        rest = [got.get(timeout=5.0) for _ in range(10)]
        assert rest[-1][0] - rest[0][0] > 0.1  # real time again: 10 messages, not a burst
    finally:
        dev.stop()
    assert dev.error is None
    assert not dev.is_alive()
    late = _drain(got, quiet_s=0.3)
    received = head + fast + rest + late
    # in order, none lost: what it counts as sent is what arrived
    assert [k for _, k in received] == [m.key for m in outgoing[: dev.sent]]
    assert dev.sent < len(outgoing)  # stopped before the end


def test_a_failure_in_the_thread_is_kept_for_its_owner() -> None:
    dev = DeviceThread("not an endpoint", [], name="pub02")
    dev.start()
    dev.join(30)
    assert not dev.is_alive()
    assert isinstance(dev.error, Exception), dev.error


def test_nothing_is_sent_before_ready(listener: tuple[str, queue.Queue[tuple[float, str]]]) -> None:
    endpoint, got = listener
    outgoing = prepare(simulate(SimConfig(seed=4, duration_s=12.0, device="pub03")).messages)
    polls: list[float] = []

    def ready() -> bool:
        polls.append(time.monotonic())
        return polls[-1] - polls[0] > 0.5

    dev = DeviceThread(endpoint, outgoing, name="pub03", head_s=0.2, gated=True, ready=ready)
    dev.start()
    try:
        first = got.get(timeout=10.0)
        assert len(polls) > 2 and first[0] >= polls[-1]  # after the poll that said ready
        assert first[1] == outgoing[0].key
    finally:
        dev.stop()
    assert dev.error is None
