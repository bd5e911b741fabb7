"""Time to a clinic's report: `rehab analyze` of a simulated session, then its PDF report,
FHIR Bundle and MCAP file (the special issue's clinicians ask for a report within 5 minutes).

    python benchmarks/report_time.py [--seed 1] [--duration 1800]
    python benchmarks/report_time.py --mode wearable [--tracker] [--duration 1800]

``--mode wearable``: a simulated wearable session (contract §8, reaching). Without
``--tracker`` the joint angles are the simulator's truth, so the figure is the clinical
sections and exports alone; ``--tracker`` runs the wearable tracker as ``rehab analyze`` does
(its speed is the wearable estimator's, benchmarks/wearable_paper.py).
"""

from __future__ import annotations

import argparse
import io
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from backend import clinical
from backend.analysis import analyze, gc_paused, read_estimates
from backend.exports import ExportMeta, fhir, mcap_file, pdf
from estimators.params import PipelineParams
from protocol import recording
from simulator import SimConfig, simulate


def wearable(args: argparse.Namespace) -> None:
    """The wearable mode's report: clinical sections, report.json, PDF, FHIR, MCAP."""
    from backend import analysis_wearable
    from estimators.wearable.params import WearableParams
    from simulator import wearable as w

    sim = w.simulate(w.WearableSimConfig(move="reaching", duration_s=args.duration, seed=args.seed))
    times: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as d:
        paths = w.write(sim, Path(d) / "sim")
        out = Path(d) / "out"
        out.mkdir()
        if args.tracker:
            t0 = time.perf_counter()
            params = WearableParams.from_json(json.loads(paths["params"].read_text()))
            rep = analysis_wearable.analyze(paths["recording"], params, out)
            times["rehab analyze (tracker and clinical sections)"] = time.perf_counter() - t0
            joints = analysis_wearable.read_joints(out / "joints.csv")
        else:
            joints = analysis_wearable.read_joints(paths["truth"])
        valid = joints["t"] >= joints["t"][0] + 2.0  # after the start's rest window
        t0 = time.perf_counter()
        sec = clinical.wearable_sections(joints["t"], joints, valid)
        times["clinical sections (joint angles in)"] = time.perf_counter() - t0
        if not args.tracker:
            rep = {"mode": "wearable", "device": sim.config.device, "cycles": [], **sec}
            rep["summary"] = {"rows": len(joints["t"]), "movements": len(sec["movements"])}
        meta = ExportMeta(session="bench", device=sim.config.device, patient_code="P-BENCH")
        t0 = time.perf_counter()
        body = pdf.render(rep, meta)
        times["PDF report"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        bundle = json.dumps(fhir.bundle(rep, meta))
        times["FHIR Bundle"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        buf = io.BytesIO()
        n = mcap_file.write(buf, paths["recording"], rep, None, meta, joints=joints)
        times["MCAP file"] = time.perf_counter() - t0
    print(
        f"{args.duration / 60:.0f}-minute simulated wearable session (reaching, seed "
        f"{args.seed}), {len(rep['movements'])} movements, joint angles from "
        f"{'the tracker' if args.tracker else 'the simulator truth'}; "
        f"{platform.processor() or platform.machine()}, Python {platform.python_version()}"
    )
    _table(times)
    print(
        f"PDF {len(body) / 1e3:.0f} kB, Bundle {len(bundle) / 1e3:.0f} kB, MCAP {n} messages, "
        f"{len(buf.getvalue()) / 1e6:.1f} MB"
    )


def _table(times: dict[str, float]) -> None:
    print("| step | wall time (s) |\n|---|---|")
    for k, v in times.items():
        print(f"| {k} | {v:.2f} |")
    total = sum(v for k, v in times.items() if not k.startswith("of which"))
    print(f"| total | {total:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=1800.0, help="session length, s")
    ap.add_argument("--mode", choices=("robot", "wearable"), default="robot")
    ap.add_argument("--tracker", action="store_true", help="wearable: run the tracker too")
    args = ap.parse_args()
    if args.mode == "wearable":
        wearable(args)
        return
    sim = simulate(SimConfig(seed=args.seed, duration_s=args.duration))
    with tempfile.TemporaryDirectory() as d:
        rec, out = Path(d) / "session.jsonl.gz", Path(d) / "out"
        recording.write(rec, sim.messages)
        times: dict[str, float] = {}
        t0 = time.perf_counter()
        with gc_paused():
            run, rep = analyze(rec, PipelineParams(), out)
        times["analyze (with the clinical sections)"] = time.perf_counter() - t0
        st = {k: np.concatenate(v) for k, v in run._stats.items()}
        t0 = time.perf_counter()
        clinical.sections(st, run.cycles, {})
        times["of which the clinical sections (recomputed alone)"] = time.perf_counter() - t0
        meta = ExportMeta(session="bench", device=run.device, patient_code="P-BENCH")
        t0 = time.perf_counter()
        body = pdf.render(json.loads((out / "report.json").read_text()), meta)
        times["PDF report"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        bundle = json.dumps(fhir.bundle(rep, meta))
        times["FHIR Bundle"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        buf = io.BytesIO()
        n = mcap_file.write(buf, rec, rep, read_estimates(out / "estimates.csv"), meta)
        times["MCAP file"] = time.perf_counter() - t0
    print(
        f"{args.duration / 60:.0f}-minute simulated session (seed {args.seed}), "
        f"{len(rep['cycles'])} cycles; {platform.processor() or platform.machine()}, "
        f"Python {platform.python_version()}"
    )
    _table(times)
    print(
        f"PDF {len(body) / 1e3:.0f} kB, Bundle {len(bundle) / 1e3:.0f} kB, MCAP {n} messages, "
        f"{len(buf.getvalue()) / 1e6:.1f} MB"
    )


if __name__ == "__main__":
    main()
