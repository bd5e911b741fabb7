"""``kill -9`` mid-session, restart: the session is listed as interrupted, its recording up
to the kill is intact (at most the last second of accepted data is lost), and its report
and estimates are regenerated from that recording."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import httpx

from backend.analysis import CSV_HEADER, analyze
from backend.live.files import dump_report
from backend.settings import Settings
from estimators.params import PipelineParams
from protocol import recording
from simulator import SimConfig, simulate
from simulator.publish import Outgoing, Publisher, play, prepare
from tests.live.conftest import free_port, login, wait_for

REPO = Path(__file__).resolve().parents[2]
DEVICE = "crash01"


class ServiceProcess:
    def __init__(self, data_dir: Path, db_url: str) -> None:
        self.port, self.zport = free_port(), free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.zport}"
        self.url = f"http://127.0.0.1:{self.port}"
        self.args = [
            sys.executable,
            "-m",
            "backend.cli",
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--zenoh-listen",
            self.endpoint,
            "--data-dir",
            str(data_dir),
            "--database-url",
            db_url,
            "--log-level",
            "warning",
            "--admit",
            "*",
        ]
        self.settings = Settings(data_dir=data_dir, database_url=db_url)
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.proc = subprocess.Popen(self.args, cwd=REPO, stdout=subprocess.DEVNULL)

        def healthy() -> bool:
            assert self.proc is not None and self.proc.poll() is None, "service died"
            try:
                return httpx.get(self.url + "/api/health", timeout=1).status_code == 200
            except httpx.HTTPError:
                return False

        # the default `rehab serve`: the API node waits for its worker processes
        wait_for(healthy, timeout=120, what="service up")

    def kill(self) -> None:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def test_kill_9_mid_session(tmp_path: Path, any_db_url: str) -> None:
    """On SQLite and PostgreSQL."""
    db_url = any_db_url
    sim = simulate(SimConfig(seed=31, duration_s=40.0, device=DEVICE))
    outgoing = prepare(sim.messages)
    svc = ServiceProcess(tmp_path / "data", db_url)
    sent: list[tuple[float, Outgoing]] = []
    stop = threading.Event()
    try:
        svc.start()
        api, _ = login(svc.url, svc.settings)
        with Publisher.connect(svc.endpoint) as pub:
            pub.declare(outgoing)
            assert pub.wait_for_subscribers(10.0)
            wait_for(
                lambda: api.get(f"/api/devices/{DEVICE}").status_code == 200,
                what="device registered",
            )
            pid = api.post("/api/patients", json={"code": "crash", "affected_side": "right"})
            r = api.post("/api/sessions", json={"patient_id": pid.json()["id"], "device": DEVICE})
            assert r.status_code == 201, r.text
            session: dict[str, Any] = r.json()
            player = threading.Thread(
                target=play,
                args=(pub, outgoing, 1.0),
                kwargs={"stop": stop, "on_sent": lambda m, t: sent.append((t, m))},
            )
            player.start()
            time.sleep(8.0)
            svc.kill()
            killed_at = time.time()
            stop.set()
            player.join()
        api.close()

        svc.start()
        api, _ = login(svc.url, svc.settings)
        sid = session["id"]
        listed = api.get("/api/sessions", params={"status": "interrupted"}).json()
        assert [s["id"] for s in listed] == [sid]
        interrupted = listed[0]
        assert interrupted["stopped_at"] is not None

        # the recording: exactly the first messages sent, missing at most the last second
        stored = svc.settings.data_dir / interrupted["recording_path"]
        lines = [(k, bytes(p)) for k, p in recording.read(stored)]
        assert lines == [(m.key, m.payload) for m in outgoing[: len(lines)]]
        before_kill = [m for t, m in sent if t < killed_at - 1.0]
        assert len(lines) >= len(before_kill) > 100

        # report and estimates regenerated from it, and served
        run, want = analyze(stored, PipelineParams.from_json(interrupted["params"]))
        rep = api.get(f"/api/sessions/{sid}/report")
        assert rep.status_code == 200, rep.text
        assert rep.json()["report"]["summary"] == want["summary"]
        csv = api.get(f"/api/sessions/{sid}/estimates.csv").text
        assert csv == CSV_HEADER + "\n" + "".join(x + "\n" for x in run.est_lines)
        assert (stored.parent / str(sid) / "report.json").read_text() == dump_report(want)
        assert want["summary"]["rows"] > 100
        wait_for(
            lambda: api.get(f"/api/sessions/{sid}").json()["summary"] is not None,
            what="summary stored after recovery",
        )
        api.close()
    finally:
        stop.set()
        svc.stop()
    assert os.path.exists(stored)


def test_shutdown_finishes_running_sessions(tmp_path: Path) -> None:
    """SIGTERM: the running session is finished (files complete, report written) and
    stored as interrupted, with its summary."""
    sim = simulate(SimConfig(seed=32, duration_s=20.0, device=DEVICE))
    outgoing = prepare(sim.messages)
    svc = ServiceProcess(tmp_path / "data", f"sqlite+aiosqlite:///{tmp_path / 'db.sqlite'}")
    try:
        svc.start()
        api, _ = login(svc.url, svc.settings)
        with Publisher.connect(svc.endpoint) as pub:
            pub.declare(outgoing)
            assert pub.wait_for_subscribers(10.0)
            wait_for(
                lambda: api.get(f"/api/devices/{DEVICE}").status_code == 200,
                what="device registered",
            )
            pid = api.post("/api/patients", json={"code": "term", "affected_side": "left"})
            started = api.post(
                "/api/sessions", json={"patient_id": pid.json()["id"], "device": DEVICE}
            ).json()
            sid = started["id"]
            play(pub, outgoing, 0.0)
            wait_for(
                lambda: (
                    (api.get(f"/api/devices/{DEVICE}").json()["stats"] or {})
                    .get("ingest", {})
                    .get("messages", 0)
                    >= len(outgoing)
                ),
                what="received",
            )
            api.close()
            svc.stop()
        assert svc.proc is not None and svc.proc.returncode is not None
        out = svc.settings.data_dir / "recordings" / str(sid)
        report = (out / "report.json").read_text()
        stored = svc.settings.data_dir / "recordings" / f"{sid}.jsonl.gz"
        _, want = analyze(stored, PipelineParams.from_json(started["params"]))
        assert report == dump_report(want)
        svc.start()
        api, _ = login(svc.url, svc.settings)
        session = api.get(f"/api/sessions/{sid}").json()
        assert session["status"] == "interrupted"
        assert (
            session["summary"]["rows"]
            == want["summary"]["rows"]
            == len([k for k, _ in sim.messages if k.endswith("/robot")])
        )
        api.close()
    finally:
        svc.stop()
