"""Wall time of `rehab analyze` with its start-up (interpreter, imports), and what the
imports cost, module by module (`python -X importtime`).

    python benchmarks/startup.py [--seed 1] [--duration 480] [--repeat 5]

Each figure is the fastest of ``--repeat`` fresh processes (the machine's other load only
ever adds to a run). Target (issue 23): ≤ 1.1 s wall for 8 minutes, start-up included.
The robot kernels come from the module built ahead of time (``python -m estimators.aot``)
when it is up to date; the same runs with numba's JIT (``REHAB_AOT=0``) alternate with them
as an A/B.
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
GROUPS = ("numpy", "vqf", "backend.cli", "backend.analysis")
PACKAGES = ("backend", "estimators", "protocol", "simulator", "evaluation")
START = "import backend.cli, backend.analysis"
KERNELS = (
    "import sys; from estimators import aot, jit; "
    "print(all(jit.uses_aot(getattr(sys.modules[k.fn.__module__], k.fn.__name__)) "
    "for k in aot.kernels().values()))"
)
# numba's first call of a compiled (cached) function (with REHAB_AOT=0): it loads numba's
# registries, and with them scipy.linalg (numba's BLAS check) and cffi's parser when installed
FIRST_CALL = (
    "import time, numpy as np; from estimators.filters import LowPass; t = time.perf_counter(); "
    "LowPass(5, 0.5, 25.0)(np.zeros((4, 3)), np.zeros((3, 2, 3))); "
    "print(time.perf_counter() - t)"
)


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=480.0)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    # as a user's runs after the first: the project's bytecode cached (an environment with
    # PYTHONDONTWRITEBYTECODE compiles every module from source: ~0.15 s CPU more per run)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = str(ROOT)
    subprocess.run([sys.executable, "-m", "compileall", "-q", *PACKAGES], cwd=ROOT, env=env)
    jit_env = {**env, "REHAB_AOT": "0"}
    aot = subprocess.run(
        [sys.executable, "-c", KERNELS], env=env, check=True, capture_output=True, text=True
    ).stdout.strip()
    print(
        "robot kernels: "
        + ("built ahead of time" if aot == "True" else "numba's JIT (python -m estimators.aot)")
    )
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
        runs, jit_runs = [], []
        for _ in range(args.repeat):  # alternating: the same minutes' load for both
            runs.append(run([*rehab, "analyze", rec, "--out", out], env))
            jit_runs.append(run([*rehab, "analyze", rec, "--out", out], jit_env))
        bare = [run([sys.executable, "-c", "pass"], env) for _ in range(args.repeat)]
        start = [run([sys.executable, "-c", START], env) for _ in range(args.repeat)]
    for name, rs in (("", runs), (" with numba's JIT (REHAB_AOT=0)", jit_runs)):
        wall, cpu = min(rs)
        print(
            f"rehab analyze{name}, {args.duration:.0f} s of data, start-up included: "
            f"{wall:.2f} s wall, {cpu:.2f} s CPU (fastest of {args.repeat}; all: "
            + ", ".join(f"{w:.2f}" for w, _ in rs)
            + f"; least CPU {min(c for _, c in rs):.2f} s)"
        )
    print(f"interpreter alone: {min(bare)[0]:.3f} s wall")
    print(
        f"start-up ({START}): {min(start)[0]:.2f} s wall, "
        f"least CPU {min(c for _, c in start):.2f} s"
    )
    costs = [import_costs(env) for _ in range(args.repeat)]
    print(
        "imports, each after the previous (fastest of "
        f"{args.repeat}): "
        + ", ".join(f"{g} {min(c.get(g, 0.0) for c in costs):.2f} s" for g in GROUPS)
    )
    first = [
        float(
            subprocess.run(
                [sys.executable, "-c", FIRST_CALL],
                env=jit_env,
                check=True,
                capture_output=True,
                text=True,
            ).stdout
        )
        for _ in range(args.repeat)
    ]
    print(
        f"numba's first compiled call (cached; REHAB_AOT=0 only): {min(first):.2f} s "
        f"(fastest of {args.repeat})"
    )
    print(f"load average: {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
