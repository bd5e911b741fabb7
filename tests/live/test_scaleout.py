"""Scale-out for real: ``rehab serve --workers 2`` (an API node and two worker processes),
devices streaming over Zenoh on loopback, a real database; a worker killed with SIGKILL, a
worker cut off from its database."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
import uuid
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import httpx
import psycopg
import pytest
import zenoh
from sqlalchemy.engine import make_url

from backend.analysis import CSV_HEADER, analyze, dump_report
from backend.settings import Settings
from estimators.params import PipelineParams
from protocol import recording
from protocol.zenoh_config import make_config
from simulator import SimConfig, simulate
from simulator.publish import Outgoing, Publisher, play, prepare
from tests.backend.conftest import _admin_conninfo
from tests.live.conftest import free_port, login, wait_for

REPO = Path(__file__).resolve().parents[2]


def children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(x) for x in path.read_text().split()] if path.exists() else []


def cmdline(pid: int) -> str:
    return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()


class Cluster:
    """``rehab serve --workers N`` in a subprocess, SQLite in its data directory."""

    def __init__(self, data_dir: Path, workers: int) -> None:
        self.port, self.zport = free_port(), free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.zport}"
        self.url = f"http://127.0.0.1:{self.port}"
        self.settings = Settings(data_dir=data_dir)
        self.db_file = data_dir / "rehab.db"
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "backend.cli",
                "serve",
                "--port",
                str(self.port),
                "--zenoh-listen",
                self.endpoint,
                "--data-dir",
                str(data_dir),
                "--workers",
                str(workers),
                "--admit",
                "*",
                "--log-level",
                "warning",
            ],
            cwd=REPO,
        )

        def healthy() -> bool:
            assert self.proc.poll() is None, "service died"
            try:
                return httpx.get(self.url + "/api/health", timeout=1).status_code == 200
            except httpx.HTTPError:
                return False

        try:
            wait_for(healthy, timeout=60, what="service up")
            wait_for(lambda: len(self.workers()) == workers, what="workers started")
        except BaseException:
            self.stop()  # the caller never gets the object: stop what started
            raise

    def workers(self) -> list[int]:
        return [p for p in children(self.proc.pid) if "rehab worker" in cmdline(p)]

    def leases(self) -> dict[str, tuple[str, int, float]]:
        with sqlite3.connect(self.db_file) as db:
            rows = db.execute("SELECT device, holder, epoch, expires_at FROM device_leases")
            return {d: (h, e, x) for d, h, e, x in rows}

    def stop(self) -> None:
        if self.proc.poll() is None:
            left = self.workers()
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(40)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                for pid in left:  # a killed node cannot stop its workers: no orphans
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGKILL)


class Estimates:
    """Arrival times of every device's estimates, as any Zenoh subscriber sees them."""

    def __init__(self, endpoint: str) -> None:
        self.times: dict[str, list[float]] = defaultdict(list)
        self._session = zenoh.open(make_config(connect=endpoint, mode="peer"))
        self._sub = self._session.declare_subscriber("rehab/*/estimate", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        self.times[str(sample.key_expr).split("/")[1]].append(time.time())

    def close(self) -> None:
        self._sub.undeclare()  # type: ignore[no-untyped-call]
        self._session.close()  # type: ignore[no-untyped-call]


def streams(n: int, seconds: float) -> tuple[list[str], list[Outgoing]]:
    names = [f"fo{i:02d}" for i in range(n)]
    merged: list[Outgoing] = []
    for i, name in enumerate(names):
        sim = simulate(SimConfig(seed=100 + i, duration_s=seconds, device=name))
        merged.extend(prepare(sim.messages))
    merged.sort(key=lambda m: m.at)
    return names, merged


def in_order_once(lines: list[tuple[str, bytes]], sent: list[Outgoing]) -> bool:
    """The recording is a subsequence of what was sent: in order, nothing twice."""
    it = iter((m.key, m.payload) for m in sent)
    return all(any(line == m for m in it) for line in lines)


@pytest.mark.slow
@pytest.mark.parametrize("tokens", [True, False], ids=["tokens", "no-tokens"])
def test_sigkill_a_worker_sessions_continue(tmp_path: Path, tokens: bool) -> None:
    """``no-tokens``: devices found from their data only (the API node's notices), and the
    dead worker's devices from their expired leases (workers subscribe per lease)."""
    names, outgoing = streams(10, 45.0)
    cluster = Cluster(tmp_path / "data", workers=2)
    est = Estimates(cluster.endpoint)
    stop = threading.Event()
    player: threading.Thread | None = None
    try:
        api, _ = login(cluster.url, cluster.settings)
        with Publisher.connect(cluster.endpoint) as pub:
            if tokens:
                pub.declare(outgoing)
            else:
                for m in outgoing:
                    pub.declare_key(m.key)
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
            time.sleep(10.0)
            wait_for(lambda: all(est.times[n] for n in names), what="estimates of all")

            # SIGKILL the worker holding fo00
            victim_holder = cluster.leases()["fo00"][0]
            victim = int(victim_holder.split("-")[-2])
            assert victim in cluster.workers()
            moved = [n for n, (h, _, _) in cluster.leases().items() if h == victim_holder]
            os.kill(victim, signal.SIGKILL)
            killed = time.time()
            time.sleep(6.0)
            resumed = {}
            for n in moved:
                after = [t for t in est.times[n] if t > killed]
                assert after, f"{n}: no estimate after the kill"
                resumed[n] = after[0] - killed
            print("estimates resumed after (s):", resumed)
            assert max(resumed.values()) <= 2.0, resumed
            leases = cluster.leases()
            assert all(leases[n][0] != victim_holder for n in moved)
            stop.set()
            player.join()
        time.sleep(1.0)
        for name in names:
            r = api.post(f"/api/sessions/{sessions[name]['id']}/stop")
            assert r.status_code == 200, r.text
            assert r.json()["status"] == "stopped"
            assert r.json()["summary"] is not None, name
        for name in names:
            s = sessions[name]
            stored = cluster.settings.data_dir / s["recording_path"]
            lines = [(k, bytes(p)) for k, p in recording.read(stored) if k is not None]
            mine = [m for m in outgoing if m.key.split("/")[1] == name]
            assert in_order_once(lines, mine), name
            run, want = analyze(stored, PipelineParams.from_json(s["params"]))
            out = stored.parent / str(s["id"])
            assert (out / "estimates.csv").read_text() == CSV_HEADER + "\n" + "".join(
                x + "\n" for x in run.est_lines
            ), name
            assert (out / "report.json").read_text() == dump_report(want), name
            cycles = api.get(f"/api/sessions/{s['id']}/cycles")
            if cycles.status_code == 200:
                assert len(cycles.json()) == len(want["cycles"]), name
        api.close()
    finally:
        stop.set()
        if player is not None:
            player.join(10)
        est.close()
        cluster.stop()
    assert not any(Path(f"/proc/{p}").exists() for p in cluster.workers())


# --------------------------------------------------------------------------- partition


class Proxy:
    """A TCP relay to the database that the test can black-hole: a partition (bytes stop,
    connections stay open, new ones are accepted and then hang), then healed."""

    def __init__(self, host: str, port: int) -> None:
        self.upstream = (host, port)
        self.cut = threading.Event()
        self.closing = threading.Event()
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port: int = self.listener.getsockname()[1]
        self._conns: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while not self.closing.is_set():
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            up = socket.create_connection(self.upstream)
            self._conns += [client, up]
            threading.Thread(target=self._pump, args=(client, up), daemon=True).start()
            threading.Thread(target=self._pump, args=(up, client), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                while self.cut.is_set() and not self.closing.is_set():
                    time.sleep(0.02)
                dst.sendall(data)
        except OSError:
            pass

    def close(self) -> None:
        self.closing.set()
        self.listener.close()
        for c in self._conns:
            with contextlib.suppress(OSError):
                c.close()


def worker_proc(endpoint: str, db_url: str, data_dir: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "backend.cli",
            "worker",
            "--zenoh-connect",
            endpoint,
            "--database-url",
            db_url,
            "--data-dir",
            str(data_dir),
            "--admit",
            "*",
            "--log-level",
            "warning",
        ],
        cwd=REPO,
    )


@pytest.fixture
def pg_url(postgres_server: str) -> Iterator[str]:
    server = Settings(database_url=postgres_server).db_url
    name = f"rehab_test_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(_admin_conninfo(server), autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield make_url(server).set(database=name).render_as_string(hide_password=False)
    finally:
        with psycopg.connect(_admin_conninfo(server), autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


class Attributed:
    """Each estimate with who published it (the worker's ``holder:epoch`` attachment)."""

    def __init__(self, endpoint: str) -> None:
        self.seen: list[tuple[str, float, str, int]] = []  # device, arrival, holder, epoch
        self._session = zenoh.open(make_config(connect=endpoint, mode="peer"))
        self._sub = self._session.declare_subscriber("rehab/*/estimate", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        att = sample.attachment.to_bytes().decode() if sample.attachment is not None else ":0"
        holder, _, epoch = att.rpartition(":")
        self.seen.append((str(sample.key_expr).split("/")[1], time.time(), holder, int(epoch)))

    def workers(self) -> int:
        """Workers alive (their liveliness tokens)."""
        replies = self._session.liveliness().get("rehab/@worker/*", timeout=2.0)
        return sum(1 for r in replies if r.ok is not None)

    def close(self) -> None:
        self._sub.undeclare()  # type: ignore[no-untyped-call]
        self._session.close()  # type: ignore[no-untyped-call]


@pytest.mark.slow
def test_worker_cut_off_from_the_database_stops_before_takeover(
    tmp_path: Path, pg_url: str
) -> None:
    data_dir = tmp_path / "data"
    names, outgoing = streams(6, 40.0)
    url = make_url(Settings(database_url=pg_url).db_url)
    port, zport = free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    api_node = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "backend.cli",
            "serve",
            "--port",
            str(port),
            "--zenoh-listen",
            endpoint,
            "--data-dir",
            str(data_dir),
            "--database-url",
            pg_url,
            "--workers",
            "0",
            "--admit",
            "*",
            "--log-level",
            "warning",
        ],
        cwd=REPO,
    )
    # each worker reaches the database through its own relay: the test cuts off whichever
    # holds the first device (rendezvous hashing over random holder ids decides which)
    proxies = [Proxy(str(url.host), int(url.port or 5432)) for _ in range(2)]
    procs: list[subprocess.Popen[bytes]] = []
    stop = threading.Event()
    est: Attributed | None = None
    try:
        base = f"http://127.0.0.1:{port}"
        wait_for(lambda: _healthy(base), timeout=60, what="API node up")
        procs += [
            worker_proc(
                endpoint, url.set(host="127.0.0.1", port=p.port).render_as_string(False), data_dir
            )
            for p in proxies
        ]
        est = Attributed(endpoint)
        wait_for(lambda: est is not None and est.workers() == 2, timeout=60, what="workers up")
        api, _ = login(base, Settings(data_dir=data_dir, database_url=pg_url))
        with Publisher.connect(endpoint) as pub:
            pub.declare(outgoing)
            assert pub.wait_for_subscribers(20.0)
            player = threading.Thread(
                target=play, args=(pub, outgoing, 1.0), kwargs={"stop": stop}, daemon=True
            )
            player.start()

            def leases() -> dict[str, str]:
                with psycopg.connect(_admin_conninfo(pg_url)) as conn:
                    rows = conn.execute("SELECT device, holder FROM device_leases").fetchall()
                return {d: h for d, h in rows}

            wait_for(lambda: set(leases()) == set(names), what="all devices leased")
            before = leases()
            victim = before[names[0]]
            proxy = next(p for p, w in zip(proxies, procs, strict=True) if f"-{w.pid}-" in victim)
            moved = [d for d, h in before.items() if h == victim]
            sessions = {}
            for name in names:
                pid = api.post(
                    "/api/patients", json={"code": f"p-{name}", "affected_side": "left"}
                ).json()["id"]
                r = api.post("/api/sessions", json={"patient_id": pid, "device": name})
                assert r.status_code == 201, r.text
                sessions[name] = r.json()
            time.sleep(6.0)
            proxy.cut.set()
            cut_at = time.time()
            time.sleep(6.0)
            after = leases()
            assert all(after[d] != victim for d in moved), after
            for d in moved:
                old = [t for dev, t, h, _ in est.seen if dev == d and h == victim]
                new = [t for dev, t, h, _ in est.seen if dev == d and h == after[d]]
                assert old and new, d
                # the cut-off worker went quiet before the new holder published anything
                assert max(old) < min(new), (d, max(old) - cut_at, min(new) - cut_at)
                assert min(new) - cut_at < 3.0, d
            proxy.cut.clear()  # healed: the old holder must find its leases gone
            healed = time.time()
            time.sleep(3.0)
            late = [x for x in est.seen if x[2] == victim and x[1] > cut_at + 1.0]
            assert not late, late[:3]
            stop.set()
            player.join()
        assert healed
        time.sleep(1.0)
        for name in names:
            r = api.post(f"/api/sessions/{sessions[name]['id']}/stop")
            assert r.status_code == 200, r.text
            assert r.json()["summary"] is not None, name
        for name in moved:
            s = sessions[name]
            stored = data_dir / s["recording_path"]
            _, want = analyze(stored, PipelineParams.from_json(s["params"]))
            out = stored.parent / str(s["id"])
            assert (out / "report.json").read_text() == dump_report(want), name
        api.close()
    finally:
        stop.set()
        if est is not None:
            est.close()
        for p in procs:
            p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
        api_node.send_signal(signal.SIGTERM)
        api_node.wait(30)
        for relay in proxies:
            relay.close()


def _healthy(url: str) -> bool:
    try:
        return httpx.get(url + "/api/health", timeout=1).status_code == 200
    except httpx.HTTPError:
        return False
