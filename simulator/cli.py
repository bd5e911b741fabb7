"""``simulate`` sub-command: write a contract recording, its truth and the subject.

Registered into the top-level ``rehab`` CLI via :func:`add_parser`; also runnable alone as
``python -m simulator.cli simulate --seed 1 --out DIR``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from protocol import recording
from simulator.config import SimConfig

RECORDING_NAME = "recording.jsonl.gz"
TRUTH_NAME = "truth.npz"
SUBJECT_NAME = "subject.json"


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``simulate`` on an ``argparse`` sub-parsers object; sets ``func=run``."""
    p: argparse.ArgumentParser = subparsers.add_parser(
        "simulate",
        help="simulate a session and write a recording with its ground truth",
        description="Simulate the seed paper's experiment (IMU on the upper arm, two robot "
        f"cuffs) and write DIR/{RECORDING_NAME}, DIR/{TRUTH_NAME} and DIR/{SUBJECT_NAME}.",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--duration",
        type=float,
        default=480.0,
        metavar="S",
        help="session length in seconds (default 480)",
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    p.add_argument(
        "--imu-rate",
        type=float,
        default=100.0,
        metavar="HZ",
        help="IMU sampling rate (default 100)",
    )
    p.add_argument(
        "--robot-rate",
        type=float,
        default=25.0,
        metavar="HZ",
        help="robot sampling rate (default 25)",
    )
    p.add_argument(
        "--imu-batch", type=int, default=4, metavar="K", help="IMU samples per message (default 4)"
    )
    p.add_argument("--device", default="sim01", help="device name in the keys (default sim01)")
    p.add_argument(
        "--cycle-events",
        action="store_true",
        help="publish a cycle_start event at every cycle start",
    )
    p.add_argument(
        "--publish",
        metavar="ENDPOINT",
        help="also publish the session over Zenoh to ENDPOINT (a service or a "
        "router, e.g. tcp/127.0.0.1:7447), timed by its timestamps",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="X",
        help="with --publish: 1 = real time (default), 20 = twenty times faster, "
        "0 = as fast as possible",
    )
    p.add_argument(
        "--ideal", action="store_true", help="switch every sensor, robot and placement error off"
    )
    from simulator import wearable_cli

    wearable_cli.add_arguments(p)
    p.set_defaults(func=run)
    return p


def _zero_gzip_mtime(path: Path) -> None:
    # gzip stores the write time in header bytes 4–7 (not covered by the CRC); zero means
    # "unknown" (RFC 1952) and makes equal recordings byte-identical.
    with open(path, "r+b") as fh:
        head = fh.read(8)
        if head[:2] == b"\x1f\x8b":
            fh.seek(4)
            fh.write(b"\x00\x00\x00\x00")


def run(args: argparse.Namespace) -> int:
    """Simulate and write the three files; print a one-line summary. Returns the exit code."""
    if getattr(args, "mode", "robot") == "wearable":
        from simulator import wearable_cli

        return wearable_cli.run(args)
    try:
        cfg = SimConfig(
            seed=args.seed,
            duration_s=args.duration,
            imu_rate_hz=args.imu_rate,
            robot_rate_hz=args.robot_rate,
            imu_batch=args.imu_batch,
            device=args.device,
            cycle_events=args.cycle_events,
            ideal=args.ideal,
        )
    except ValueError as exc:
        print(f"simulate: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    from simulator.session import simulate  # SciPy and the arm model: only when simulating

    sim = simulate(cfg, progress=True)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    rec = out / RECORDING_NAME
    recording.write(rec, sim.messages)
    _zero_gzip_mtime(rec)
    sim.truth.save(out / TRUTH_NAME, sim.subject)
    (out / SUBJECT_NAME).write_text(sim.subject.to_json() + "\n", encoding="utf-8")
    print(f"{sim.summary()} -> {out} ({time.perf_counter() - start:.1f} s)")
    if getattr(args, "publish", None):
        from simulator.publish import publish

        start = time.perf_counter()
        n = publish(args.publish, sim.messages, args.speed)
        print(f"published {n} messages to {args.publish} ({time.perf_counter() - start:.1f} s)")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="simulator")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())
