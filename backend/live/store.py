"""Database writes of the live side, off the pipelines' path.

Workers submit small operations (a completed cycle, the device registry snapshot, a nominal
shoulder); one task runs whatever has queued in a single transaction. If that transaction
fails, each operation is retried alone, so one bad row cannot take the others with it.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.engine import Database

log = logging.getLogger(__name__)

Op = Callable[[AsyncSession], Awaitable[Any]]
Fence = tuple[str, str, int]  # (device, lease holder, epoch): see backend.live.lease
MAX_BATCH = 500


class DbWriter:
    def __init__(self, database: Database, maxsize: int = 10_000) -> None:
        self.database = database
        self._queue: asyncio.Queue[tuple[str, Op, Fence | None] | None] = asyncio.Queue(maxsize)
        self._task: asyncio.Task[None] | None = None
        self.dropped = 0
        self.failed = 0
        self.fenced = 0  # writes refused: the device's lease had moved on

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="live-db-writer")

    def submit(self, what: str, op: Op, fence: Fence | None = None) -> None:
        """``fence``: written only while that lease holder still holds the device at that
        epoch (checked in the write's own transaction)."""
        try:
            self._queue.put_nowait((what, op, fence))
        except asyncio.QueueFull:
            self.dropped += 1
            log.error("database writes are backed up; dropped %s", what)

    async def _run(self) -> None:
        while True:
            first = await self._queue.get()
            if first is None:
                return
            batch = [first]
            last = False
            while not self._queue.empty() and len(batch) < MAX_BATCH:
                item = self._queue.get_nowait()
                if item is None:
                    last = True
                    break
                batch.append(item)
            await self._write(batch)
            if last:
                return

    async def _write(self, batch: list[tuple[str, Op, Fence | None]]) -> None:
        from backend.live.lease import holds

        try:
            async with self.database.transaction() as db:
                ok: dict[Fence, bool] = {}
                for what, op, fence in batch:
                    if fence is not None:
                        if fence not in ok:
                            ok[fence] = await holds(db, *fence)
                        if not ok[fence]:
                            self.fenced += 1
                            log.warning("not written, lease lost: %s", what)
                            continue
                    await op(db)
            return
        except Exception:
            if len(batch) == 1:
                self.failed += 1
                log.exception("database write failed: %s", batch[0][0])
                return
        for item in batch:
            await self._write([item])

    async def close(self, timeout: float = 5.0) -> None:
        """Write what is queued (bounded by ``timeout``), then stop."""
        task, self._task = self._task, None
        if task is None:
            return
        try:
            await asyncio.wait_for(self._queue.put(None), timeout)
            await asyncio.wait_for(task, timeout)
        except TimeoutError:
            log.error("shutdown: %d database writes not done", self._queue.qsize())
            task.cancel()
