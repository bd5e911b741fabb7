"""The 3D view (viser) for the dashboard: where it is, which device it shows, and the view
itself through an authenticated proxy.

Included by ``backend.app`` behind the therapist guard (not through ``api_router``, whose
module belongs to the REST layer). The viser server starts on the first request, bound to
loopback: a patient's live arm is patient data, so browsers reach it only through
``/api/viz/view/`` (its page over HTTP, its scene over a WebSocket), as a logged-in
therapist, from the service's own origin; the socket closes when that login ends.
"""

from __future__ import annotations

import asyncio
import contextlib
from typing import Annotated

import httpx
from fastapi import (
    APIRouter,
    Depends,
    HTTPException,
    Response,
    WebSocket,
    WebSocketException,
    status,
)
from pydantic import BaseModel
from sqlalchemy import select
from starlette.requests import HTTPConnection
from websockets.asyncio.client import connect as ws_connect
from websockets.typing import Subprotocol

from backend.auth.guards import CurrentTherapist, current_therapist, login_still_valid
from backend.db.audit import audit
from backend.db.models import Device, Session
from backend.deps import DB, State
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


VIEW_PATH = "/api/viz/view/"
_HOP_BY_HOP = frozenset({"content-encoding", "content-length", "transfer-encoding", "connection"})


def _out(viz: Viz) -> VizOut:
    # The port is not reachable from browsers (loopback): the dashboard frames the path.
    return VizOut(enabled=viz.enabled, port=viz.port, path=VIEW_PATH, device=viz.selected)


@router.get("/view/{path:path}", include_in_schema=False)
async def viz_view(path: str, viz: VizDep) -> Response:
    """viser's page (one self-contained HTML file) and anything it asks for, from loopback."""
    port = viz.start()
    if port is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "3D view switched off")
    async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=10) as upstream:
        r = await upstream.get("/" + path, headers={"Accept-Encoding": "identity"})
    headers = {k: v for k, v in r.headers.items() if k.lower() not in _HOP_BY_HOP}
    return Response(r.content, status_code=r.status_code, headers=headers)


@router.websocket("/view")  # viser's client connects to its page's URL without the slash
@router.websocket("/view/{path:path}")
async def viz_socket(
    websocket: WebSocket, therapist: CurrentTherapist, state: State, viz: VizDep
) -> None:
    """viser's scene stream, relayed both ways (binary msgpack frames)."""
    port = viz.start()
    if port is None:
        raise WebSocketException(status.WS_1008_POLICY_VIOLATION, "3D view switched off")
    login_id: str = websocket.state.login_id
    async with state.database.transaction() as db:
        audit(db, therapist, "viz.view", f"device:{viz.selected}" if viz.selected else None)
    offered = list(websocket.scope.get("subprotocols", []))
    async with ws_connect(
        f"ws://127.0.0.1:{port}/",
        subprotocols=[Subprotocol(p) for p in offered] or None,
        max_size=None,
        compression=None,
    ) as upstream:
        await websocket.accept(subprotocol=upstream.subprotocol)
        ended = asyncio.Event()
        reason = ["login ended"]

        def revoke(why: str) -> None:
            reason[0] = why
            ended.set()

        state.sockets.add(therapist.id, login_id, revoke)

        async def down() -> None:
            async for message in upstream:
                if isinstance(message, bytes):
                    await websocket.send_bytes(message)
                else:
                    await websocket.send_text(message)

        async def up() -> None:
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    return
                if message.get("bytes") is not None:
                    await upstream.send(message["bytes"])
                elif message.get("text") is not None:
                    await upstream.send(message["text"])

        async def recheck() -> None:
            while not ended.is_set():
                await asyncio.sleep(state.settings.ws_recheck_s)
                if not await login_still_valid(state, therapist.id, login_id):
                    revoke("login ended")

        async def revoked() -> None:
            await ended.wait()

        tasks = [asyncio.create_task(t()) for t in (down, up, recheck, revoked)]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            state.sockets.remove(login_id, revoke)
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        if ended.is_set():
            with contextlib.suppress(Exception):
                await websocket.close(status.WS_1008_POLICY_VIOLATION, reason[0])
        else:
            with contextlib.suppress(Exception):
                await websocket.close()


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
