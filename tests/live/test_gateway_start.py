"""A session start on an API node (``--workers``) with SQLite returns at once: the request's
transaction holds the database's one write lock until it does, and the workers' lease
renewals need that lock (waiting up to a second for the holder per start, 50 starts in a row
kept renewals waiting 2 s and leases were lost)."""

from __future__ import annotations

import socket
import time
from datetime import UTC, datetime
from pathlib import Path

import pytest

from backend.db.engine import Database
from backend.deps import SessionInfo
from backend.live.budget import DEVICE_FLOOR_BYTES
from backend.live.gateway import Gateway, worker_command
from backend.settings import Settings


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@pytest.mark.anyio
async def test_session_start_does_not_wait_for_a_holder_on_sqlite(tmp_path: Path) -> None:
    settings = Settings(
        data_dir=tmp_path / "data",
        database_url=f"sqlite+aiosqlite:///{tmp_path / 'db.sqlite'}",
        zenoh_listen=f"tcp/127.0.0.1:{_free_port()}",
    )
    database = Database(settings.db_url)
    await database.migrate()
    node = Gateway(settings, database, workers=0)
    await node.start()
    try:
        assert node.zio is not None  # a real Zenoh session: the start query finds no holder
        info = SessionInfo(id=7, device="d1", patient_id=1, params={}, started_at=datetime.now(UTC))
        t0 = time.monotonic()
        path = await node.session_started(info)
        took = time.monotonic() - t0
        assert path is not None and "7" in path
        assert took < 0.5, took  # the holder is asked after the commit (session_committed)
    finally:
        await node.close()
        await database.dispose()


def test_local_workers_share_the_ingest_budget(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The node's ingest budget is the machine's: with ``--workers 2`` each local worker
    queues at most half of it (each had all of it: twice the budget under a flood)."""
    settings = Settings(data_dir=tmp_path, ingest_max_bytes=64 << 20)
    _, env = worker_command(settings, "tcp/127.0.0.1:7447", workers=2)
    for name in ("REHAB_INGEST_MAX_BYTES", "REHAB_DATA_DIR"):
        monkeypatch.setenv(name, env[name])
    assert Settings().ingest_max_bytes == 32 << 20  # what the worker process reads
    _, env = worker_command(settings, "tcp/127.0.0.1:7447", workers=200)
    assert int(env["REHAB_INGEST_MAX_BYTES"]) == DEVICE_FLOOR_BYTES  # never below a floor
