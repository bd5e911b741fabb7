"""Login, tokens, cookies, rate limiting, the first admin and password storage."""

from __future__ import annotations

import stat
from datetime import datetime, timedelta

import httpx
import pytest
from fastapi import FastAPI
from sqlalchemy import select

from backend.app import create_app
from backend.auth.first_admin import read_admin_credentials
from backend.auth.passwords import verify_password
from backend.auth.ratelimit import LoginLimiter
from backend.auth.tokens import TokenSigner
from backend.db.base import utcnow
from backend.db.models import AuditLog, Therapist
from backend.deps import AppState
from backend.settings import Settings
from tests.backend.conftest import login

pytestmark = pytest.mark.anyio


async def audit_actions(state: AppState) -> list[tuple[str | None, str]]:
    async with state.database.session() as db:
        rows = await db.scalars(select(AuditLog).order_by(AuditLog.id))
        return [(a.actor, a.action) for a in rows]


async def test_first_admin_and_credentials_file(state: AppState, settings: Settings) -> None:
    creds = state.first_admin
    assert creds is not None and creds.username == "admin" and len(creds.password) >= 20
    path = settings.admin_credentials_file
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert read_admin_credentials(settings) == creds
    # A second start on the same data creates no other admin and keeps the file.
    again = create_app(settings)
    async with again.router.lifespan_context(again):
        assert again.state.rehab.first_admin is None
    assert read_admin_credentials(settings) == creds
    assert stat.S_IMODE(settings.secret_key_file.stat().st_mode) == 0o600
    assert stat.S_IMODE(settings.data_dir.stat().st_mode) == 0o700


async def test_first_admin_password_from_file(tmp_path: object, db_url: str) -> None:
    from pathlib import Path

    base = Path(str(tmp_path))
    secret = base / "admin-password"
    secret.write_text("a-chosen-password-123\n")
    settings = Settings(
        data_dir=base / "d2", database_url=db_url, admin_username="boss", admin_password_file=secret
    )
    application = create_app(settings)
    async with application.router.lifespan_context(application):
        creds = application.state.rehab.first_admin
        assert (creds.username, creds.password) == ("boss", "a-chosen-password-123")
        assert not settings.admin_credentials_file.exists()  # the operator already has it


async def test_password_is_stored_as_argon2_hash(state: AppState) -> None:
    assert state.first_admin is not None
    async with state.database.session() as db:
        admin = await db.scalar(select(Therapist))
    assert admin is not None
    assert admin.password_hash.startswith("$argon2id$")
    assert state.first_admin.password not in admin.password_hash
    assert verify_password(state.first_admin.password, admin.password_hash)[0]
    assert not verify_password("wrong", admin.password_hash)[0]


async def test_login_sets_token_and_cookie(client: httpx.AsyncClient, state: AppState) -> None:
    assert state.first_admin is not None
    r = await client.post(
        "/api/auth/login",
        json={"username": "admin", "password": state.first_admin.password},
    )
    assert r.status_code == 200
    body = r.json()
    assert body["token_type"] == "bearer" and body["therapist"]["is_admin"] is True
    expires = datetime.fromisoformat(body["expires_at"])
    ttl = timedelta(seconds=state.settings.access_token_ttl_s)
    assert abs(expires - (utcnow() + ttl)) < timedelta(minutes=1)

    cookie = r.headers["set-cookie"].lower()
    assert cookie.startswith(f"{state.settings.cookie_name}={body['access_token']}".lower())
    for attribute in ("httponly", "secure", "samesite=strict", "path=/"):
        assert attribute in cookie

    # The cookie alone authenticates (the dashboard)...
    me = await client.get("/api/auth/me")
    assert me.status_code == 200 and me.json()["username"] == "admin"
    # ...and so does the bearer token alone (scripts).
    client.cookies.clear()
    assert (await client.get("/api/auth/me")).status_code == 401
    headers = {"Authorization": f"Bearer {body['access_token']}"}
    assert (await client.get("/api/auth/me", headers=headers)).status_code == 200

    assert ("admin", "login") in await audit_actions(state)


async def test_login_failures(client: httpx.AsyncClient, state: AppState) -> None:
    for username, password in (("admin", "wrong-password"), ("nobody", "whatever")):
        r = await client.post("/api/auth/login", json={"username": username, "password": password})
        assert r.status_code == 401
        assert "set-cookie" not in r.headers
    r = await client.post("/api/auth/login", json={"username": "admin"})
    assert r.status_code == 422
    actions = await audit_actions(state)
    assert ("admin", "login.failed") in actions and ("nobody", "login.failed") in actions


async def test_expired_and_foreign_tokens(client: httpx.AsyncClient, state: AppState) -> None:
    expired = state.signer.issue_access(1, -1, "x").token
    r = await client.get("/api/auth/me", headers={"Authorization": f"Bearer {expired}"})
    assert r.status_code == 401
    # Signed with another key (another installation).
    foreign = TokenSigner(b"y" * 40).issue_access(1, 60, "x").token
    r = await client.get("/api/auth/me", headers={"Authorization": f"Bearer {foreign}"})
    assert r.status_code == 401
    assert state.first_admin is not None
    valid = (await login(client, "admin", state.first_admin.password))["Authorization"]
    client.cookies.clear()
    r = await client.get("/api/auth/me", headers={"Authorization": valid})
    assert r.status_code == 200


async def test_login_rate_limit(client: httpx.AsyncClient, state: AppState) -> None:
    assert state.first_admin is not None
    # Smaller limits than the defaults: each attempt costs a real Argon2 verification.
    state.limiter = LoginLimiter(max_failures=3, window_s=300, per_client_factor=2)
    limit = state.limiter.max_failures
    for _ in range(limit):
        r = await client.post("/api/auth/login", json={"username": "admin", "password": "nope"})
        assert r.status_code == 401
    # Blocked now, even with the right password; the answer says how long to wait.
    r = await client.post(
        "/api/auth/login", json={"username": "admin", "password": state.first_admin.password}
    )
    assert r.status_code == 429
    assert 0 < int(r.headers["retry-after"]) <= 300
    # The per-client limit also stops spraying many usernames from one address.
    per_client = state.limiter.per_client_max
    codes = []
    for i in range(per_client):
        r = await client.post("/api/auth/login", json={"username": f"u{i}", "password": "nope"})
        codes.append(r.status_code)
    assert codes[-1] == 429 and 401 in codes


async def test_success_resets_failures(client: httpx.AsyncClient, state: AppState) -> None:
    assert state.first_admin is not None
    state.limiter = LoginLimiter(max_failures=3, window_s=300)
    for _ in range(2):
        for _ in range(2):
            r = await client.post("/api/auth/login", json={"username": "admin", "password": "nope"})
            assert r.status_code == 401
        await login(client, "admin", state.first_admin.password)


async def test_therapists_admin_only_and_deactivation(
    client: httpx.AsyncClient, state: AppState, admin: dict[str, str]
) -> None:
    r = await client.post(
        "/api/therapists",
        json={"username": "ther1", "password": "long-enough-pw"},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    ther_id = r.json()["id"]
    dup = await client.post(
        "/api/therapists", json={"username": "ther1", "password": "long-enough-pw"}, headers=admin
    )
    assert dup.status_code == 409
    short = await client.post(
        "/api/therapists", json={"username": "ther2", "password": "short"}, headers=admin
    )
    assert short.status_code == 422

    ther = await login(client, "ther1", "long-enough-pw")
    client.cookies.clear()
    assert (await client.get("/api/patients", headers=ther)).status_code == 200
    for path in ("/api/therapists", "/api/audit"):
        assert (await client.get(path, headers=ther)).status_code == 403
    listed = (await client.get("/api/therapists", headers=admin)).json()
    assert {t["username"] for t in listed} == {"admin", "ther1"}

    r = await client.post(f"/api/therapists/{ther_id}/deactivate", headers=admin)
    assert r.status_code == 200 and r.json()["active"] is False
    # Takes effect at once, for the issued token and for new logins.
    assert (await client.get("/api/patients", headers=ther)).status_code == 401
    r = await client.post(
        "/api/auth/login", json={"username": "ther1", "password": "long-enough-pw"}
    )
    assert r.status_code == 401
    me = (await client.get("/api/auth/me", headers=admin)).json()
    r = await client.post(f"/api/therapists/{me['id']}/deactivate", headers=admin)
    assert r.status_code == 409  # no locking oneself out
    r = await client.post(f"/api/therapists/{ther_id}/activate", headers=admin)
    assert r.json()["active"] is True

    actions = [a for _, a in await audit_actions(state)]
    for action in ("therapist.create", "therapist.deactivate", "therapist.activate"):
        assert action in actions


async def test_logout_and_password_change(
    app: FastAPI, client: httpx.AsyncClient, state: AppState, settings: Settings
) -> None:
    assert state.first_admin is not None
    old = state.first_admin.password
    await login(client, "admin", old)  # cookie kept
    r = await client.post(
        "/api/auth/password",
        json={"current_password": "wrong-one", "new_password": "a-new-password"},
    )
    assert r.status_code == 403
    r = await client.post(
        "/api/auth/password", json={"current_password": old, "new_password": "a-new-password"}
    )
    assert r.status_code == 204
    assert not settings.admin_credentials_file.exists()

    r = await client.post("/api/auth/logout")
    assert r.status_code == 204
    assert (
        'rehab_session=""' in r.headers["set-cookie"]
        or "max-age=0" in r.headers["set-cookie"].lower()
    )
    assert (await client.get("/api/auth/me")).status_code == 401
    bad = await client.post("/api/auth/login", json={"username": "admin", "password": old})
    assert bad.status_code == 401
    await login(client, "admin", "a-new-password")
    actions = [a for _, a in await audit_actions(state)]
    assert "therapist.password" in actions and "logout" in actions
