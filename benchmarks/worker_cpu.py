"""A worker's CPU per device-second, in one process and without the load generator: the
loop side of ``rehab worker`` (ingest routing, the devices' turns, recording, the pipelines,
estimate and feedback puts, the dashboard feed) fed N simulated devices' messages as fast
as it takes them, in the bursts a worker's receiving thread hands over.

``benchmarks/latency.py --workers 2`` measures the same on the real processes, but its
figure moves with whatever else the machine runs (the load generator, other jobs); this one
counts only this process's CPU (``time.process_time``, and the loop thread's alone), so two
versions of the code compare in the same minutes on a shared machine. Not covered: the
receiving side (Zenoh's threads, the worker's receiving thread with its key filter and
payload copies), the lease thread and the database writer (cycles only queue here).

    python benchmarks/worker_cpu.py                  # 25 devices (a worker's share of 50)
    python benchmarks/worker_cpu.py --devices 25 --seconds 30 --burst-ms 4 --profile out.prof
    python benchmarks/worker_cpu.py --no-feed        # ablations: --no-puts, --no-session, ...

``--profile`` writes cProfile statistics of the measured part, timed by the loop thread's
CPU (``pstats`` to read them).
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from backend.deps import SessionInfo  # noqa: E402
from backend.live import warmup  # noqa: E402
from backend.live.budget import IngestBudget  # noqa: E402
from backend.live.devices import DeviceStats  # noqa: E402
from backend.live.files import SessionFiles  # noqa: E402
from backend.live.hub import Hub  # noqa: E402
from backend.live.ingest import Ingest  # noqa: E402
from backend.live.node import FeedForwarder  # noqa: E402
from backend.live.run import SessionContext  # noqa: E402
from backend.live.store import DbWriter  # noqa: E402
from backend.live.worker import DeviceWorker, Scheduler, StartSession  # noqa: E402
from backend.live.zenoh_io import ZenohIO  # noqa: E402
from estimators.params import PipelineParams  # noqa: E402
from protocol.zenoh_config import make_config  # noqa: E402
from simulator import SimConfig, simulate  # noqa: E402
from simulator.publish import prepare  # noqa: E402

PHASES = 8  # robot-to-IMU phases, as benchmarks/latency.py
START_SPREAD_S = 5.0


def schedule(n: int, seconds: float) -> list[tuple[float, str, bytes]]:
    """(arrival time, key, payload) of ``n`` devices, as ``benchmarks/latency.py`` sends."""
    cfg = SimConfig(seed=1, duration_s=seconds + 1.0, device="tmpl")
    period = 1.0 / cfg.robot_rate_hz
    templates = [
        prepare(simulate(replace(cfg, robot_time_offset_s=period * k / PHASES)).messages)
        for k in range(PHASES)
    ]
    rng = np.random.default_rng(1)
    out: list[tuple[float, str, bytes]] = []
    for i in range(n):
        name = f"bench{i:03d}"
        start = round(START_SPREAD_S * rng.random(), 3)
        for m in templates[i % PHASES]:
            out.append((m.at + start, m.key.replace("/tmpl/", f"/{name}/", 1), m.payload))
    out.sort(key=lambda x: x[0])
    return out


async def run(args: argparse.Namespace) -> dict[str, Any]:
    warmup.load_kernels()
    loop = asyncio.get_running_loop()
    port = args.port
    zio = ZenohIO(
        make_config(listen=f"tcp/127.0.0.1:{port}"),
        "rehab",
        loop,
        lambda b: None,
        lambda d, a: None,
        1 << 20,
        subscribe=False,
    )
    zio.open()
    # the API node and the load generator: a subscriber in a process of its own (the
    # publishers send to remote subscribers only; one here would also share our GIL)
    sub = subprocess.Popen(
        [sys.executable, __file__, "--role", "subscriber", "--port", str(port)]
        + (["--no-subscriber"] if args.no_subscriber else []),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert sub.stdin is not None and sub.stdout is not None
    sub.stdout.readline()
    feed_pub = zio.session.declare_publisher("rehab/@feed/bench")  # type: ignore[union-attr]
    feed = FeedForwarder(feed_pub)
    hub = Hub(30.0, 256)
    if not args.no_feed:
        hub.clients.add(feed)  # type: ignore[arg-type]
    sched = Scheduler(rest=False)
    db = DbWriter(None)  # type: ignore[arg-type]  # never started: cycles queue (bounded)
    budget = IngestBudget(256 << 20)
    tmp = Path(tempfile.mkdtemp(prefix="worker-cpu-"))
    workers: dict[str, DeviceWorker] = {}
    files: list[SessionFiles] = []
    for i in range(args.devices):
        name = f"bench{i:03d}"
        w = DeviceWorker(
            name,
            DeviceStats(name),
            scheduler=sched,
            prefix="rehab",
            zio=None if args.no_puts else zio,
            hub=hub,
            db=db,
            max_items=4096,
            max_bytes=32 << 20,
            on_change=lambda n: None,
            budget=budget,
        )
        w.set_lease("bench-1-x", 1, lambda: True)
        info = SessionInfo(
            id=i + 1, device=name, patient_id=1, params={}, started_at=datetime.now(UTC)
        )
        if not args.no_session:
            f = SessionFiles(tmp, i + 1)
            files.append(f)
            w.command(StartSession(SessionContext(info, PipelineParams(), None), f))
        workers[name] = w
    ingest = Ingest("rehab", workers.get)
    msgs = schedule(args.devices, args.seconds)
    burst = args.burst_ms / 1000.0
    batches: list[list[tuple[str, bytes | None, int, float]]] = []
    cur: list[tuple[str, bytes | None, int, float]] = []
    edge = msgs[0][0] + burst
    for at, key, payload in msgs:
        if at >= edge and cur:
            batches.append(cur)
            cur = []
            edge = at + burst
        cur.append((key, payload, len(payload), at))
    batches.append(cur)
    await asyncio.sleep(0.5)  # the subscriber's link
    tick = msgs[0][0]
    prof = cProfile.Profile(time.thread_time) if args.profile else None
    wall0, cpu0, main0 = time.perf_counter(), time.process_time(), time.thread_time()
    if prof:
        prof.enable()
    for batch in batches:
        ingest.route(batch)
        sched.run()
        feed.flush()  # one put per loop iteration (FEED_TICK_S 0)
        if batch[-1][3] >= tick:  # the ticker's flush every 0.25 s of data
            tick += 0.25
            for f in files:
                f.flush()
        await asyncio.sleep(0)
    while any(w.queued for w in workers.values()):
        sched.run()
        await asyncio.sleep(0)
    if prof:
        prof.disable()
        prof.dump_stats(args.profile)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    main = time.thread_time() - main0
    device_s = args.devices * args.seconds
    await asyncio.sleep(0.5)
    result = {
        "devices": args.devices,
        "seconds": args.seconds,
        "messages": len(msgs),
        "batches": len(batches),
        "cpu_s": round(cpu, 3),
        "wall_s": round(wall, 3),
        "cpu_ms_per_device_s": round(1000 * cpu / device_s, 3),
        # the event loop's thread; the rest is Zenoh's threads sending the puts
        "loop_thread_ms_per_device_s": round(1000 * main / device_s, 3),
        "estimate_rows": sum(w.stats.robot_samples for w in workers.values()),
    }
    sub.stdin.write("stop\n")
    sub.stdin.flush()
    result["received_by_subscriber"] = int(sub.stdout.readline())
    sub.wait(10)
    zio.close()
    shutil.rmtree(tmp, ignore_errors=True)
    return result


def subscriber(port: int, quiet: bool) -> None:
    session = zenoh.open(make_config(connect=f"tcp/127.0.0.1:{port}"))
    received = [0]

    def on_sample(s: zenoh.Sample) -> None:
        received[0] += 1

    if not quiet:
        session.declare_subscriber("rehab/**", on_sample)
        session.declare_subscriber("rehab/@feed/*", on_sample)  # the API node's
    time.sleep(0.5)
    print("ready", flush=True)
    sys.stdin.readline()
    print(received[0], flush=True)
    session.close()  # type: ignore[no-untyped-call]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--devices", type=int, default=25)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--burst-ms", type=float, default=4.0, help="arrivals handed over at once")
    ap.add_argument("--port", type=int, default=7650)
    ap.add_argument("--profile", metavar="FILE", help="cProfile of the measured part")
    ap.add_argument("--no-feed", action="store_true", help="no dashboard watching")
    ap.add_argument("--no-puts", action="store_true", help="no estimate or feedback puts")
    ap.add_argument("--no-session", action="store_true", help="previews: nothing recorded")
    ap.add_argument("--no-subscriber", action="store_true", help="puts reach nobody")
    ap.add_argument("--role", choices=["subscriber"], help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.role:
        subscriber(args.port, args.no_subscriber)
        return 0
    print(json.dumps(asyncio.run(run(args))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
