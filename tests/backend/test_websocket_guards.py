"""The guards also protect WebSocket routes (the live feeds are added by the pipeline side):
a therapist by cookie or bearer header, an overlay by the token in its first message (never
in the URL: a token in the query is refused as an old link); refusals close 1008."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
from fastapi import WebSocket
from starlette.websockets import WebSocketDisconnect

from backend.app import create_app
from backend.auth.guards import CurrentTherapist, OverlayAccess
from backend.db.devices import touch_device
from backend.deps import AppState
from backend.settings import Settings

with warnings.catch_warnings():  # newer starlette nags about its httpx-based client
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient


def test_guards_on_websockets(tmp_path: Path) -> None:
    app = create_app(Settings(data_dir=tmp_path))

    @app.websocket("/ws/therapist")
    async def therapist_feed(websocket: WebSocket, therapist: CurrentTherapist) -> None:
        await websocket.accept()
        # The guard must not pin a database connection for the life of the socket.
        pinned = app.state.rehab.database.engine.pool.checkedout()
        await websocket.send_json({"user": therapist.username, "pinned": pinned})
        await websocket.close()

    @app.websocket("/ws/overlay")
    async def overlay_feed(websocket: WebSocket, grant: OverlayAccess) -> None:
        # (accepted by the guard, which read the token from the first message)
        await websocket.send_json({"device": grant.device, "session": grant.session_id})
        await websocket.close()

    with TestClient(app, base_url="https://testserver") as client:
        state: AppState = app.state.rehab
        assert state.first_admin is not None

        async def register_device() -> None:
            async with state.database.transaction() as db:
                await touch_device(db, "dev")

        client.portal.call(register_device)  # type: ignore[union-attr]
        r = client.post(
            "/api/auth/login", json={"username": "admin", "password": state.first_admin.password}
        )
        token = r.json()["access_token"]
        pid = client.post("/api/patients", json={"code": "X", "affected_side": "left"}).json()
        sid = client.post("/api/sessions", json={"patient_id": pid["id"], "device": "dev"}).json()
        link = client.post(f"/api/sessions/{sid['id']}/overlay-link").json()
        client.cookies.clear()

        for headers in ({"Cookie": f"rehab_session={token}"}, {"Authorization": f"Bearer {token}"}):
            with client.websocket_connect("/ws/therapist", headers=headers) as ws:
                assert ws.receive_json() == {"user": "admin", "pinned": 0}
        with client.websocket_connect("/ws/overlay") as ws:
            ws.send_json({"type": "auth", "token": link["token"]})
            assert ws.receive_json() == {"device": "dev", "session": sid["id"]}

        refused = [
            ("/ws/therapist", {}, None),
            ("/ws/therapist", {"Authorization": f"Bearer {link['token']}"}, None),
            ("/ws/overlay", {}, {"type": "auth", "token": token}),
            ("/ws/overlay", {}, {"type": "auth", "token": "forged"}),
            ("/ws/overlay", {}, {"token": link["token"]}),
            ("/ws/overlay", {}, [link["token"]]),
            (f"/ws/overlay?token={link['token']}", {}, None),  # an old link: token in the URL
        ]
        for path, headers, first in refused:
            with (
                pytest.raises(WebSocketDisconnect) as exc,
                client.websocket_connect(path, headers=headers) as ws,
            ):
                if first is not None:
                    ws.send_json(first)
                ws.receive_json()
            assert exc.value.code == 1008, path
            if "?token=" in path:
                assert "old form" in exc.value.reason
