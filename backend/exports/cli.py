"""``rehab export RECORDING --analysis DIR --pdf FILE --fhir FILE --mcap FILE``: a session's
clinical exports offline, for studies and archives, from what ``rehab analyze`` wrote."""

from __future__ import annotations

import argparse
import json
import sys
from datetime import datetime
from pathlib import Path

from backend.exports import ExportMeta


def _time(text: str | None) -> datetime | None:
    if text is None:
        return None
    try:
        t = datetime.fromisoformat(text)
    except ValueError:
        raise SystemExit(f"rehab export: not an ISO 8601 time: {text!r}") from None
    if t.tzinfo is None:
        raise SystemExit(f"rehab export: give the time zone of {text!r} (e.g. +01:00 or Z)")
    return t


def cmd_export(args: argparse.Namespace) -> int:
    rec, out_dir = Path(args.recording), Path(args.analysis)
    if not (args.pdf or args.fhir or args.mcap):
        print("rehab export: nothing to do (give --pdf, --fhir and/or --mcap)", file=sys.stderr)
        return 2
    if not rec.is_file():
        print(f"rehab export: no such recording: {rec}", file=sys.stderr)
        return 2
    try:
        report = json.loads((out_dir / "report.json").read_text())
    except (OSError, ValueError) as exc:
        print(
            f"rehab export: no report.json in {out_dir} (run rehab analyze): {exc}", file=sys.stderr
        )
        return 2
    name = rec.name.removesuffix(".gz").removesuffix(".jsonl")
    meta = ExportMeta(
        session=args.session or name,
        device=report.get("device") or "",
        patient_code=args.patient,
        started_at=_time(args.started),
        stopped_at=_time(args.stopped),
        therapist=args.therapist,
    )
    done = []
    if args.pdf:
        from backend.exports import pdf

        Path(args.pdf).write_bytes(pdf.render(report, meta))
        done.append(args.pdf)
    if args.fhir:
        from backend.exports import fhir

        Path(args.fhir).write_text(json.dumps(fhir.bundle(report, meta), indent=1))
        done.append(args.fhir)
    if args.mcap:
        from backend.analysis import read_estimates
        from backend.analysis_wearable import read_joints
        from backend.exports import mcap_file

        est_path, joints_path = out_dir / "estimates.csv", out_dir / "joints.csv"
        estimates = read_estimates(est_path) if est_path.is_file() else None
        joints = read_joints(joints_path) if joints_path.is_file() else None
        n = mcap_file.write(Path(args.mcap), rec, report, estimates, meta, joints=joints)
        done.append(f"{args.mcap} ({n} messages)")
    print("rehab export: wrote " + ", ".join(done))
    return 0


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    e = sub.add_parser(
        "export", help="a session's PDF report, FHIR R4 Bundle and MCAP file, offline"
    )
    e.add_argument("recording", help="the session's recording (contract §5)")
    e.add_argument("--analysis", required=True, help="the directory rehab analyze wrote")
    e.add_argument("--pdf", help="write the PDF report here")
    e.add_argument("--fhir", help="write the FHIR R4 Bundle (JSON) here")
    e.add_argument("--mcap", help="write the recording and estimates as MCAP here")
    e.add_argument("--patient", help="the patient's pseudonymous code")
    e.add_argument("--session", help="the session's name (default: the recording's)")
    e.add_argument("--therapist", help="the therapist's name or username")
    e.add_argument("--started", help="session start, ISO 8601 with time zone")
    e.add_argument("--stopped", help="session end, ISO 8601 with time zone")
    e.set_defaults(func=cmd_export)
