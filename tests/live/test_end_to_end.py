"""A simulated device publishes over Zenoh into the running service during a session: the
session's files are identical to ``rehab analyze`` of its stored recording and of the
original recording; the same data at 1× and at 20× real time give identical results."""

from __future__ import annotations

import gzip
import json
import sqlite3
import threading
from pathlib import Path
from typing import Any

import pytest

from backend.analysis import CSV_HEADER, DETAILS_HEADER, DeviceRun, analyze
from backend.live.files import dump_report
from estimators.params import PipelineParams
from protocol import recording
from simulator import SimConfig, simulate
from simulator.publish import play, prepare
from tests.live.conftest import Service, wait_for


def analysis(path: Path, params: dict[str, Any]) -> tuple[str, dict[str, Any], str]:
    """``rehab analyze``'s estimates.csv, report and details.csv."""
    run: DeviceRun
    run, rep = analyze(path, PipelineParams.from_json(params))
    est = CSV_HEADER + "\n" + "".join(x + "\n" for x in run.est_lines)
    return est, rep, DETAILS_HEADER + "\n" + "".join(x + "\n" for x in run.det_lines)


def stream(
    service: Service,
    device: str,
    messages: list[tuple[str, Any]],
    speed: float,
    session: bool = True,
) -> dict[str, Any] | None:
    """Announce the device, start a session on it, play, wait until all is received."""
    outgoing = prepare(messages)
    with service.publisher() as pub:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        started = service.start(device) if session else None
        play(pub, outgoing, speed)
        wait_for(
            lambda: service.received(device) >= len(outgoing),
            timeout=60,
            what=f"{device}: {len(outgoing)} messages received",
        )
    return started


def exports(service: Service, sid: int) -> tuple[str, dict[str, Any], bytes]:
    r = service.api.get(f"/api/sessions/{sid}/estimates.csv")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    csv = r.text
    rep = service.api.get(f"/api/sessions/{sid}/report")
    assert rep.status_code == 200, rep.text
    rec = service.api.get(f"/api/sessions/{sid}/recording.jsonl.gz")
    assert rec.status_code == 200
    return csv, rep.json(), rec.content


def test_live_session_equals_offline_analysis(service: Service, tmp_path: Path) -> None:
    device = "e2e01"
    sim = simulate(SimConfig(seed=11, duration_s=75.0, device=device))
    original = tmp_path / "original.jsonl.gz"
    recording.write(original, sim.messages)

    session = stream(service, device, sim.messages, speed=20.0)
    assert session is not None
    sid = session["id"]
    stopped = service.stop(sid)
    assert stopped["status"] == "stopped"
    assert stopped["recording_path"] == f"recordings/{sid}.jsonl.gz"
    csv, exported, rec_bytes = exports(service, sid)
    r = service.api.get(f"/api/sessions/{sid}/details.csv")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    assert r.headers["content-disposition"] == f'attachment; filename="session-{sid}-details.csv"'
    details = r.text

    stored = service.data_dir / stopped["recording_path"]
    # the stored recording holds exactly the published messages, byte for byte
    assert gzip.decompress(rec_bytes) == gzip.decompress(stored.read_bytes())
    assert [(k, bytes(p)) for k, p in recording.read(stored)] == [
        (k, bytes(p)) for k, p in recording.read(original)
    ]

    params = stopped["params"]
    for source in (stored, original):
        want_csv, want_report, want_details = analysis(source, params)
        assert csv == want_csv
        assert details == want_details
        assert exported["report"] == json.loads(dump_report(want_report))
    out = service.data_dir / "recordings" / str(sid)
    assert (out / "report.json").read_text() == dump_report(want_report)
    assert (out / "estimates.csv").read_text() == want_csv

    # the session carries what the live run produced
    rep = exported["report"]
    assert rep["summary"]["rows"] == sum(1 for k, _ in sim.messages if k.endswith("/robot"))
    assert rep["summary"]["cycles"] > 0
    assert stopped["summary"]["cycles"] == rep["summary"]["cycles"]
    cycles = service.api.get(f"/api/sessions/{sid}/cycles").json()
    assert [(c["start"], c["end"], c["compensatory"]) for c in cycles] == [
        (c["start"], c["end"], c["compensatory"]) for c in rep["cycles"]
    ]
    assert exported["patient"]["code"] == f"p-{device}"
    assert exported["session"]["id"] == sid and exported["provisional"] is False
    audit = service.api.get("/api/audit").json()
    actions = {(a["action"], a["object"]) for a in audit}
    for action in ("export.report", "export.estimates", "export.details", "export.recording"):
        assert (action, f"session:{sid}") in actions
    history_without_reports(service, stopped, rep)


RANGES = ("elbow_flexion_deg", "upper_arm_elevation_deg", "upper_arm_azimuth_deg")


def history_without_reports(service: Service, stopped: dict[str, Any], rep: dict[str, Any]) -> None:
    """A patient's history reads the sessions list: its summaries carry the range of motion
    (from the live run, or from the stored report for sessions stored before), and reading
    it is no export."""
    sid = stopped["id"]
    for key in RANGES:
        assert stopped["summary"][key] == rep[key] and rep[key]["range"] > 0
    assert stopped["summary"]["shoulder_displacement_m"] == rep["shoulder_displacement_m"]
    assert stopped["summary"]["compensatory_share"] == rep["summary"]["compensatory_share"]

    def history() -> dict[str, Any]:
        listed = service.api.get("/api/sessions", params={"patient_id": stopped["patient_id"]})
        assert listed.status_code == 200, listed.text
        (one,) = listed.json()
        summary: dict[str, Any] = one["summary"]
        return summary

    def audited() -> list[dict[str, Any]]:
        entries: list[dict[str, Any]] = service.api.get(
            "/api/audit", params={"object": f"session:{sid}"}
        ).json()
        return entries

    audit_before = audited()
    assert history() == stopped["summary"]
    # a summary stored before it held the range of motion: completed from report.json, once
    old = {k: v for k, v in stopped["summary"].items() if k not in RANGES}
    with sqlite3.connect(service.data_dir / "rehab.db", timeout=10) as db:
        db.execute("UPDATE sessions SET summary = ? WHERE id = ?", (json.dumps(old), sid))
    db.close()
    assert history() == stopped["summary"]
    with sqlite3.connect(service.data_dir / "rehab.db", timeout=10) as db:
        (kept,) = db.execute("SELECT summary FROM sessions WHERE id = ?", (sid,)).fetchone()
    db.close()
    assert json.loads(kept) == stopped["summary"]
    assert service.api.get(f"/api/sessions/{sid}").json()["summary"] == stopped["summary"]
    # reading the history is audited as a read (issue 21), and is no export
    exported = [a for a in audited() if a["action"].startswith("export.")]
    assert exported == [a for a in audit_before if a["action"].startswith("export.")]
    assert any(a["action"] == "session.read" for a in audited())


@pytest.mark.slow
def test_publish_speed_does_not_change_results(service: Service) -> None:
    """30 s of data at 1× and at 20× (two devices at once): identical files."""
    results: dict[str, tuple[str, dict[str, Any]]] = {}
    errors: list[BaseException] = []

    def one(device: str, speed: float) -> None:
        try:
            sim = simulate(SimConfig(seed=5, duration_s=30.0, device=device))
            session = stream(service, device, sim.messages, speed)
            assert session is not None
            service.stop(session["id"])
            csv, exported, _ = exports(service, session["id"])
            results[device] = csv, exported["report"]
        except BaseException as exc:
            errors.append(exc)

    threads = [
        threading.Thread(target=one, args=("speed01", 1.0)),
        threading.Thread(target=one, args=("speed20", 20.0)),
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    (csv1, rep1), (csv20, rep20) = results["speed01"], results["speed20"]
    assert csv1 == csv20
    assert rep1.pop("device") == "speed01" and rep20.pop("device") == "speed20"
    assert rep1 == rep20
    assert rep1["summary"]["rows"] > 0
