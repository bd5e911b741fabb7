"""The floor of a live poll in pure Python: what one robot sample and one 4-sample IMU message
cost when nothing but their unavoidable arithmetic is done.

Not the pipeline. Per IMU message: VQF's batch update and the quaternions as floats. Per
robot sample: the elbow from the cuffs (eq. 13), two orientation look-ups (nlerp between the
neighbouring IMU samples, for the robot's instant and its latency), a heading rotation with
drift (eqs. 9–10), the shoulder (eq. 12), its displacement, the elbow angle (eq. 11), the
fixed-shoulder baseline, elevation and azimuth, a state, and the row as a numpy array. No
checks, gaps, segments, quality counters, nominal shoulder, cycles, fusion grid or heading
update (the heading is a made-up drift), so the numbers are meaningless; the time is what
any pure-Python design pays at least. Compare with ``speed.py``'s streaming figure, which
adds the fusion grid and heading updates (amortised) and everything this leaves out.

    python benchmarks/live_floor.py [--seed 1] [--duration 480] [--repeat 3]
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import time

import numpy as np
from vqf import VQF

from protocol import wire
from simulator import SimConfig, simulate


def floor_run(msgs: list[wire.Message], ts: float) -> int:
    v = VQF(ts, tauAcc=3.0)
    tl: list[float] = []  # the newest IMU samples' times and quaternions, as floats
    ql: list[float] = []
    n_rows = 0
    for m in msgs:
        if isinstance(m, wire.ImuMessage):
            out = v.updateBatch(np.ascontiguousarray(m.gyr), np.ascontiguousarray(m.acc))
            tl += m.t.tolist()
            ql += out["quat6D"].ravel().tolist()
            if len(tl) > 64:
                del tl[:32], ql[:128]
        elif isinstance(m, wire.RobotMessage) and len(tl) > 1:
            t = m.t.tolist()[0]
            w, p = m.wrist.tolist()[0], m.proximal.tolist()[0]
            x, y, z = w[0] - p[0], w[1] - p[1], w[2] - p[2]
            n = math.sqrt(x * x + y * y + z * z)
            xc = (x / n, y / n, z / n)
            pe = (p[0] - 0.05 * xc[0], p[1] - 0.05 * xc[1], p[2] - 0.05 * xc[2])
            q = [1.0, 0.0, 0.0, 0.0]
            for s in (t - 0.03, t):
                i = len(tl) - 1
                while i > 1 and tl[i - 1] > s:
                    i -= 1
                k = i - 1
                a = min(max((s - tl[k]) / (tl[i] - tl[k]), 0.0), 1.0)
                q0, q1 = ql[4 * k : 4 * k + 4], ql[4 * i : 4 * i + 4]
                q = [q0[j] + a * (q1[j] - q0[j]) for j in range(4)]
                nq = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
                q = [c / nq for c in q]
            d = 0.3 + 1e-4 * t
            c, sn = math.cos(d / 2), math.sin(d / 2)
            qw, qx, qy, qz = (
                c * q[0] - sn * q[3],
                c * q[1] - sn * q[2],
                c * q[2] + sn * q[1],
                c * q[3] + sn * q[0],
            )
            ax = (1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy + qw * qz), 2 * (qx * qz - qw * qy))
            sh = (pe[0] - 0.3 * ax[0], pe[1] - 0.3 * ax[1], pe[2] - 0.3 * ax[2])
            disp = math.hypot(sh[0], sh[1] - 0.5)
            dot = ax[0] * xc[0] + ax[1] * xc[1] + ax[2] * xc[2]
            ang = math.degrees(math.acos(max(-1.0, min(1.0, dot))))
            conv = math.degrees(math.acos(max(-1.0, min(1.0, -xc[2]))))
            elev = math.degrees(math.acos(max(-1.0, min(1.0, -ax[2]))))
            azim = math.degrees(math.atan2(ax[0], ax[1]))
            state = 1.0 if disp > 0.1 else 0.0
            row = [t, *pe, *sh, ang, d, 1.0, disp, state, qw, qx, qy, qz, 1.0, 1.0, elev]
            row += [azim, 0.0, 0.5, 0.0, conv, *w, 0.3]
            np.fromiter(row, np.float64, len(row)).reshape(1, len(row))
            n_rows += 1
    return n_rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=480.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    sim = simulate(SimConfig(seed=args.seed, duration_s=args.duration))
    msgs = [wire.decode(k, p) for k, p in sim.messages]
    del sim
    n_imu = sum(len(m.t) for m in msgs if isinstance(m, wire.ImuMessage))
    ts = float(np.median(np.diff(next(m.t for m in msgs if isinstance(m, wire.ImuMessage)))))
    gc.collect()
    gc.freeze()
    best, n = math.inf, 0
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        n = floor_run(msgs, ts)
        best = min(best, time.perf_counter() - t0)
    print(
        f"floor of a live poll: {1e6 * best / n:.1f} µs per robot sample, "
        f"{1e6 * best / n_imu:.1f} µs per IMU sample (best of {args.repeat})"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
