"""A worker's receiving side, both ways, in the same seconds: CPU of taking 25 of 50
devices' data with one subscription to every device (filtered on the key, as
``rehab serve --single-process`` takes all) against one subscription per held device
(``rehab worker``, docs/scaling.md "Device discovery").

A Zenoh router, the latency benchmark's publisher (50 devices in real time) and two
receiving processes, one per way, each a :class:`backend.live.zenoh_io.ZenohIO` whose
batches go to a no-op on its event loop. Each prints its process CPU over the window.

    python benchmarks/receive_side.py --seconds 30
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import zenoh

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from backend.live.zenoh_io import ZenohIO  # noqa: E402
from protocol import keys  # noqa: E402
from protocol.zenoh_config import make_config  # noqa: E402


def device_name(i: int) -> str:
    return f"bench{i:03d}"  # as benchmarks/latency.py names them


async def receive(endpoint: str, per_device: bool, held: int, seconds: float) -> dict[str, float]:
    mine = {device_name(i) for i in range(0, 2 * held, 2)}  # every other device
    got = [0]

    def on_batch(batch: list[tuple[str, bytes | None, int, float]]) -> None:
        got[0] += len(batch)

    def accept(key: str) -> bool:
        try:
            return keys.parse(key).device in mine
        except keys.KeyError_:
            return True

    zio = ZenohIO(
        make_config(connect=endpoint, mode="client"),
        keys.DEFAULT_PREFIX,
        asyncio.get_running_loop(),
        on_batch,
        lambda d, a: None,
        1 << 20,
        accept=accept,
        per_device=per_device,
    )
    zio.open()
    if per_device:
        for name in sorted(mine):
            zio.subscribe_device(name)
    while not got[0]:  # the publisher prepares its messages first
        await asyncio.sleep(0.1)
    await asyncio.sleep(6.0)  # its devices all started (within 5 s)
    t0, c0, n0 = time.monotonic(), time.process_time(), got[0]
    await asyncio.sleep(seconds)
    cpu, wall, n = time.process_time() - c0, time.monotonic() - t0, got[0] - n0
    zio.close()
    return {"cpu_percent": round(100 * cpu / wall, 2), "messages_per_s": round(n / wall, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--port", type=int, default=7660)
    ap.add_argument("--role", choices=["all", "per-device"], help=argparse.SUPPRESS)
    args = ap.parse_args()
    endpoint = f"tcp/127.0.0.1:{args.port}"
    if args.role:
        out = asyncio.run(receive(endpoint, args.role == "per-device", 25, args.seconds))
        print(json.dumps({args.role: out}), flush=True)
        return
    router = zenoh.open(make_config(listen=endpoint, mode="router"))
    try:
        me = [sys.executable, __file__, "--port", str(args.port), "--seconds", str(args.seconds)]
        takers = [
            subprocess.Popen([*me, "--role", r], stdout=subprocess.PIPE, text=True)
            for r in ("all", "per-device")
        ]
        time.sleep(2.0)
        pub = subprocess.Popen(
            [
                sys.executable,
                str(REPO / "benchmarks" / "latency.py"),
                "--role",
                "publisher",
                "--endpoint",
                endpoint,
                "--devices",
                "50",
                "--duration",
                str(args.seconds + 10),
                "--out",
                os.devnull,
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert pub.stdin is not None and pub.stdout is not None
        pub.stdout.readline()  # ready
        pub.stdin.write("go\n")
        pub.stdin.flush()
        for t in takers:
            out, _ = t.communicate()
            print(out.strip())
        pub.kill()
    finally:
        router.close()  # type: ignore[no-untyped-call]


if __name__ == "__main__":
    main()
