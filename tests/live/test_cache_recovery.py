"""The takeover gap recovered from a device's publication cache, for real: ``rehab serve
--workers 2``, devices publishing through zenoh-ext AdvancedPublishers with a cache, the
worker holding one of them killed with SIGKILL. The killed worker's devices' recordings hold
every message sent during their sessions, in order: no gap, although for about a second no
worker held them (and the dead one's last quarter second was never flushed)."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest
import zenoh

from backend.analysis import CSV_HEADER, analyze, dump_report
from backend.live import recovery
from backend.live.ingest import RawMessage, recorded_form
from estimators.params import PipelineParams
from protocol import keys, recording
from protocol.zenoh_config import make_config
from simulator import SimConfig, simulate
from simulator.publish import Publisher, play, prepare
from tests.live.conftest import free_port, login, wait_for
from tests.live.test_scaleout import Cluster, Estimates, streams


def test_the_gap_comes_from_the_cache_in_publication_order() -> None:
    """Real Zenoh on loopback: a device publishes through cached AdvancedPublishers; the
    new holder's history holds, per key, what the recording and its queue both miss, and
    :func:`recovery.gap` returns exactly those messages, in the order they were sent. With
    plain publishers (no cache) the history is empty: nothing is invented."""
    sim = simulate(SimConfig(seed=5, duration_s=12.0, device="cr01"))
    sent = [(m.key, m.payload) for m in prepare(sim.messages)]
    a, b = len(sent) // 3, len(sent) * 2 // 3  # recorded up to a; queued from b on
    for cache in (500, 0):
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        holder = zenoh.open(make_config(listen=endpoint, mode="peer"))
        try:
            with Publisher.connect(endpoint, cache=cache) as pub:
                for key, _ in sent:
                    pub.declare_key(key)
                time.sleep(0.5)
                for key, payload in sent:
                    pub.put(key, payload)
                time.sleep(0.3)
                history = recovery.CacheHistory(holder, "rehab", "cr01", 30.0)
                time.sleep(recovery.MIN_WAIT_S)
                samples = history.close()
            recorded = [(k, recorded_form(p)) for k, p in sent[:a]]
            queued = [RawMessage(k, p, len(p), 0.0, keys.parse(k).kind) for k, p in sent[b:]]
            missing = recovery.gap(samples, recorded, queued, "rehab")
        finally:
            holder.close()  # type: ignore[no-untyped-call]
        if cache:
            assert [(m.key, m.payload) for m in missing] == sent[a:b]
        else:
            assert samples == [] and missing == []


def _contiguous(lines: list[tuple[str, bytes]], sent: list[tuple[str, bytes]]) -> int:
    """How many sent messages are missing between the recording's first and last line
    (the recording must otherwise be that slice of what was sent, in order)."""
    i0 = sent.index(lines[0])
    i1 = sent.index(lines[-1])
    window = sent[i0 : i1 + 1]
    assert set(lines) <= set(window) and len(set(lines)) == len(lines), "in order, once"
    return len(window) - len(lines)


@pytest.mark.slow
def test_sigkill_with_a_publication_cache_leaves_no_gap(tmp_path: Path) -> None:
    names, outgoing = streams(4, 40.0)
    cluster = Cluster(tmp_path / "data", workers=2)
    est = Estimates(cluster.endpoint)
    stop = threading.Event()
    player: threading.Thread | None = None
    try:
        api, _ = login(cluster.url, cluster.settings)
        # 2000 messages per key: ~80 s of a device's IMU or robot stream
        with Publisher.connect(cluster.endpoint, cache=2000) as pub:
            pub.declare(outgoing)
            assert pub.wait_for_subscribers(10.0)
            player = threading.Thread(
                target=play, args=(pub, outgoing, 1.0), daemon=True, kwargs={"stop": stop}
            )
            player.start()
            wait_for(lambda: set(cluster.leases()) == set(names), what="all devices leased")
            sessions = {}
            for name in names:
                pid = api.post(
                    "/api/patients", json={"code": f"p-{name}", "affected_side": "right"}
                ).json()["id"]
                r = api.post("/api/sessions", json={"patient_id": pid, "device": name})
                assert r.status_code == 201, r.text
                sessions[name] = r.json()
            wait_for(lambda: all(est.times[n] for n in names), what="estimates of all")
            time.sleep(5.0)
            victim_holder = cluster.leases()["fo00"][0]
            victim = int(victim_holder.split("-")[-2])
            moved = [n for n, (h, _, _) in cluster.leases().items() if h == victim_holder]
            os.kill(victim, signal.SIGKILL)
            killed = time.time()
            wait_for(
                lambda: all(any(t > killed for t in est.times[n]) for n in moved),
                timeout=30,
                what="estimates resumed",
            )
            time.sleep(3.0)
            stop.set()
            player.join()
        time.sleep(1.0)
        for name in names:
            r = api.post(f"/api/sessions/{sessions[name]['id']}/stop")
            assert r.status_code == 200, r.text
        api.close()
        for name in moved:
            stored = cluster.settings.data_dir / sessions[name]["recording_path"]
            lines = [(k, bytes(p)) for k, p in recording.read(stored) if k is not None]
            mine = [(m.key, m.payload) for m in outgoing if m.key.split("/")[1] == name]
            assert _contiguous(lines, mine) == 0, f"{name}: messages missing"
            # and the files are those `rehab analyze` makes of the recording
            run, want = analyze(stored, PipelineParams.from_json(sessions[name]["params"]))
            out = stored.parent / str(sessions[name]["id"])
            assert (out / "estimates.csv").read_text() == CSV_HEADER + "\n" + "".join(
                x + "\n" for x in run.est_lines
            ), name
            assert (out / "report.json").read_text() == dump_report(want), name
    finally:
        stop.set()
        if player is not None:
            player.join(10)
        est.close()
        cluster.stop()
