"""Storage on SQLite and on PostgreSQL: migrations, CRUD through the API, the functions the
live side calls, restarts, and the audit log."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from fastapi import FastAPI
from sqlalchemy import Connection, select

from backend.app import create_app
from backend.db import Database
from backend.db.base import Base, utcnow
from backend.db.devices import mark_device_offline, touch_device, touch_devices
from backend.db.engine import alembic_config
from backend.db.models import AuditLog, Device
from backend.db.sessions import active_session, record_cycle, store_nominal_shoulder
from backend.deps import AppState, LiveUnavailable, SessionInfo
from backend.settings import Settings

pytestmark = pytest.mark.anyio


@pytest.fixture
def db_url(any_db_url: str) -> str:
    return any_db_url


def _diff(conn: Connection) -> list[Any]:
    context = MigrationContext.configure(conn, opts={"compare_type": True})
    return list(compare_metadata(context, Base.metadata))


def _downgrade_base(conn: Connection) -> None:
    cfg = alembic_config()
    cfg.attributes["connection"] = conn
    command.downgrade(cfg, "base")


async def test_migrations_match_models(db_url: str) -> None:
    database = Database(db_url)
    try:
        await database.migrate()
        async with database.engine.connect() as conn:
            assert await conn.run_sync(_diff) == []
        # Down and up again: the downgrade is complete and the upgrade repeatable.
        async with database.engine.begin() as conn:
            await conn.run_sync(_downgrade_base)
        await database.migrate()
        async with database.engine.connect() as conn:
            assert await conn.run_sync(_diff) == []
    finally:
        await database.dispose()


async def audit_log(state: AppState) -> list[tuple[str | None, str, str | None]]:
    async with state.database.session() as db:
        rows = await db.scalars(select(AuditLog).order_by(AuditLog.id))
        return [(a.actor, a.action, a.object) for a in rows]


async def test_patient_crud_round_trip(
    client: httpx.AsyncClient, state: AppState, admin: dict[str, str]
) -> None:
    new = {"code": "P-001", "affected_side": "right", "upper_arm_length_m": 0.32, "notes": "x"}
    r = await client.post("/api/patients", json=new, headers=admin)
    assert r.status_code == 201, r.text
    patient = r.json()
    pid = patient["id"]
    assert patient["upper_arm_length_m"] == 0.32 and patient["tolerance_m"] == 0.10
    assert patient["params"] == {
        "upper_arm_length_m": 0.32,
        "imu_to_elbow_m": 0.15,
        "cuff_to_elbow_m": 0.06,
        "tolerance_m": 0.10,
        "max_outside_fraction": 0.20,
        "displacement_norm": "horizontal",
        "warning_after_s": 1.0,
        "nominal_shoulder_m": None,
    }
    assert (await client.get(f"/api/patients/{pid}", headers=admin)).json() == patient

    assert (await client.post("/api/patients", json=new, headers=admin)).status_code == 409
    for bad in (
        {"code": "Jane Doe", "affected_side": "left"},  # codes have no spaces
        {"code": "P-2", "affected_side": "up"},
        {"code": "P-2", "affected_side": "left", "tolerance_m": -1},
        {"code": "P-2", "affected_side": "left", "name": "Jane"},  # unknown fields refused
    ):
        assert (await client.post("/api/patients", json=bad, headers=admin)).status_code == 422

    r = await client.patch(
        f"/api/patients/{pid}",
        json={"tolerance_m": 0.08, "displacement_norm": "3d"},
        headers=admin,
    )
    assert r.status_code == 200
    assert r.json()["params"]["tolerance_m"] == 0.08 and r.json()["displacement_norm"] == "3d"
    assert r.json()["updated_at"] >= patient["updated_at"]
    r = await client.patch(f"/api/patients/{pid}", json={"code": None}, headers=admin)
    assert r.status_code == 422
    # The tolerated duration may be adaptive (null: max_outside_fraction × last cycle).
    r = await client.patch(f"/api/patients/{pid}", json={"warning_after_s": None}, headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["warning_after_s"] is None and r.json()["params"]["warning_after_s"] is None
    got = (await client.get(f"/api/patients/{pid}", headers=admin)).json()
    assert got["warning_after_s"] is None
    r = await client.patch(f"/api/patients/{pid}", json={"warning_after_s": 2.5}, headers=admin)
    assert r.json()["params"]["warning_after_s"] == 2.5
    r = await client.patch(f"/api/patients/{pid}", json={"warning_after_s": -1}, headers=admin)
    assert r.status_code == 422

    await client.post("/api/patients", json={"code": "Q-9", "affected_side": "left"}, headers=admin)
    codes = [p["code"] for p in (await client.get("/api/patients", headers=admin)).json()]
    assert codes == ["P-001", "Q-9"]
    r = await client.get("/api/patients", params={"code": "P"}, headers=admin)
    assert [p["code"] for p in r.json()] == ["P-001"]
    r = await client.get("/api/patients", params={"code": "_"}, headers=admin)
    assert r.json() == []  # a LIKE wildcard is taken literally

    assert (await client.delete(f"/api/patients/{pid}", headers=admin)).status_code == 204
    assert (await client.get(f"/api/patients/{pid}", headers=admin)).status_code == 404

    log = await audit_log(state)
    for action in ("patient.create", "patient.update", "patient.delete"):
        assert ("admin", action, f"patient:{pid}") in log


async def test_device_registry(
    client: httpx.AsyncClient, state: AppState, admin: dict[str, str]
) -> None:
    async with state.database.transaction() as db:
        await touch_device(db, "rig-1", stats={"rejected": {"bad_shape": 2}})
        await touch_device(db, "rig-2", seen_at=utcnow() - timedelta(minutes=5))
    async with state.database.transaction() as db:
        await touch_device(db, "rig-1")  # an update keeps first_seen and the stats
    async with state.database.session() as db:
        seen = (await db.scalars(select(Device.last_seen).where(Device.name == "rig-1"))).one()
    async with state.database.transaction() as db:  # a queued, older snapshot lands late
        await touch_device(db, "rig-1", seen_at=seen - timedelta(seconds=2))
    async with state.database.session() as db:
        after = (await db.scalars(select(Device.last_seen).where(Device.name == "rig-1"))).one()
    assert after == seen  # last_seen never goes back
    devices = (await client.get("/api/devices", headers=admin)).json()
    assert [d["name"] for d in devices] == ["rig-1", "rig-2"]
    rig1, rig2 = devices
    assert rig1["status"] == "online" and rig1["stats"] == {"rejected": {"bad_shape": 2}}
    assert rig1["first_seen"] <= rig1["last_seen"]
    assert rig2["status"] == "offline"  # silent for longer than device_offline_after_s
    assert rig1["active_session_id"] is None

    async with state.database.transaction() as db:
        await mark_device_offline(db, "rig-1")
    r = await client.get("/api/devices/rig-1", headers=admin)
    assert r.json()["status"] == "offline"
    assert (await client.get("/api/devices/nope", headers=admin)).status_code == 404

    async with state.database.session() as db:
        device = await db.scalar(select(Device).where(Device.name == "rig-1"))
    assert device is not None and device.last_seen.tzinfo is not None
    assert device.last_seen.utcoffset() == timedelta(0)
    assert abs(device.last_seen - datetime.now(UTC)) < timedelta(minutes=1)


async def test_device_registry_in_one_statement(state: AppState) -> None:
    """The live writers' form: many devices per upsert, stats replaced per device, a name
    twice kept once, last_seen never back; without stats the stored ones stay."""
    t = utcnow()
    async with state.database.transaction() as db:
        await touch_devices(
            db,
            [
                ("rig-a", t, {"n": 1}),
                ("rig-b", t, {"n": 2}),
                ("rig-a", t, {"n": 3}),
            ],
        )
    async with state.database.transaction() as db:
        await touch_devices(db, [("rig-a", t - timedelta(seconds=5), None), ("rig-c", t, None)])
    async with state.database.session() as db:
        rows = (await db.execute(select(Device.name, Device.last_seen, Device.stats))).all()
    got = {name: (seen, stats) for name, seen, stats in rows}
    assert set(got) == {"rig-a", "rig-b", "rig-c"}
    assert got["rig-a"][1] == {"n": 3} and got["rig-b"][1] == {"n": 2}
    assert got["rig-a"][0] == got["rig-b"][0] == got["rig-c"][0]  # not moved back


async def _patient_and_device(
    client: httpx.AsyncClient, state: AppState, admin: dict[str, str], device: str = "rig-1"
) -> int:
    async with state.database.transaction() as db:
        await touch_device(db, device)
    r = await client.post(
        "/api/patients",
        json={"code": f"P-{device}", "affected_side": "left", "tolerance_m": 0.12},
        headers=admin,
    )
    pid: int = r.json()["id"]
    return pid


async def test_session_lifecycle(
    client: httpx.AsyncClient, state: AppState, admin: dict[str, str]
) -> None:
    pid = await _patient_and_device(client, state, admin)
    missing = await client.post(
        "/api/sessions", json={"patient_id": pid, "device": "ghost"}, headers=admin
    )
    assert missing.status_code == 404
    r = await client.post(
        "/api/sessions",
        json={
            "patient_id": pid,
            "device": "rig-1",
            "params": {"max_outside_fraction": 0.3, "nominal_shoulder_m": [0.1, 0.2, 0.3]},
        },
        headers=admin,
    )
    assert r.status_code == 201, r.text
    session = r.json()
    sid = session["id"]
    assert session["status"] == "active" and session["device"] == "rig-1"
    assert session["patient_code"] == "P-rig-1" and session["therapist"] == "admin"
    # The patient's parameters, with the session's overrides on top.
    assert session["params"]["tolerance_m"] == 0.12
    assert session["params"]["max_outside_fraction"] == 0.3
    assert session["nominal_shoulder"]["point"] == [0.1, 0.2, 0.3]
    assert session["nominal_shoulder"]["source"] == "params"
    assert session["params"]["warning_after_s"] == 1.0  # the patient's (not overridden)

    again = await client.post(
        "/api/sessions", json={"patient_id": pid, "device": "rig-1"}, headers=admin
    )
    assert again.status_code == 409  # one active session per device
    r = await client.get("/api/devices/rig-1", headers=admin)
    assert r.json()["active_session_id"] == sid

    # Nominal shoulder: a therapist's point; the estimate needs a pipeline; reset.
    r = await client.put(
        f"/api/sessions/{sid}/nominal-shoulder",
        json={"source": "point", "point": [0.0, 0.5, 1.0]},
        headers=admin,
    )
    assert r.status_code == 200
    assert r.json()["nominal_shoulder"]["point"] == [0.0, 0.5, 1.0]
    assert r.json()["nominal_shoulder"]["set_by"] == "admin"
    r = await client.put(
        f"/api/sessions/{sid}/nominal-shoulder", json={"source": "estimate"}, headers=admin
    )
    assert r.status_code == 409
    r = await client.put(
        f"/api/sessions/{sid}/nominal-shoulder", json={"source": "point"}, headers=admin
    )
    assert r.status_code == 422
    r = await client.delete(f"/api/sessions/{sid}/nominal-shoulder", headers=admin)
    assert r.status_code == 200 and r.json()["nominal_shoulder"] is None

    # The pipeline side: which session runs on a device, nominal from an event, cycles.
    async with state.database.transaction() as db:
        running = await active_session(db, "rig-1")
        assert running is not None and running.id == sid
        await store_nominal_shoulder(db, sid, (1.0, 2.0, 3.0), "event")
        await record_cycle(db, sid, start=0.0, end=4.0, outside_fraction=0.1, compensatory=False)
        await record_cycle(
            db, sid, start=4.0, end=8.5, outside_fraction=0.5, compensatory=True,
            coverage=0.98, peak_displacement_m=0.21,
        )  # fmt: skip
    got = (await client.get(f"/api/sessions/{sid}", headers=admin)).json()
    assert got["nominal_shoulder"]["source"] == "event"
    cycles = (await client.get(f"/api/sessions/{sid}/cycles", headers=admin)).json()
    assert [(c["index"], c["start"], c["end"], c["compensatory"]) for c in cycles] == [
        (0, 0.0, 4.0, False),
        (1, 4.0, 8.5, True),
    ]
    assert cycles[1]["peak_displacement_m"] == 0.21
    assert (await client.get("/api/sessions/999/cycles", headers=admin)).status_code == 404

    r = await client.post(f"/api/sessions/{sid}/stop", headers=admin)
    assert r.status_code == 200
    assert r.json()["status"] == "stopped" and r.json()["stopped_at"] is not None
    assert (await client.post(f"/api/sessions/{sid}/stop", headers=admin)).status_code == 409
    r = await client.put(
        f"/api/sessions/{sid}/nominal-shoulder",
        json={"source": "point", "point": [0, 0, 0]},
        headers=admin,
    )
    assert r.status_code == 409

    # A new session on the freed device, with the adaptive tolerated duration (an explicit
    # null; omitted keys and other nulls keep the patient's); lists per patient and status.
    r = await client.post(
        "/api/sessions",
        json={
            "patient_id": pid,
            "device": "rig-1",
            "params": {"warning_after_s": None, "tolerance_m": None},
        },
        headers=admin,
    )
    assert r.status_code == 201
    assert r.json()["params"]["warning_after_s"] is None
    assert r.json()["params"]["tolerance_m"] == 0.12
    listed = (await client.get("/api/sessions", params={"patient_id": pid}, headers=admin)).json()
    assert [s["id"] for s in listed] == [r.json()["id"], sid]
    active = await client.get("/api/sessions", params={"status": "active"}, headers=admin)
    assert [s["id"] for s in active.json()] == [r.json()["id"]]
    by_device = await client.get("/api/sessions", params={"device": "rig-1"}, headers=admin)
    assert len(by_device.json()) == 2
    # Patients with recorded sessions are not deletable.
    assert (await client.delete(f"/api/patients/{pid}", headers=admin)).status_code == 409

    log = await audit_log(state)
    for action in (
        "session.start",
        "session.nominal_shoulder",
        "session.nominal_shoulder_reset",
        "session.stop",
    ):
        assert ("admin", action, f"session:{sid}") in log


async def test_restart_marks_sessions_interrupted(
    app: FastAPI, client: httpx.AsyncClient, state: AppState, admin: dict[str, str],
    settings: Settings,
) -> None:  # fmt: skip
    pid = await _patient_and_device(client, state, admin)
    r = await client.post(
        "/api/sessions", json={"patient_id": pid, "device": "rig-1"}, headers=admin
    )
    sid = r.json()["id"]
    async with state.database.transaction() as db:
        await record_cycle(db, sid, start=0.0, end=3.0, outside_fraction=0.0, compensatory=False)
        await touch_device(db, "rig-1")  # data kept coming in until the kill

    # A second service on the same data, as after a kill -9 of the first.
    restarted = create_app(settings)
    async with restarted.router.lifespan_context(restarted):
        assert restarted.state.rehab.interrupted_sessions == [sid]
        transport = httpx.ASGITransport(app=restarted)
        async with httpx.AsyncClient(transport=transport, base_url="https://t") as c2:
            got = (await c2.get(f"/api/sessions/{sid}", headers=admin)).json()
            cycles = (await c2.get(f"/api/sessions/{sid}/cycles", headers=admin)).json()
            device = (await c2.get("/api/devices/rig-1", headers=admin)).json()
    assert got["status"] == "interrupted"
    assert got["stopped_at"] == device["last_seen"] > got["started_at"]  # when data stopped
    assert len(cycles) == 1
    assert device["status"] == "offline" and device["active_session_id"] is None


class RecordingLive:
    """Stands in for the pipeline manager (not ours yet): records what REST asked of it."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, Any]] = []
        self.refuse_reset = False

    async def session_started(self, session: SessionInfo) -> str | None:
        self.calls.append(("started", session))
        return f"recordings/session-{session.id}.jsonl"

    async def session_committed(self, session: SessionInfo) -> None:
        self.calls.append(("committed", session))

    async def session_stopped(self, session: SessionInfo) -> dict[str, Any] | None:
        self.calls.append(("stopped", session.id))
        return {"cycles": 0, "compensatory": 0}

    async def set_nominal_shoulder(
        self, session: SessionInfo, point: Sequence[float] | None, from_estimate: bool
    ) -> Sequence[float] | None:
        self.calls.append(("nominal", (point, from_estimate)))
        if from_estimate:
            return (0.4, 0.5, 0.6)
        if point is None and not self.refuse_reset:
            return None
        raise LiveUnavailable("refused")


async def test_live_hooks(
    client: httpx.AsyncClient, state: AppState, admin: dict[str, str]
) -> None:
    live = RecordingLive()
    state.live = live
    pid = await _patient_and_device(client, state, admin)
    r = await client.post(
        "/api/sessions", json={"patient_id": pid, "device": "rig-1"}, headers=admin
    )
    sid = r.json()["id"]
    assert r.json()["recording_path"] == f"recordings/session-{sid}.jsonl"
    kind, info = live.calls[0]
    assert kind == "started" and (info.id, info.device, info.patient_id) == (sid, "rig-1", pid)
    assert info.params["tolerance_m"] == 0.12
    kind, committed = live.calls[1]  # after the commit: the same session, its recording set
    assert kind == "committed" and committed.id == sid
    assert committed.recording_path == f"recordings/session-{sid}.jsonl"

    r = await client.put(
        f"/api/sessions/{sid}/nominal-shoulder", json={"source": "estimate"}, headers=admin
    )
    assert r.json()["nominal_shoulder"]["point"] == [0.4, 0.5, 0.6]
    assert r.json()["nominal_shoulder"]["source"] == "estimate"
    r = await client.put(
        f"/api/sessions/{sid}/nominal-shoulder",
        json={"source": "point", "point": [1, 1, 1]},
        headers=admin,
    )
    assert r.status_code == 409  # the live side refused: nothing stored
    assert (await client.get(f"/api/sessions/{sid}", headers=admin)).json()["nominal_shoulder"][
        "point"
    ] == [0.4, 0.5, 0.6]

    live.refuse_reset = True  # e.g. the device no longer runs the session
    r = await client.delete(f"/api/sessions/{sid}/nominal-shoulder", headers=admin)
    assert r.status_code == 409 and r.json()["detail"] == "refused"
    assert (await client.get(f"/api/sessions/{sid}", headers=admin)).json()["nominal_shoulder"][
        "point"
    ] == [0.4, 0.5, 0.6]  # nothing stored
    log = await audit_log(state)
    assert ("admin", "session.nominal_shoulder_reset", f"session:{sid}") not in log

    r = await client.post(f"/api/sessions/{sid}/stop", headers=admin)
    summary = r.json()["summary"]
    assert summary["cycles"] == 0 and summary["compensatory"] == 0
    assert ("stopped", sid) in live.calls
