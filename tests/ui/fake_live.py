"""A stand-in for the live side, for front-end development only: the real app (REST, auth,
storage, static files, 3D view) plus synthetic ``/api/ws/live`` and ``/api/ws/overlay``
feeds that follow the WebSocket protocol. Not used by the UI tests, which run against the
real service (``rehab serve`` with simulated devices over Zenoh).

    python -m tests.ui.fake_live --port 8765 --data-dir /tmp/rehab-fake
"""

from __future__ import annotations

import argparse
import asyncio
import math
import time
from typing import Any

import uvicorn
from fastapi import FastAPI, WebSocket, WebSocketDisconnect
from sqlalchemy import select

from backend.app import create_app
from backend.auth.guards import CurrentTherapist, OverlayAccess
from backend.db.devices import touch_device
from backend.db.models import Device, Patient, Session
from backend.settings import Settings

PERIOD_S = 5.0
RATE_HZ = 25.0


class FakeDevice:
    def __init__(self, name: str, drift: bool) -> None:
        self.name = name
        self.drift = drift
        self.t0 = time.monotonic()
        self.outside_since: float | None = None
        self.cycle_outside = 0
        self.cycle_n = 0
        self.cycle_index = 0
        self.cycle_start = 0.0
        self.last_state: str | None = None

    def row(self, t: float) -> dict[str, Any]:
        ph = (t % PERIOD_S) / PERIOD_S
        # wrist on a 0.30 x 0.20 rectangle (perimeter parametrisation)
        a, b = 0.15, 0.10
        per = 4 * (a + b)
        s = ph * per
        if s < 2 * a:
            wx, wy = a - s, b
        elif s < 2 * a + 2 * b:
            wx, wy = -a, b - (s - 2 * a)
        elif s < 4 * a + 2 * b:
            wx, wy = -a + (s - 2 * a - 2 * b), -b
        else:
            wx, wy = a, -b + (s - 4 * a - 2 * b)
        wx, wy, wz = 0.05 + wx, 0.40 + wy, 0.0
        nominal = (0.15, 0.0, 0.40)
        lean = 0.0
        if self.drift and t > 12:
            lean = 0.16 * max(0.0, math.sin(2 * math.pi * t / 20.0)) * min(1.0, (t - 12) / 6)
        lean += 0.025 * math.sin(2 * math.pi * ph)
        sx, sy, sz = nominal[0] - 0.2 * lean, nominal[1] + lean, nominal[2] - 0.3 * lean
        # elbow: midpoint pushed down and out
        ex, ey, ez = (sx + wx) / 2 + 0.06, (sy + wy) / 2, (sz + wz) / 2 - 0.08
        ua = (ex - sx, ey - sy, ez - sz)
        fa = (wx - ex, wy - ey, wz - ez)
        dot = sum(p * q for p, q in zip(ua, fa, strict=True))
        nu = math.sqrt(sum(p * p for p in ua))
        nf = math.sqrt(sum(p * p for p in fa))
        elbow_angle = math.degrees(math.acos(max(-1.0, min(1.0, dot / (nu * nf)))))
        elev = math.degrees(math.asin(max(-1.0, min(1.0, -ua[2] / nu))))
        converged = t > 8.0
        disp = math.hypot(sx - nominal[0], sy - nominal[1]) if converged else None
        state: str | None = None
        if disp is not None:
            if disp <= 0.10:
                state, self.outside_since = "ok", None
            else:
                if self.outside_since is None:
                    self.outside_since = t
                state = "warning" if t - self.outside_since > 1.0 else "outside"
        nom = nominal if converged else (None, None, None)
        return {
            "t": t, "elbow_x": ex, "elbow_y": ey, "elbow_z": ez,
            "shoulder_x": sx, "shoulder_y": sy, "shoulder_z": sz,
            "elbow_angle_deg": elbow_angle, "heading_offset_deg": 12.0,
            "heading_converged": 1 if converged else 0,
            "shoulder_displacement_m": disp, "state": state,
            "upper_arm_elevation_deg": 90 - elev if False else elev + 40,
            "upper_arm_azimuth_deg": 10.0, "heading_confidence": 0.9 if converged else 0.2,
            "nominal_x": nom[0], "nominal_y": nom[1], "nominal_z": nom[2],
            "wrist_x": wx, "wrist_y": wy, "wrist_z": wz,
            "dx": (sx - nominal[0]) if converged else None,
            "dy": (sy - nominal[1]) if converged else None,
        }


def install_fake_live(app: FastAPI, names: list[str]) -> None:
    devices = {n: FakeDevice(n, drift=(i % 2 == 1)) for i, n in enumerate(names)}
    subscribers: set[asyncio.Queue[dict[str, Any]]] = set()

    async def session_of(name: str) -> tuple[int | None, str | None]:
        state = app.state.rehab
        async with state.database.session() as db:
            row = (
                await db.execute(
                    select(Session.id, Patient.code)
                    .join(Session.device)
                    .join(Session.patient)
                    .where(Device.name == name, Session.status == "active")
                )
            ).first()
        return (row[0], row[1]) if row else (None, None)

    async def producer() -> None:
        state = app.state.rehab
        async with state.database.transaction() as db:
            for n in names:
                await touch_device(db, n)
        last_status = 0.0
        last_touch = 0.0
        pending: dict[str, list[dict[str, Any]]] = {n: [] for n in names}
        k = 0
        start = time.monotonic()
        while True:
            k += 1
            await asyncio.sleep(max(0.0, start + k / RATE_HZ - time.monotonic()))
            now = time.monotonic()
            out: list[dict[str, Any]] = []
            for n, d in devices.items():
                t = now - d.t0
                r = d.row(t)
                pending[n].append(r)
                if r["state"] != d.last_state and r["state"] is not None:
                    out.append({"type": "state", "device": n, "t": t, "state": r["state"]})
                d.last_state = r["state"]
                if r["state"] is not None:
                    d.cycle_n += 1
                    d.cycle_outside += r["state"] != "ok"
                if int(t / PERIOD_S) != int((t - 1 / RATE_HZ) / PERIOD_S) and d.cycle_n > 10:
                    d.cycle_index += 1
                    frac = d.cycle_outside / d.cycle_n
                    out.append({
                        "type": "cycle", "device": n, "start": d.cycle_start, "end": t,
                        "outside_fraction": frac, "compensatory": frac > 0.2,
                        "index": d.cycle_index,
                    })
                    d.cycle_start, d.cycle_n, d.cycle_outside = t, 0, 0
                rows = pending[n]
                if len(rows) >= 1:
                    cols = {key: [x[key] for x in rows] for key in rows[0]}
                    out.append({"type": "estimate", "device": n, "rows": cols})
                    viz = getattr(app.state, "viz", None)
                    if viz is not None:
                        viz.update(n, cols)
                    pending[n] = []
            if now - last_status > 1.0:
                last_status = now
                for n, d in devices.items():
                    sid, code = await session_of(n)
                    t = now - d.t0
                    out.append({
                        "type": "status", "device": n, "online": True, "session_id": sid,
                        "patient": code, "heading_converged": t > 8,
                        "convergence_progress": min(1.0, t / 8), "heading_confidence": 0.9,
                        "heading_std_deg": 1.2, "upper_arm_length_m": 0.3,
                        "quality": {"rejected": {}, "seq_lost": {}, "robot_gaps": 0},
                        "rates_hz": {"imu": 100.0, "robot": 25.0}, "tolerance_m": 0.1,
                    })
            if now - last_touch > 2.0:
                last_touch = now
                async with state.database.transaction() as db:
                    for n in names:
                        await touch_device(db, n)
            for q in list(subscribers):
                for m in out:
                    if q.qsize() < 2000:
                        q.put_nowait(m)

    @app.websocket("/api/ws/live")
    async def live(websocket: WebSocket, therapist: CurrentTherapist) -> None:
        ensure_running()
        await websocket.accept()
        wanted = websocket.query_params.get("devices")
        sel = set(wanted.split(",")) if wanted else set(names)
        q: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        subscribers.add(q)
        try:
            await websocket.send_json({"type": "hello", "devices": [n for n in names if n in sel]})
            while True:
                m = await q.get()
                if m.get("device") in sel:
                    await websocket.send_json(m)
        except WebSocketDisconnect:
            pass
        finally:
            subscribers.discard(q)

    @app.websocket("/api/ws/overlay")
    async def overlay(websocket: WebSocket, grant: OverlayAccess) -> None:
        ensure_running()
        await websocket.accept()
        q: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        subscribers.add(q)
        keep = ("t", "wrist_x", "wrist_y", "wrist_z", "shoulder_displacement_m", "dx", "dy",
                "state")
        try:
            while True:
                m = await q.get()
                if m.get("device") != grant.device:
                    continue
                m = dict(m)
                m.pop("device", None)
                if m["type"] == "estimate":
                    m["rows"] = {k: m["rows"][k] for k in keep}
                await websocket.send_json(m)
        except WebSocketDisconnect:
            pass
        finally:
            subscribers.discard(q)

    task: list[asyncio.Task[None]] = []

    def ensure_running() -> None:
        if not task:
            task.append(asyncio.get_running_loop().create_task(producer()))

    app.state.fake_live_start = ensure_running


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, default=8765)
    ap.add_argument("--data-dir", default="/tmp/rehab-fake")
    ap.add_argument("--devices", default="sim01,sim02,sim03,sim04")
    args = ap.parse_args()
    settings = Settings(data_dir=args.data_dir, port=args.port, cookie_secure=False)
    app = create_app(settings)
    install_fake_live(app, args.devices.split(","))
    uvicorn.run(app, host="127.0.0.1", port=args.port, log_level="warning")


if __name__ == "__main__":
    main()
