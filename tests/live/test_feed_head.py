"""The API node reads a worker's rows message's type and device from its first bytes
(``gateway.ROWS_HEAD``) to drop, undecoded, the rows nobody on the node watches: the hub's
messages must keep that shape, or every message is decoded again (correct, but the cost
this saves comes back)."""

from __future__ import annotations

import asyncio

import orjson

from backend.live.feed import Block
from backend.live.gateway import ROWS_HEAD
from backend.live.hub import Hub


def hub_texts(kind: str) -> list[str]:
    async def run() -> list[str]:
        hub = Hub(30.0, 16)
        client = hub.connect()
        block = Block(("t", "x"), [[1.0, 1.01], [float("nan"), 2.0]], ["ok", None])
        hub.rows("dev-01_a", 7, block, None, kind=kind)
        hub.flush("dev-01_a")
        out = []
        while not client.queue.empty():
            text = client.queue.get_nowait()
            assert text is not None
            out.append(text)
        return out

    return asyncio.run(run())


def test_rows_messages_are_recognised_by_their_head() -> None:
    for kind in ("estimate", "joints"):
        (text,) = hub_texts(kind)
        head = ROWS_HEAD.match(text.encode())
        assert head is not None, text[:80]
        msg = orjson.loads(text)
        assert (msg["type"], msg["device"]) == (kind, "dev-01_a")
        assert head[1] == b"dev-01_a"


def test_other_messages_are_not() -> None:
    for msg in (
        {"type": "status", "device": "d1", "online": True},
        {"type": "state", "device": "d1", "t": 1.0, "state": "ok"},
        {"device": "d1", "type": "estimate", "rows": {}},  # another order: decoded in full
    ):
        assert ROWS_HEAD.match(orjson.dumps(msg)) is None
