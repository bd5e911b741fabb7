"""The WebSocket feeds: the protocol the dashboard and the overlay code against, the 30 Hz
cap without losing rows, and who may read what."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from backend.live.feed import DISPLAY_EXTRA, OVERLAY_COLUMNS
from backend.schemas import live as messages
from simulator import SimConfig, simulate
from simulator.publish import play, prepare
from tests.live.conftest import Service, wait_for

CONTRACT_COLUMNS = (
    "t",
    "elbow_x",
    "elbow_y",
    "elbow_z",
    "shoulder_x",
    "shoulder_y",
    "shoulder_z",
    "elbow_angle_deg",
    "heading_offset_deg",
    "heading_converged",
    "shoulder_displacement_m",
    "state",
)


class Listener:
    """Collects a socket's messages in a thread (with their arrival times)."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.messages: list[tuple[float, dict[str, Any]]] = []
        self.closed: tuple[int, str] | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for text in self.ws:
                self.messages.append((time.monotonic(), json.loads(text)))
        except ConnectionClosed:
            pass
        code = self.ws.close_code
        self.closed = (code, self.ws.close_reason or "") if code is not None else (1006, "")

    def of(self, kind: str, device: str | None = None) -> list[dict[str, Any]]:
        return [
            m
            for _, m in self.messages
            if m["type"] == kind and (device is None or m.get("device") == device)
        ]

    def close(self) -> None:
        self.ws.close()
        self._thread.join(10)


def ws_url(service: Service, path: str) -> str:
    return service.url.replace("http://", "ws://") + path


def therapist(service: Service, query: str = "") -> Listener:
    return Listener(
        connect(
            ws_url(service, "/api/ws/live" + query),
            additional_headers={"Authorization": f"Bearer {service.token}"},
        )
    )


def refused(
    service: Service, path: str, headers: dict[str, str] | None = None, first: str | None = None
) -> str:
    """Refused with close code 1008 after the handshake (what a browser can read), and
    nothing sent before; ``first``: sent first (the overlay's token). Returns the reason."""
    url = ws_url(service, path)
    with (
        connect(url, additional_headers=headers or {}, open_timeout=10) as ws,
        pytest.raises(ConnectionClosed) as exc,
    ):
        if first is not None:
            ws.send(first)
        ws.recv(timeout=10)
    assert exc.value.rcvd is not None and exc.value.rcvd.code == 1008, path
    return exc.value.rcvd.reason


def auth(token: str) -> str:
    """The overlay's first message: its token, never in the URL."""
    return json.dumps({"type": "auth", "token": token})


def overlay_feed(service: Service, token: str) -> ClientConnection:
    ws = connect(ws_url(service, "/api/ws/overlay"))
    ws.send(auth(token))
    return ws


def test_live_and_overlay_feeds(service: Service) -> None:
    live_and_overlay_feeds(service)


def test_live_and_overlay_feeds_through_workers(workers_service: Service) -> None:
    """The same feeds when worker processes run the pipelines: the API node fans the
    workers' messages out, the overlay's included."""
    live_and_overlay_feeds(workers_service)


def live_and_overlay_feeds(service: Service) -> None:
    main, other = "ws01", "ws02"
    sims = {
        d: simulate(SimConfig(seed=s, duration_s=50.0, device=d))
        for d, s in ((main, 3), (other, 4))
    }
    outgoing = sorted((m for s in sims.values() for m in prepare(s.messages)), key=lambda m: m.at)
    with service.publisher() as pub:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        # the adaptive tolerated duration (null) and a tolerance of the session's own
        session = service.start(main, tolerance_m=0.12, warning_after_s=None)
        sid = session["id"]
        assert session["params"]["warning_after_s"] is None
        assert session["params"]["tolerance_m"] == 0.12
        if service.manager.workers:  # one process: the pipeline runs here
            assert service.manager.workers[main].live.params.warning_after_s is None
        wait_for(lambda: service.device(other), what="second device")
        token = service.api.post(f"/api/sessions/{sid}/overlay-link").json()["token"]

        # who may read what
        refused(service, "/api/ws/live")
        refused(service, "/api/ws/live", {"Authorization": f"Bearer {token}"})
        refused(service, f"/api/ws/live?token={token}")
        assert refused(service, "/api/ws/overlay") == "no overlay token"
        refused(service, "/api/ws/overlay", first=auth("forged"))
        refused(service, "/api/ws/overlay", first=auth(service.token))
        refused(service, "/api/ws/overlay", first="not json")
        # a link of the old form (the token in the URL) fails, and says why, valid token or not
        assert "old form" in refused(service, f"/api/ws/overlay?token={token}")

        everything = therapist(service)
        only_other = therapist(service, f"?devices={other}")
        overlay = Listener(overlay_feed(service, token))
        time.sleep(0.3)
        play(pub, outgoing, speed=20.0)
        for d, s in sims.items():
            n = len(s.messages)
            wait_for(lambda: service.received(d) >= n, timeout=60, what=d)  # noqa: B023
        time.sleep(1.5)  # statuses tick once a second
        stopped = service.stop(sid)
    wait_for(lambda: overlay.closed is not None, timeout=10, what="overlay closed")
    assert overlay.closed == (1000, "session ended")
    time.sleep(0.3)
    everything.close()
    only_other.close()

    # every message is one of the models (backend/schemas/live.py): no key more, none missing
    for listener, model in ((everything, messages.LIVE), (overlay, messages.OVERLAY)):
        for _, m in listener.messages:
            model.validate_python(m, strict=True)

    # therapist: hello first, then status / estimate / state / cycle
    first = everything.messages[0][1]
    assert first["type"] == "hello" and main in first["devices"]
    assert only_other.messages[0][1] == {"type": "hello", "devices": [other]}
    assert {m.get("device") for _, m in only_other.messages[1:]} == {other}
    kinds = {m["type"] for _, m in everything.messages}
    assert {"hello", "status", "estimate", "state", "cycle"} <= kinds

    # the last status of the running session (through workers, more than one status can
    # follow the stop before the socket closes: the stop's and the second tick's)
    status = [m for m in everything.of("status", main) if m["session_id"] is not None][-1]
    for key in (
        "online",
        "session_id",
        "patient",
        "heading_converged",
        "convergence_progress",
        "heading_confidence",
        "heading_std_deg",
        "upper_arm_length_m",
        "quality",
        "rates_hz",
    ):
        assert key in status, key
    assert status["session_id"] == sid and status["patient"] == f"p-{main}"
    assert status["online"] is True and status["heading_converged"] is True
    assert status["tolerance_m"] == 0.12
    assert set(status["rates_hz"]) == {"imu", "robot"}

    # estimates: every column, every row exactly once, at most 30 messages per second
    est = [
        (t, m) for t, m in everything.messages if m["type"] == "estimate" and m["device"] == main
    ]
    assert set(est[0][1]["rows"]) == set(CONTRACT_COLUMNS) | set(DISPLAY_EXTRA)
    t_rows = [t for _, m in est for t in m["rows"]["t"]]
    csv = service.api.get(f"/api/sessions/{sid}/estimates.csv").text.splitlines()[1:]
    assert t_rows == [float(line.split(",")[0]) for line in csv]
    arrivals = [t for t, _ in est]
    for i in range(len(arrivals) - 31):  # any 31 consecutive messages span ≥ 1 s (jitter)
        assert arrivals[i + 30] - arrivals[i] >= 0.9
    assert len(est) < len(t_rows) / 2  # 20× real time: many rows per message

    states = everything.of("state", main)
    assert states and all(s["state"] in ("ok", "outside", "warning") for s in states)
    cycles = everything.of("cycle", main)
    assert [c["index"] for c in cycles] == list(range(len(cycles)))
    assert len(cycles) == stopped["summary"]["cycles"]
    assert set(cycles[0]) == {
        "type",
        "device",
        "start",
        "end",
        "outside_fraction",
        "compensatory",
        "index",
    }

    # overlay: its own device and session only, and only these fields
    assert overlay.messages
    assert {m["device"] for _, m in overlay.messages} == {main}
    for _, m in overlay.messages:
        if m["type"] == "status":
            assert set(m) == {
                "type",
                "device",
                "heading_converged",
                "convergence_progress",
                "online",
                "tolerance_m",
            }
            assert m["tolerance_m"] == 0.12  # the overlay draws its circle from it
        elif m["type"] == "estimate":
            assert set(m["rows"]) == set(OVERLAY_COLUMNS)
        else:
            assert m["type"] in ("state", "cycle"), m["type"]
    o_rows = [t for m in overlay.of("estimate") for t in m["rows"]["t"]]
    assert o_rows == t_rows
    assert [c["index"] for c in overlay.of("cycle")] == [c["index"] for c in cycles]

    # the link died with the session
    assert refused(service, "/api/ws/overlay", first=auth(token)) == "session is not active"
