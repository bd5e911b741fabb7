"""Wearable devices in the live service (contract §8): a simulated two-IMU + camera device
publishes over Zenoh during a wearable session. The session's joints.csv and report.json are
those of ``rehab analyze`` of its recording, byte for byte; the joint angles go out on
``rehab/<device>/joints``; bad input (no forearm stream, a mounting that does not fit) is
flagged and counted, never a crash or a silently wrong angle."""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from backend import analysis_wearable as aw
from backend.analysis import dump_report
from protocol import keys, recording, wire
from simulator import wearable as sw
from simulator.publish import play, prepare
from tests.live.conftest import Service, wait_for


def start_wearable(service: Service, device: str, spec: dict[str, Any]) -> dict[str, Any]:
    wait_for(lambda: service.device(device), what=f"device {device} registered")
    body = {"patient_id": service.patient(f"p-{device}"), "device": device, "wearable": spec}
    r = service.api.post("/api/sessions", json=body)
    assert r.status_code == 201, r.text
    session: dict[str, Any] = r.json()
    return session


def spec_of(params: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in params.items() if k not in ("mode", "upper_arm_length_m")}


class JointsListener:
    """A subscriber of ``rehab/<device>/joints``, as an independent tool would be."""

    def __init__(self, endpoint: str, device: str) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.payloads: list[bytes] = []
        self._lock = threading.Lock()
        self.sub = self.session.declare_subscriber(keys.joints(device), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.payloads.append(sample.payload.to_bytes())

    def rows(self) -> dict[str, np.ndarray]:
        with self._lock:
            parts = [wire.decode_joints(p) for p in self.payloads]
        return {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


def run_session(
    service: Service,
    sim: sw.WearableSimulation,
    spec: dict[str, Any],
    drop: str | None = None,
    listener: JointsListener | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    device = sim.config.device
    msgs = [(k, p) for k, p in sim.messages if drop is None or not k.endswith(drop)]
    outgoing = prepare(msgs)
    with service.publisher() as pub:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        session = start_wearable(service, device, spec)
        play(pub, outgoing, 50.0)
        wait_for(
            lambda: service.received(device) >= len(outgoing),
            timeout=90,
            what=f"{device}: {len(outgoing)} messages received",
        )
    status = wait_for(lambda: _status(service, device), what="wearable status")
    stopped = service.stop(session["id"])
    return stopped, status


def _status(service: Service, device: str) -> dict[str, Any] | None:
    w = service.manager.workers.get(device)
    if w is None or w.live.session is None:
        return None
    msg, _, _ = service.manager.status(device)
    return msg if msg.get("mode") == "wearable" else None


def offline(service: Service, stopped: dict[str, Any], out: Path) -> dict[str, Any]:
    stored = service.data_dir / stopped["recording_path"]
    params = aw.load_params(stopped["params"])
    return aw.analyze(stored, params, out, stopped["device"])


def test_wearable_session_live_equals_offline(service: Service, tmp_path: Path) -> None:
    device = "wlive01"
    sim = sw.simulate(sw.WearableSimConfig(move="reaching", duration_s=20.0, seed=3, device=device))
    listener = JointsListener(service.endpoint, device)
    try:
        stopped, status = run_session(service, sim, spec_of(sim.params), listener=listener)
        assert stopped["status"] == "stopped"
        assert stopped["params"]["mode"] == "wearable"
        sid = stopped["id"]
        out_dir = service.data_dir / "recordings" / str(sid)
        want = offline(service, stopped, tmp_path / "off")
        # live = offline, to the byte
        live_joints = (out_dir / "joints.csv").read_text()
        assert live_joints == (tmp_path / "off" / "joints.csv").read_text()
        assert (out_dir / "report.json").read_text() == dump_report(want)
        assert not (out_dir / "estimates.csv").exists()
        n = len(sim.t)
        assert want["summary"]["rows"] == n and live_joints.count("\n") == n + 1
        # the session's summary: ROM per joint, as the report
        assert stopped["summary"]["mode"] == "wearable"
        assert stopped["summary"]["rom"] == want["rom"]
        assert want["rom"]["elbow_flexion_deg"]["max"] > 20.0
        # the published joints: the same values as joints.csv (all rows, in order)
        wait_for(
            lambda: sum(len(wire.decode_joints(p)["t"]) for p in listener.payloads) >= n,
            what="all joints published",
        )
        pub = listener.rows()
        assert len(pub["t"]) == n
        lines = live_joints.splitlines()
        assert lines[0] == ",".join(wire.JOINT_COLUMNS)
        for i in (0, n // 2, n - 1):
            cells = lines[i + 1].split(",")
            for c, cell in zip(wire.JOINT_COLUMNS, cells, strict=True):
                v = pub[c][i]
                assert (cell == "" and math.isnan(v)) or abs(float(cell) - v) < 1e-3, (c, i)
        assert "shoulder_flexion_std_deg" in pub  # each angle's confidence travels along
        # the status while running: confidence per angle, a threshold for "sure"
        assert status["mode"] == "wearable" and status["sure_std_deg"] > 0
        assert set(status["angles_std_deg"]) == set(aw.ANGLES)
        final = want["data_quality"]["rejected"]  # the tracker's counts so far, then all
        assert all(n <= final.get(r, 0) for r, n in status["quality"]["rejected"].items())
    finally:
        listener.close()


def test_missing_forearm_stream_is_flagged_never_made_up(service: Service, tmp_path: Path) -> None:
    device = "wlive02"
    sim = sw.simulate(sw.WearableSimConfig(move="reaching", duration_s=8.0, seed=4, device=device))
    stopped, status = run_session(service, sim, spec_of(sim.params), drop="/imu/forearm")
    sid = stopped["id"]
    joints = (service.data_dir / "recordings" / str(sid) / "joints.csv").read_text().splitlines()
    header = joints[0].split(",")
    e, s = header.index("elbow_flexion_deg"), header.index("shoulder_flexion_deg")
    rows = [ln.split(",") for ln in joints[1:]]
    assert rows and all(r[e] == "" for r in rows)  # no elbow angle without a forearm IMU
    assert any(r[s] != "" for r in rows)  # the shoulder's still are
    assert stopped["summary"]["flagged_rows"]["forearm_missing"] == len(rows)
    assert any("forearm" in m for m in status["messages"])
    assert status["angles_sure"]["elbow_flexion_deg"] is False
    assert status["quality"]["flagged_rows"]["forearm_missing"] > 0
    want = offline(service, stopped, tmp_path / "off")
    assert want["data_quality"] == stopped_report(service, sid)["data_quality"]


def test_mounting_that_does_not_fit_is_flagged(service: Service) -> None:
    device = "wlive03"
    sim = sw.simulate(sw.WearableSimConfig(move="reaching", duration_s=8.0, seed=5, device=device))
    spec = spec_of(sim.params)
    # the upper-arm IMU said to be turned by 90° about its x axis: gravity at rest disagrees
    spec["upperarm_imu"] = {"position_m": [0.0, -0.04, -0.24], "quat": [0.0, 0.0, 0.0, 1.0]}
    stopped, status = run_session(service, sim, spec)
    assert stopped["summary"]["flagged_rows"]["mounting_mismatch"] > 0
    assert any("mounting" in m for m in status["messages"])
    rep = stopped_report(service, stopped["id"])
    rom = rep["rom"]["shoulder_flexion_deg"]
    assert rom["max"] is None  # no angle shown from a mounting that does not fit


def test_bad_wearable_parameters_are_refused(service: Service) -> None:
    device = "wlive04"
    with service.publisher() as pub:
        pub.announce(device)
        wait_for(lambda: service.device(device), what="registered")
        body = {
            "patient_id": service.patient(f"p-{device}"),
            "device": device,
            "wearable": {"upperarm_imu": {"quat": [1.0, 1.0, 0.0, 0.0]}},
        }
        r = service.api.post("/api/sessions", json=body)
    assert r.status_code == 422 and "unit quaternion" in r.text


def stopped_report(service: Service, sid: int) -> dict[str, Any]:
    path = service.data_dir / "recordings" / str(sid) / "report.json"
    rep: dict[str, Any] = json.loads(path.read_text())
    return rep


def test_recording_is_as_published(service: Service, tmp_path: Path) -> None:
    """The stored recording holds the device's messages byte for byte (re-analysable)."""
    device = "wlive05"
    sim = sw.simulate(sw.WearableSimConfig(move="reaching", duration_s=4.0, seed=6, device=device))
    original = tmp_path / "orig.jsonl.gz"
    recording.write(original, sim.messages)
    stopped, _ = run_session(service, sim, spec_of(sim.params))
    stored = service.data_dir / stopped["recording_path"]
    assert [(k, bytes(p)) for k, p in recording.read(stored)] == [
        (k, bytes(p)) for k, p in recording.read(original)
    ]


def test_rom_test_through_the_api(service: Service) -> None:
    """The therapist asks for maximal flexion: start, the movement, stop; the peak is in the
    answer, the session's report and its summary."""
    device = "wlive06"
    sim = sw.simulate(sw.WearableSimConfig(move="rom", duration_s=8.0, seed=8, device=device))
    outgoing = prepare(sim.messages)
    half = next(i for i, o in enumerate(outgoing) if o.key.endswith("upperarm") and _t(o) >= 3.0)
    with service.publisher() as pub:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        session = start_wearable(service, device, spec_of(sim.params))
        sid = session["id"]
        play(pub, outgoing[:half], 50.0)
        wait_for(lambda: service.received(device) >= half, what="first part")
        r = service.api.post(f"/api/sessions/{sid}/rom-test", json={"movement": "shoulder_flexion"})
        assert r.status_code == 200, r.text
        assert r.json()["movement"] == "shoulder_flexion" and r.json()["start_t"] > 2.0
        play(pub, outgoing[half:], 50.0)
        wait_for(lambda: service.received(device) >= len(outgoing), what="all")
        wait_for(lambda: (_status(service, device) or {}).get("rom_active"), what="status")
        r = service.api.delete(f"/api/sessions/{sid}/rom-test")
        assert r.status_code == 200, r.text
        test = r.json()
        assert 135.0 < test["peak_deg"] < 165.0 and test["joint"] == "shoulder_flexion_deg"
        assert service.api.delete(f"/api/sessions/{sid}/rom-test").status_code == 409
        bad = service.api.post(f"/api/sessions/{sid}/rom-test", json={"movement": "wiggle"})
        assert bad.status_code == 422
    stopped = service.stop(sid)
    assert stopped["summary"]["rom_tests"] == [test]
    assert stopped_report(service, sid)["rom_tests"] == [test]


def _t(o: Any) -> float:
    return float(o.at)
