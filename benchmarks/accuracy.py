"""Accuracy on simulated sessions: the paper's tables, paper method beside the improved one.

For each subject (seed): simulate an 8-minute session, run `rehab analyze` with each method,
compare with the ground truth (`evaluation.evaluate`), and pool the errors over subjects.
Errors are taken after heading convergence; the pipeline keeps its default arm parameters.

    python benchmarks/accuracy.py [--seeds 1 2 3 4 5] [--duration 480] [--json out.json]
    python benchmarks/accuracy.py --gyro-bias-scale 2.5    # fast drift: the gyro bias × 2.5
    python benchmarks/accuracy.py --methods improved        # one method only
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from backend.analysis import analyze
from estimators.params import PipelineParams
from evaluation.evaluate import evaluate, load_truth, stats
from protocol import recording
from simulator import SimConfig, simulate

METHODS = {
    "improved": PipelineParams(),
    "improved, assumed l_A": PipelineParams(arm_length="fixed"),
    "paper (as published)": PipelineParams(method="paper"),
}


def run_subject(seed: int, duration: float, work: Path, bias_scale: float = 1.0) -> dict[str, Any]:
    d = work / f"s{seed}"
    d.mkdir(parents=True, exist_ok=True)
    sim = simulate(SimConfig(seed=seed, duration_s=duration, gyro_bias_scale=bias_scale))
    recording.write(d / "recording.jsonl.gz", sim.messages)
    sim.truth.save(d / "truth.npz", sim.subject)
    truth = load_truth(d / "truth.npz")
    out: dict[str, Any] = {
        "seed": seed,
        "upper_arm_true_m": sim.subject.upper_arm_m,
        "imu_to_elbow_true_m": sim.subject.imu_to_elbow_m,
        "latency_true_s": sim.subject.latency_s,
        "heading_drift_dps": sim.heading_drift_dps,
    }
    for name, params in METHODS.items():
        t0 = time.perf_counter()
        analyze(d / "recording.jsonl.gz", params, d / name)
        out[name] = {"analyze_s": time.perf_counter() - t0, **evaluate(d / name, truth)}
    return out


def pooled(results: list[dict[str, Any]], method: str) -> dict[str, Any]:
    raw = [r[method]["raw"] for r in results]
    phase = np.concatenate([x["phase"] for x in raw])
    res: dict[str, Any] = {}
    for code, name in ((1, "proper"), (3, "compensatory"), (0, "all")):
        m = (phase == code) if code else np.isin(phase, (1, 3))
        res[name] = {
            k: stats(np.concatenate([x[k] for x in raw])[m])
            for k in ("shoulder_m", "elbow_deg", "conv_shoulder_m", "conv_elbow_deg")
        }
    conf = [r[method]["cycles"]["confusion"] for r in results]
    res["confusion"] = {k: sum(c[k] for c in conf) for k in conf[0]}
    conv = [r[method]["heading"]["convergence_s"] for r in results]
    res["convergence_s"] = conv
    return res


def _cm(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.1f}"


def _deg(x: float | None) -> str:
    return "—" if x is None else f"{x:.1f}"


def markdown(results: list[dict[str, Any]]) -> str:
    lines = [
        "| method | subject | shoulder median / p95 (cm) | elbow median / p95 (°) | "
        "conventional shoulder, compensatory median / p95 (cm) | cycles correct | converged after motion (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for method in METHODS:
        rows = [(str(r["seed"]), r[method]) for r in results]
        for label, r in rows:
            a = r["accuracy"]["all"]
            cy = r["cycles"]
            lines.append(
                f"| {method} | {label} | {_cm(a['shoulder_m']['median'])} / {_cm(a['shoulder_m']['p95'])} "
                f"| {_deg(a['elbow_deg']['median'])} / {_deg(a['elbow_deg']['p95'])} "
                f"| {_cm(r['accuracy']['compensatory']['conv_shoulder_m']['median'])} / {_cm(r['accuracy']['compensatory']['conv_shoulder_m']['p95'])} "
                f"| {cy['correct']}/{cy['judged']} (missed {cy['judged'] and sum(v for k, v in cy['confusion'].items() if k.endswith('missed'))}) "
                f"| {_deg(r['heading']['convergence_s'])} |"
            )
        p = pooled(results, method)
        for ph in ("proper", "compensatory", "all"):
            a = p[ph]
            c = p["confusion"]
            right = c["proper->proper"] + c["compensatory->compensatory"]
            judged = right + c["proper->compensatory"] + c["compensatory->proper"]
            lines.append(
                f"| **{method}** | **pooled, {ph}** | {_cm(a['shoulder_m']['median'])} / {_cm(a['shoulder_m']['p95'])} "
                f"| {_deg(a['elbow_deg']['median'])} / {_deg(a['elbow_deg']['p95'])} "
                f"| {_cm(a['conv_shoulder_m']['median'])} / {_cm(a['conv_shoulder_m']['p95'])} | {right}/{judged} "
                f"| max {_deg(max(x for x in p['convergence_s'] if x is not None) if any(x is not None for x in p['convergence_s']) else None)} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=480.0)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--work", type=Path, help="keep recordings and outputs here")
    ap.add_argument("--gyro-bias-scale", type=float, default=1.0, help="fast drift: 2.5")
    ap.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(METHODS))
    args = ap.parse_args(argv)
    for name in list(METHODS):
        if name not in args.methods:
            del METHODS[name]
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        results = []
        for s in args.seeds:
            results.append(run_subject(s, args.duration, work, args.gyro_bias_scale))
            print(f"subject {s} done", file=sys.stderr)
    print(markdown(results))
    if args.json:
        for r in results:
            for m in METHODS:
                r[m].pop("raw")
        args.json.write_text(json.dumps(results, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
