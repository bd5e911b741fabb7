"""Dashboard update rate: N simulated devices on one screen (``/grid``) in headless chromium.

``rehab serve`` runs in a subprocess (SQLite in a temp dir, an embedded Zenoh on loopback).
Each device publishes over Zenoh as a real one does (100 Hz IMU in messages of 4 samples,
25 Hz robot); its first minute, the heading calibration, is played 8× faster, the rest in
real time. A session runs on every device (recording, cycles and the live report are part
of the load) unless ``--no-sessions``. Debian's chromium (``/usr/bin/chromium``, as the UI
tests use it; software rendering) logs in, opens ``/grid?devices=…`` and, once every device
is calibrated, counts over ``--duration`` seconds:

- rendered updates per device: the live plots redrawn with new rows
  (``window.__rehabLive.frames``; the target is ≥ 20 per second per device);
- estimate messages received per device (the service sends at most 30 per second);
- the page's animation frames per second, and its long tasks (> 50 ms main-thread work).

    python benchmarks/dashboard.py                     # 4 devices, 30 s
    python benchmarks/dashboard.py --devices 8 --duration 60 --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.serving import wait_healthy  # noqa: E402
from simulator import SimConfig, simulate  # noqa: E402  (the repository on the path first)
from simulator.publish import DeviceThread, prepare  # noqa: E402

TARGET_HZ = 20.0
CALIBRATION_S = 60.0  # simulated seconds played fast
FAST = 8.0
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]  # fmt: skip
# Counts animation frames and long tasks from the page's first script on.
PAGE_PROBE = """
window.__bench = {raf: 0, longTasks: 0, longMs: 0};
(function tick() { window.__bench.raf++; requestAnimationFrame(tick); })();
try {
  new PerformanceObserver((list) => {
    for (const e of list.getEntries()) { window.__bench.longTasks++; window.__bench.longMs += e.duration; }
  }).observe({type: "longtask", buffered: true});
} catch (e) {}
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def device(endpoint: str, name: str, seed: int, duration_s: float) -> DeviceThread:
    """One simulated device: the calibration minute fast, then real time, until stopped."""
    sim = simulate(SimConfig(seed=seed, duration_s=duration_s, device=name))
    return DeviceThread(
        endpoint, prepare(sim.messages), name=name, fast_until_s=CALIBRATION_S, fast=FAST
    )


def start_service(data: Path) -> tuple[subprocess.Popen[bytes], str, str, dict[str, str]]:
    port, zport = free_port(), free_port()
    log = open(data / "service.log", "wb")  # noqa: SIM115  (closed with the process)
    proc = subprocess.Popen(
        [sys.executable, "-m", "backend.cli", "serve", "--host", "127.0.0.1", "--port", str(port),
         "--zenoh-listen", f"tcp/127.0.0.1:{zport}", "--data-dir", str(data / "data"),
         "--log-level", "warning", "--admit", "*"],
        cwd=REPO, env={**os.environ, "REHAB_VISER_ENABLED": "0"}, stdout=log,
        stderr=subprocess.STDOUT,
    )  # fmt: skip
    url = f"http://127.0.0.1:{port}"
    wait_healthy(proc, url, log=data / "service.log")
    creds = dict(line.split(": ", 1) for line in
                 (data / "data" / "admin-credentials.txt").read_text().splitlines())  # fmt: skip
    return proc, url, f"tcp/127.0.0.1:{zport}", creds


def start_sessions(url: str, creds: dict[str, str], names: list[str]) -> None:
    with httpx.Client(base_url=url, timeout=30) as api:
        r = api.post(
            "/api/auth/login", json={"username": creds["username"], "password": creds["password"]}
        )
        r.raise_for_status()
        api.headers["Authorization"] = f"Bearer {r.json()['access_token']}"
        api.cookies.clear()
        for name in names:
            deadline = time.monotonic() + 30
            while api.get(f"/api/devices/{name}").status_code != 200:
                if time.monotonic() > deadline:
                    raise SystemExit(f"device {name} never registered")
                time.sleep(0.2)
            r = api.post("/api/patients", json={"code": f"B-{name}", "affected_side": "right"})
            r.raise_for_status()
            r = api.post("/api/sessions", json={"patient_id": r.json()["id"], "device": name})
            r.raise_for_status()


def measure(url: str, creds: dict[str, str], devices: list[DeviceThread], duration: float,
            chromium: str) -> dict[str, Any]:  # fmt: skip
    names = [d.name.removeprefix("sim-") for d in devices]
    from playwright.sync_api import expect, sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(base_url=url, viewport={"width": 1440, "height": 1000})
            page.set_default_timeout(60_000)
            page.add_init_script(PAGE_PROBE)
            page.goto("/login")
            page.get_by_label("Username").fill(creds["username"])
            page.get_by_label("Password").fill(creds["password"])
            page.keyboard.press("Enter")
            expect(page.get_by_role("heading", name="Devices", exact=True)).to_be_visible()
            page.goto(f"/grid?devices={','.join(names)}")
            for n in names:
                ind = page.locator(f".grid-cell[data-device={n}] .indicator")
                expect(ind).not_to_have_attribute("data-state", "waiting", timeout=90_000)
            for d in devices:  # measured in real time only
                if not d.realtime.wait(120):
                    raise SystemExit(f"{d.name}: still calibrating")
            page.wait_for_timeout(2000)
            snap = "() => structuredClone({live: window.__rehabLive, bench: window.__bench})"
            before = page.evaluate(snap)
            t0 = time.monotonic()
            page.wait_for_timeout(duration * 1000)
            after = page.evaluate(snap)
            dt = time.monotonic() - t0
        finally:
            browser.close()

    def rate(kind: str, n: str) -> float:
        b, a = before["live"][kind].get(n, 0), after["live"][kind].get(n, 0)
        return float(a - b) / dt

    long_tasks = after["bench"]["longTasks"] - before["bench"]["longTasks"]
    return {
        "seconds": dt,
        "updates_per_s": {n: rate("frames", n) for n in names},
        "messages_per_s": {n: rate("estimates", n) for n in names},
        "animation_frames_per_s": (after["bench"]["raf"] - before["bench"]["raf"]) / dt,
        "long_tasks": long_tasks,
        "long_task_ms": after["bench"]["longMs"] - before["bench"]["longMs"],
    }


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--devices", type=int, default=4)
    ap.add_argument("--duration", type=float, default=30.0, help="measured seconds")
    ap.add_argument("--no-sessions", action="store_true", help="devices without sessions")
    ap.add_argument(
        "--chromium", default=os.environ.get("REHAB_TEST_CHROMIUM", "/usr/bin/chromium")
    )
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    if not Path(args.chromium).exists():
        print(f"{args.chromium} missing: apt-get install chromium", file=sys.stderr)
        return 2
    if not (REPO / "frontend" / "dist" / "index.html").exists():
        print("front end not built: frontend/build.sh", file=sys.stderr)
        return 2
    names = [f"dash{i:02d}" for i in range(1, args.devices + 1)]
    sim_s = CALIBRATION_S + args.duration + 90.0  # calibration, page start-up and margin
    with tempfile.TemporaryDirectory(prefix="rehab-dashboard-") as tmp:
        proc, url, endpoint, creds = start_service(Path(tmp))
        devices = [device(endpoint, n, 20 + i, sim_s) for i, n in enumerate(names)]
        try:
            for d in devices:
                d.start()
            if not args.no_sessions:
                start_sessions(url, creds, names)
            result = measure(url, creds, devices, args.duration, args.chromium)
        finally:
            for d in devices:
                d.stop_event.set()
            for d in devices:
                d.join(10)
            proc.terminate()
            proc.wait(30)
        errors = [d.error for d in devices if d.error is not None]
        if errors:
            raise errors[0]
    result.update(devices=args.devices, sessions=not args.no_sessions,
                  machine=f"{platform.machine()}, {os.cpu_count()} CPUs, "
                          f"Python {platform.python_version()}")  # fmt: skip
    ups = result["updates_per_s"]
    print(
        f"{args.devices} devices on /grid, {result['seconds']:.1f} s measured "
        f"({'with' if result['sessions'] else 'without'} sessions)"
    )
    for n in names:
        print(
            f"  {n}: {ups[n]:5.1f} rendered updates/s, "
            f"{result['messages_per_s'][n]:5.1f} estimate messages/s"
        )
    print(
        f"  page: {result['animation_frames_per_s']:.1f} animation frames/s, "
        f"{result['long_tasks']} long tasks ({result['long_task_ms']:.0f} ms)"
    )
    ok = min(ups.values()) >= TARGET_HZ
    print(
        f"  slowest device {min(ups.values()):.1f}/s: target ≥ {TARGET_HZ:.0f}/s "
        f"{'met' if ok else 'NOT met'}"
    )
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
