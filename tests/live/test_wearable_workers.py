"""A wearable session in workers mode (``rehab serve --workers 2``): the worker holding the
device runs it; joints on ``rehab/<device>/joints``, the ROM test through the API node, and
the session's joints.csv and report.json are rehab analyze's of its recording."""

from __future__ import annotations

from pathlib import Path

import pytest

from backend import analysis_wearable as aw
from backend.analysis import dump_report
from protocol import wire
from simulator import wearable as sw
from simulator.publish import Publisher, play, prepare
from tests.live.conftest import login, wait_for
from tests.live.test_scaleout import Cluster
from tests.live.test_wearable_live import JointsListener, spec_of


@pytest.mark.slow
def test_wearable_session_through_workers(tmp_path: Path) -> None:
    device = "wwork01"
    sim = sw.simulate(sw.WearableSimConfig(move="rom", duration_s=10.0, seed=9, device=device))
    outgoing = prepare(sim.messages)
    half = next(i for i, o in enumerate(outgoing) if o.at >= 3.0)
    cluster = Cluster(tmp_path / "data", workers=2)
    listener = JointsListener(cluster.endpoint, device)
    try:
        api, _ = login(cluster.url, cluster.settings)
        with Publisher.connect(cluster.endpoint) as pub:
            pub.declare(outgoing)
            assert pub.wait_for_subscribers(10.0)
            wait_for(lambda: device in cluster.leases(), what="device leased")
            pid = api.post("/api/patients", json={"code": "p-w", "affected_side": "right"})
            body = {
                "patient_id": pid.json()["id"],
                "device": device,
                "wearable": spec_of(sim.params),
            }
            r = api.post("/api/sessions", json=body)
            assert r.status_code == 201, r.text
            sid = r.json()["id"]
            play(pub, outgoing[:half], 20.0)
            wait_for(lambda: listener.payloads, what="first joints")
            r = api.post(f"/api/sessions/{sid}/rom-test", json={"movement": "shoulder_flexion"})
            assert r.status_code == 200, r.text
            play(pub, outgoing[half:], 20.0)
            n = len(sim.t)

            def published() -> int:
                return sum(len(wire.decode_joints(p)["t"]) for p in list(listener.payloads))

            wait_for(lambda: published() >= n - 5, timeout=60, what="joints published")
            r = api.delete(f"/api/sessions/{sid}/rom-test")
            assert r.status_code == 200, r.text
            test = r.json()
            assert 135.0 < test["peak_deg"] < 165.0
        r = api.post(f"/api/sessions/{sid}/stop")
        assert r.status_code == 200, r.text
        stopped = r.json()
        assert stopped["summary"]["mode"] == "wearable"
        assert stopped["summary"]["rom_tests"] == [test]
        out = cluster.settings.data_dir / "recordings" / str(sid)
        stored = cluster.settings.data_dir / stopped["recording_path"]
        want = aw.analyze(stored, aw.load_params(stopped["params"]), tmp_path / "off", device)
        assert (out / "joints.csv").read_text() == (tmp_path / "off" / "joints.csv").read_text()
        assert want["summary"]["rows"] == n
        want["rom_tests"] = [test]
        assert (out / "report.json").read_text() == dump_report(want)
    finally:
        listener.close()
        cluster.stop()
