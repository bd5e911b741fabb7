"""Malformed, hostile and huge payloads over Zenoh are rejected and counted; the service
and the other devices keep working, with the numbers they would have had anyway."""

from __future__ import annotations

import json
import threading
from typing import Any

from backend.analysis import CSV_HEADER, analyze
from estimators.params import PipelineParams
from protocol import keys, wire
from simulator import SimConfig, simulate
from simulator.publish import play, prepare
from tests.live.conftest import Service, wait_for

GOOD, EVIL = "good01", "evil01"


def _device_key(key: str) -> str | None:
    try:
        return keys.parse(key).device
    except keys.KeyError_:
        return None


def robot(t: list[float], seq: int | None = None) -> bytes:
    payload: dict[str, Any] = {
        "t": t,
        "wrist": [[0.3, 0.4, 0.1]] * len(t),
        "proximal": [[0.3, 0.2, 0.1]] * len(t),
    }
    if seq is not None:
        payload["seq"] = seq
    return wire.dumps(payload)


HOSTILE: list[tuple[str, bytes]] = [
    (f"rehab/{EVIL}/robot", b'{"t": [1.0,'),  # malformed JSON
    (f"rehab/{EVIL}/robot", b"\xff\xfe\x00garbage"),  # not UTF-8
    (f"rehab/{EVIL}/robot", b'{"t":[NaN],"wrist":[[0,0,0]],"proximal":[[0,0,1]]}'),
    (f"rehab/{EVIL}/robot", b'{"t":[1e999],"wrist":[[0,0,0]],"proximal":[[0,0,1]]}'),
    (f"rehab/{EVIL}/imu/upperarm", b'{"t":[1,2],"gyr":[[1,2,3]],"acc":[[0,0,9.8],[0,0,9.8]]}'),
    (f"rehab/{EVIL}/imu/upperarm", b'{"t":[1],"gyr":[[1,2]],"acc":[[0,0,9.8]]}'),
    (f"rehab/{EVIL}/robot", b'{"t":"now","wrist":[],"proximal":[]}'),
    (f"rehab/{EVIL}/robot", b"[1, 2, 3]"),
    (f"rehab/{EVIL}/robot", b'"just a string"'),
    (f"rehab/{EVIL}/robot", b"{}"),
    (f"rehab/{EVIL}/event", b'{"t": 1, "type": "self_destruct"}'),
    (f"rehab/{EVIL}/event", b'{"t": 1, "type": "shoulder_reference", "point": [1, 2]}'),
    # a payload that would forge a second recording line if spliced in naively
    (f"rehab/{EVIL}/robot", b'1},"key":"rehab/' + GOOD.encode() + b'/robot","payload":{"t":[1]'),
    (f"rehab/{EVIL}/robot", b'{"t":[1]}\n{"key":"x","payload":{}}'),
    (f"rehab/{EVIL}/robot", b"{" + b" " * (2 << 20) + b"}"),  # 2 MiB
    (f"rehab/{EVIL}/bogus", b"{}"),  # not a contract key
    (f"rehab/{EVIL}/imu/leg", b"{}"),
    (f"rehab/{EVIL}/robot/extra", b"{}"),
    ("rehab/" + "x" * 65 + "/robot", robot([1.0])),  # device name too long
    (f"rehab/{EVIL}/robot", robot([10.0, 10.04], seq=0)),
    (f"rehab/{EVIL}/robot", robot([9.0], seq=1)),  # time going backwards
    (f"rehab/{EVIL}/robot", robot([10.04], seq=2)),  # duplicate time
]
FLOOD = 20_000


def test_hostile_input_is_rejected_and_counted(service: Service) -> None:
    sim = simulate(SimConfig(seed=21, duration_s=45.0, device=GOOD))
    outgoing = prepare(sim.messages)
    with service.publisher() as pub, service.publisher() as evil:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        evil.announce(EVIL)
        good_session = service.start(GOOD)
        evil_session = service.start(EVIL)

        def attack() -> None:
            for key, payload in HOSTILE:
                evil.put(key, payload)
            flood = robot([1.0])  # valid, but always the same time: rejected by the pipeline
            for _ in range(FLOOD):
                evil.put(f"rehab/{EVIL}/robot", flood)

        attacker = threading.Thread(target=attack)
        attacker.start()
        play(pub, outgoing, speed=20.0)
        attacker.join()
        wait_for(lambda: service.received(GOOD) >= len(outgoing), timeout=60, what="good data")
        sent_evil = sum(1 for k, _ in HOSTILE if _device_key(k) == EVIL) + FLOOD
        wait_for(lambda: service.received(EVIL) >= sent_evil, timeout=60, what="hostile data")

        def drained() -> bool:
            dev = service.device(EVIL)
            return dev is not None and dev["stats"]["ingest"]["queued"] == 0

        wait_for(drained, timeout=60, what="evil queue drained")
        good = service.stop(good_session["id"])
        bad = service.stop(evil_session["id"])
    assert service.api.get("/api/health").json()["status"] == "ok"

    # the good device: exactly the numbers of an offline analysis of its own data
    good_csv = service.api.get(f"/api/sessions/{good['id']}/estimates.csv").text
    good_rep = service.api.get(f"/api/sessions/{good['id']}/report").json()["report"]
    params = PipelineParams.from_json(good["params"])
    original = service.data_dir / "good-original.jsonl"
    original.write_text(
        "".join(json.dumps({"key": k, "payload": p}) + "\n" for k, p in sim.messages)
    )
    run, want = analyze(original, params)
    assert good_csv == CSV_HEADER + "\n" + "".join(x + "\n" for x in run.est_lines)
    assert good_rep["summary"] == want["summary"]
    assert good_rep["cycles"] == want["cycles"]
    assert good_rep["summary"]["cycles"] > 0

    # the hostile device: every message accounted for, reasons visible
    stats = service.device(EVIL)["stats"]  # type: ignore[index]
    ingest = stats["ingest"]
    assert ingest["messages"] == sent_evil
    assert ingest["accepted"] + sum(ingest["rejected"].values()) + ingest["dropped"] == sent_evil
    assert ingest["rejected"]["too_large"] == 1
    # invalid JSON is recorded as a JSON string (so it cannot forge a line) and decoded
    # from there, like `rehab analyze` decodes it: counted as not_object
    for reason in (
        "not_object",
        "bad_shape",
        "length_mismatch",
        "bad_type",
        "missing_field",
        "unknown_event",
    ):
        assert ingest["rejected"].get(reason, 0) >= 1, (reason, ingest["rejected"])
    bad_rep = service.api.get(f"/api/sessions/{bad['id']}/report").json()["report"]
    rejected = bad_rep["data_quality"]["rejected"]
    assert rejected.get("time_backwards", 0) >= 1
    assert rejected.get("duplicate_t", 0) >= 1
    if ingest["dropped"] < FLOOD:  # what was not dropped at the door hit the pipeline
        assert rejected.get("duplicate_t", 0) + rejected.get("time_backwards", 0) > 2

    # the hostile session's recording reproduces its report, and forged nothing
    stored = service.data_dir / bad["recording_path"]
    run2, rep2 = analyze(stored, PipelineParams.from_json(bad["params"]))
    assert bad_rep == json.loads(json.dumps(rep2))
    assert run2.device == EVIL and rep2["data_quality"]["other_devices"] == {}
    assert service.device("x" * 65) is None

    # keys that are not contract inputs are counted globally, and never create a device
    assert service.manager.ingest.counters["unknown_key"] >= 4
    devices = {d["name"] for d in service.api.get("/api/devices").json()}
    assert not any(len(d) > 64 for d in devices)
