"""Issue 21, REST side: login throttling without races, bounded request bodies, validation
errors that echo nothing, security headers, no CDN docs, Origin checks."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

import httpx
import pytest
from fastapi import FastAPI
from sqlalchemy import func, select

from backend.app import create_app
from backend.auth.ratelimit import LoginLimiter
from backend.db.models import AuditLog
from backend.deps import AppState
from backend.settings import Settings

pytestmark = pytest.mark.anyio

MiB = 1 << 20


async def failed_logins(state: AppState) -> int:
    async with state.database.session() as db:
        n = await db.scalar(
            select(func.count()).select_from(AuditLog).where(AuditLog.action == "login.failed")
        )
    return int(n or 0)


async def test_parallel_attempts_on_one_account_are_counted_before_verifying(
    client: httpx.AsyncClient, state: AppState
) -> None:
    assert state.first_admin is not None
    state.limiter = LoginLimiter(max_failures=5, window_s=300)
    # 59 guesses and the right password, all at once: the counter must not be read by 60
    # requests before any of them has failed.
    bodies = [{"username": "admin", "password": f"guess-{i}"} for i in range(59)]
    bodies.append({"username": "admin", "password": state.first_admin.password})
    replies = await asyncio.gather(*(client.post("/api/auth/login", json=b) for b in bodies))
    codes = [r.status_code for r in replies]
    verified = [c for c in codes if c != 429]
    assert len(verified) <= 5, codes
    assert codes.count(429) >= 55
    assert await failed_logins(state) <= 5


async def test_argon2_runs_are_bounded(client: httpx.AsyncClient, state: AppState) -> None:
    """Many clients at once (each under its own limit) never run more than the configured
    number of password hashes at the same time."""
    slots = state.password_slots
    assert slots.total_tokens == state.settings.password_hash_concurrency
    seen: list[float] = []
    done = asyncio.Event()

    async def sample() -> None:
        while not done.is_set():
            seen.append(slots.borrowed_tokens)
            await asyncio.sleep(0.001)

    sampler = asyncio.create_task(sample())
    bodies = [{"username": f"user{i}", "password": "x"} for i in range(12)]
    replies = await asyncio.gather(
        *(
            client.post("/api/auth/login", json=b, headers={"X-Forwarded-For": f"10.0.0.{i + 1}"})
            for i, b in enumerate(bodies)
        )
    )
    done.set()
    await sampler
    assert [r.status_code for r in replies] == [401] * 12
    assert 1 <= max(seen) <= state.settings.password_hash_concurrency


async def test_an_account_backs_off_across_addresses(
    client: httpx.AsyncClient, state: AppState
) -> None:
    """A guesser spreading over many addresses still meets the per-account limit."""
    state.limiter = LoginLimiter(max_failures=3, window_s=300, per_account_factor=2)
    codes = []
    for i in range(10):
        r = await client.post(
            "/api/auth/login",
            json={"username": "admin", "password": "nope"},
            headers={"X-Forwarded-For": f"10.1.0.{i + 1}"},
        )
        codes.append(r.status_code)
    assert codes[:6] == [401] * 6 and codes[6:] == [429] * 4, codes


async def test_clients_behind_the_proxy_do_not_share_one_lockout(
    client: httpx.AsyncClient, state: AppState
) -> None:
    """uvicorn runs without proxy headers; the app itself trusts X-Forwarded-For from
    ``forwarded_allow_ips`` only (the test client connects from 127.0.0.1)."""
    assert state.first_admin is not None
    state.limiter = LoginLimiter(max_failures=2, window_s=300, per_client_factor=2)
    sprayer = {"X-Forwarded-For": "10.2.0.1"}
    for i in range(4):
        await client.post(
            "/api/auth/login", json={"username": f"n{i}", "password": "x"}, headers=sprayer
        )
    r = await client.post(
        "/api/auth/login", json={"username": "other", "password": "x"}, headers=sprayer
    )
    assert r.status_code == 429
    # Another workstation behind the same proxy logs in.
    r = await client.post(
        "/api/auth/login",
        json={"username": "admin", "password": state.first_admin.password},
        headers={"X-Forwarded-For": "10.2.0.2"},
    )
    assert r.status_code == 200


async def test_forwarded_for_from_an_untrusted_peer_is_ignored(
    tmp_path: object, db_url: str
) -> None:
    from pathlib import Path

    settings = Settings(
        data_dir=Path(str(tmp_path)) / "d", database_url=db_url, forwarded_allow_ips=["10.9.9.9"]
    )
    app = create_app(settings)
    async with app.router.lifespan_context(app):
        app.state.rehab.limiter = LoginLimiter(max_failures=1, window_s=300, per_client_factor=1)
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="https://t") as c:
            codes = []
            for i in range(3):
                r = await c.post(
                    "/api/auth/login",
                    json={"username": f"x{i}", "password": "x"},
                    headers={"X-Forwarded-For": f"10.3.0.{i + 1}"},
                )
                codes.append(r.status_code)
    assert codes == [401, 429, 429]  # one address (the peer): the header is not believed


async def test_huge_body_is_refused_before_it_is_read(client: httpx.AsyncClient) -> None:
    sent = 0

    async def body() -> AsyncIterator[bytes]:
        nonlocal sent
        chunk = b"x" * MiB
        for _ in range(400):
            sent += len(chunk)
            yield chunk

    r = await client.post(
        "/api/auth/login", content=body(), headers={"Content-Type": "application/json"}
    )
    assert r.status_code == 413
    assert sent <= 4 * MiB, sent
    # Announced too large: refused without reading anything.
    r = await client.post(
        "/api/auth/login",
        content=b"{}",
        headers={"Content-Type": "application/json", "Content-Length": str(400 * MiB)},
    )
    assert r.status_code == 413


async def test_validation_errors_do_not_echo_input(client: httpx.AsyncClient) -> None:
    marker = "ECHO" * 25_000  # 100 kB
    r = await client.post("/api/auth/login", json={"username": marker, "password": "x"})
    assert r.status_code == 422
    assert "ECHO" not in r.text and len(r.content) < 2000
    detail = r.json()["detail"]
    assert detail and {"loc", "msg", "type"} <= set(detail[0]) and "input" not in detail[0]
    r = await client.post(
        "/api/auth/login",
        content=b"{not json" + marker.encode(),
        headers={"Content-Type": "application/json"},
    )
    assert r.status_code == 422 and "ECHO" not in r.text


async def test_security_headers_and_no_cdn_docs(client: httpx.AsyncClient) -> None:
    r = await client.get("/api/health")
    assert r.headers["x-content-type-options"] == "nosniff"
    assert r.headers["cache-control"] == "no-store"
    assert r.headers["referrer-policy"] == "no-referrer"
    r = await client.post("/api/auth/login", json={"username": "a", "password": "b"})
    assert r.headers["cache-control"] == "no-store"
    # Swagger UI would load its scripts from a CDN: off unless asked for.
    assert (await client.get("/api/docs")).status_code == 404
    assert (await client.get("/api/openapi.json")).status_code == 200


async def test_docs_when_switched_on(tmp_path: object, db_url: str) -> None:
    from pathlib import Path

    app = create_app(
        Settings(data_dir=Path(str(tmp_path)) / "d", database_url=db_url, api_docs=True)
    )
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="https://t") as c:
            r = await c.get("/api/docs")
    assert r.status_code == 200


async def test_cross_origin_state_changes_are_refused(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    patient = {"code": "P1", "affected_side": "left"}
    evil = {**admin, "Origin": "https://evil.example"}
    r = await client.post("/api/patients", json=patient, headers=evil)
    assert r.status_code == 403
    r = await client.post(
        "/api/patients", json=patient, headers={**admin, "Sec-Fetch-Site": "cross-site"}
    )
    assert r.status_code == 403
    # Login too (login CSRF).
    r = await client.post(
        "/api/auth/login",
        json={"username": "a", "password": "b"},
        headers={"Origin": "https://evil.example"},
    )
    assert r.status_code == 403
    # Reads are not state changes; the same origin and scripts (no Origin) may write.
    assert (await client.get("/api/patients", headers=evil)).status_code == 200
    same = {**admin, "Origin": "https://testserver", "Sec-Fetch-Site": "same-origin"}
    assert (await client.post("/api/patients", json=patient, headers=same)).status_code == 201
    r = await client.post("/api/patients", json={**patient, "code": "P2"}, headers=admin)
    assert r.status_code == 201


async def test_configured_origins_may_write(tmp_path: object, db_url: str) -> None:
    from pathlib import Path

    settings = Settings(
        data_dir=Path(str(tmp_path)) / "d",
        database_url=db_url,
        cors_origins=["https://dash.clinic.example"],
    )
    app: FastAPI = create_app(settings)
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="https://t") as c:
            r = await c.post(
                "/api/auth/login",
                json={"username": "a", "password": "b"},
                headers={"Origin": "https://dash.clinic.example"},
            )
    assert r.status_code == 401


async def test_reads_of_patient_data_are_audited(
    client: httpx.AsyncClient, admin: dict[str, str], state: AppState
) -> None:
    r = await client.post(
        "/api/patients", json={"code": "R1", "affected_side": "left"}, headers=admin
    )
    pid = r.json()["id"]
    for path in ("/api/patients", f"/api/patients/{pid}", "/api/sessions"):
        assert (await client.get(path, headers=admin)).status_code == 200
    assert (await client.get(f"/api/sessions?patient_id={pid}", headers=admin)).status_code == 200
    async with state.database.session() as db:
        rows = list(await db.scalars(select(AuditLog).order_by(AuditLog.id)))
    got = [(a.actor, a.action, a.object) for a in rows]
    assert ("admin", "patient.list", None) in got
    assert ("admin", "patient.read", f"patient:{pid}") in got
    assert ("admin", "session.list", None) in got
    assert ("admin", "session.list", f"patient:{pid}") in got


def test_secrets_from_files(tmp_path: object) -> None:
    """Docker secrets: the signing key and the database password come from files, so
    neither sits in the compose file or the environment."""
    from pathlib import Path

    from backend.auth.secret import load_or_create_secret

    base = Path(str(tmp_path))
    (base / "key").write_text("k" * 48 + "\n")
    (base / "pw").write_text("s3cret/pw@x\n")
    env = {
        "REHAB_SECRET_FILE": str(base / "key"),
        "REHAB_DATABASE_URL": "postgresql://rehab@postgres:5432/rehab",
        "REHAB_DATABASE_PASSWORD_FILE": str(base / "pw"),
        "REHAB_DATA_DIR": str(base / "data"),
    }
    mp = pytest.MonkeyPatch()
    try:
        for k, v in env.items():
            mp.setenv(k, v)
        settings = Settings()
    finally:
        mp.undo()
    assert load_or_create_secret(settings) == b"k" * 48
    assert not settings.secret_key_file.exists()  # nothing generated beside it
    from sqlalchemy.engine import make_url

    url = make_url(settings.db_url)
    assert url.password == "s3cret/pw@x" and url.drivername == "postgresql+psycopg"
    assert "s3cret" not in repr(settings)
