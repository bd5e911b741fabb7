"""The ``rehab`` command line: analyze, evaluate, simulate (and serve, demo)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from estimators.params import ParamsError, PipelineParams


def _load_params(path: str | None) -> PipelineParams:
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


def cmd_analyze(args: argparse.Namespace) -> int:
    from backend.analysis import analyze, gc_paused

    rec = Path(args.recording)
    if not rec.is_file():
        print(f"rehab analyze: no such recording: {rec}", file=sys.stderr)
        return 2
    wearable = _wearable_params(args.params)
    if wearable is not None:  # contract §8: the mode is chosen by the parameter file
        from backend import analysis_wearable

        return analysis_wearable.cmd_analyze(rec, wearable, args.out, args.device)
    params = _load_params(args.params)
    t0 = time.perf_counter()
    with gc_paused():
        run, rep = analyze(rec, params, args.out, device=args.device, progress=sys.stderr.isatty())
    dt = time.perf_counter() - t0
    s = rep["summary"]
    q = rep["data_quality"]
    rejected = sum(q["rejected"].values())
    print(
        f"{run.device or '(no device)'}: {s['rows']} estimates, {s['cycles']} cycles "
        f"({s['compensatory_cycles']} compensatory), heading converged at "
        f"{rep['heading']['converged_t']}, {rejected} messages rejected, {dt:.2f} s -> {args.out}"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="rehab", description=__doc__)
    sub = ap.add_subparsers(dest="command", required=True)

    a = sub.add_parser("analyze", help="run the pipeline over a recording (contract §6)")
    a.add_argument("recording")
    a.add_argument("--params", help="parameters JSON (contract §4)")
    a.add_argument("--out", required=True, help="output directory")
    a.add_argument("--device", help="device to analyse when the recording has several")
    a.set_defaults(func=cmd_analyze)

    from simulator import cli as sim_cli

    sim_cli.add_parser(sub)

    from backend import evaluate

    evaluate.add_parser(sub)

    from backend import cli_live

    cli_live.add_parser(sub)

    args = ap.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
