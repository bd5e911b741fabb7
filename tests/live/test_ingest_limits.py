"""Ingest limits for real (loopback Zenoh, real service): the samples per message are capped;
a session's recording has a byte budget; device events that change a session are audited
with their source. (The flood, with the service in its own process: tests/live/test_fuzz.py.)"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from backend.settings import Settings
from protocol import wire
from simulator import SimConfig, simulate
from simulator.publish import Publisher, play, prepare
from tests.live.conftest import Service, _service, free_port, wait_for


@pytest.fixture(scope="module")
def limited(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    yield from _service(
        Settings(
            data_dir=tmp_path_factory.mktemp("limits"),
            port=free_port(),
            zenoh_listen=f"tcp/127.0.0.1:{free_port()}",
            cookie_secure=False,
            admit=["*"],
            recording_max_bytes=64 << 10,
            ingest_max_bytes=16 << 20,
            viser_enabled=False,
        )
    )


def imu(n: int, t0: float) -> bytes:
    t = (t0 + np.arange(n) * 0.01).round(5).tolist()
    rows = [[0.01, -0.02, 0.03]] * n
    return json.dumps({"t": t, "gyr": rows, "acc": [[0.1, 0.2, 9.8]] * n}).encode()


def test_samples_per_message_are_capped() -> None:
    with pytest.raises(wire.WireError) as exc:
        wire.decode("rehab/d/imu/upperarm", imu(wire.MAX_SAMPLES + 1, 0.0))
    assert exc.value.reason == "too_many_samples"
    ok = wire.decode("rehab/d/imu/upperarm", imu(wire.MAX_SAMPLES, 0.0))
    assert isinstance(ok, wire.ImuMessage) and len(ok.t) == 2000


def test_recording_budget_and_event_audit(limited: Service) -> None:
    dev = "budget01"
    sim = simulate(SimConfig(seed=4, duration_s=30.0, device=dev))
    outgoing = prepare(sim.messages)
    with Publisher.connect(limited.endpoint) as pub:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        pub.announce(dev)
        session = limited.start(dev)
        pub.put(
            f"rehab/{dev}/event",
            json.dumps({"t": 0.0, "type": "shoulder_reference", "point": [0.1, 0.2, 0.3]}).encode(),
        )
        play(pub, outgoing, speed=0.0)
        wait_for(lambda: limited.received(dev) >= len(outgoing) + 1, what="all messages received")
        stopped = limited.stop(session["id"])
    dev_info = limited.device(dev)
    assert dev_info is not None
    rejected = dev_info["stats"]["ingest"]["rejected"]
    assert rejected.get("recording_full", 0) > 0
    rec = Path(limited.data_dir) / stopped["recording_path"]
    # gzip of at most 64 KiB of lines
    assert rec.stat().st_size < 64 << 10
    audit = limited.api.get("/api/audit", params={"action": "device.shoulder_reference"}).json()
    mine = [
        a
        for a in audit
        if a["object"] == f"session:{session['id']}"
        and a["details"].get("point") == [0.1, 0.2, 0.3]
    ]
    assert len(mine) == 1
    assert mine[0]["actor"] == f"device:{dev}"
    assert mine[0]["details"]["key"] == f"rehab/{dev}/event"
    assert mine[0]["details"]["point"] == [0.1, 0.2, 0.3]
    assert mine[0]["details"]["source"] == "unauthenticated"
