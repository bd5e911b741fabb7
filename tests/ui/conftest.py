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
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest

from simulator.publish import DeviceThread, prepare

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
    from playwright.sync_api import Browser, ConsoleMessage, Locator, Page, sync_playwright
except ImportError:  # pragma: no cover - dev extra not installed
    sync_playwright = None


NO_BROWSER = {"test_viz.py", "test_static.py"}  # these need neither chromium nor a build


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
        if path.parent == Path(__file__).parent and path.name not in NO_BROWSER:
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
             "--data-dir", str(data / "data"), "--log-level", "warning", "--admit", "*"],
            cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT,
        )  # fmt: skip
    url = f"http://127.0.0.1:{port}"
    try:
        # the default `rehab serve`: healthy once its worker processes are up (slow to
        # import on a loaded machine: 46 s seen at load 10)
        deadline = time.monotonic() + 150
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


class SimDevice(DeviceThread):
    """A simulated session of ``layout`` played by a device thread (see
    :class:`simulator.publish.DeviceThread` for ``head_s``, ``gated`` and the fast part)."""

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
        from simulator import SimConfig, simulate

        duration = sum(d for _, d in layout)
        sim = simulate(SimConfig(seed=seed, duration_s=duration, device=device, layout=layout))
        super().__init__(
            endpoint, prepare(sim.messages), name=device, head_s=head_s,
            fast_until_s=fast_until_s, fast=fast, gated=gated,
        )  # fmt: skip
        self.device = device

    def wait_known(self, service: Service, timeout_s: float = 30.0) -> None:
        """Block until the service has heard from this device (its REST resource exists)."""
        deadline = time.monotonic() + timeout_s
        api = service.api()
        try:
            while api.get(f"/api/devices/{self.device}").status_code != 200:
                if self.error is not None or not self.is_alive():
                    raise AssertionError(f"{self.name} stopped: {self.error!r}")
                if time.monotonic() > deadline:
                    raise AssertionError(f"the service did not hear from {self.device}")
                time.sleep(0.1)
        finally:
            api.close()


@dataclass
class ConsoleLog:
    """Console errors and page errors of every page of a context, and every URL its pages
    (and their frames: the 3D view) requested or opened a WebSocket to."""

    errors: list[str] = field(default_factory=list)
    urls: list[str] = field(default_factory=list)

    def watch(self, page: Page) -> Page:
        def on_console(msg: ConsoleMessage) -> None:
            if msg.type == "error":
                # A failed load names its resource only in the location, not in the text.
                src = msg.location.get("url") or ""
                where = f" [{src}]" if src and src != page.url else ""
                self.errors.append(f"{page.url}: {msg.text}{where}")

        page.on("console", on_console)
        page.on("pageerror", lambda exc: self.errors.append(f"{page.url}: {exc}"))
        page.on("request", lambda r: self.urls.append(r.url))
        page.on("websocket", lambda ws: self.urls.append(ws.url))
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


# Added to every page of the test contexts (not to frames: the 3D view's stays as it is): a
# gate on the pages' WebSockets, so a screenshot can hold the live feed still. Messages that
# arrive while it is frozen are kept and delivered, in order, when it thaws.
WS_GATE_JS = """(() => {
  if (window.top !== window || window.__wsGate) return;
  const Native = window.WebSocket;
  const gate = { frozen: false, held: [] };
  gate.freeze = () => { gate.frozen = true; };
  gate.thaw = () => {
    gate.frozen = false;
    for (const [ws, data] of gate.held.splice(0)) {
      ws.dispatchEvent(new MessageEvent("message", { data }));
    }
  };
  window.__wsGate = gate;
  window.WebSocket = class extends Native {
    constructor(...args) {
      super(...args);
      this.addEventListener("message", (ev) => {
        if (!gate.frozen) return;
        ev.stopImmediatePropagation();
        gate.held.push([this, ev.data]);
      });
    }
  };
})();"""


def hold_when(page: Page, condition: str, *, timeout_s: float = 30) -> None:
    """Hold the page's live feed still (``WS_GATE_JS``) as soon as the JavaScript expression
    ``condition`` holds, renders already under way let through: the page then keeps showing
    that moment until :func:`shot_held` (or ``window.__wsGate.thaw()``). Retried until
    ``timeout_s``."""
    freeze = f"""() => {{
        window.__wsGate.freeze();
        const frames = new Promise((done) =>
            requestAnimationFrame(() => requestAnimationFrame(done)));
        const later = new Promise((done) => setTimeout(done, 300));  // a page without frames
        return Promise.race([frames, later]).then(() => {{
            const ok = !!({condition});
            if (!ok) window.__wsGate.thaw();
            return ok;
        }});
    }}"""
    deadline = time.monotonic() + timeout_s
    while True:
        remaining_ms = max(1.0, (deadline - time.monotonic()) * 1000)
        # A function, not an expression: the pages' CSP forbids eval.
        page.wait_for_function(f"() => ({condition})", timeout=remaining_ms, polling=50)
        if page.evaluate(freeze):
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"{condition!r} never held still")


def shot_held(
    page: Page,
    name: str,
    condition: str,
    *,
    during: Callable[[], None] | None = None,
    locator: Locator | None = None,
    **kw: Any,
) -> Path:
    """The screenshot of a page (or of ``locator`` on it) held by :func:`hold_when`
    (``condition`` still holds, and ``during`` is called on the same still page); then the
    live feed goes on."""
    path = shot_path(name)
    try:
        (locator or page).screenshot(path=str(path), **kw)
        assert page.evaluate(f"() => !!({condition})"), f"{name}: {condition!r} no longer holds"
        if during is not None:
            during()
    finally:
        page.evaluate("() => window.__wsGate.thaw()")
    return path


def shot_while(
    page: Page,
    name: str,
    condition: str,
    *,
    timeout_s: float = 30,
    during: Callable[[], None] | None = None,
    **kw: Any,
) -> Path:
    """A screenshot of the page while ``condition`` holds: live data would otherwise change
    under the camera (a screenshot of "the warning" must show the warning)."""
    hold_when(page, condition, timeout_s=timeout_s)
    return shot_held(page, name, condition, during=during, **kw)


def colour_pixels(page: Page, selector: str, rgb: str, tolerance: int = 60) -> int:
    """How many pixels of the first canvas under ``selector`` are close to ``rgb``
    (``#rrggbb``): a chart's series is drawn, not just its axes."""
    r, g, b = (int(rgb[i : i + 2], 16) for i in (1, 3, 5))
    js = """([sel, r, g, b, tol]) => {
        const c = document.querySelector(sel);
        if (!c) return -1;
        const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
        let n = 0;
        for (let i = 0; i < d.length; i += 4) {
            if (d[i + 3] > 0 && Math.abs(d[i] - r) + Math.abs(d[i + 1] - g)
                + Math.abs(d[i + 2] - b) < tol) n++;
        }
        return n;
    }"""
    n: int = page.evaluate(js, [selector, r, g, b, tolerance])
    assert n >= 0, f"no canvas at {selector}"
    return n


def contrast_ratio(fg: str, bg: str) -> float:
    """WCAG contrast ratio of two CSS ``rgb(...)``/``rgba(...)`` colours."""

    def lum(css: str) -> float:
        vals = [float(v) for v in css[css.index("(") + 1 : css.index(")")].split(",")[:3]]
        lin = [c / 255 / 12.92 if c / 255 <= 0.04045 else ((c / 255 + 0.055) / 1.055) ** 2.4
               for c in vals]  # fmt: skip
        return 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]

    a, b = sorted((lum(fg), lum(bg)), reverse=True)
    return (a + 0.05) / (b + 0.05)
