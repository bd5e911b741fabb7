"""``rehab simulate --mode wearable``: a two-IMU session with optional camera and its truth."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from simulator.wearable_moves import MOVES


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The wearable options of ``simulate`` (the robot options are ignored in this mode)."""
    p.add_argument(
        "--mode",
        choices=("robot", "wearable"),
        default="robot",
        help="robot (default): IMU + robot cuffs; wearable: two IMUs + optional camera",
    )
    p.add_argument(
        "--move",
        choices=MOVES,
        default="reaching",
        help="wearable movement (default reaching)",
    )
    p.add_argument("--no-camera", action="store_true", help="wearable: no camera stream")
    p.add_argument("--side", choices=("right", "left"), default="right", help="wearable: arm")


def run(args: argparse.Namespace) -> int:
    """Write DIR/recording.jsonl.gz, DIR/params.json (contract §8) and DIR/truth.csv."""
    from simulator import wearable as w  # SciPy: only when simulating, not for every `rehab`

    try:
        cfg = w.WearableSimConfig(
            move=args.move,
            duration_s=args.duration,
            seed=args.seed,
            imu_hz=args.imu_rate,
            camera=not args.no_camera,
            side=args.side,
            device=args.device if args.device != "sim01" else "wear01",
            imu=w.ImuErrors.paper() if args.ideal else w.ImuErrors(),
            cam=w.CameraErrors.paper() if args.ideal else w.CameraErrors(),
        )
        start = time.perf_counter()
        sim = w.simulate(cfg)
    except ValueError as exc:
        print(f"simulate: {exc}", file=sys.stderr)
        return 2
    out: Path = args.out
    w.write(sim, out)
    print(f"{sim.summary()} -> {out} ({time.perf_counter() - start:.1f} s)")
    return 0
