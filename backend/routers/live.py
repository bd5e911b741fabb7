"""Live feeds over WebSocket: the therapists' dashboard and the patient's game overlay.

The message protocol is documented in :mod:`backend.live.feed`. Refusals (no or bad
credentials, an overlay link whose session ended) close with 1008; a service running
without its live side closes with 1013 (try again later). The overlay's token comes in the
socket's first message (:func:`backend.auth.guards.overlay_grant`), never in the URL.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from typing import Annotated

from fastapi import APIRouter, Query, WebSocket, WebSocketException, status
from starlette.websockets import WebSocketDisconnect

from backend.auth.guards import CurrentTherapist, OverlayAccess, login_still_valid
from backend.db.audit import audit
from backend.deps import State
from backend.live.hub import Client, dumps
from backend.live.manager import LiveManager
from backend.schemas.live import HelloMsg
from protocol import keys

router = APIRouter(tags=["live"])

MAX_FILTER = 256


def _manager(state: State) -> LiveManager:
    if not isinstance(state.live, LiveManager):
        raise WebSocketException(status.WS_1013_TRY_AGAIN_LATER, "live side not running")
    return state.live


def _ip(websocket: WebSocket) -> str:
    return websocket.client.host if websocket.client else "unknown"


def _device_filter(devices: str | None) -> list[str] | None:
    if devices is None:
        return None
    names = [d for d in (x.strip() for x in devices.split(",")) if d]
    if len(names) > MAX_FILTER or not all(keys.DEVICE_RE.fullmatch(d) for d in names):
        raise WebSocketException(status.WS_1008_POLICY_VIOLATION, "bad devices filter")
    return names


async def _pump(
    websocket: WebSocket, client: Client, recheck: Callable[[], Awaitable[bool]] | None = None
) -> None:
    """Send the client's queue; return when either side ends. ``recheck`` (a therapist's
    feed) runs every ``ws_recheck_s``: false closes the socket with 1008."""

    async def send() -> None:
        while True:
            text = await client.queue.get()
            if text is None:
                await websocket.close(client.close_code, client.close_reason)
                return
            await websocket.send_text(text)

    async def check() -> None:
        assert recheck is not None
        interval = websocket.app.state.rehab.settings.ws_recheck_s
        while True:
            await asyncio.sleep(interval)
            if not await recheck():
                client.revoke("login ended")

    async def receive() -> None:
        with contextlib.suppress(WebSocketDisconnect):
            while True:  # nothing is expected from the client; this notices it leaving
                msg = await websocket.receive()
                if msg["type"] == "websocket.disconnect":
                    return

    tasks = [asyncio.create_task(send()), asyncio.create_task(receive())]
    if recheck is not None:
        tasks.append(asyncio.create_task(check()))
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


@router.websocket("/ws/live")
async def live_feed(
    websocket: WebSocket,
    therapist: CurrentTherapist,
    state: State,
    devices: Annotated[str | None, Query(max_length=20_000)] = None,
) -> None:
    """Every device (or those in ``?devices=a,b``): hello, status, estimate, state, cycle."""
    manager = _manager(state)
    names = _device_filter(devices)
    login_id: str = websocket.state.login_id
    async with state.database.transaction() as db:  # a live view shows patient data
        audit(db, therapist, "live.view", None, {"devices": names, "ip": _ip(websocket)})
    await websocket.accept()
    client = manager.hub.connect(devices=names)
    state.sockets.add(therapist.id, login_id, client.revoke)
    try:
        hello: HelloMsg = {
            "type": "hello",
            "devices": names if names is not None else manager.device_names(),
        }
        client.send(dumps(hello))
        manager.send_initial(client)
        await _pump(websocket, client, lambda: login_still_valid(state, therapist.id, login_id))
    finally:
        state.sockets.remove(login_id, client.revoke)
        manager.hub.disconnect(client)


@router.websocket("/ws/overlay")
async def overlay_feed(websocket: WebSocket, grant: OverlayAccess, state: State) -> None:
    """One device during one session, as the overlay link allows: state, cycle, a minimal
    status and the rows the game draws."""
    manager = _manager(state)
    async with state.database.transaction() as db:
        audit(
            db,
            None,
            "overlay.view",
            f"session:{grant.session_id}",
            {"device": grant.device, "ip": _ip(websocket)},
        )
    # (accepted by the grant: its token comes in the first message, never in the URL)
    client = manager.hub.connect(overlay=(grant.device, grant.session_id))
    try:
        if not manager.is_running(grant.session_id, grant.device):
            client.send(None)  # stopped between the token check and now
        manager.send_initial(client)
        await _pump(websocket, client)
    finally:
        manager.hub.disconnect(client)
