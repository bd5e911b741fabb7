"""Wall time of `rehab analyze` with its start-up (interpreter, imports), and what the
imports cost, module by module (`python -X importtime`).

    python benchmarks/startup.py [--seed 1] [--duration 480] [--repeat 5]

Each figure is the fastest of ``--repeat`` fresh processes (the machine's other load only
ever adds to a run). Target (issue 23): ≤ 1.1 s wall for 8 minutes, start-up included.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# what `rehab analyze` needs, one group each (each includes what it imports first)
GROUPS = ("numpy", "vqf", "scipy.sparse", "scipy.signal", "backend.analysis")


def run(args: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU time (user + system) of one process."""
    t0 = time.perf_counter()
    c0 = os.times()
    subprocess.run(args, env=env, check=True, stdout=subprocess.DEVNULL)
    c1 = os.times()
    return (
        time.perf_counter() - t0,
        (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system),
    )


def import_costs(env: dict[str, str]) -> dict[str, float]:
    """Seconds each group adds, imported in the order of GROUPS in one process."""
    code = "; ".join(f"import {g}" for g in GROUPS)
    err = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", code],
        env=env,
        check=True,
        capture_output=True,
        text=True,
    ).stderr
    out: dict[str, float] = {}
    for line in err.splitlines():
        m = re.match(r"import time:\s+\d+ \|\s+(\d+) \| (\S+)$", line)  # top level only
        if m and m.group(2) in GROUPS:
            out[m.group(2)] = int(m.group(1)) / 1e6
    return out


# what a compiled (numba) stage would add to `rehab analyze`: numba's import, then the first
# call of a kernel cached on disk (it loads numba's CPU target, which imports scipy.linalg)
_NUMBA = """
import time
import backend.analysis
import numpy as np
c0, w0 = time.process_time(), time.perf_counter()
import numba
c1, w1 = time.process_time(), time.perf_counter()
from estimators.wearable import kernel
kernel.pose(np.zeros(5), 0.3, 0.25)
c2, w2 = time.process_time(), time.perf_counter()
print(w1 - w0, c1 - c0, w2 - w1, c2 - c1)
"""


def numba_costs(env: dict[str, str], repeat: int) -> tuple[float, float, float, float]:
    """After ``backend.analysis``: numba's import and a cached kernel's first call (wall and
    CPU s each, fastest of ``repeat`` processes; the first run fills the cache)."""
    args = [sys.executable, "-c", _NUMBA]
    subprocess.run(args, env=env, check=True, capture_output=True)
    runs = [
        tuple(float(x) for x in subprocess.check_output(args, env=env, text=True).split())
        for _ in range(repeat)
    ]
    return min(runs, key=lambda r: r[0] + r[2])  # type: ignore[return-value]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=480.0)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    rehab = [sys.executable, "-m", "backend.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        sim = Path(tmp) / "sim"
        sim_args = ["--seed", str(args.seed), "--duration", str(args.duration), "--out", str(sim)]
        subprocess.run(
            [*rehab, "simulate", *sim_args],
            env=env,
            check=True,
            stdout=subprocess.DEVNULL,
        )
        rec = str(sim / "recording.jsonl.gz")
        out = str(Path(tmp) / "out")
        runs = [run([*rehab, "analyze", rec, "--out", out], env) for _ in range(args.repeat)]
        bare = [run([sys.executable, "-c", "pass"], env) for _ in range(args.repeat)]
    wall, cpu = min(runs)
    print(
        f"rehab analyze, {args.duration:.0f} s of data, start-up included: {wall:.2f} s wall, "
        f"{cpu:.2f} s CPU (fastest of {args.repeat}; all: "
        + ", ".join(f"{w:.2f}" for w, _ in runs)
        + ")"
    )
    print(f"interpreter alone: {min(bare)[0]:.3f} s wall")
    costs = [import_costs(env) for _ in range(args.repeat)]
    print(
        "imports, each after the previous (fastest of "
        f"{args.repeat}): "
        + ", ".join(f"{g} {min(c.get(g, 0.0) for c in costs):.2f} s" for g in GROUPS)
    )
    iw, ic, fw, fc = numba_costs(env, args.repeat)
    print(
        f"numba after backend.analysis (not imported by it): import {iw:.2f} s wall "
        f"({ic:.2f} CPU), a cached kernel's first call {fw:.2f} s wall ({fc:.2f} CPU)"
    )
    print(f"load average: {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
