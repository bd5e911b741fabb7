"""Device leases on a real database (SQLite and PostgreSQL): one holder at a time, a new
epoch at each change of holder, no revival of an expired lease, fenced writes."""

from __future__ import annotations

import asyncio

import pytest

from backend.db.engine import Database
from backend.live import lease
from backend.live.store import DbWriter


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.mark.anyio
async def test_one_holder_epochs_and_expiry(any_db_url: str) -> None:
    db = Database(any_db_url)
    await db.migrate()
    try:
        now = 1000.0
        async with db.transaction() as s:
            assert await lease.acquire(s, "d1", "A", now) == 1
        async with db.transaction() as s:
            assert await lease.acquire(s, "d1", "B", now + 0.1) is None  # A holds it
            assert await lease.renew(s, "A", now + 0.5) == {"d1": 1}
        # A's renewal at +0.5 keeps it until +0.5 + TTL
        async with db.transaction() as s:
            assert await lease.acquire(s, "d1", "B", now + 0.5 + lease.TTL_S - 0.01) is None
            assert await lease.acquire(s, "d1", "B", now + 0.5 + lease.TTL_S) == 2
        async with db.transaction() as s:
            # expired and taken: A's renewal finds nothing, never revives it
            assert await lease.renew(s, "A", now + 2.0) == {}
            assert await lease.holds(s, "d1", "B", 2)
            assert not await lease.holds(s, "d1", "A", 1)
            await lease.release(s, "B")
        async with db.transaction() as s:  # released: free at once
            assert await lease.acquire(s, "d1", "A", now + 2.1) == 3
    finally:
        await db.dispose()


@pytest.mark.anyio
async def test_concurrent_takers_one_winner(any_db_url: str) -> None:
    db = Database(any_db_url)
    await db.migrate()
    try:

        async def take(holder: str) -> int | None:
            async with db.transaction() as s:
                return await lease.acquire(s, "d2", holder, 5000.0)

        results = []
        for holder in ("A", "B", "C", "D"):  # interleaved on one loop, then truly at once
            results.append(await take(holder))
        assert results == [1, None, None, None]
        async with db.transaction() as s:
            await lease.release(s, "A")
        won = await asyncio.gather(*(take(h) for h in ("B", "C", "D")), return_exceptions=True)
        assert sum(1 for w in won if isinstance(w, int)) == 1, won
    finally:
        await db.dispose()


@pytest.mark.anyio
async def test_writes_of_a_stale_epoch_are_dropped(any_db_url: str) -> None:
    db = Database(any_db_url)
    await db.migrate()
    writer = DbWriter(db)
    writer.start()
    try:
        async with db.transaction() as s:
            assert await lease.acquire(s, "d3", "A", 100.0) == 1
            assert await lease.acquire(s, "d3", "B", 100.0 + lease.TTL_S) == 2
        done: list[str] = []

        async def op(_: object) -> None:
            done.append("written")

        writer.submit("stale", op, fence=("d3", "A", 1))
        writer.submit("current", op, fence=("d3", "B", 2))
        await writer.close()
        assert done == ["written"] and writer.fenced == 1
    finally:
        await db.dispose()


def test_rendezvous_spreads_and_agrees() -> None:
    workers = ["w1", "w2", "w3"]
    firsts = [
        next(w for w in workers if lease.rank(f"dev{i}", w, workers) == 0) for i in range(300)
    ]
    counts = {w: firsts.count(w) for w in workers}
    assert all(70 <= c <= 130 for c in counts.values()), counts
    for i in range(20):  # every worker computes the same order
        ranks = sorted(lease.rank(f"dev{i}", w, workers) for w in workers)
        assert ranks == [0, 1, 2]


@pytest.mark.anyio
async def test_renewals_hold_while_a_busy_loop_writes(any_db_url: str) -> None:
    """A worker's loop busy with pipelines (10 ms rounds) while its writer stores the
    registry of 25 devices each second: the lease thread's renewals, which need the
    database's write lock (SQLite) or the fenced rows (PostgreSQL), never wait long. The
    writer's transactions used to run on that loop, each statement waiting for the loop to
    come round, and held renewals back past the lease's expiry (the 50-device churn)."""
    import threading
    import time

    from backend.db.devices import touch_device

    db = Database(any_db_url)
    await db.migrate()
    engine = lease.sync_engine(any_db_url)
    writer = DbWriter(db)
    writer.start()
    stop = threading.Event()
    rtts: list[float] = []
    kept: list[dict[str, int]] = []
    try:
        with engine.begin() as conn:
            assert lease.acquire_sync(conn, "d1", "A", time.time()) == 1

        def renewals() -> None:
            while not stop.wait(lease.RENEW_S):
                t0 = time.monotonic()
                with engine.begin() as conn:
                    kept.append(lease.renew_sync(conn, "A", time.time()))
                rtts.append(time.monotonic() - t0)

        thread = threading.Thread(target=renewals)
        thread.start()
        names = [f"dev{i:02d}" for i in range(25)]
        end = time.monotonic() + 3.0
        next_write = 0.0
        while time.monotonic() < end:
            if time.monotonic() >= next_write:
                next_write = time.monotonic() + 1.0
                for n in names:  # one op per device, fenced like a worker's cycles

                    async def op(s: object, n: str = n) -> None:
                        await touch_device(s, n, stats={"rates_hz": {"imu": 100.0}})  # type: ignore[arg-type]

                    writer.submit(f"registry of {n}", op, fence=("d1", "A", 1))
            time.sleep(0.01)  # a scheduling round of the pipelines, holding the loop
            await asyncio.sleep(0)
        stop.set()
        await asyncio.to_thread(thread.join)
        await writer.close()
        assert writer.failed == 0 and writer.fenced == 0
        # far inside the lease's self-expiry margin (TTL − MARGIN − RENEW = 0.7 s)
        assert max(rtts) < 0.25, sorted(rtts)[-5:]
        assert len(rtts) >= 8
        assert all(k == {"d1": 1} for k in kept), kept  # never expired
        async with db.session() as s:
            from backend.db.models import Device

            assert len((await s.execute(lease.select(Device.name))).all()) == 25
    finally:
        stop.set()
        await writer.close()
        engine.dispose()
        await db.dispose()
