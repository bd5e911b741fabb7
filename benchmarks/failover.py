"""Failover of a long session: takeover from a pipeline snapshot vs the whole recording.

A simulated session is fast-forwarded through a holder that snapshots every ``--every``
seconds of data (as a worker does), then dies ``--tail`` seconds of data after its last
snapshot. The next holder's takeover (snapshot checks, file prefix copies, restore, tail
replay, rename) is timed, then the same takeover with no snapshot (full replay).

    python benchmarks/failover.py [--minutes 20] [--every 30] [--tail 25] [--seed 3]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import orjson

from backend.deps import SessionInfo
from backend.live import snapshot
from backend.live.devices import DeviceStats
from backend.live.files import SessionFiles
from backend.live.ingest import RawMessage
from backend.live.node import replay
from backend.live.run import LiveRun, SessionContext, rows_ready
from estimators.params import PipelineParams
from protocol import keys
from simulator import SimConfig, simulate

DEVICE = "bench01"


def _context() -> SessionContext:
    info = SessionInfo(id=1, device=DEVICE, patient_id=1, params={}, started_at=datetime.now(UTC))
    return SessionContext(info, PipelineParams(), None)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=20.0)
    ap.add_argument("--every", type=float, default=snapshot.EVERY_S)
    ap.add_argument("--tail", type=float, default=25.0, help="data after the last snapshot, s")
    ap.add_argument("--seed", type=int, default=3)
    a = ap.parse_args()

    sim = simulate(SimConfig(seed=a.seed, duration_s=a.minutes * 60, device=DEVICE))
    msgs = [(k, orjson.dumps(p)) for k, p in sim.messages]
    data = Path(tempfile.mkdtemp(prefix="failover-bench-"))
    try:
        files = SessionFiles(data, 1)
        run = LiveRun(DEVICE, "rehab", DeviceStats(DEVICE), _context(), files)
        due: float | None = None
        captures: list[float] = []
        sizes: list[int] = []
        last_snap_t = 0.0
        # dies --tail seconds of data after the last snapshot before the simulation ends
        end_t = (a.minutes * 60 - a.tail) // a.every * a.every + a.tail
        for key, payload in msgs:
            run.ingest(RawMessage(key, payload, len(payload), 0.0, keys.parse(key).kind))
            if run.fed_since_poll and rows_ready(run.pipeline):
                run.poll()
            t = run.latest_t
            if t is None:
                continue
            if due is None:
                due = t + a.every
            elif t >= due:
                due = t + a.every
                t0 = time.perf_counter()
                path, content = snapshot.capture(run, 1)  # on the device's turn
                captures.append(time.perf_counter() - t0)
                snapshot.write(path, content)  # a thread's, live
                sizes.append(len(content))
                last_snap_t = t
            if t >= end_t and last_snap_t:
                break
        files.flush()  # SIGKILL: nothing closed
        rec = data / "recordings" / "1.jsonl.gz"
        died = run.latest_t or 0.0
        print(
            f"session: {died:.0f} s of data, recording {os.path.getsize(rec) / 1e6:.1f} MB,"
            f" {files.recorder.lines} lines; died {died - last_snap_t:.0f} s after the last snapshot"
        )
        print(
            f"snapshot capture on the device's turn: median {statistics.median(captures) * 1e3:.1f}"
            f" ms, max {max(captures) * 1e3:.1f} ms; size last {sizes[-1] / 1e6:.2f} MB"
        )
        for label, keep in (("from snapshot", True), ("whole recording", False)):
            if not keep:
                shutil.rmtree(data / "recordings" / "1.state", ignore_errors=True)
            t0 = time.perf_counter()
            ready = snapshot.prepare(data, _context(), DEVICE, "rehab", f"epoch{2 if keep else 3}")
            t1 = time.perf_counter()
            replay(ready.run, rec, "rehab", ready.skip)
            t2 = time.perf_counter()
            ready.files.flush()
            ready.files.close(None)  # not promoted: the next variant starts from the same files
            print(
                f"takeover {label}: {t2 - t0:.2f} s (prepare {t1 - t0:.2f} s, replay of"
                f" {ready.files.recorder.lines - ready.skip} lines {t2 - t1:.2f} s)"
            )
        print("load average:", " ".join(f"{x:.2f}" for x in os.getloadavg()))
    finally:
        shutil.rmtree(data, ignore_errors=True)


if __name__ == "__main__":
    main()
