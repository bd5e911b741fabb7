"""The device registry as the ingest fills it (see :func:`backend.db.devices.touch_device`)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Path, status
from sqlalchemy import select

from backend.auth.guards import AdminTherapist, require_admin
from backend.db.audit import audit
from backend.db.base import utcnow
from backend.db.devices import is_online, is_removed
from backend.db.models import Device, Session
from backend.deps import DB, LiveUnavailable, SettingsDep, State
from backend.live.manager import LiveManager
from backend.schemas.devices import DeviceOut
from protocol import keys

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
        if not is_removed(device)
    ]


@router.get("")
async def list_devices(db: DB, settings: SettingsDep) -> list[DeviceOut]:
    return await _devices(db, settings)


def _manager(state: State) -> LiveManager:
    live = state.live
    if not isinstance(live, LiveManager):
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, "no live service")
    return live


DeviceName = Path(pattern=f"^{keys.DEVICE_RE.pattern}$", max_length=64)


@router.get("/admission", dependencies=[Depends(require_admin)])
async def admission(state: State) -> dict[str, Any]:
    """The ``--admit`` globs and the names waiting for approval (in memory, bounded)."""
    return _manager(state).admission.snapshot()


@router.post("/{name}/admit", status_code=status.HTTP_201_CREATED)
async def admit_device(
    name: Annotated[str, DeviceName], admin: AdminTherapist, state: State, db: DB
) -> dict[str, str]:
    try:
        _manager(state).admit_device(name)
    except LiveUnavailable as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    audit(db, admin, "device.admit", f"device:{name}")
    await db.commit()
    return {"name": name, "status": "admitted"}


@router.delete("/{name}", status_code=status.HTTP_204_NO_CONTENT)
async def remove_device(
    name: Annotated[str, DeviceName], admin: AdminTherapist, state: State, db: DB
) -> None:
    if not _manager(state).remove_device(name):
        raise HTTPException(status.HTTP_409_CONFLICT, "the device is running a session")
    audit(db, admin, "device.remove", f"device:{name}")
    await db.commit()


@router.get("/{name}")
async def read_device(name: str, db: DB, settings: SettingsDep) -> DeviceOut:
    found = await _devices(db, settings, name)
    if not found:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "device not found")
    return found[0]
