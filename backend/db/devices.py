"""The device registry, written by the Zenoh ingest and read by the REST layer."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import delete, func, select, update
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.base import utcnow
from backend.db.models import Device, Session

REMOVED = "removed"  # key in a kept row's stats: an administrator removed the device


async def touch_device(
    db: AsyncSession,
    name: str,
    *,
    seen_at: datetime | None = None,
    stats: dict[str, Any] | None = None,
) -> None:
    """Register ``name`` on first sight, else mark it online and seen at ``seen_at`` (now).

    One upsert statement, so concurrent callers never collide on the unique name. ``stats``
    (rates, rejected-message counters, ...) replaces the stored snapshot when given. Meant to
    be called about once a second per device, not per message.
    """
    await touch_devices(db, [(name, seen_at or utcnow(), stats)])


async def touch_devices(
    db: AsyncSession, rows: Sequence[tuple[str, datetime, dict[str, Any] | None]]
) -> None:
    """:func:`touch_device` of many devices ``(name, seen_at, stats)`` in one statement: a
    live writer holds the database's write lock for one round trip, not one per device.
    ``stats`` is given for every row or for none."""
    by_name = {name: (seen, stats) for name, seen, stats in rows}  # one row per name
    if not by_name:
        return
    with_stats = next(iter(by_name.values()))[1] is not None
    values = [
        {
            "name": name,
            "first_seen": seen,
            "last_seen": seen,
            "status": "online",
            **({"stats": stats} if with_stats else {}),
        }
        for name, (seen, stats) in by_name.items()
    ]
    pg = db.get_bind().dialect.name == "postgresql"
    stmt = (pg_insert if pg else sqlite_insert)(Device).values(values)
    # never back in time: writers queue their snapshots, so an older one can land last
    newest = func.greatest if pg else func.max  # SQLite: its two-argument max() (ISO text)
    changes: dict[str, Any] = {
        "last_seen": newest(Device.last_seen, stmt.excluded.last_seen),
        "status": "online",
    }
    if with_stats:
        changes["stats"] = stmt.excluded.stats
    await db.execute(stmt.on_conflict_do_update(index_elements=["name"], set_=changes))


async def mark_device_offline(db: AsyncSession, name: str) -> None:
    """For the ingest when a device's liveliness token disappears."""
    await db.execute(update(Device).where(Device.name == name).values(status="offline"))


async def mark_all_devices_offline(db: AsyncSession) -> None:
    """At start: whatever a previous run saw is stale until data arrives again."""
    await db.execute(update(Device).values(status="offline"))


async def get_device(db: AsyncSession, name: str) -> Device | None:
    return await db.scalar(select(Device).where(Device.name == name))


def is_online(device: Device, offline_after_s: float, now: datetime | None = None) -> bool:
    """Online = the ingest says so and data arrived recently (covers a dead ingest task)."""
    now = now or utcnow()
    return device.status == "online" and now - device.last_seen <= timedelta(
        seconds=offline_after_s
    )


def is_removed(device: Device) -> bool:
    return bool(device.stats and device.stats.get(REMOVED))


async def registered_devices(db: AsyncSession) -> list[str]:
    """Names an administrator admitted (or the ingest registered): not removed ones."""
    return [d.name for d in await db.scalars(select(Device)) if not is_removed(d)]


async def remove_device(db: AsyncSession, name: str) -> None:
    """Forget ``name``: its row goes, unless sessions refer to it; then it stays for their
    history, offline and marked removed (a later admission replaces the mark)."""
    device = await get_device(db, name)
    if device is None:
        return
    used = await db.scalar(select(func.count()).where(Session.device_id == device.id))
    if used:
        device.status = "offline"
        device.stats = {REMOVED: utcnow().isoformat()}
    else:
        await db.execute(delete(Device).where(Device.id == device.id))
