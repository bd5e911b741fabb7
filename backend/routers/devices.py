"""The device registry as the ingest fills it (see :func:`backend.db.devices.touch_device`)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, status
from sqlalchemy import select

from backend.db.base import utcnow
from backend.db.devices import is_online
from backend.db.models import Device, Session
from backend.deps import DB, SettingsDep
from backend.schemas.devices import DeviceOut

router = APIRouter(prefix="/devices", tags=["devices"])


async def _devices(db: DB, settings: SettingsDep, name: str | None = None) -> list[DeviceOut]:
    stmt = (
        select(Device, Session.id)
        .outerjoin(Session, (Session.device_id == Device.id) & (Session.status == "active"))
        .order_by(Device.name)
    )
    if name is not None:
        stmt = stmt.where(Device.name == name)
    now = utcnow()
    return [
        DeviceOut(
            name=device.name,
            first_seen=device.first_seen,
            last_seen=device.last_seen,
            status="online"
            if is_online(device, settings.device_offline_after_s, now)
            else "offline",
            stats=device.stats,
            active_session_id=session_id,
        )
        for device, session_id in await db.execute(stmt)
    ]


@router.get("")
async def list_devices(db: DB, settings: SettingsDep) -> list[DeviceOut]:
    return await _devices(db, settings)


@router.get("/{name}")
async def read_device(name: str, db: DB, settings: SettingsDep) -> DeviceOut:
    found = await _devices(db, settings, name)
    if not found:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "device not found")
    return found[0]
