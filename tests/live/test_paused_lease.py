"""A device whose lease is not surely held drops what waits (never processes it), counts
it, and gives its bytes back to the ingest budget all devices share."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from backend.db.engine import Database
from backend.live.budget import IngestBudget
from backend.live.devices import DeviceStats
from backend.live.hub import Hub
from backend.live.ingest import RawMessage
from backend.live.store import DbWriter
from backend.live.worker import DeviceWorker, Scheduler


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.mark.anyio
async def test_paused_lease_drops_counts_and_frees_the_budget(tmp_path: Path) -> None:
    budget = IngestBudget(1 << 20)
    stats = DeviceStats("d1")
    w = DeviceWorker(
        "d1",
        stats,
        scheduler=Scheduler(),
        prefix="rehab",
        zio=None,
        hub=Hub(30.0, 16),
        db=DbWriter(Database(f"sqlite+aiosqlite:///{tmp_path / 'db.sqlite'}")),
        max_items=100,
        max_bytes=1 << 20,
        on_change=lambda _: None,
        budget=budget,
    )
    held = False
    w.set_lease("A", 1, lambda: held)
    for i in range(5):
        w.offer(RawMessage("rehab/d1/imu", b"x" * 1000, 1000, float(i), "imu"))
    assert budget.used == 5000 and w.queued == 5
    await asyncio.sleep(0.01)  # the scheduler's round: the lease is paused
    assert w.queued == 0 and stats.accepted == 0
    assert stats.rejected == {"lease_paused": 5}
    assert budget.used == 0
