"""The 3D view (viser) for the dashboard: where it is, and which device it shows.

Included by ``backend.app`` behind the therapist guard (not through ``api_router``, whose
module belongs to the REST layer). The viser server starts on the first request.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, status
from pydantic import BaseModel
from sqlalchemy import select
from starlette.requests import HTTPConnection

from backend.auth.guards import current_therapist
from backend.db.models import Device, Session
from backend.deps import DB
from backend.schemas.common import DeviceName, Strict
from backend.viz import Viz

router = APIRouter(prefix="/api/viz", tags=["viz"], dependencies=[Depends(current_therapist)])


class VizOut(BaseModel):
    enabled: bool
    port: int | None
    path: str | None = None  # set when the view is proxied under the API's own origin
    device: str | None


class VizSelect(Strict):
    device: DeviceName


def get_viz(conn: HTTPConnection) -> Viz:
    viz: Viz | None = getattr(conn.app.state, "viz", None)
    if viz is None:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, "3D view not running")
    return viz


VizDep = Annotated[Viz, Depends(get_viz)]


def _out(viz: Viz) -> VizOut:
    return VizOut(enabled=viz.enabled, port=viz.port, device=viz.selected)


@router.get("")
async def viz_info(viz: VizDep) -> VizOut:
    """Start the 3D view if needed; its port (the dashboard embeds it in a frame)."""
    viz.start()
    return _out(viz)


@router.put("/device")
async def viz_select(body: VizSelect, viz: VizDep, db: DB) -> VizOut:
    """Show this device in the 3D view (one device at a time per service)."""
    params = await db.scalar(
        select(Session.params)
        .join(Session.device)
        .where(Device.name == body.device, Session.status == "active")
        .order_by(Session.id.desc())
        .limit(1)
    )
    await db.commit()
    if isinstance(params, dict):
        viz.configure(
            body.device,
            tolerance_m=params.get("tolerance_m"),
            cuff_to_elbow_m=params.get("cuff_to_elbow_m"),
            imu_to_elbow_m=params.get("imu_to_elbow_m"),
        )
    viz.start()
    viz.select(body.device)
    return _out(viz)
