"""Device admission: invented names cost nothing persistent, an administrator admits and
removes devices, ``--admit`` globs admit without approval; all of it across a restart."""

from __future__ import annotations

import json
import time
from pathlib import Path

import httpx
import pytest
import zenoh

from backend.live.admission import MAX_PENDING, Admission
from backend.settings import Settings
from simulator.publish import Publisher
from tests.live.conftest import free_port, login, run_service, stop_service, wait_for

BLOCK = zenoh.CongestionControl.BLOCK


def robot(t: float) -> bytes:
    return json.dumps(
        {"t": [t], "wrist": [[0.3, 0.4, 0.1]], "proximal": [[0.3, 0.2, 0.1]]}
    ).encode()


def received(api: httpx.Client, name: str) -> int:
    r = api.get(f"/api/devices/{name}")
    if r.status_code != 200:
        return 0
    return int(((r.json().get("stats") or {}).get("ingest") or {}).get("messages", 0))


def test_admission_bounds_and_globs() -> None:
    a = Admission(["ward3-*"], max_pending=4)
    assert a.allows("ward3-01") and not a.allows("ward4-01")
    for i in range(10):
        a.refuse(f"x{i}", float(i))
    assert len(a.pending) == 4 and a.forgotten == 6 and a.refused == 10
    a.admit("x9")
    assert a.allows("x9") and "x9" not in a.pending
    a.remove("x9")
    assert not a.allows("x9")
    assert Admission(["*"]).allows("anything")


def test_invented_names_fill_nothing_and_real_devices_survive_restart(tmp_path: Path) -> None:
    settings = Settings(
        data_dir=tmp_path,
        port=free_port(),
        zenoh_listen=f"tcp/127.0.0.1:{free_port()}",
        cookie_secure=False,
        admit=["ward3-*"],
    )
    assert settings.zenoh_listen is not None
    running = run_service(settings)
    api, _ = login(f"http://127.0.0.1:{settings.port}", settings)
    try:
        with Publisher.connect(settings.zenoh_listen) as pub:
            pub.declare_key("rehab/probe/robot")
            assert pub.wait_for_subscribers(10.0)
            for i in range(1000):
                pub.session.put(f"rehab/fake{i:04d}/robot", robot(1.0), congestion_control=BLOCK)
            pub.session.put("rehab/clinic01/robot", robot(1.0), congestion_control=BLOCK)
            pub.put("rehab/ward3-01/robot", robot(1.0))  # admitted by the glob
            wait_for(lambda: received(api, "ward3-01") == 1, what="the glob's device")
            wait_for(
                lambda: api.get("/api/devices/admission").json()["refused_messages"] == 1001,
                what="refusals counted",
            )
            adm = api.get("/api/devices/admission").json()
            assert len(adm["pending"]) == MAX_PENDING
            assert adm["pending"][0]["name"] == "clinic01"  # the newest first
            assert [d["name"] for d in api.get("/api/devices").json()] == ["ward3-01"]
            assert api.get("/api/devices/clinic01").status_code == 404
            # an administrator admits the real device: registered at once
            assert api.post("/api/devices/clinic01/admit").status_code == 201
            assert api.get("/api/devices/clinic01").status_code == 200
            pub.put("rehab/clinic01/robot", robot(2.0))
            wait_for(lambda: received(api, "clinic01") == 1, what="clinic01 admitted")
            # a removed device is refused again
            pub.put("rehab/gone01/robot", robot(1.0))
            assert api.post("/api/devices/gone01/admit").status_code == 201
            assert api.delete("/api/devices/gone01").status_code == 204
            wait_for(lambda: api.get("/api/devices/gone01").status_code == 404, what="removed")
            assert api.post("/api/devices/bad%20name/admit").status_code == 422
            audit = api.get("/api/audit").json()
            actions = {(e["action"], e["object"]) for e in audit}
            assert ("device.admit", "device:clinic01") in actions
            assert ("device.remove", "device:gone01") in actions
    finally:
        api.close()
        stop_service(running)
    # restart: the admitted device is still admitted, the invented names left no trace
    settings = settings.model_copy(update={"port": free_port()})
    assert settings.zenoh_listen is not None
    running = run_service(settings)
    api, _ = login(f"http://127.0.0.1:{settings.port}", settings)
    try:
        assert sorted(d["name"] for d in api.get("/api/devices").json()) == [
            "clinic01",
            "ward3-01",
        ]
        assert api.get("/api/devices/admission").json()["pending"] == []
        with Publisher.connect(settings.zenoh_listen) as pub:
            pub.declare_key("rehab/clinic01/robot")
            assert pub.wait_for_subscribers(10.0)
            pub.put("rehab/clinic01/robot", robot(3.0))
            pub.session.put("rehab/gone01/robot", robot(3.0))
            wait_for(lambda: received(api, "clinic01") >= 1, what="clinic01 after restart")
            time.sleep(0.3)
            assert api.get("/api/devices/gone01").status_code == 404
    finally:
        api.close()
        stop_service(running)


@pytest.mark.parametrize("value", ['["*"]', '["a*","b?"]'])
def test_admit_from_environment(value: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("REHAB_ADMIT", value)
    assert Settings().admit == json.loads(value)
