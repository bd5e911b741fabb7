"""Issue 21: logins are revocable server-side (logout, password change, deactivation), die
when idle, and the audit log is append-only in the database itself."""

from __future__ import annotations

from datetime import timedelta

import httpx
import pytest
from sqlalchemy import select, text, update
from sqlalchemy.exc import DBAPIError

from backend.db.base import utcnow
from backend.db.models import AuditLog, Login
from backend.deps import AppState
from tests.backend.conftest import login

pytestmark = pytest.mark.anyio


@pytest.fixture
def db_url(any_db_url: str) -> str:
    """Both backends: the append-only triggers differ between SQLite and PostgreSQL."""
    return any_db_url


async def new_therapist(client: httpx.AsyncClient, admin: dict[str, str], name: str) -> int:
    r = await client.post(
        "/api/therapists", json={"username": name, "password": "long-enough-pw"}, headers=admin
    )
    assert r.status_code == 201, r.text
    therapist_id: int = r.json()["id"]
    return therapist_id


async def bearer(
    client: httpx.AsyncClient, name: str, password: str = "long-enough-pw"
) -> dict[str, str]:
    headers = await login(client, name, password)
    client.cookies.clear()
    return headers


async def me(client: httpx.AsyncClient, headers: dict[str, str]) -> int:
    return (await client.get("/api/auth/me", headers=headers)).status_code


async def test_logout_revokes_the_token(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    await new_therapist(client, admin, "t1")
    a = await bearer(client, "t1")
    b = await bearer(client, "t1")  # a second workstation
    assert await me(client, a) == 200
    assert (await client.post("/api/auth/logout", headers=a)).status_code == 204
    assert await me(client, a) == 401
    assert await me(client, b) == 200  # only that login ends


async def test_password_change_ends_the_other_logins(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    await new_therapist(client, admin, "t2")
    here = await bearer(client, "t2")
    stolen = await bearer(client, "t2")
    r = await client.post(
        "/api/auth/password",
        json={"current_password": "long-enough-pw", "new_password": "another-long-pw"},
        headers=here,
    )
    assert r.status_code == 204
    assert await me(client, stolen) == 401
    assert await me(client, here) == 200


async def test_deactivation_revokes_for_good(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    tid = await new_therapist(client, admin, "t3")
    t = await bearer(client, "t3")
    assert (
        await client.post(f"/api/therapists/{tid}/deactivate", headers=admin)
    ).status_code == 200
    assert await me(client, t) == 401
    assert (await client.post(f"/api/therapists/{tid}/activate", headers=admin)).status_code == 200
    assert await me(client, t) == 401  # reactivating does not revive old tokens
    assert await me(client, await bearer(client, "t3")) == 200


async def test_idle_logins_end(
    client: httpx.AsyncClient, admin: dict[str, str], state: AppState
) -> None:
    await new_therapist(client, admin, "t4")
    t = await bearer(client, "t4")
    assert await me(client, t) == 200
    idle = timedelta(seconds=state.settings.session_idle_s + 5)
    async with state.database.transaction() as db:
        await db.execute(update(Login).values(last_seen=utcnow() - idle))
    assert await me(client, t) == 401
    assert await me(client, admin) == 401  # every login went idle


async def test_a_signed_token_without_a_login_is_refused(
    client: httpx.AsyncClient, state: AppState
) -> None:
    """The signing key alone no longer makes a valid token: the login must exist."""
    forged = state.signer.issue_access(1, 60, "no-such-login").token
    assert await me(client, {"Authorization": f"Bearer {forged}"}) == 401


async def test_audit_rows_cannot_be_changed(
    client: httpx.AsyncClient, admin: dict[str, str], state: AppState
) -> None:
    async with state.database.session() as db:
        assert await db.scalar(select(AuditLog.id).limit(1)) is not None
    for statement in (
        update(AuditLog).values(action="tampered"),
        text("DELETE FROM audit_log"),
    ):
        with pytest.raises(DBAPIError, match="append-only"):
            async with state.database.transaction() as db:
                await db.execute(statement)
    async with state.database.session() as db:
        actions = set(await db.scalars(select(AuditLog.action)))
    assert "tampered" not in actions and "login" in actions
