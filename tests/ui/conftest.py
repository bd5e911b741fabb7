"""Browser tests against the real service: ``rehab serve`` in a subprocess (real Zenoh on
loopback, SQLite in a temp dir), simulated devices publishing over Zenoh in real time, and
Debian's chromium driven by Playwright.

Skipped, with the reason, when ``/usr/bin/chromium``, Playwright or the built front end
(``frontend/build.sh``) is missing. Screenshots go to ``test-artifacts/``.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest

REPO = Path(__file__).resolve().parents[2]
CHROMIUM = Path(os.environ.get("REHAB_TEST_CHROMIUM", "/usr/bin/chromium"))
ARTIFACTS = REPO / "test-artifacts"
DIST = REPO / "frontend" / "dist" / "index.html"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]

try:
    from playwright.sync_api import Browser, ConsoleMessage, Page, sync_playwright
except ImportError:  # pragma: no cover - dev extra not installed
    sync_playwright = None


def _skip_reason() -> str | None:
    if sync_playwright is None:
        return "playwright is not installed (pip install -e '.[dev]')"
    if not CHROMIUM.exists():
        return f"{CHROMIUM} missing: install Debian's chromium (apt-get install chromium)"
    if not DIST.exists():
        return "front end not built: run frontend/build.sh (./run does it)"
    return None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    reason = _skip_reason()
    if reason is None:
        return
    for item in items:
        path = Path(str(item.fspath))
        if path.parent == Path(__file__).parent and path.name != "test_viz.py":
            item.add_marker(pytest.mark.skip(reason=reason))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@dataclass
class Service:
    url: str
    zenoh: str
    data_dir: Path
    username: str
    password: str
    proc: subprocess.Popen[bytes]
    log: Path

    def api(self) -> httpx.Client:
        """A logged-in API client (bearer token)."""
        c = httpx.Client(base_url=self.url, timeout=10)
        r = c.post("/api/auth/login", json={"username": self.username, "password": self.password})
        r.raise_for_status()
        c.headers["Authorization"] = f"Bearer {r.json()['access_token']}"
        c.cookies.clear()
        return c


@pytest.fixture(scope="session")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    data = tmp_path_factory.mktemp("ui-service")
    port, zport = free_port(), free_port()
    log = data / "service.log"
    env = {**os.environ, "REHAB_VISER_PORT": "0", "PYTHONUNBUFFERED": "1"}
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "backend.cli", "serve", "--host", "127.0.0.1",
             "--port", str(port), "--zenoh-listen", f"tcp/127.0.0.1:{zport}",
             "--data-dir", str(data / "data"), "--log-level", "warning"],
            cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT,
        )  # fmt: skip
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            if proc.poll() is not None:
                pytest.fail(f"rehab serve exited:\n{log.read_text()}")
            try:
                if httpx.get(url + "/api/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                pytest.fail(f"rehab serve did not start:\n{log.read_text()}")
            time.sleep(0.2)
        creds = dict(
            line.split(": ", 1)
            for line in (data / "data" / "admin-credentials.txt").read_text().splitlines()
        )
        yield Service(
            url, f"tcp/127.0.0.1:{zport}", data / "data", creds["username"], creds["password"],
            proc, log,
        )  # fmt: skip
    finally:
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class SimDevice(threading.Thread):
    """A simulated device publishing over Zenoh as a real one would.

    It plays ``head_s`` seconds in real time (so the service knows the device), then waits
    for :meth:`go` (a session has started), plays until ``fast_until_s`` at ``fast`` times
    real time (the heading calibration, shortened), and the rest in real time.
    """

    def __init__(
        self,
        endpoint: str,
        device: str,
        layout: tuple[tuple[str, float], ...],
        *,
        seed: int = 1,
        head_s: float = 1.5,
        fast_until_s: float = 0.0,
        fast: float = 1.0,
        gated: bool = False,
    ) -> None:
        super().__init__(name=f"sim-{device}", daemon=True)
        from simulator import SimConfig, simulate
        from simulator.publish import prepare

        duration = sum(d for _, d in layout)
        sim = simulate(SimConfig(seed=seed, duration_s=duration, device=device, layout=layout))
        self.outgoing = prepare(sim.messages)
        self.endpoint = endpoint
        self.device = device
        self.head_s = head_s
        self.fast_until_s = fast_until_s
        self.fast = fast
        self._go = threading.Event()
        if not gated:
            self._go.set()
        self.stop_event = threading.Event()
        self.error: BaseException | None = None
        self.sent = 0

    def go(self) -> None:
        self._go.set()

    def stop(self) -> None:
        self.stop_event.set()
        self._go.set()
        self.join(10)

    def run(self) -> None:
        from simulator.publish import Publisher, play

        try:
            with Publisher.connect(self.endpoint) as pub:
                pub.declare(self.outgoing)
                pub.wait_for_subscribers(10.0)
                t0 = self.outgoing[0].at
                head = [m for m in self.outgoing if m.at < t0 + self.head_s]
                fast = [m for m in self.outgoing[len(head) :] if m.at < t0 + self.fast_until_s]
                rest = self.outgoing[len(head) + len(fast) :]
                self.sent += play(pub, head, 1.0, stop=self.stop_event)
                while not self._go.wait(0.2):
                    if self.stop_event.is_set():
                        return
                self.sent += play(pub, fast, self.fast, stop=self.stop_event)
                self.sent += play(pub, rest, 1.0, stop=self.stop_event)
        except BaseException as exc:  # reported by the test that owns the device
            self.error = exc


@dataclass
class ConsoleLog:
    """Console errors and page errors of every page of a context."""

    errors: list[str] = field(default_factory=list)

    def watch(self, page: Page) -> Page:
        def on_console(msg: ConsoleMessage) -> None:
            if msg.type == "error":
                self.errors.append(f"{page.url}: {msg.text}")

        page.on("console", on_console)
        page.on("pageerror", lambda exc: self.errors.append(f"{page.url}: {exc}"))
        return page


@pytest.fixture(scope="session")
def browser() -> Iterator[Browser]:
    assert sync_playwright is not None
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture(scope="session")
def artifacts() -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS


def shot_path(name: str) -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS / f"{name}.png"


def shot(page: Page, name: str, **kw: Any) -> Path:
    path = shot_path(name)
    page.screenshot(path=str(path), **kw)
    return path
