"""Time to a clinic's report: `rehab analyze` of a simulated session, then its PDF report,
FHIR Bundle and MCAP file (the special issue's clinicians ask for a report within 5 minutes).

    python benchmarks/report_time.py [--seed 1] [--duration 1800]
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=1800.0, help="session length, s")
    args = ap.parse_args()
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
    print("| step | wall time (s) |\n|---|---|")
    for k, v in times.items():
        print(f"| {k} | {v:.2f} |")
    total = sum(v for k, v in times.items() if not k.startswith("of which"))
    print(f"| total | {total:.2f} |")
    print(
        f"PDF {len(body) / 1e3:.0f} kB, Bundle {len(bundle) / 1e3:.0f} kB, MCAP {n} messages, "
        f"{len(buf.getvalue()) / 1e6:.1f} MB"
    )


if __name__ == "__main__":
    main()
