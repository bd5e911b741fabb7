"""Live latency and capacity: N simulated devices stream in real time into ``rehab serve``.

Three processes besides this one: the service (``rehab serve``, SQLite, a session on every
device so recording and cycle storage are part of the load), a publisher (all devices:
100 Hz IMU in messages of 4 samples, 25 Hz robot, the devices starting at random instants
over 5 s), and a subscriber (``rehab/*/estimate`` on Zenoh, and the therapists' WebSocket
feed). Publisher and subscriber stand for devices and screens on other machines: they do
the least per message they can (the subscriber notes arrival time and bytes, and decodes
after the run); their CPU is reported (``load_generator_cpu_percent``).

A message leaves when its newest sample is taken (``simulator.publish``). A device's robot
and IMU run on clocks of their own, so where a robot sample falls between two IMU messages
(each covers 40 ms) differs between devices: each device's robot is sampled at one of
``PHASES`` offsets spread over the robot period (``SimConfig.robot_time_offset_s``), so a
robot sample arrives 0–35 ms after the IMU message before it.

The publisher notes the wall time at which it sent each robot sample, the subscriber the
wall time at which the estimate row of that sample arrived (matched by device and ``t``).
Latency = arrival − send, same machine, same clock; ``publisher_late_ms`` is how late the
publisher itself sent them (not in the latency). The pipeline decides a robot sample when
the IMU has reached it, or (product method) when the newest IMU sample is at most
``imu_predict_s`` = 50 ms older, the upper arm predicted from it: longer than an IMU
message's 40 ms, so a sample waits for the IMU only if the IMU message comes late. (The
paper's method, ``imu_predict_s`` 0, would wait for the IMU message that covers the sample:
0–35 ms at these phases; the one phase used before, robot 10 ms after the IMU message, made
it 30 ms for all.) On the WebSocket the 30 Hz decimation adds to it.

    python benchmarks/latency.py                       # 50 devices, 120 s
    python benchmarks/latency.py --devices 20 --duration 60 --json out.json
    python benchmarks/latency.py --sweep --duration 40 # largest N with p99 ≤ 50 ms
    python benchmarks/latency.py --workers 2           # the pipelines in 2 worker processes
    python benchmarks/latency.py --worker-routers 2    # 2 workers, each its own Zenoh router
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from serving import wait_healthy  # benchmarks/ is the script's own directory

REPO = Path(__file__).resolve().parents[1]
TARGET_P99_MS = 50.0
WARMUP_S = 10.0  # excluded from the steady-state figures (process start, first polls)
START_SPREAD_S = 5.0  # devices start within this (the converged heading-update interval)
PHASES = 8  # robot-to-IMU phases of the devices (see publisher)
START_DECIMALS = 3  # device start times in whole milliseconds (see publisher)
CLK_TCK = os.sysconf("SC_CLK_TCK")
PAGE = os.sysconf("SC_PAGE_SIZE")


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def device_name(i: int) -> str:
    return f"bench{i:03d}"


# --------------------------------------------------------------------------- publisher


def publisher(args: argparse.Namespace) -> None:
    from simulator import SimConfig, simulate
    from simulator.publish import Publisher, prepare

    n = args.devices
    cfg = SimConfig(seed=1, duration_s=args.duration + 1.0, device="tmpl")
    robot_period = 1.0 / cfg.robot_rate_hz
    # A device's robot and IMU run on clocks of their own: where a robot sample falls
    # between two IMU messages differs from device to device. PHASES templates, each the
    # same motion with the robot sampled that much later (robot_time_offset_s), cover the
    # robot period evenly. --lockstep: all the same (phase 0), the worst case.
    phases = 1 if args.lockstep else min(n, PHASES)
    templates = [
        prepare(simulate(replace(cfg, robot_time_offset_s=robot_period * k / phases)).messages)
        for k in range(phases)
    ]
    rng = np.random.default_rng(1)
    pub = Publisher.connect(args.endpoint)
    # (release time, device, the key's put, payload, robot sample time or None)
    schedule: list[tuple[float, int, Any, bytes, float | None]] = []
    for i in range(n):
        name = device_name(i)
        pub.announce(name)
        # Devices start their sessions at moments of their own over one heading-update
        # interval (as a clinic's would), each on its own clock from 0: at random
        # milliseconds, not on a grid (START_SPREAD_S * i / 50 is a multiple of half the
        # robot period: half the devices sent at the same instant). Whole milliseconds: the
        # samples' times are on a 5 ms grid, so messages leave on a 1 ms grid, at most 1 000
        # wake-ups of this process a second (continuous starts: one per message, 2 500 a
        # second, and 2.3 times the CPU). --lockstep: all within one robot period, so every
        # periodic cost of the pipelines (heading updates, cycle verdicts) falls on the same
        # instant: the worst case.
        start = (
            robot_period * i / n
            if args.lockstep
            else round(START_SPREAD_S * rng.random(), START_DECIMALS)
        )
        puts: dict[str, Any] = {}
        for m in templates[i % phases]:
            put = puts.get(m.key)
            if put is None:
                key = m.key.replace("/tmpl/", f"/{name}/", 1)
                put = puts[m.key] = pub.declare_key(key).put
            robot_t = m.at if m.key.endswith("/robot") else None
            schedule.append((m.at + start, i, put, m.payload, robot_t))
    schedule.sort(key=lambda x: (x[0], x[1]))
    ok = pub.wait_for_subscribers(30.0)
    print("ready" if ok else "ready (no subscriber!)", flush=True)
    sys.stdin.readline()  # "go"
    sent: list[list[tuple[float, float]]] = [[] for _ in range(n)]
    late: list[float] = []  # how long after its time each robot sample went out (s)
    cpu0 = time.process_time()
    t0 = schedule[0][0]
    base = time.monotonic() + 0.2 - t0
    monotonic, sleep = time.monotonic, time.sleep
    to_wall = time.time() - time.monotonic()  # one clock read per message, not two
    for at, i, put, payload, robot_t in schedule:
        delay = base + at - monotonic()
        if delay > 0:
            sleep(delay)
        put(payload)
        if robot_t is not None:
            now = monotonic()
            sent[i].append((robot_t, now + to_wall))
            late.append(now - base - at)
    end_late = monotonic() - (base + schedule[-1][0])
    Path(args.out).write_text(
        json.dumps(
            {
                "sent": sent,
                "late": late,
                "messages": len(schedule),
                "late_s": end_late,
                "cpu_s": time.process_time() - cpu0,
            }
        )
    )
    time.sleep(1.0)
    pub.close()
    print("done", flush=True)


# --------------------------------------------------------------------------- subscriber


def subscriber(args: argparse.Namespace) -> None:
    import orjson
    import zenoh
    from websockets.sync.client import connect

    from protocol.zenoh_config import make_config

    # arrival (wall time) and payload; decoded after the run, so that the callbacks of
    # this process (which shares the two cores with the service) do the least they can
    zraw: list[tuple[float, str, bytes, bytes | None]] = []
    wraw: list[tuple[float, str]] = []

    def on_estimate(sample: zenoh.Sample) -> None:
        now = time.time()
        att = sample.attachment
        zraw.append(
            (
                now,
                str(sample.key_expr),
                sample.payload.to_bytes(),
                att.to_bytes() if att is not None else None,
            )
        )

    session = zenoh.open(make_config(connect=args.endpoint, mode="peer"))
    sub = session.declare_subscriber("rehab/*/estimate", on_estimate)
    stop = threading.Event()

    def websocket() -> None:
        url = args.url.replace("http://", "ws://") + "/api/ws/live"
        with connect(
            url, additional_headers={"Authorization": f"Bearer {args.token}"}, max_size=None
        ) as ws:
            while not stop.is_set():
                try:
                    text = ws.recv(timeout=0.5)
                except TimeoutError:
                    continue
                wraw.append((time.time(), str(text)))

    ws_thread = threading.Thread(target=websocket, daemon=True)
    ws_thread.start()
    print("ready", flush=True)
    sys.stdin.readline()  # "stop"
    stop.set()
    ws_thread.join(5)
    sub.undeclare()  # type: ignore[no-untyped-call]
    session.close()  # type: ignore[no-untyped-call]
    zrecv: dict[str, list[tuple[float, float]]] = {}
    wrecv: dict[str, list[tuple[float, float]]] = {}
    by_holder: dict[str, int] = {}  # estimate rows by publishing worker (the attachment)
    for now, key, payload, att in zraw:
        t = orjson.loads(payload)["t"]
        zrecv.setdefault(key.split("/")[1], []).extend((x, now) for x in t)
        holder = att.decode().rsplit(":", 1)[0] if att is not None else ""
        by_holder[holder] = by_holder.get(holder, 0) + len(t)
    for now, text in wraw:
        msg = orjson.loads(text)
        if msg["type"] == "estimate":
            wrecv.setdefault(msg["device"], []).extend((x, now) for x in msg["rows"]["t"])
    Path(args.out).write_text(
        json.dumps({"zenoh": zrecv, "websocket": wrecv, "by_holder": by_holder})
    )
    print("done", flush=True)


# --------------------------------------------------------------------------- orchestration


def proc_sample(pid: int) -> tuple[float, int]:
    """(CPU seconds used so far, resident bytes) of a process."""
    stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    cpu = (int(stat[11]) + int(stat[12])) / CLK_TCK
    rss = int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * PAGE
    return cpu, rss


def thread_cpu(pid: int) -> dict[int, tuple[str, float]]:
    """(name, CPU seconds used so far) of each thread of a process, by thread id."""
    out: dict[int, tuple[str, float]] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name, rest = (task / "stat").read_text().split(" (", 1)[1].rsplit(")", 1)
        except (OSError, ValueError):  # the thread ended
            continue
        stat = rest.split()
        out[int(task.name)] = (name, (int(stat[11]) + int(stat[12])) / CLK_TCK)
    return out


def worker_threads(pid: int, before: dict[int, tuple[str, float]], wall: float) -> dict[str, float]:
    """A worker's CPU (% of a core) since ``before``: its event loop (the main thread),
    Zenoh's threads (receiving ``rx-*``, sending ``tx-*``, the rest), and its other Python
    threads (the receiving thread, the lease thread, the database writer: Python does not
    name them for the OS)."""
    out = {"loop": 0.0, "zenoh_rx": 0.0, "zenoh_tx": 0.0, "zenoh_other": 0.0, "python": 0.0}
    for tid, (name, cpu) in thread_cpu(pid).items():
        used = 100 * (cpu - before.get(tid, (name, 0.0))[1]) / wall
        if tid == pid:
            part = "loop"
        elif name.startswith("rx-"):
            part = "zenoh_rx"
        elif name.startswith("tx-"):
            part = "zenoh_tx"
        elif name.startswith(("app-", "net-", "acc-")):
            part = "zenoh_other"
        else:
            part = "python"
        out[part] += used
    return {k: round(v, 1) for k, v in out.items()}


def latencies(
    sent: list[list[tuple[float, float]]],
    recv: dict[str, list[tuple[float, float]]],
    t_start: float,
    warmup: float,
) -> tuple[np.ndarray, int, int]:
    """Latencies (s) of the steady state, and (robot samples sent, rows received) overall."""
    lat: list[float] = []
    n_sent = n_recv = 0
    for i, rows in enumerate(sent):
        got = dict(recv.get(device_name(i), []))
        n_sent += len(rows)
        n_recv += sum(1 for t, _ in rows if t in got)
        lat.extend(got[t] - w for t, w in rows if t in got and w - t_start >= warmup)
    return np.array(lat), n_sent, n_recv


def stats_ms(a: np.ndarray) -> dict[str, float | None]:
    if not len(a):
        return {"p50": None, "p90": None, "p99": None, "max": None}
    p50, p90, p99 = np.percentile(a, [50, 90, 99]) * 1e3
    return {
        "p50": round(float(p50), 2),
        "p90": round(float(p90), 2),
        "p99": round(float(p99), 2),
        "max": round(float(a.max() * 1e3), 2),
    }


def tree(pid: int) -> list[int]:
    """A process and its descendants (the API node and its local workers)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        for task in Path(f"/proc/{p}/task").glob("*/children"):
            try:
                todo.extend(int(x) for x in task.read_text().split())
            except OSError:
                continue
    return out


def tree_cpu(pids: list[int]) -> dict[int, float]:
    out = {}
    for p in pids:
        try:
            out[p] = proc_sample(p)[0]
        except OSError:
            continue
    return out


def run(
    n: int,
    duration: float,
    sessions: bool = True,
    verbose: bool = True,
    lockstep: bool = False,
    workers: int | None = None,
    worker_routers: int = 0,
    database_url: str | None = None,
) -> dict[str, Any]:
    import httpx

    from backend.auth.first_admin import read_admin_credentials
    from backend.settings import Settings

    def say(*a: object) -> None:
        if verbose:
            print(f"[{n} devices]", *a, file=sys.stderr, flush=True)

    work = Path(tempfile.mkdtemp(prefix="rehab-bench-"))
    port, zport = free_port(), free_port()
    endpoint, url = f"tcp/127.0.0.1:{zport}", f"http://127.0.0.1:{port}"
    service = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "backend.cli",
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--zenoh-listen",
            endpoint,
            "--data-dir",
            str(work / "data"),
            "--log-level",
            "warning",
            "--admit",
            "*",
            # --worker-routers: an API-only node; the workers, each its own Zenoh router
            # joined to the node's (router to router), are started below
            *(
                ["--workers", str(0 if worker_routers else workers)]
                if workers is not None
                else ["--single-process"]  # no --workers: the one-process figures
            ),
            *(["--database-url", database_url] if database_url else []),
        ],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
    )
    procs: list[subprocess.Popen[str]] = []
    remote: list[subprocess.Popen[bytes]] = []
    try:
        wait_healthy(service, url, timeout=180)  # the node waits for its workers
        for _ in range(worker_routers):
            remote.append(
                subprocess.Popen(
                    [
                        sys.executable,
                        "-m",
                        "backend.cli",
                        "worker",
                        "--zenoh-connect",
                        endpoint,
                        "--router",
                        f"tcp/127.0.0.1:{free_port()}",
                        "--data-dir",
                        str(work / "data"),
                        *(["--database-url", database_url] if database_url else []),
                        "--log-level",
                        "warning",
                    ],
                    cwd=REPO,
                )
            )
        creds = read_admin_credentials(Settings(data_dir=work / "data"))
        assert creds is not None
        api = httpx.Client(base_url=url, timeout=60)
        token = api.post(
            "/api/auth/login", json={"username": creds.username, "password": creds.password}
        ).json()["access_token"]
        api.cookies.clear()
        api.headers["Authorization"] = f"Bearer {token}"
        me = [sys.executable, __file__]
        sub = subprocess.Popen(
            [
                *me,
                "--role",
                "subscriber",
                "--endpoint",
                endpoint,
                "--url",
                url,
                "--token",
                token,
                "--out",
                str(work / "sub.json"),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=REPO,
        )
        procs.append(sub)
        assert sub.stdout is not None and sub.stdin is not None
        sub.stdout.readline()
        pub = subprocess.Popen(
            [
                *me,
                "--role",
                "publisher",
                "--endpoint",
                endpoint,
                "--devices",
                str(n),
                "--duration",
                str(duration),
                "--out",
                str(work / "pub.json"),
                *(["--lockstep"] if lockstep else []),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=REPO,
        )
        procs.append(pub)
        assert pub.stdout is not None and pub.stdin is not None
        say("publisher:", pub.stdout.readline().strip())
        deadline = time.monotonic() + 60
        while len(api.get("/api/devices").json()) < n:
            if time.monotonic() > deadline:
                raise RuntimeError("devices not registered")
            time.sleep(0.2)
        if sessions:
            for i in range(n):
                pid = api.post(
                    "/api/patients", json={"code": f"bench-{i}", "affected_side": "right"}
                ).json()["id"]
                r = api.post("/api/sessions", json={"patient_id": pid, "device": device_name(i)})
                assert r.status_code == 201, r.text
        time.sleep(1.0)
        cpu0, rss0 = proc_sample(service.pid)
        threads0 = thread_cpu(service.pid)
        pids = tree(service.pid) + [p.pid for p in remote]
        wthreads0 = {p: thread_cpu(p) for p in pids if p != service.pid}
        tree0 = tree_cpu(pids)
        say(f"idle service: {rss0 / 2**20:.0f} MiB; streaming {duration:.0f} s")
        sub_cpu0 = proc_sample(sub.pid)[0]
        t_start = time.time()
        pub.stdin.write("go\n")
        pub.stdin.flush()
        peak = rss0
        samples: list[tuple[float, float, int]] = []
        while pub.poll() is None:
            time.sleep(1.0)
            cpu, rss = proc_sample(service.pid)
            samples.append((time.time(), cpu, rss))
            peak = max(peak, rss)
        wall = time.time() - t_start
        cpu1, rss1 = proc_sample(service.pid)
        sub_cpu = proc_sample(sub.pid)[0] - sub_cpu0
        threads1 = thread_cpu(service.pid)
        tree1 = tree_cpu(pids)
        wthreads = {p: worker_threads(p, t0, wall) for p, t0 in wthreads0.items()}
        by_proc = {p: tree1[p] - tree0.get(p, 0.0) for p in tree1 if p in tree0}
        worker_cpu = sum(c for p, c in by_proc.items() if p != service.pid)
        # the event loop's thread (the pipelines, ingest, outputs): the one that saturates
        used = {
            tid: (name, cpu - threads0.get(tid, (name, 0.0))[1])
            for tid, (name, cpu) in threads1.items()
        }
        main_cpu = used.get(service.pid, ("", 0.0))[1]
        busiest = sorted(used.items(), key=lambda kv: -kv[1][1])[:6]
        time.sleep(2.0)  # the last estimates
        sub.stdin.write("stop\n")
        sub.stdin.flush()
        sub.wait(60)
        time.sleep(1.5)  # device stats are flushed once a second
        devices = {d["name"]: d for d in api.get("/api/devices").json()}
        pubres = json.loads((work / "pub.json").read_text())
        subres = json.loads((work / "sub.json").read_text())
        received = sum(
            (d.get("stats") or {}).get("ingest", {}).get("messages", 0) for d in devices.values()
        )
        dropped = sum(
            (d.get("stats") or {}).get("ingest", {}).get("dropped", 0) for d in devices.values()
        )
        zl, z_sent, z_recv = latencies(pubres["sent"], subres["zenoh"], t_start, WARMUP_S)
        wl, _, w_recv = latencies(pubres["sent"], subres["websocket"], t_start, WARMUP_S)
        zl_all, _, _ = latencies(pubres["sent"], subres["zenoh"], t_start, 0.0)
        rejected: dict[str, int] = {}
        for d in devices.values():
            for reason, k in (
                (d.get("stats") or {}).get("ingest", {}).get("rejected") or {}
            ).items():
                rejected[reason] = rejected.get(reason, 0) + k
        # CPU per device-second of each worker: its CPU over the device-seconds it answered
        # (its share of the estimate rows, told apart by the holder:epoch attachment; a
        # holder id is <host>-<pid>-<random>)
        rows_by_pid = {
            int(h.rsplit("-", 2)[1]): k for h, k in subres["by_holder"].items() if h.count("-") >= 2
        }
        total_rows = sum(subres["by_holder"].values()) or 1
        per_worker = {
            f"worker {p}": round(1000 * c / (rows_by_pid[p] / total_rows * n * wall), 2)
            for p, c in by_proc.items()
            if p != service.pid and rows_by_pid.get(p)
        }
        steady = [s for s in samples if s[0] - t_start >= WARMUP_S]
        cpu_steady = (
            (steady[-1][1] - steady[0][1]) / (steady[-1][0] - steady[0][0])
            if len(steady) > 2
            else None
        )
        result = {
            "devices": n,
            "duration_s": duration,
            "sessions": sessions,
            "lockstep": lockstep,
            "messages_published": pubres["messages"],
            "messages_received": received,
            "messages_lost": pubres["messages"] - received,
            "messages_dropped": dropped,
            "robot_samples": z_sent,
            "estimates_received_zenoh": z_recv,
            "estimates_received_websocket": w_recv,
            "publisher_late_s": round(pubres["late_s"], 3),
            # robot samples: sent this long after their time (the publisher's own timing;
            # not part of the latency, which starts when the sample is sent)
            "publisher_late_ms": stats_ms(np.array(pubres["late"])),
            # the load generator: 50 devices that would be on other machines
            "load_generator_cpu_percent": {
                "publisher": round(100 * pubres["cpu_s"] / wall, 1),
                "subscriber": round(100 * sub_cpu / wall, 1),
            },
            "latency_zenoh_ms": stats_ms(zl),
            "latency_zenoh_all_ms": stats_ms(zl_all),
            "latency_websocket_ms": stats_ms(wl),
            "service_cpu_percent": round(100 * (cpu1 - cpu0) / wall, 1),
            "service_cpu_percent_steady": None
            if cpu_steady is None
            else round(100 * cpu_steady, 1),
            "service_main_thread_cpu_percent": round(100 * main_cpu / wall, 1),
            "service_threads_cpu_percent": {
                f"{name} {tid}": round(100 * cpu / wall, 1) for tid, (name, cpu) in busiest
            },
            "service_rss_idle_mib": round(rss0 / 2**20, 1),
            "service_rss_end_mib": round(rss1 / 2**20, 1),
            "service_rss_peak_mib": round(peak / 2**20, 1),
            "memory_per_device_mib": round((rss1 - rss0) / n / 2**20, 2),
            "cpu_per_device_percent": round(100 * (cpu1 - cpu0) / wall / n, 2),
            "workers": len(pids) - 1,
            "cpu_percent_by_process": {
                ("api" if p == service.pid else f"worker {p}"): round(100 * c / wall, 1)
                for p, c in by_proc.items()
            },
            "total_cpu_percent": round(100 * sum(by_proc.values()) / wall, 1),
            # the pipelines' cost: worker CPU seconds per device-second of real-time data
            "worker_cpu_ms_per_device_s": round(1000 * worker_cpu / wall / n, 2)
            if len(pids) > 1
            else None,
            "worker_cpu_ms_per_device_s_by_worker": per_worker,
            "worker_threads_cpu_percent": {f"worker {p}": v for p, v in wthreads.items()},
            "devices_by_worker": {
                f"worker {p}": round(k / total_rows * n, 1) for p, k in rows_by_pid.items()
            },
            "rejected": rejected,
        }
        result["meets_target"] = bool(
            result["messages_lost"] == 0
            and z_recv == z_sent
            and result["latency_zenoh_ms"]["p99"] is not None
            and result["latency_zenoh_ms"]["p99"] <= TARGET_P99_MS
        )
        say(json.dumps(result))
        api.close()
        return result
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        for rw in remote:
            rw.send_signal(signal.SIGTERM)
        for rw in remote:
            try:
                rw.wait(30)
            except subprocess.TimeoutExpired:
                rw.kill()
        service.send_signal(signal.SIGTERM)
        try:
            service.wait(60)
        except subprocess.TimeoutExpired:
            service.kill()
        import shutil

        shutil.rmtree(work, ignore_errors=True)


def sweep(duration: float, start: int, sessions: bool, lockstep: bool = False) -> dict[str, Any]:
    """Grow N while the target holds, then bisect between the last pass and first fail."""
    runs: dict[int, dict[str, Any]] = {}

    def ok(n: int) -> bool:
        if n not in runs:
            runs[n] = run(n, duration, sessions, lockstep=lockstep)
        return bool(runs[n]["meets_target"])

    lo, hi = 0, start
    while ok(hi):
        lo, hi = hi, hi * 2
    while hi - lo > max(1, lo // 10):
        mid = (lo + hi) // 2
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return {
        "capacity_devices": lo,
        "target_p99_ms": TARGET_P99_MS,
        "runs": [runs[k] for k in sorted(runs)],
    }


def report(r: dict[str, Any]) -> str:
    z, w = r["latency_zenoh_ms"], r["latency_websocket_ms"]
    return (
        f"{r['devices']} devices, {r['duration_s']:.0f} s: lost {r['messages_lost']} of "
        f"{r['messages_published']} messages ({r['messages_dropped']} dropped), estimates "
        f"{r['estimates_received_zenoh']}/{r['robot_samples']}; latency to Zenoh p50 "
        f"{z['p50']} ms, p99 {z['p99']} ms (max {z['max']}); to WebSocket p50 {w['p50']} ms, "
        f"p99 {w['p99']} ms; service CPU {r['service_cpu_percent']} % "
        f"(main thread {r['service_main_thread_cpu_percent']} %) "
        f"({r['cpu_per_device_percent']} %/device), RSS {r['service_rss_idle_mib']} → "
        f"{r['service_rss_end_mib']} MiB ({r['memory_per_device_mib']} MiB/device)"
        f" {'OK' if r['meets_target'] else 'FAILS p99 <= 50 ms'}"
        + (
            f"; {r['workers']} workers, CPU by process {r['cpu_percent_by_process']}, "
            f"{r['worker_cpu_ms_per_device_s']} ms of worker CPU per device-second "
            f"(by worker {r['worker_cpu_ms_per_device_s_by_worker']}, devices "
            f"{r['devices_by_worker']}); rejected {r['rejected']}"
            if r.get("workers")
            else ""
        )
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--devices", type=int, default=50)
    ap.add_argument("--duration", type=float, default=120.0, metavar="S")
    ap.add_argument("--sweep", action="store_true", help="find the largest N meeting p99 ≤ 50 ms")
    ap.add_argument(
        "--lockstep",
        action="store_true",
        help="all devices start within 40 ms with the same data (worst case)",
    )
    ap.add_argument("--sweep-start", type=int, default=10)
    ap.add_argument(
        "--no-sessions",
        action="store_true",
        help="devices stream without a session (no recording, no cycle storage)",
    )
    ap.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="rehab serve --workers N (default: the service's default, the core count)",
    )
    ap.add_argument(
        "--worker-routers",
        type=int,
        default=0,
        metavar="N",
        help="an API-only node and N `rehab worker --router` processes, each its own Zenoh "
        "router joined to the node's (the multi-machine topology on one machine)",
    )
    ap.add_argument("--database-url", metavar="URL", help="default: SQLite in the data dir")
    ap.add_argument("--json", metavar="FILE", help="write the results as JSON")
    # internal: the publisher and subscriber processes
    ap.add_argument("--role", choices=["publisher", "subscriber"], help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    ap.add_argument("--url", help=argparse.SUPPRESS)
    ap.add_argument("--token", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.role == "publisher":
        publisher(args)
        return 0
    if args.role == "subscriber":
        subscriber(args)
        return 0
    # a SIGTERM (a job stopped) unwinds like Ctrl-C: the `finally` stops the service and its
    # workers instead of leaving them running
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    if args.sweep:
        result = sweep(args.duration, args.sweep_start, not args.no_sessions, args.lockstep)
        for r in result["runs"]:
            print(report(r))
        print(f"capacity: {result['capacity_devices']} devices at p99 ≤ {TARGET_P99_MS:.0f} ms")
    else:
        result = run(
            args.devices,
            args.duration,
            not args.no_sessions,
            lockstep=args.lockstep,
            workers=args.workers if not args.worker_routers else 0,
            worker_routers=args.worker_routers,
            database_url=args.database_url,
        )
        print(report(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
