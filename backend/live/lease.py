"""Device leases: exactly one worker runs a device's pipeline at a time.

The authority is one database row per device (``device_leases``: holder, epoch, expiry),
changed only by single conditional statements, so SQLite (one machine) and PostgreSQL
(several) both decide races without any lock of ours:

- take: ``UPDATE … SET holder=me, epoch=epoch+1, expires_at=now+TTL WHERE device=d AND
  expires_at <= now`` — one winner per expiry, and a new epoch (the fencing token);
- renew: ``UPDATE … SET expires_at=now+TTL WHERE holder=me AND expires_at > now`` — one
  statement for all the worker's devices; a lease that expired is never revived;
- fence: every database write of a device's outputs runs in a transaction that first reads
  the row (``FOR UPDATE`` on PostgreSQL) and drops the write unless holder and epoch are
  still the writer's (:func:`holds`).

Self-expiry: a worker counts its lease from the moment it *sent* the renewal, on its
monotonic clock, and stops processing and publishing the device ``MARGIN_S`` before the row
can expire. A worker cut off from the database therefore goes quiet before any other can
take its devices. (Wall clocks of the machines must agree within the margin: NTP does.)

Zenoh liveliness (``<prefix>/@worker/<id>``) only spreads devices: a worker tries at once
for the devices that rendezvous hashing over the live workers gives it, and for the others
after a delay growing with its rank (so a dead or overloaded first choice costs little).
"""

from __future__ import annotations

import hashlib
import os
import socket
import threading
import time
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import Connection, Engine, create_engine, event, select, update
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.engine import make_url
from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.engine import _sqlite_pragmas
from backend.db.models import DeviceLease

TTL_S = 1.2  # a dead worker's devices are free this long after its last renewal
RENEW_S = 0.2  # renewal (and free-device) period
MARGIN_S = 0.3  # a holder stops this long before its row can expire (skew, a late put)
RANK_DELAY_S = 0.3  # the n-th choice of rendezvous hashing tries n × this late


def new_holder_id() -> str:
    """``<host>-<pid>-<random>``: unique per process start, and says where it runs."""
    host = "".join(c for c in socket.gethostname() if c.isalnum() or c in "-_.")[:32]
    return f"{host or 'worker'}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def _insert_free(pg: bool, device: str) -> Any:
    ins = (pg_insert if pg else sqlite_insert)(DeviceLease).values(
        device=device, holder="", epoch=0, expires_at=0.0
    )
    return ins.on_conflict_do_nothing(index_elements=["device"])


def _take(device: str, holder: str, now: float, ttl: float) -> Any:
    return (
        update(DeviceLease)
        .where(DeviceLease.device == device, DeviceLease.expires_at <= now)
        .values(holder=holder, epoch=DeviceLease.epoch + 1, expires_at=now + ttl)
        .returning(DeviceLease.epoch)
    )


def _extend(holder: str, now: float, ttl: float) -> Any:
    return (
        update(DeviceLease)
        .where(DeviceLease.holder == holder, DeviceLease.expires_at > now)
        .values(expires_at=now + ttl)
        .returning(DeviceLease.device, DeviceLease.epoch)
    )


_ALL = select(DeviceLease.device, DeviceLease.holder, DeviceLease.epoch, DeviceLease.expires_at)


async def acquire(
    db: AsyncSession, device: str, holder: str, now: float, ttl: float = TTL_S
) -> int | None:
    """Take ``device`` if its lease is free or expired; return the new epoch, else None."""
    await db.execute(_insert_free(db.get_bind().dialect.name == "postgresql", device))
    epoch = await db.scalar(_take(device, holder, now, ttl))
    return None if epoch is None else int(epoch)


async def renew(db: AsyncSession, holder: str, now: float, ttl: float = TTL_S) -> dict[str, int]:
    """Extend every unexpired lease of ``holder``; return them (device → epoch)."""
    rows = await db.execute(_extend(holder, now, ttl))
    return {d: int(e) for d, e in rows.all()}


# The same on a blocking connection: a worker keeps its leases from a thread of its own, so
# a busy event loop (the pipelines) never delays a renewal into a false expiry.


def acquire_sync(
    conn: Connection, device: str, holder: str, now: float, ttl: float = TTL_S
) -> int | None:
    conn.execute(_insert_free(conn.dialect.name == "postgresql", device))
    epoch = conn.scalar(_take(device, holder, now, ttl))
    return None if epoch is None else int(epoch)


def renew_sync(conn: Connection, holder: str, now: float, ttl: float = TTL_S) -> dict[str, int]:
    return {d: int(e) for d, e in conn.execute(_extend(holder, now, ttl)).all()}


def release_sync(conn: Connection, holder: str, devices: Iterable[str]) -> None:
    conn.execute(
        update(DeviceLease)
        .where(DeviceLease.holder == holder, DeviceLease.device.in_(list(devices)))
        .values(expires_at=0.0)
    )


def table_sync(conn: Connection) -> dict[str, tuple[str, int, float]]:
    return {d: (h, int(e), float(x)) for d, h, e, x in conn.execute(_ALL).all()}


def _unexpired(rows: dict[str, tuple[str, int, float]], now: float | None) -> list[str]:
    now = time.time() if now is None else now
    return [d for d, (_, _, x) in rows.items() if x > now]


def held_devices_sync(conn: Connection, now: float | None = None) -> list[str]:
    """:func:`held_devices` on a blocking connection."""
    return _unexpired(table_sync(conn), now)


def sync_engine(async_url: str) -> Engine:
    """A blocking engine on the same database (sqlite+aiosqlite → sqlite; psycopg is both)."""
    url = make_url(async_url)
    if url.drivername == "sqlite+aiosqlite":
        url = url.set(drivername="sqlite")
    engine = create_engine(url, pool_size=1, pool_pre_ping=True)
    if engine.dialect.name == "sqlite":
        event.listen(engine, "connect", _sqlite_pragmas)
    return engine


async def release(db: AsyncSession, holder: str, devices: Iterable[str] | None = None) -> None:
    """Give leases up now (a clean stop): the others need not wait for the expiry."""
    stmt = update(DeviceLease).where(DeviceLease.holder == holder)
    if devices is not None:
        stmt = stmt.where(DeviceLease.device.in_(list(devices)))
    await db.execute(stmt.values(expires_at=0.0))


async def holds(db: AsyncSession, device: str, holder: str, epoch: int) -> bool:
    """Inside a write transaction: is ``holder`` still the holder at ``epoch``? PostgreSQL
    locks the row until the commit, so no takeover can slip in between (SQLite's single
    writer and WAL snapshot do the same: a takeover committed since our read fails our
    commit)."""
    stmt = select(DeviceLease.holder, DeviceLease.epoch).where(DeviceLease.device == device)
    if db.get_bind().dialect.name == "postgresql":
        stmt = stmt.with_for_update()
    row = (await db.execute(stmt)).first()
    return row is not None and row[0] == holder and int(row[1]) == epoch


async def table(db: AsyncSession) -> dict[str, tuple[str, int, float]]:
    rows = await db.execute(_ALL)
    return {d: (h, int(e), float(x)) for d, h, e, x in rows.all()}


async def held_devices(db: AsyncSession, now: float | None = None) -> list[str]:
    """Devices whose lease has not expired: a worker is running them."""
    return _unexpired(await table(db), now)


def rank(device: str, me: str, workers: Sequence[str]) -> int:
    """My place for ``device`` in rendezvous (highest-random-weight) hashing over the live
    workers: 0 = first choice. Every worker computes the same order."""

    def weight(w: str) -> bytes:
        return hashlib.blake2b(f"{device}/{w}".encode(), digest_size=8).digest()

    order = sorted({*workers, me}, key=weight, reverse=True)
    return order.index(me)


@dataclass
class Held:
    """A worker's view of its leases, on its monotonic clock."""

    holder: str = field(default_factory=new_holder_id)
    epochs: dict[str, int] = field(default_factory=dict)
    deadlines: dict[str, float] = field(default_factory=dict)  # monotonic: stop by then
    lock: threading.Lock = field(default_factory=threading.Lock)  # the lease thread's and loop's

    def valid(self, device: str, now_mono: float | None = None) -> bool:
        deadline = self.deadlines.get(device)
        if deadline is None:
            return False
        return (time.monotonic() if now_mono is None else now_mono) < deadline

    def granted(self, device: str, epoch: int, sent_mono: float, ttl: float = TTL_S) -> None:
        with self.lock:
            self.deadlines[device] = sent_mono + ttl - MARGIN_S
            self.epochs[device] = epoch

    def renewed(self, device: str, epoch: int, sent_mono: float, ttl: float = TTL_S) -> bool:
        """Extend, unless the device was dropped (or re-taken) meanwhile."""
        with self.lock:
            if self.epochs.get(device) != epoch:
                return False
            self.deadlines[device] = sent_mono + ttl - MARGIN_S
            return True

    def drop(self, device: str) -> None:
        with self.lock:
            self.epochs.pop(device, None)
            self.deadlines.pop(device, None)
