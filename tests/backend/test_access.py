"""Without credentials nothing but the allow-list answers; an overlay token opens nothing
but its own live feed. Routes are enumerated from the app itself, so new ones are covered."""

from __future__ import annotations

import re
from datetime import datetime, timedelta

import httpx
import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute

from backend.auth.guards import OverlayDenied, verify_overlay_token
from backend.db.base import utcnow
from backend.db.devices import touch_device
from backend.deps import AppState
from estimators import aot

pytestmark = pytest.mark.anyio

# Reachable without credentials; none of them returns patient data.
PUBLIC = {("GET", "/api/health"), ("POST", "/api/auth/login")}
DOCS = {"/api/openapi.json", "/api/docs", "/api/docs/oauth2-redirect"}
# Routes an overlay token may use (HTTP ones; the live feed is a WebSocket, not in OpenAPI).
OVERLAY_ROUTES: set[tuple[str, str]] = set()


def operations(app: FastAPI) -> list[tuple[str, str]]:
    return [
        (method.upper(), path)
        for path, ops in app.openapi()["paths"].items()
        for method in ops
        if method in {"get", "post", "put", "patch", "delete"}
    ]


def concrete(path: str) -> str:
    # Any value will do: authentication must fail before the object is looked up.
    return re.sub(r"\{[^}]+\}", "1", path)


async def call(client: httpx.AsyncClient, method: str, path: str, **kw: object) -> httpx.Response:
    body: dict[str, object] | None = {} if method in {"POST", "PUT", "PATCH"} else None
    return await client.request(method, concrete(path), json=body, **kw)  # type: ignore[arg-type]


async def test_every_route_is_in_the_openapi(app: FastAPI) -> None:
    documented = {path for _, path in operations(app)}
    for route in app.routes:
        if isinstance(route, APIRoute) and route.path not in DOCS:
            assert route.path in documented, f"{route.path} is hidden from the OpenAPI"


async def test_no_credentials_no_access(app: FastAPI, client: httpx.AsyncClient) -> None:
    ops = operations(app)
    assert len(ops) >= 20
    for method, path in ops:
        r = await call(client, method, path)
        if (method, path) in PUBLIC:
            assert r.status_code != 401, (method, path)
        else:
            assert r.status_code == 401, (method, path, r.status_code, r.text)
            assert r.headers.get("www-authenticate") == "Bearer"


async def test_docs_and_health_are_public(client: httpx.AsyncClient) -> None:
    assert (await client.get("/api/openapi.json")).status_code == 200
    # Swagger UI loads from a CDN: off by default (settings.api_docs, test_security.py).
    assert (await client.get("/api/docs")).status_code == 404
    health = await client.get("/api/health")
    assert health.status_code == 200
    assert set(health.json()) == {"status", "version", "database", "estimators"}
    assert health.json()["estimators"] == aot.mode()
    assert health.json()["database"] == "ok"


async def test_garbage_tokens_are_rejected(app: FastAPI, client: httpx.AsyncClient) -> None:
    for token in ("x", "a.b.c", "Bearer", "null"):
        r = await client.get("/api/patients", headers={"Authorization": f"Bearer {token}"})
        assert r.status_code == 401
        client.cookies.set("rehab_session", token)
        assert (await client.get("/api/patients")).status_code == 401
        client.cookies.clear()


async def start_session(
    client: httpx.AsyncClient, state: AppState, admin: dict[str, str], device: str
) -> int:
    async with state.database.transaction() as db:
        await touch_device(db, device)
    r = await client.post(
        "/api/patients", json={"code": f"P-{device}", "affected_side": "left"}, headers=admin
    )
    assert r.status_code == 201, r.text
    r = await client.post(
        "/api/sessions", json={"patient_id": r.json()["id"], "device": device}, headers=admin
    )
    assert r.status_code == 201, r.text
    session_id: int = r.json()["id"]
    return session_id


async def overlay_link(client: httpx.AsyncClient, admin: dict[str, str], session_id: int) -> str:
    r = await client.post(f"/api/sessions/{session_id}/overlay-link", headers=admin)
    assert r.status_code == 201, r.text
    body = r.json()
    # the token after "#": browsers never send the fragment, so no request line carries it
    assert body["path"] == f"/overlay#token={body['token']}"
    token: str = body["token"]
    return token


async def test_overlay_token_opens_no_route(
    app: FastAPI, client: httpx.AsyncClient, state: AppState, admin: dict[str, str]
) -> None:
    session_id = await start_session(client, state, admin, "dev-a")
    token = await overlay_link(client, admin, session_id)
    # Control: a cookie set this way does reach the app (a therapist's token passes).
    client.cookies.set(state.settings.cookie_name, admin["Authorization"].removeprefix("Bearer "))
    assert (await client.get("/api/auth/me")).status_code == 200
    client.cookies.clear()
    for method, path in operations(app):
        if (method, path) in PUBLIC | OVERLAY_ROUTES:
            continue
        as_bearer = await call(client, method, path, headers={"Authorization": f"Bearer {token}"})
        assert as_bearer.status_code == 401, (method, path, as_bearer.status_code)
        as_query = await call(client, method, path, params={"token": token})
        assert as_query.status_code == 401, (method, path, as_query.status_code)
        client.cookies.set(state.settings.cookie_name, token)
        as_cookie = await call(client, method, path)
        client.cookies.clear()
        assert as_cookie.status_code == 401, (method, path, as_cookie.status_code)


async def test_overlay_token_is_bound_to_its_session_and_device(
    client: httpx.AsyncClient, state: AppState, admin: dict[str, str]
) -> None:
    sid_a = await start_session(client, state, admin, "dev-a")
    sid_b = await start_session(client, state, admin, "dev-b")
    token = await overlay_link(client, admin, sid_a)
    assert await verify_overlay_token(state, token) == ("dev-a", sid_a)

    # Forged claims: right key, wrong device or another session.
    for device, sid in (("dev-b", sid_a), ("dev-a", sid_b)):
        forged = state.signer.issue_overlay(device, sid, 60).token
        with pytest.raises(OverlayDenied):
            await verify_overlay_token(state, forged)
    # Wrong kind of token, tampered, expired.
    with pytest.raises(OverlayDenied):
        await verify_overlay_token(state, admin["Authorization"].removeprefix("Bearer "))
    with pytest.raises(OverlayDenied):
        await verify_overlay_token(state, token[:-2] + ("A" if token[-2] != "A" else "B") + "x")
    with pytest.raises(OverlayDenied):
        await verify_overlay_token(state, state.signer.issue_overlay("dev-a", sid_a, -1).token)
    link = (await client.post(f"/api/sessions/{sid_a}/overlay-link", headers=admin)).json()
    expected = utcnow() + timedelta(seconds=state.settings.overlay_token_ttl_s)
    assert abs(datetime.fromisoformat(link["expires_at"]) - expected) < timedelta(minutes=1)

    # Stopping the session revokes every link to it.
    assert (await client.post(f"/api/sessions/{sid_a}/stop", headers=admin)).status_code == 200
    with pytest.raises(OverlayDenied):
        await verify_overlay_token(state, token)
    r = await client.post(f"/api/sessions/{sid_a}/overlay-link", headers=admin)
    assert r.status_code == 409
