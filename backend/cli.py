"""The ``rehab`` command line: analyze, evaluate, simulate (and serve, demo)."""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the robot pipeline is imported only for its own analyses (not the wearable's)
    from estimators.params import PipelineParams

# the modules registering the other sub-commands, and the names they register
_COMMANDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("simulator.cli", ("simulate",)),
    ("evaluation.evaluate", ("evaluate",)),
    ("backend.exports.cli", ("export",)),
    ("backend.cli_live", ("serve", "worker", "demo")),
)


def _load_params(path: str | None) -> PipelineParams:
    from estimators.params import ParamsError, PipelineParams

    if path is None:
        return PipelineParams()
    try:
        obj = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(f"rehab: cannot read parameters {path}: {exc}") from None
    try:
        return PipelineParams.from_json(obj)
    except ParamsError as exc:
        raise SystemExit(f"rehab: bad parameters in {path}: {exc}") from None


def _wearable_params(path: str | None) -> dict[str, object] | None:
    """The parameter object if it asks for the wearable mode (``"mode": "wearable"``)."""
    if path is None:
        return None
    try:
        obj = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None  # reported by _load_params
    return obj if isinstance(obj, dict) and obj.get("mode") == "wearable" else None


def _analyze_one(
    rec: Path, params: PipelineParams, out: Path, device: str | None, progress: bool
) -> str:
    """One recording into ``out``; its summary line (raises on a recording it cannot read)."""
    from backend.analysis import analyze, gc_paused

    t0 = time.perf_counter()
    with gc_paused():
        run, rep = analyze(rec, params, out, device=device, progress=progress)
    dt = time.perf_counter() - t0
    s = rep["summary"]
    q = rep["data_quality"]
    rejected = sum(q["rejected"].values())
    return (
        f"{run.device or '(no device)'}: {s['rows']} estimates, {s['cycles']} cycles "
        f"({s['compensatory_cycles']} compensatory), heading converged at "
        f"{rep['heading']['converged_t']}, {rejected} messages rejected, {dt:.2f} s -> {out}"
    )


def _out_name(rec: Path) -> str:
    """An output folder's name for a recording: its file name without the recording suffixes."""
    name = rec.name
    for suffix in (".gz", ".jsonl", ".mcap"):
        name = name.removesuffix(suffix)
    return name or rec.name


def cmd_analyze(args: argparse.Namespace) -> int:
    recs = [Path(r) for r in args.recording]
    missing = [r for r in recs if not r.is_file()]
    for r in missing:
        print(f"rehab analyze: no such recording: {r}", file=sys.stderr)
    if missing:
        return 2
    wearable = _wearable_params(args.params)
    if wearable is not None:  # contract §8: the mode is chosen by the parameter file
        from backend import analysis_wearable

        if len(recs) == 1:
            return analysis_wearable.cmd_analyze(recs[0], wearable, args.out, args.device)
        codes = [
            analysis_wearable.cmd_analyze(
                r, wearable, str(Path(args.out) / _out_name(r)), args.device
            )
            for r in recs
        ]
        return max(codes)
    params = _load_params(args.params)
    out = Path(args.out)
    if len(recs) == 1:
        print(_analyze_one(recs[0], params, out, args.device, sys.stderr.isatty()))
        return 0
    # many recordings (a study's re-analysis): DIR/<recording name>/ each, in parallel
    names = [_out_name(r) for r in recs]
    if len(set(names)) != len(names):
        names = [f"{i:04d}_{n}" for i, n in enumerate(names)]
    jobs = max(1, min(args.jobs, len(recs)))
    failed = 0
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [
            pool.submit(_analyze_one, r, params, out / n, args.device, False)
            for r, n in zip(recs, names, strict=True)
        ]
        for r, f in zip(recs, futures, strict=True):
            try:
                print(f.result())
            except Exception as exc:  # one bad recording does not stop the others
                failed += 1
                print(f"rehab analyze: {r}: {exc}", file=sys.stderr)
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="rehab", description=__doc__)
    sub = ap.add_subparsers(dest="command", required=True)

    a = sub.add_parser("analyze", help="run the pipeline over a recording (contract §6)")
    a.add_argument("recording", nargs="+", help="one recording, or many: DIR/<name>/ each")
    a.add_argument("--params", help="parameters JSON (contract §4)")
    a.add_argument("--out", required=True, help="output directory")
    a.add_argument(
        "--jobs", type=int, default=os.cpu_count() or 1, help="processes for many recordings"
    )
    a.add_argument("--device", help="device to analyse when the recording has several")
    a.set_defaults(func=cmd_analyze)

    # the other commands' modules (and what they import: SciPy, the service stack) are
    # imported only for the command run, or all of them for ``--help``
    argv = sys.argv[1:] if argv is None else argv
    first = argv[0] if argv else ""
    wanted = [m for m, names in _COMMANDS if first in names]
    for module in [] if first == "analyze" else wanted or [m for m, _ in _COMMANDS]:
        importlib.import_module(module).add_parser(sub)

    args = ap.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
