"""A therapist sets and resets the nominal shoulder during a session: the changes go into
the recording as events, so re-analysis reproduces the session exactly."""

from __future__ import annotations

import json
from typing import Any

from backend.analysis import CSV_HEADER, analyze
from backend.live.files import dump_report
from estimators.params import PipelineParams
from protocol import recording
from simulator import SimConfig, simulate
from simulator.publish import play, prepare
from tests.live.conftest import Service, wait_for


def test_nominal_shoulder_set_and_reset(service: Service) -> None:
    device = "nom01"
    sim = simulate(SimConfig(seed=41, duration_s=60.0, device=device))
    outgoing = prepare(sim.messages)
    thirds = [
        outgoing[: len(outgoing) // 3],
        outgoing[len(outgoing) // 3 : 2 * len(outgoing) // 3],
        outgoing[2 * len(outgoing) // 3 :],
    ]
    with service.publisher() as pub:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        session = service.start(device)
        sid = session["id"]
        url = f"/api/sessions/{sid}/nominal-shoulder"
        # before any data: the point waits for the first message
        r = service.api.put(url, json={"source": "point", "point": [0.1, -0.2, 0.3]})
        assert r.status_code == 200, r.text
        assert service.api.put(url, json={"source": "estimate"}).status_code == 409
        sent = 0
        for i, part in enumerate(thirds):
            play(pub, part, speed=20.0)
            sent += len(part)
            wait_for(
                lambda: service.received(device) >= sent,  # noqa: B023 (called right here)
                timeout=60,
                what="data",
            )
            if i == 0:
                r = service.api.put(url, json={"source": "estimate"})
                assert r.status_code == 200, r.text
                got: dict[str, Any] = r.json()["nominal_shoulder"]
                assert got["source"] == "estimate" and len(got["point"]) == 3
            elif i == 1:
                r = service.api.delete(url)
                assert r.status_code == 200 and r.json()["nominal_shoulder"] is None
        # the automatic nominal after the reset is stored once the pipeline adopts it
        wait_for(
            lambda: (
                (service.api.get(f"/api/sessions/{sid}").json()["nominal_shoulder"] or {}).get(
                    "source"
                )
                == "auto"
            ),
            timeout=20,
            what="auto nominal stored",
        )
        stopped = service.stop(sid)

    stored = service.data_dir / stopped["recording_path"]
    lines = [(k or "", p) for k, p in recording.read(stored)]
    events = [json.loads(bytes(p)) for k, p in lines if k.endswith("/event")]
    device_events = [p for k, p in sim.messages if k.endswith("/event")]
    assert events[0]["type"] == "shoulder_reference"  # the therapist's, ahead of all data
    assert [e for e in events[1:] if e["type"] != "nominal_reset"] == device_events
    assert sum(e["type"] == "nominal_reset" for e in events) == 2
    assert lines[0][0].endswith("/event")  # went in ahead of the first message
    assert events[0]["point"] == [0.1, -0.2, 0.3]
    assert events[0]["t"] == min(json.loads(outgoing[0].payload)["t"])

    run, want = analyze(stored, PipelineParams.from_json(stopped["params"]))
    csv = service.api.get(f"/api/sessions/{sid}/estimates.csv").text
    assert csv == CSV_HEADER + "\n" + "".join(x + "\n" for x in run.est_lines)
    out = service.data_dir / "recordings" / str(sid) / "report.json"
    assert out.read_text() == dump_report(want)
    # the rows follow the therapist: the given point first, then other nominals
    noms = [line.split(",") for line in run.det_lines]
    assert any(r[9:12] == ["0.10000", "-0.20000", "0.30000"] for r in noms)
