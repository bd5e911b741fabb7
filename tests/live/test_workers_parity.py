"""Workers mode has what the one process has: ``rehab serve --workers 2`` (the API node in
this process, two real ``rehab worker`` processes, Zenoh on loopback, SQLite). The feeds
through workers are tested in test_websocket.py."""

from __future__ import annotations

import time

from backend.live.gateway import Gateway
from protocol import keys, recording
from simulator import SimConfig, simulate
from simulator.publish import play, prepare
from tests.live.conftest import Service, wait_for


def test_a_session_started_before_the_device_is_heard_records_all_of_it(
    workers_service: Service,
) -> None:
    """A session started on a registered device no worker has heard of (admitted by an
    administrator, or back after a while): a worker leases it on the start, so the first
    message the device sends after the answer is in the recording, as in the one process.
    Before, no worker held it: its first messages were dropped until one leased it."""
    svc = workers_service
    assert isinstance(svc.manager, Gateway)
    name = "wp01"
    r = svc.api.post(f"/api/devices/{name}/admit")
    assert r.status_code == 201, r.text
    session = svc.start(name)
    outgoing = prepare(simulate(SimConfig(seed=11, duration_s=15.0, device=name)).messages)
    with svc.publisher() as pub:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        play(pub, outgoing, speed=3.0)
        wait_for(lambda: svc.received(name) >= len(outgoing), timeout=60, what="all received")
    time.sleep(0.5)
    svc.stop(session["id"])
    lines = [(k, bytes(p)) for k, p in recording.read(svc.data_dir / session["recording_path"])]
    assert lines == [(m.key, m.payload) for m in outgoing]


def test_live_report_export_and_3d_view_of_a_running_session(workers_service: Service) -> None:
    """A running session's report so far and its CSV as of now come from the worker that
    runs it; the 3D view on the API node shows the device's arm."""
    svc = workers_service
    viz = svc.app.state.viz
    name = "wp02"
    outgoing = prepare(simulate(SimConfig(seed=12, duration_s=40.0, device=name)).messages)
    with svc.publisher() as pub:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        session = svc.start(name, tolerance_m=0.11)
        sid = session["id"]
        r = svc.api.put("/api/viz/device", json={"device": name})
        assert r.status_code == 200, r.text
        assert viz.selected == name
        play(pub, outgoing, speed=4.0)
        wait_for(lambda: svc.received(name) >= len(outgoing), timeout=60, what="all received")
        r = svc.api.get(f"/api/sessions/{sid}/report")
        assert r.status_code == 200, r.text
        assert r.json()["provisional"] is True
        cycles = r.json()["report"]["cycles"]
        assert cycles, "the report so far has the cycles of the 40 s played"
        csv = svc.api.get(f"/api/sessions/{sid}/estimates.csv")
        assert csv.status_code == 200, csv.text
        rows = csv.text.splitlines()[1:]
        last_t = outgoing[-1].at
        frame = viz.frame(name)
        assert frame is not None and frame.shoulder is not None and frame.trace
        assert frame.tolerance_m == 0.11  # the session's parameters, as in the one process
    stopped = svc.stop(sid)
    final = svc.api.get(f"/api/sessions/{sid}/estimates.csv").text.splitlines()[1:]
    # flushed on asking: the CSV of the running session held (nearly) every row by then
    assert len(rows) > 0.95 * len(final), (len(rows), len(final), last_t)
    assert len(cycles) == stopped["summary"]["cycles"]


def test_a_quiet_device_holding_its_token_stays_online(workers_service: Service) -> None:
    """Online by its liveliness token, as in the one process, not only while its data
    flows: the token comes before any worker leases the device, and the holder must keep
    it (the dashboard said "Device offline" to a device waiting for the patient)."""
    svc = workers_service
    name = "wp03"
    sim = simulate(SimConfig(seed=13, duration_s=15.0, device=name))
    outgoing = [m for m in prepare(sim.messages) if m.at < 2.0]  # 2 s of data, then quiet
    with svc.publisher() as pub:
        pub.declare(outgoing)
        assert pub.wait_for_subscribers(10.0)
        play(pub, outgoing, speed=1.0)
        # (without a session, messages before a worker leases the device are not kept)
        wait_for(lambda: svc.received(name) > 0, timeout=30, what="data heard")
        time.sleep(svc.settings.device_offline_after_s + 3.0)  # silent, its token held
        device = svc.device(name)
        assert device is not None and device["status"] == "online", device
    wait_for(
        lambda: (svc.device(name) or {}).get("status") == "offline", timeout=30, what="offline"
    )


def test_a_device_without_a_token_is_found_from_its_data(workers_service: Service) -> None:
    """Workers subscribe only to the devices they hold; a device that declares no
    liveliness token (the contract asks none) is found by the API node's sampling of the
    devices' inputs and its notice to the workers: one worker leases it, runs its pipeline
    and publishes its estimates (one holder), and the registry lists it."""
    svc = workers_service
    assert isinstance(svc.manager, Gateway)
    name = "wp04"
    outgoing = prepare(simulate(SimConfig(seed=14, duration_s=12.0, device=name)).messages)
    holders: list[str] = []
    with svc.publisher() as pub:
        listen = pub.session.declare_subscriber(
            keys.estimate(name),
            lambda s: holders.append(s.attachment.to_bytes().decode() if s.attachment else ""),
        )
        try:
            for m in outgoing:
                pub.declare_key(m.key)  # publishers only: no pub.announce(), no token
            assert pub.wait_for_subscribers(10.0)  # the API node's sampling subscriptions
            play(pub, outgoing, speed=1.0)
            wait_for(lambda: svc.received(name) > 0, timeout=30, what="data taken")
            wait_for(lambda: len(holders) > 50, timeout=30, what="estimates")
        finally:
            listen.undeclare()
    assert svc.device(name) is not None
    assert len(set(holders)) == 1, set(holders)  # one holder, one epoch
    # the first estimates follow the lease within a second of data (12 s sent)
    assert len(holders) > 0.7 * sum(m.key.endswith("/robot") for m in outgoing), len(holders)
