"""The live service for real: uvicorn on a free port, an embedded Zenoh on another, a real
database, and devices publishing over a real Zenoh session on loopback."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn
from fastapi import FastAPI

from backend.app import create_app
from backend.auth.first_admin import read_admin_credentials
from backend.live.manager import LiveManager
from backend.settings import Settings
from simulator.publish import Publisher

# the PostgreSQL fixtures of the storage tests (server started once per run)
from tests.backend.conftest import any_db_url, postgres_server  # noqa: F401


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def wait_for(check: Callable[[], Any], timeout: float = 20.0, what: str = "condition") -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


@dataclass
class Service:
    settings: Settings
    url: str
    endpoint: str  # Zenoh
    api: httpx.Client  # logged in as the first admin (bearer)
    token: str
    app: FastAPI

    @property
    def manager(self) -> LiveManager:
        """For reading counters that have no REST route (in-process services only)."""
        manager = self.app.state.rehab.live
        assert isinstance(manager, LiveManager)
        return manager

    @property
    def data_dir(self) -> Path:
        return self.settings.data_dir

    def device(self, name: str) -> dict[str, Any] | None:
        r = self.api.get(f"/api/devices/{name}")
        return r.json() if r.status_code == 200 else None

    def received(self, name: str) -> int:
        dev = self.device(name)
        stats = (dev or {}).get("stats") or {}
        return int(stats.get("ingest", {}).get("messages", 0))

    def patient(self, code: str) -> int:
        r = self.api.post("/api/patients", json={"code": code, "affected_side": "right"})
        assert r.status_code == 201, r.text
        pid: int = r.json()["id"]
        return pid

    def start(self, device: str, code: str | None = None, **params: Any) -> dict[str, Any]:
        wait_for(lambda: self.device(device), what=f"device {device} registered")
        body: dict[str, Any] = {"patient_id": self.patient(code or f"p-{device}"), "device": device}
        if params:
            body["params"] = params
        r = self.api.post("/api/sessions", json=body)
        assert r.status_code == 201, r.text
        session: dict[str, Any] = r.json()
        return session

    def stop(self, session_id: int) -> dict[str, Any]:
        r = self.api.post(f"/api/sessions/{session_id}/stop")
        assert r.status_code == 200, r.text
        session: dict[str, Any] = r.json()
        return session

    def publisher(self) -> Publisher:
        return Publisher.connect(self.endpoint)


def login(url: str, settings: Settings) -> tuple[httpx.Client, str]:
    creds = read_admin_credentials(settings)
    assert creds is not None
    client = httpx.Client(base_url=url, timeout=60.0)
    r = client.post(
        "/api/auth/login", json={"username": creds.username, "password": creds.password}
    )
    assert r.status_code == 200, r.text
    token: str = r.json()["access_token"]
    client.cookies.clear()
    client.headers["Authorization"] = f"Bearer {token}"
    return client, token


@dataclass
class _Running:
    server: uvicorn.Server
    thread: threading.Thread
    app: FastAPI


def run_service(settings: Settings) -> _Running:
    app = create_app(settings)
    app.state.live_required = True
    server = uvicorn.Server(
        uvicorn.Config(
            app, host="127.0.0.1", port=settings.port, log_level="warning", ws="websockets-sansio"
        )
    )
    thread = threading.Thread(target=server.run, name="service", daemon=True)
    thread.start()
    # with workers, the API node waits for their processes (imports: slow on a loaded box)
    wait = 20.0 if not settings.workers else 90.0
    wait_for(lambda: server.started or not thread.is_alive(), wait, what="service start")
    assert server.started, "the service did not start"
    return _Running(server, thread, app)


def stop_service(running: _Running) -> None:
    running.server.should_exit = True
    running.thread.join(30)
    assert not running.thread.is_alive()


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """One service per test module (SQLite); tests use their own device names."""
    data = tmp_path_factory.mktemp("live")
    yield from _service(
        Settings(
            data_dir=data,
            port=free_port(),
            zenoh_listen=f"tcp/127.0.0.1:{free_port()}",
            cookie_secure=False,
            admit=["*"],  # every device name, as a test harness publishes many
        )
    )


@pytest.fixture(scope="module")
def workers_service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """The scaled-out service: the API node (``rehab serve --workers 2`` in this process,
    so that a test can read its 3D view) and two real ``rehab worker`` processes."""
    data = tmp_path_factory.mktemp("live-workers")
    yield from _service(
        Settings(
            data_dir=data,
            port=free_port(),
            zenoh_listen=f"tcp/127.0.0.1:{free_port()}",
            cookie_secure=False,
            admit=["*"],
            workers=2,
        )
    )


def _service(settings: Settings) -> Iterator[Service]:
    running = run_service(settings)
    url = f"http://127.0.0.1:{settings.port}"
    api, token = login(url, settings)
    assert settings.zenoh_listen is not None
    try:
        yield Service(settings, url, settings.zenoh_listen, api, token, running.app)
    finally:
        api.close()
        stop_service(running)
