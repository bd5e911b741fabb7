"""Hostile Zenoh input against a real service: ≥ 10⁵ hostile payloads on random and real keys,
mixed with one valid device, and a flood of the largest messages a device may send.

    python benchmarks/fuzz.py [--payloads 100000] [--flood-s 15] [--seed 1] [--workers 2]

Starts ``rehab serve --admit '*'`` in its own process (SQLite in a temporary directory) and
checks, printing the figures:

- 0 crashes: the service process is alive and healthy at the end;
- the valid device's estimates equal those of an undisturbed run (its session's
  estimates.csv byte for byte, compared with ``rehab analyze`` of the clean recording);
- memory flat: the service's RSS at the end of the hostile phase against its RSS after the
  warm-up (and its peak); after the flood, its RSS 3 s and ``SETTLE_S`` later
  (``rss_settled_mib``: what stays) against its RSS before it;
- the API answering within 1 s throughout: ``/api/health`` timed every 0.1 s from this
  process (the worst time is printed).

Phases: (1) the fuzz phase, the valid device playing a session at full speed while a second
process sends hostile payloads; (2) the flood phase, 20 names sending 2000-sample IMU
messages and 450 kB ones (over the cap) as fast as Zenoh takes them.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from backend.analysis import analyze  # noqa: E402
from backend.auth.first_admin import read_admin_credentials  # noqa: E402
from backend.live.files import outputs_dir  # noqa: E402
from backend.settings import Settings  # noqa: E402
from benchmarks.serving import wait_healthy  # noqa: E402
from estimators.params import PipelineParams  # noqa: E402
from protocol import recording, wire  # noqa: E402
from simulator import SimConfig, simulate  # noqa: E402
from simulator.publish import Publisher, play, prepare  # noqa: E402

GOOD = "fuzzgood"
SETTLE_S = 12.0  # after the flood, before the memory that stays is read
FLAT_MIB = 100  # "memory flat": what may stay after the flood, above the level before it


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (the worker processes of ``--workers N``)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as fh:
                    todo += [int(c) for c in fh.read().split()]
        except OSError:
            continue
    return out


def rss_by_process(pid: int) -> list[float]:
    """Resident memory (MiB) of the service's processes: ``pid`` first, then its children
    (the workers of ``--workers N``)."""
    out = []
    for p in _tree(pid):
        try:
            with open(f"/proc/{p}/status") as fh:
                for line in fh:
                    if line.startswith("VmRSS:"):
                        out.append(int(line.split()[1]) / 1024)
        except OSError:
            continue
    return out


def rss_mib(pid: int) -> float:
    """Resident memory of the service: its process and every child (workers)."""
    return sum(rss_by_process(pid))


# --------------------------------------------------------------------------- hostile payloads

_NUMBERS = [0, -1, 1e308, -1e308, 1e9, -1e9, 5e-324, 2**63, -(2**63), 0.1, 1e-9]
_TEXTS = [
    b"",
    b"{",
    b"[]",
    b"null",
    b'"x"',
    b"\xff\xfe\x00",
    b"NaN",
    b'{"t":[NaN]}',
    b'{"t":[Infinity]}',
    b'{"t":1e999}',
    b"{}" * 1000,
    b'{"t":[1],"gyr":[[1,2,3]],"acc":[[1,2]]}',
    b'{"type":"shoulder_reference","t":1,"point":[1,2]}',
    b'{"type":"nominal_reset","t":-1e300}',
    b'{"type":"cycle_start","t":"now"}',
    b'{"key":"rehab/x/robot","payload":{}}\n{"key":1}',
]


def hostile_payload(rng: random.Random) -> bytes:
    r = rng.random()
    if r < 0.2:
        return rng.choice(_TEXTS)
    if r < 0.35:
        return rng.randbytes(rng.randint(0, 512))
    if r < 0.45:
        return b"[" * rng.randint(1, 5000)  # deep nesting
    n = rng.choice([0, 1, 2, 7, 50, 2001])
    t = [rng.choice(_NUMBERS) if rng.random() < 0.3 else rng.uniform(-10, 1e3) for _ in range(n)]
    if rng.random() < 0.5:
        t.sort()
    vec = [[rng.choice(_NUMBERS) for _ in range(rng.choice([2, 3, 3, 3, 4]))] for _ in range(n)]
    obj: dict[str, Any] = rng.choice(
        [
            {"t": t, "gyr": vec, "acc": vec},
            {"t": t, "wrist": vec, "proximal": vec[::-1]},
            {"t": t[0] if t else 0, "type": "shoulder_reference", "point": vec[0] if vec else []},
            {"t": t, "elbow": vec, "wrist": vec},
            {"t": t, "gyr": vec, "acc": vec, "seq": rng.choice([-1, 0, 2**64, "x"])},
        ]
    )
    return json.dumps(obj).encode()


def invalid_payload(rng: random.Random) -> bytes:
    """Never a valid message (for the valid device's own keys: valid data there would be
    data, whoever sent it; that is what Zenoh's TLS and access control are for)."""
    r = rng.random()
    if r < 0.4:
        text = rng.choice(_TEXTS)
        try:
            wire.decode(f"rehab/{GOOD}/event", text)
        except wire.WireError:
            return text
        return b"{" + text
    if r < 0.7:
        return rng.randbytes(rng.randint(0, 512))
    n = rng.randint(1, 20)
    t = sorted(rng.uniform(0, 100) for _ in range(n))
    return json.dumps({"t": t, "gyr": [[1.0, 2.0]] * n, "acc": [[0, 0, 9.8]] * (n + 1)}).encode()


def hostile(rng: random.Random) -> tuple[str, bytes]:
    key = hostile_key(rng)
    if f"/{GOOD}/" in key:
        return key, invalid_payload(rng)
    return key, hostile_payload(rng)


def hostile_key(rng: random.Random) -> str:
    r = rng.random()
    if r < 0.3:  # the valid device's own keys: the worst place for junk
        return rng.choice(
            [f"rehab/{GOOD}/imu/upperarm", f"rehab/{GOOD}/robot", f"rehab/{GOOD}/event"]
        )
    if r < 0.6:  # other real-looking keys
        dev = rng.choice(["evil01", "evil02", "x" * 64, "a-b_c"])
        kind = rng.choice(["imu/upperarm", "imu/forearm", "robot", "camera", "event", "estimate"])
        return f"rehab/{dev}/{kind}"
    parts = ["rehab", rng.choice(["", "x" * 65, "ok", "é", "dev"]), rng.choice(["", "imu", "z"])]
    return "/".join(p for p in parts if p) or "rehab/x"


FUZZER = """
import random, sys, time, zenoh
sys.path.insert(0, sys.argv[4])
from benchmarks.fuzz import hostile
from protocol.zenoh_config import make_config
endpoint, n, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
rng = random.Random(seed)
cfg = make_config(connect=endpoint, mode="peer")
cfg.insert_json5("transport/shared_memory/enabled", "true")  # as Zenoh's default: a stranger's
s = zenoh.open(cfg)
time.sleep(1.0)
sent = 0
for _ in range(n):
    key, payload = hostile(rng)
    try:
        s.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
        sent += 1
    except Exception:
        pass  # an invalid key expression: Zenoh refuses it before the network
print(sent, flush=True)
s.close()
"""

FLOODER = """
import json, sys, time, zenoh
sys.path.insert(0, sys.argv[4])
from protocol.zenoh_config import make_config
endpoint, seconds, names = sys.argv[1], float(sys.argv[2]), sys.argv[3].split(",")

def imu(n, t0):
    t = [round(t0 + i * 0.01, 5) for i in range(n)]
    return json.dumps({"t": t, "gyr": [[0.01, -0.02, 0.03]] * n, "acc": [[0.1, 0.2, 9.8]] * n}).encode()

big = [imu(2000, 1.0 + 20.0 * k) for k in range(40)]  # the most a message may hold
huge = imu(5000, 0.0)  # ~450 kB as in the finding: over the cap
cfg = make_config(connect=endpoint, mode="peer")
cfg.insert_json5("transport/shared_memory/enabled", "true")  # as Zenoh's default: a stranger's
s = zenoh.open(cfg)
pubs = {n: s.declare_publisher(f"rehab/{n}/imu/upperarm") for n in names}
time.sleep(1.0)
end, k, sent = time.monotonic() + seconds, 0, 0
while time.monotonic() < end:
    for n in names:
        pubs[n].put(big[k % len(big)] if k % 3 else huge)
        sent += 1
    k += 1
print(sent, flush=True)
s.close()
"""


PROBER = """
import os, sys, time, httpx
url, stop, out = sys.argv[1], sys.argv[2], sys.argv[3]
with httpx.Client(base_url=url, timeout=30.0) as c, open(out, "w", buffering=1) as fh:
    while not os.path.exists(stop):
        t0, p0 = time.time(), time.perf_counter()
        try:
            ok = c.get("/api/health").status_code == 200
        except httpx.HTTPError:
            ok = False
        fh.write(f"{t0} {time.perf_counter() - p0} {int(ok)}\\n")
        time.sleep(0.1)
"""


class Prober:
    """``/api/health`` every 0.1 s from a process of its own (in this one, the valid device's
    publishing held the GIL and added its waits to the times): the worst answer time per
    phase, and failures."""

    def __init__(self, url: str, work: Path) -> None:
        self.url = url
        self._stop = work / "prober.stop"
        # a file, not a pipe: a pipe nobody reads until the end held ~1600 rows (~3 min), then
        # blocked the prober, and a long run's flood went unprobed
        self._out = work / "prober.txt"
        self._phases: list[tuple[float, str]] = [(0.0, "fuzz")]
        self._proc: subprocess.Popen[bytes] | None = None
        self.worst = 0.0
        self.worst_by_phase: dict[str, float] = {}
        self.failures = 0
        self.n = 0

    def start(self) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, "-c", PROBER, self.url, str(self._stop), str(self._out)]
        )

    @property
    def phase(self) -> str:
        return self._phases[-1][1]

    @phase.setter
    def phase(self, name: str) -> None:
        self._phases.append((time.time(), name))

    def finish(self) -> None:
        assert self._proc is not None
        self._stop.touch()
        self._proc.wait(timeout=60)
        for row in self._out.read_text().splitlines():
            t0, dt, ok = float(row.split()[0]), float(row.split()[1]), row.split()[2] == "1"
            phase = [name for since, name in self._phases if since <= t0][-1]
            self.worst = max(self.worst, dt)
            w = self.worst_by_phase
            w[phase] = max(w.get(phase, 0.0), dt)
            self.failures += not ok
            self.n += 1


def run(
    payloads: int,
    flood_s: float,
    seed: int,
    duration_s: float = 60.0,
    admit_flood: bool = True,
    workers: int | None = None,
) -> dict[str, Any]:
    """``admit_flood``: the service admits every name (``--admit '*'``, the flood's 20 names
    get pipelines); else only the valid device and the fuzzer's names (the flood's names
    are refused unregistered, as by default)."""
    work = Path(tempfile.mkdtemp(prefix="rehab-fuzz-"))
    port, zport = free_port(), free_port()
    endpoint, url = f"tcp/127.0.0.1:{zport}", f"http://127.0.0.1:{port}"
    env = {**os.environ, "REHAB_VISER_ENABLED": "0", "PYTHONPATH": str(REPO)}
    log = open(work / "service.log", "wb")  # noqa: SIM115 (closed with the process)
    svc = subprocess.Popen(
        [sys.executable, "-m", "backend.cli", "serve", "--host", "127.0.0.1", "--port", str(port),
         "--zenoh-listen", endpoint, "--data-dir", str(work / "data"), "--log-level", "error",
         *(["--admit", "*"] if admit_flood else ["--admit", f"{GOOD}", "--admit", "evil*"]),
         *(["--workers", str(workers)] if workers else ["--single-process"])],
        cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    out: dict[str, Any] = {"work": str(work), "workers": workers or 0}
    try:
        wait_healthy(svc, url, timeout=180, log=work / "service.log")  # workers start first
        creds = read_admin_credentials(Settings(data_dir=work / "data"))
        assert creds is not None
        api = httpx.Client(base_url=url, timeout=60.0)
        r = api.post(
            "/api/auth/login", json={"username": creds.username, "password": creds.password}
        )
        api.headers["Authorization"] = f"Bearer {r.json()['access_token']}"
        api.cookies.clear()

        sim = simulate(SimConfig(seed=seed, duration_s=duration_s, device=GOOD))
        outgoing = prepare(sim.messages)
        clean = work / "clean.jsonl.gz"
        recording.write(clean, sim.messages)

        prober = Prober(url, work)
        prober.start()
        with Publisher.connect(endpoint) as pub:
            pub.declare(outgoing)
            assert pub.wait_for_subscribers(10.0)
            pub.announce(GOOD)
            deadline = time.monotonic() + 20
            while api.get(f"/api/devices/{GOOD}").status_code != 200:
                if time.monotonic() > deadline:
                    raise SystemExit("valid device not registered")
                time.sleep(0.1)
            pid = api.post("/api/patients", json={"code": "fuzz", "affected_side": "right"}).json()[
                "id"
            ]
            session = api.post("/api/sessions", json={"patient_id": pid, "device": GOOD}).json()
            time.sleep(1.0)
            rss_warm = rss_mib(svc.pid)
            peak = rss_warm
            t0 = time.perf_counter()
            fuzzer = subprocess.Popen(
                [sys.executable, "-c", FUZZER, endpoint, str(payloads), str(seed), str(REPO)],
                cwd=REPO, env=env, stdout=subprocess.PIPE, text=True,
            )  # fmt: skip
            # the valid device at 4x real time meanwhile, its messages in their order
            speed = max(1.0, duration_s / 15.0)
            play(pub, outgoing, speed=speed)
            while fuzzer.poll() is None:
                peak = max(peak, rss_mib(svc.pid))
                time.sleep(0.2)
            sent = int((fuzzer.stdout.read() if fuzzer.stdout else "0").split()[0])
            fuzz_s = time.perf_counter() - t0
            time.sleep(2.0)
            rss_after = rss_mib(svc.pid)
            received, deadline = 0, time.monotonic() + 60
            while received < len(outgoing) and time.monotonic() < deadline:
                dev = api.get(f"/api/devices/{GOOD}").json()
                received = dev["stats"]["ingest"]["accepted"]
                time.sleep(0.2)
            out["valid_accepted"] = received
            stopped = api.post(f"/api/sessions/{session['id']}/stop").json()
        rec_dir = outputs_dir(work / "data" / stopped["recording_path"])
        live_est = (rec_dir / "estimates.csv").read_text().splitlines()[1:]
        run_clean, _ = analyze(clean, PipelineParams.from_json(stopped["params"]))
        out.update(
            hostile_sent=sent,
            fuzz_s=round(fuzz_s, 1),
            valid_messages=len(outgoing),
            estimates_equal=live_est == run_clean.est_lines,
            estimate_rows=len(live_est),
            rss_warm_mib=round(rss_warm),
            rss_after_fuzz_mib=round(rss_after),
            rss_peak_fuzz_mib=round(peak),
        )
        # flood phase
        prober.phase = "flood"
        names = ",".join(f"flood{i:02d}" for i in range(20))
        flooder = subprocess.Popen(
            [sys.executable, "-c", FLOODER, endpoint, str(flood_s), names, str(REPO)],
            cwd=REPO, env=env, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        procs0 = rss_by_process(svc.pid)
        rss0, peak = sum(procs0), 0.0
        while flooder.poll() is None:
            peak = max(peak, rss_mib(svc.pid))
            time.sleep(0.2)
        flood_sent = int((flooder.stdout.read() if flooder.stdout else "0").split()[0])
        time.sleep(3.0)
        rss_after_flood = rss_mib(svc.pid)
        # the backlog drained and the freed memory given back (backend.live.memory trims
        # every few seconds): what stays
        prober.phase = "after"
        time.sleep(SETTLE_S)
        prober.finish()
        procs = rss_by_process(svc.pid)
        health = api.get("/api/health")
        out.update(
            flood_messages=flood_sent,
            rss_before_flood_mib=round(rss0),
            rss_peak_flood_mib=round(peak),
            rss_after_flood_mib=round(rss_after_flood),
            rss_settled_mib=round(sum(procs)),
            # per process (the API node, then its workers): which one keeps what
            rss_before_flood_by_process_mib=[round(x) for x in procs0],
            rss_settled_by_process_mib=[round(x) for x in procs],
            health_probes=prober.n,
            health_worst_ms=round(prober.worst * 1000),
            health_worst_ms_by_phase={k: round(v * 1000) for k, v in prober.worst_by_phase.items()},
            health_failures=prober.failures,
            alive=svc.poll() is None and health.status_code == 200,
        )
        api.close()
    finally:
        (work / "prober.stop").touch()  # the prober process ends (if it was started)
        if svc.poll() is None:
            svc.send_signal(signal.SIGTERM)
            try:
                svc.wait(30)
            except subprocess.TimeoutExpired:
                svc.kill()
        log.close()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--payloads", type=int, default=100_000)
    ap.add_argument("--flood-s", type=float, default=15.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--flood-not-admitted", action="store_true", help="the flood's names are not admitted"
    )
    ap.add_argument(
        "--workers", type=int, default=None, help="rehab serve --workers N (the scale-out mode)"
    )
    args = ap.parse_args()
    out = run(
        args.payloads,
        args.flood_s,
        args.seed,
        admit_flood=not args.flood_not_admitted,
        workers=args.workers,
    )
    out["load_average"] = os.getloadavg()
    print(json.dumps(out, indent=1))
    ok = (
        out["alive"]
        and out["estimates_equal"]
        and out["health_worst_ms"] < 1000
        and out["health_failures"] == 0
        and out["rss_settled_mib"] - out["rss_before_flood_mib"] < FLAT_MIB
    )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
