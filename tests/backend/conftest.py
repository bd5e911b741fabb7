"""Fixtures: the real app on a real database (SQLite in a temp dir, or PostgreSQL).

PostgreSQL: ``REHAB_TEST_POSTGRES_URL`` if set (CI), else a throwaway server started with
``scripts/postgres-test-server.sh`` when the PostgreSQL binaries are installed, else the
PostgreSQL variants are skipped.
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import tempfile
import uuid
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import httpx
import psycopg
import pytest
from fastapi import FastAPI
from sqlalchemy.engine import make_url

from backend.app import create_app
from backend.deps import AppState
from backend.settings import Settings

REPO = Path(__file__).resolve().parents[2]
PG_SCRIPT = REPO / "scripts" / "postgres-test-server.sh"


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def _have_postgres_binaries() -> bool:
    return bool(glob.glob("/usr/lib/postgresql/*/bin/initdb")) or shutil.which("initdb") is not None


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[str]:
    """A PostgreSQL server URL (SQLAlchemy form) for the whole test run."""
    url = os.environ.get("REHAB_TEST_POSTGRES_URL")
    if url:
        yield url
        return
    if not _have_postgres_binaries():
        pytest.skip(
            "PostgreSQL not available: set REHAB_TEST_POSTGRES_URL or install Debian's "
            "`postgresql` package (scripts/postgres-test-server.sh starts it)"
        )
    # Not under pytest's tmp dir: that one is private to the current user, and as root the
    # server runs as `postgres`.
    workdir = tempfile.mkdtemp(prefix="rehab-pg-")
    try:
        started = subprocess.run(
            ["bash", str(PG_SCRIPT), "start", workdir],
            capture_output=True,
            text=True,
            timeout=60,
        )
        if started.returncode != 0:
            pytest.fail(f"postgres-test-server.sh failed:\n{started.stderr}")
        yield started.stdout.strip()
    finally:
        subprocess.run(["bash", str(PG_SCRIPT), "stop", workdir], timeout=60, check=False)


def _admin_conninfo(url: str) -> str:
    return make_url(url).set(drivername="postgresql").render_as_string(hide_password=False)


@pytest.fixture(params=["sqlite", "postgresql"])
def any_db_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """A fresh, empty database on each backend."""
    if request.param == "sqlite":
        yield f"sqlite+aiosqlite:///{tmp_path / 'test.db'}"
        return
    server = Settings(database_url=request.getfixturevalue("postgres_server")).db_url
    name = f"rehab_test_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(_admin_conninfo(server), autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield make_url(server).set(database=name).render_as_string(hide_password=False)
    finally:
        with psycopg.connect(_admin_conninfo(server), autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture
def db_url(tmp_path: Path) -> str:
    """SQLite unless a module asks for both backends (``db_url = any_db_url`` there)."""
    return f"sqlite+aiosqlite:///{tmp_path / 'test.db'}"


@pytest.fixture
def settings(tmp_path: Path, db_url: str) -> Settings:
    return Settings(data_dir=tmp_path / "data", database_url=db_url)


@pytest.fixture
async def app(settings: Settings) -> AsyncIterator[FastAPI]:
    """The real app with its lifespan running (migrations, first admin)."""
    application = create_app(settings)
    async with application.router.lifespan_context(application):
        yield application


@pytest.fixture
def state(app: FastAPI) -> AppState:
    rehab: AppState = app.state.rehab
    return rehab


@pytest.fixture
async def client(app: FastAPI) -> AsyncIterator[httpx.AsyncClient]:
    # https: the session cookie is Secure, and httpx only sends it back over https.
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="https://testserver") as c:
        yield c


async def login(client: httpx.AsyncClient, username: str, password: str) -> dict[str, str]:
    """Log in and return bearer headers (the client also keeps the cookie: clear it if the
    test must use the header alone)."""
    r = await client.post("/api/auth/login", json={"username": username, "password": password})
    assert r.status_code == 200, r.text
    return {"Authorization": f"Bearer {r.json()['access_token']}"}


@pytest.fixture
async def admin(client: httpx.AsyncClient, state: AppState) -> dict[str, str]:
    """Bearer headers of the first admin (the cookie is dropped so each test is explicit)."""
    assert state.first_admin is not None
    headers = await login(client, state.first_admin.username, state.first_admin.password)
    client.cookies.clear()
    return headers
