"""Real-data benchmark: the pipeline on BROAD trials with a virtual elbow as the robot.

Data: BROAD (D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD—A Benchmark for Robust
Inertial Orientation Estimation", Data 6(7):72, 2021, https://doi.org/10.3390/data6070072),
CC-BY-4.0. See :mod:`evaluation.broad` for the conversion and the error definitions.

Per trial: heading convergence time, full orientation error (heading included) of ``q_RA``
after convergence over ``movement`` samples (median, 95th percentile), the inclination
error of the same estimate (= the pipeline's 6D filter, since a heading offset leaves
inclination unchanged), the VQF-alone inclination error for reference, and the heading
confidence. Prints a markdown table for docs/benchmarks.md.

Both methods are run: ``improved`` (the default) and ``paper``.

Usage: ``python benchmarks/broad.py [--data DIR] [--trials 10 21 ...] [--method both] [--json OUT]``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from evaluation import broad
from protocol import wire

METHODS = {"improved": PipelineParams(), "paper": PipelineParams(method="paper")}


def run_pipeline(messages: Sequence[wire.Message], params: PipelineParams) -> dict[str, np.ndarray]:
    """Our pipeline; returns its per-robot-sample columns."""
    out = Pipeline(params).run(messages)
    return {k: np.asarray(v) for k, v in out.rows.items()}


def evaluate(path: Path, method: str) -> dict[str, Any]:
    """Convert, run and score one trial; returns a JSON-ready dict."""
    trial = broad.load_trial(path)
    conv = broad.convert(trial)
    # Through the wire, as the service would receive it (JSON bytes → decode).
    messages = [wire.decode(k, wire.dumps(p)) for k, p in conv.messages]
    t0 = time.perf_counter()
    est = run_pipeline(messages, METHODS[method])
    runtime = time.perf_counter() - t0
    score = broad.score_trial(
        est["t"], est["q_ra"], est["heading_converged"], conv.truth, est["heading_confidence"]
    )
    std = est["heading_std_deg"][est["heading_converged"]]
    base = broad.vqf_baseline(trial, conv.truth)
    return {
        "trial": trial.name,
        "method": method,
        "duration_s": trial.n / trial.rate_hz,
        "robot_start_s": float(conv.truth.robot_t[0]) if conv.truth.robot_t.size else None,
        "runtime_s": runtime,
        "lag_ms": conv.truth.lag_s * 1e3,
        **score,
        "heading_std_median_deg": float(np.median(std)) if len(std) else None,
        "vqf_inclination_median_deg": base.inclination_median_deg,
        "vqf_inclination_p95_deg": base.inclination_p95_deg,
        "vqf_total_aligned_median_deg": base.total_aligned_median_deg,
        "vqf_total_aligned_p95_deg": base.total_aligned_p95_deg,
    }


def _fmt(x: Any, spec: str = ".2f") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    return format(x, spec)


def markdown(rows: Sequence[dict[str, Any]]) -> str:
    """The results as a markdown table (errors in degrees, times in seconds from the
    start of the recording; the robot stream may start later, see ``robot_start_s``)."""
    head = (
        "| trial | method | converged at (s) | total err. median / p95 (°) "
        "| inclination median / p95 (°) | VQF-alone inclination median / p95 (°) "
        "| confidence median | reported heading std (°) |\n"
        "|---|---|---:|---:|---:|---:|---:|---:|\n"
    )
    lines = [
        f"| {r['trial']} | {r['method']} "
        f"| {_fmt(r['t_converged_s'], '.1f')} "
        f"| {_fmt(r['total_median_deg'])} / {_fmt(r['total_p95_deg'])} "
        f"| {_fmt(r['inclination_median_deg'])} / {_fmt(r['inclination_p95_deg'])} "
        f"| {_fmt(r['vqf_inclination_median_deg'])} / {_fmt(r['vqf_inclination_p95_deg'])} "
        f"| {_fmt(r.get('confidence_median'))} | {_fmt(r.get('heading_std_median_deg'))} |"
        for r in rows
    ]
    return head + "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    ap.add_argument(
        "--data",
        type=Path,
        default=None,
        help=f"BROAD directory (default ${broad.ENV_DIR} or ../shared/data/broad)",
    )
    ap.add_argument(
        "--trials",
        nargs="*",
        default=None,
        help="trial name prefixes or substrings, e.g. 10 21_undisturbed",
    )
    ap.add_argument("--json", type=Path, default=None, help="write all figures to this file")
    ap.add_argument("--method", choices=["improved", "paper", "both"], default="both")
    args = ap.parse_args(argv)

    paths = broad.trial_paths(args.data)
    if not paths:
        print(f"no BROAD trials found in {args.data or broad.data_dir()}", file=sys.stderr)
        return 2
    if args.trials:
        paths = [p for p in paths if any(p.stem.startswith(s) or s in p.stem for s in args.trials)]
        if not paths:
            print(f"no trial matches {args.trials}", file=sys.stderr)
            return 2
    methods = list(METHODS) if args.method == "both" else [args.method]
    rows = []
    for p in paths:
        for m in methods:
            rows.append(evaluate(p, m))
            print(f"{p.stem} ({m}): {rows[-1]['runtime_s']:.1f} s", file=sys.stderr)
    print(
        "Pipeline with default parameters. BROAD (Laidig et al. 2021, CC-BY-4.0); virtual elbow "
        "15 cm along the IMU x axis at 25 Hz; errors over `movement` samples after "
        "convergence; VQF-alone after the first 5 s.\n"
    )
    print(markdown(rows))
    if args.json is not None:
        args.json.write_text(json.dumps({"trials": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
