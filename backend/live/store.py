"""Database writes of the live side, off the pipelines' path.

Workers submit small operations (a completed cycle, the device registry snapshot, a nominal
shoulder); one thread runs whatever has queued in transactions of at most ``SLICE_S`` each.
If a transaction fails, each of its operations is retried alone, so one bad row cannot take
the others with it.

The thread has an event loop and an engine of its own. A transaction holds the database's
write lock (SQLite) and the lease rows it fences (PostgreSQL ``FOR UPDATE``) from its first
write to its commit; on the pipelines' busy loop each of its statements waited for the loop
to come round, which stretched transactions to 0.1–5.7 s with 50 devices and held every
worker's lease renewals back past their expiry (issue 20). On a loop that does nothing else
a transaction lasts as long as its statements, and ``SLICE_S`` bounds that too: on a
loaded machine 25 registry updates in one transaction held a renewal back for 0.34 s.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any

from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.engine import Database

log = logging.getLogger(__name__)

Op = Callable[[AsyncSession], Awaitable[Any]]
Fence = tuple[str, str, int]  # (device, lease holder, epoch): see backend.live.lease
MAX_BATCH = 500
SLICE_S = 0.02  # a transaction commits once it has run this long (the write lock's hold)


class DbWriter:
    def __init__(self, database: Database, maxsize: int = 10_000) -> None:
        self.database = database
        self._queue: queue.Queue[tuple[str, Op, Fence | None] | None] = queue.Queue(maxsize)
        self._thread: threading.Thread | None = None
        self._abandon = False  # close() gave up waiting: drop what is left
        self.dropped = 0
        self.failed = 0
        self.fenced = 0  # writes refused: the device's lease had moved on

    def start(self) -> None:
        self._thread = threading.Thread(target=self._main, name="db-writer", daemon=True)
        self._thread.start()

    def submit(self, what: str, op: Op, fence: Fence | None = None) -> None:
        """``fence``: written only while that lease holder still holds the device at that
        epoch (checked in the write's own transaction). ``op`` runs in the writer's thread,
        on its loop: it must only use the session it is given and what it captured."""
        try:
            self._queue.put_nowait((what, op, fence))
        except queue.Full:
            self.dropped += 1
            log.error("database writes are backed up; dropped %s", what)

    def _main(self) -> None:
        loop = asyncio.new_event_loop()
        database = Database(self.database.url)  # an async engine belongs to one loop
        try:
            # connected before the first write, which otherwise waits for the connection
            loop.run_until_complete(self._connect(database))
            while True:
                first = self._queue.get()  # waits without the GIL
                if first is None or self._abandon:
                    return
                batch = [first]
                last = False
                while len(batch) < MAX_BATCH:
                    try:
                        item = self._queue.get_nowait()
                    except queue.Empty:
                        break
                    if item is None:
                        last = True
                        break
                    batch.append(item)
                loop.run_until_complete(self._write(database, batch))
                if last:
                    return
        finally:
            loop.run_until_complete(database.dispose())
            loop.close()

    async def _connect(self, database: Database) -> None:
        try:
            async with database.engine.connect():
                pass
        except Exception:
            log.exception("database not reached (the writes will try again)")

    async def _write(self, database: Database, batch: list[tuple[str, Op, Fence | None]]) -> None:
        start = 0
        while start < len(batch):
            start = await self._transaction(database, batch, start)

    async def _transaction(
        self, database: Database, batch: list[tuple[str, Op, Fence | None]], start: int
    ) -> int:
        """Write ``batch[start:]`` in one transaction until ``SLICE_S`` has passed; returns
        the index it stopped at. A failed transaction is written again one item at a time."""
        from backend.live.lease import holds

        t0 = time.monotonic()
        end = start
        try:
            async with database.transaction() as db:
                ok: dict[Fence, bool] = {}
                while end < len(batch) and (end == start or time.monotonic() - t0 < SLICE_S):
                    what, op, fence = batch[end]
                    end += 1
                    if fence is not None:
                        if fence not in ok:
                            ok[fence] = await holds(db, *fence)
                        if not ok[fence]:
                            self.fenced += 1
                            log.warning("not written, lease lost: %s", what)
                            continue
                    await op(db)
            return end
        except Exception:
            if end - start == 1:
                self.failed += 1
                log.exception("database write failed: %s", batch[start][0])
                return end
        for k in range(start, end):
            await self._transaction(database, [batch[k]], 0)
        return end

    async def close(self, timeout: float = 5.0) -> None:
        """Write what is queued (bounded by ``timeout``), then stop."""
        thread, self._thread = self._thread, None
        if thread is None:
            return
        with contextlib.suppress(queue.Full):  # full and stuck: the join below times out
            await asyncio.to_thread(self._queue.put, None, True, timeout)
        await asyncio.to_thread(thread.join, timeout)
        if thread.is_alive():
            self._abandon = True
            log.error("shutdown: %d database writes not done", self._queue.qsize())
