"""Speed: `rehab analyze` of an 8-minute session, streaming cost, one heading update.

Pinned to one core; interpreter start and imports excluded (the figures are for work done).
``--stages``: also where one `rehab analyze` (improved) spends its CPU, stage by stage.

    python benchmarks/speed.py [--seed 1] [--duration 480] [--repeat 5] [--stages]
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import gc
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from backend import analysis, clinical
from backend.analysis import DeviceRun, analyze, gc_paused
from estimators import heading as hd
from estimators.grid_stage import GridStage
from estimators.heading_stage import HeadingStage
from estimators.imu_stage import ImuStage
from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from protocol import recording, wire
from simulator import SimConfig, simulate


def best(fn, repeat: int) -> tuple[float, float, float]:
    """:func:`timed` of the fastest of ``repeat`` calls."""
    return min(timed(fn) for _ in range(repeat))


def timed(fn) -> tuple[float, float, float]:
    """Wall time, this process's CPU time and the share of the machine's CPU time the
    hypervisor gave to other guests ("steal", /proc/stat; NaN where unknown) over one call:
    a slow run with steal near 0 was slowed by contention, not preemption."""
    s0, c0, t0 = _cpu_ticks(), time.process_time(), time.perf_counter()
    fn()
    t, c, s1 = time.perf_counter() - t0, time.process_time() - c0, _cpu_ticks()
    steal = (s1[1] - s0[1]) / (s1[0] - s0[0]) if s1[0] > s0[0] else float("nan")
    return t, c, steal


def _cpu_ticks() -> tuple[int, int]:
    """All CPUs' ticks and their steal ticks so far ((0, 0) off Linux)."""
    try:
        with open("/proc/stat") as f:
            ticks = [int(x) for x in f.readline().split()[1:]]
    except OSError:
        return 0, 0
    return sum(ticks), ticks[7] if len(ticks) > 7 else 0


# `rehab analyze`'s stages: (label, owner, attribute); a stage's CPU excludes the stages it
# calls (the report's CSV formatting and clinical sections are their own lines)
STAGES: tuple[tuple[str, Any, str], ...] = (
    ("reading + decoding the recording", analysis, "decode_batches"),
    ("IMU stage (VQF, acceleration terms)", ImuStage, "process"),
    ("robot stage (eq. 13)", Pipeline, "_robot_samples"),
    ("fusion grid (anti-alias, low-pass)", GridStage, "advance"),
    ("heading updates", HeadingStage, "run"),
    ("rows (eqs. 9-12, nominal, cycles, indicator, verdicts)", Pipeline, "_rows"),
    ("CSV formatting", DeviceRun, "format_rows"),
    ("clinical report sections", clinical, "sections"),
    ("report (the rest of it)", DeviceRun, "report"),
    ("writing the files", analysis, "write_outputs"),
)


@contextlib.contextmanager
def stage_clock() -> Iterator[dict[str, float]]:
    """CPU seconds per :data:`STAGES` label while active, each stage's own (exclusive of
    the stages it calls); generator stages are timed per item they yield."""
    spent: dict[str, float] = dict.fromkeys((label for label, _, _ in STAGES), 0.0)
    stack: list[float] = []  # CPU time of the stages called by each open stage

    def enter() -> float:
        stack.append(0.0)
        return time.process_time()

    def leave(label: str, c0: float) -> None:
        dt = time.process_time() - c0
        spent[label] += dt - stack.pop()
        if stack:
            stack[-1] += dt

    def wrap(label: str, fn: Any) -> Any:
        if label.startswith("reading"):  # a generator

            @functools.wraps(fn)
            def gen(*a: Any, **k: Any) -> Iterator[Any]:
                it = fn(*a, **k)
                while True:
                    c0 = enter()
                    try:
                        item = next(it)
                    except StopIteration:
                        return
                    finally:
                        leave(label, c0)
                    yield item

            return gen

        @functools.wraps(fn)
        def timed_call(*a: Any, **k: Any) -> Any:
            c0 = enter()
            try:
                return fn(*a, **k)
            finally:
                leave(label, c0)

        return timed_call

    saved = [(owner, name, getattr(owner, name)) for _, owner, name in STAGES]
    try:
        for (label, owner, name), (_, _, fn) in zip(STAGES, saved, strict=True):
            setattr(owner, name, wrap(label, fn))
        yield spent
    finally:
        for owner, name, fn in saved:
            setattr(owner, name, fn)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=480.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--stages", action="store_true", help="CPU of analyze's stages")
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    sim = simulate(SimConfig(seed=args.seed, duration_s=args.duration))
    n_imu = sum(len(p["t"]) for k, p in sim.messages if "/imu/" in k)
    messages = sim.messages
    del sim  # the rest of the simulation is not a `rehab analyze` process's memory
    gc.collect()
    gc.freeze()  # nor are this script's own objects: no collection walks them

    def run_analyze(rec: Path, params: PipelineParams, out: Path) -> None:
        with gc_paused():  # as `rehab analyze` runs it
            analyze(rec, params, out)

    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "recording.jsonl.gz"
        recording.write(rec, messages)
        out = Path(tmp) / "out"
        for name, params in (
            ("improved", PipelineParams()),
            ("paper", PipelineParams(method="paper")),
        ):
            t = best(lambda p=params: run_analyze(rec, p, out), args.repeat)[0]
            print(
                f"analyze ({name}): {t:.3f} s for {args.duration:.0f} s of data "
                f"({len(messages)} messages) = {args.duration / t:.0f}x real time"
            )
        if args.stages:  # the fastest of the runs, with its split
            runs = []
            for _ in range(args.repeat):
                with stage_clock() as spent:
                    c0 = time.process_time()
                    run_analyze(rec, PipelineParams(), out)
                    runs.append((time.process_time() - c0, dict(spent)))
            total, spent = min(runs, key=lambda r: r[0])
            print(f"analyze (improved), CPU by stage (fastest of {args.repeat}: {total:.3f} s):")
            rest = total - sum(spent.values())
            for label, c in [*spent.items(), ("feeding, per-message book-keeping", rest)]:
                print(f"  {label:56s} {c:6.3f} s {100 * c / total:4.0f} %")
    msgs = [wire.decode(k, p) for k, p in messages]
    gc.freeze()  # the input messages, held here, are not the pipeline's to walk

    def live() -> None:
        p = Pipeline(PipelineParams())
        for m in msgs:
            p.feed(m)
            if isinstance(m, wire.RobotMessage):
                p.poll()
        p.finish()

    t, cpu, steal = best(live, max(1, args.repeat // 2))
    print(
        f"streaming (poll after every robot message): {1e6 * t / n_imu:.1f} µs per IMU sample "
        f"({n_imu} samples; that run: CPU {1e6 * cpu / n_imu:.1f} µs, steal {100 * steal:.1f} %)"
    )
    # one heading update on a full window, taken from a real run
    p = Pipeline(PipelineParams())
    p.run(msgs[: len(msgs) // 4])
    g = p._grid
    t_end = float(g.t[-1])
    for name, hp, span in (
        ("improved", hd.HeadingParams(), 40.0),
        ("paper", hd.HeadingParams.paper(), 20.0),
    ):
        w = g.window(t_end, span, int(g.seg[-1]))
        times = []
        for _ in range(50):
            s = hd.HeadingState(converged=True, delta=0.0, n_counted=10)
            t0 = time.perf_counter()
            if name == "paper":
                hd.update_paper(s, w, hp, t_end)
            else:
                hd.update_improved(s, w, hp, t_end, g.lag)
            times.append(time.perf_counter() - t0)
        print(
            f"heading update ({name}, {len(w.t)} samples): median {1e3 * statistics.median(times):.2f} ms, "
            f"max {1e3 * max(times):.2f} ms"
        )
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, numpy {np.__version__}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
