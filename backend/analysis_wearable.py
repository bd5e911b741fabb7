"""``rehab analyze`` for a wearable recording (contract §8): DIR/joints.csv and DIR/report.json.

Chosen by the parameter file's ``"mode": "wearable"`` before the robot pipeline's parameters
are read. Messages are validated by :mod:`protocol.wire` (the one schema); every line that
cannot be used is counted by reason in the report, never a crash.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from backend import clinical
from estimators.wearable import tracker
from estimators.wearable.params import WearableParams, WearableParamsError
from protocol import keys, recording, wire

JOINTS_NAME = "joints.csv"
REPORT_NAME = "report.json"
ANGLES = tracker.COLUMNS[1:6]
_FLAG_NAMES = {
    tracker.FOREARM_MISSING: "forearm_missing",
    tracker.CAMERA_USED: "camera_used",
    tracker.CAMERA_STALE: "camera_stale",
    tracker.NOT_AT_REST: "not_at_rest",
    tracker.MOUNTING_MISMATCH: "mounting_mismatch",
    tracker.INCONSISTENT: "inconsistent",
    tracker.RESTARTED: "restarted",
    tracker.INITIALISING: "initialising",
}


def is_wearable(obj: Any) -> bool:
    return isinstance(obj, dict) and obj.get("mode") == "wearable"


def analyze(
    path: str | Path, params: WearableParams, out: str | Path, device: str | None = None
) -> dict[str, Any]:
    """Run the wearable tracker over a recording; write joints.csv and report.json."""
    state = tracker.initial_state(params)
    parts: list[tracker.Rows] = []
    rejected: Counter[str] = Counter()
    chosen = device
    n_lines = 0
    cycle_starts: list[float] = []  # contract cycle_start events: the movements, if any
    for key, payload in recording.read(path):
        n_lines += 1
        if key is None:
            rejected["malformed_line"] += 1
            continue
        try:
            parsed = keys.parse(key)
        except keys.KeyError_:
            rejected["unknown_key"] += 1
            continue
        if chosen is None and parsed.kind in ("imu", "camera"):
            chosen = parsed.device
        if parsed.device != chosen:
            rejected["other_device"] += 1
            continue
        try:
            msg = wire.decode(key, payload)
        except wire.WireError as exc:
            rejected[exc.reason] += 1
            continue
        if isinstance(msg, wire.ImuMessage) and msg.segment in ("upperarm", "forearm"):
            kind: tracker.Kind = "upperarm" if msg.segment == "upperarm" else "forearm"
            rows, state = tracker.feed(params, state, kind, msg.t, msg.gyr, msg.acc)
        elif isinstance(msg, wire.CameraMessage):
            rows, state = tracker.feed(params, state, "camera", msg.t, msg.elbow, msg.wrist)
        elif isinstance(msg, wire.EventMessage) and msg.type == "cycle_start":
            cycle_starts.append(msg.t)
            continue
        else:
            rejected[f"ignored_{parsed.kind}"] += 1
            continue
        parts.append(rows)
    rows, state = tracker.flush(params, state)
    parts.append(rows)
    rows = tracker.concat(parts)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_joints(rows, out / JOINTS_NAME)
    report = make_report(rows, state, rejected, chosen, params, n_lines, cycle_starts)
    (out / REPORT_NAME).write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
    return report


def _cell(v: float, digits: int) -> str:
    return "" if not math.isfinite(v) else f"{v:.{digits}f}"


def write_joints(rows: tracker.Rows, path: Path) -> None:
    """Contract §8's joints.csv: exact header, empty cells where a value is not available."""
    digits = [6] + [3] * 5 + [4] * 6
    cols = [rows[c] for c in tracker.COLUMNS]
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(",".join(tracker.COLUMNS) + "\n")
        for i in range(len(cols[0])):
            fh.write(",".join(_cell(float(c[i]), d) for c, d in zip(cols, digits, strict=True)))
            fh.write("\n")


def read_joints(path: str | Path) -> dict[str, np.ndarray]:
    """joints.csv's columns by name (float64, NaN where a cell is empty)."""
    with open(path, encoding="utf-8") as fh:
        header = fh.readline().strip().split(",")
        lines = [ln.rstrip("\n").split(",") for ln in fh if ln.strip()]
    data = np.array(
        [[float(v) if v else math.nan for v in ln] for ln in lines], dtype=np.float64
    ).reshape(-1, len(header))
    return {name: data[:, i].copy() for i, name in enumerate(header)}


def rom(rows: tracker.Rows) -> dict[str, dict[str, float | None]]:
    """Range of motion per joint in anatomical terms: min, max, p5, p95 (deg), over the rows
    whose angle is available and whose flags do not mark the start's rest window."""
    flags = rows["flags"].astype(np.int64)
    usable = (flags & tracker.INITIALISING) == 0
    out: dict[str, dict[str, float | None]] = {}
    for c in ANGLES:
        v = rows[c][usable]
        v = v[np.isfinite(v)]
        if not len(v):
            out[c] = {"min": None, "max": None, "p5": None, "p95": None}
            continue
        out[c] = {
            "min": round(float(v.min()), 3),
            "max": round(float(v.max()), 3),
            "p5": round(float(np.percentile(v, 5)), 3),
            "p95": round(float(np.percentile(v, 95)), 3),
        }
    return out


def make_report(
    rows: tracker.Rows,
    state: tracker.TrackerState,
    rejected: Counter[str],
    device: str | None,
    params: WearableParams,
    n_lines: int,
    cycle_starts: list[float] | None = None,
) -> dict[str, Any]:
    """report.json of a wearable session: the §8 ROM (``rom``), confidence, data quality,
    and the clinical sections of :func:`backend.clinical.wearable_sections` (anatomical ROM
    per session and per movement, movement quality of the wrist path, key figures)."""
    flags = rows["flags"].astype(np.int64)
    usable = (flags & tracker.INITIALISING) == 0
    clin = clinical.wearable_sections(
        rows["t"], rows, usable, event_times=cycle_starts or (), side=params.side
    )
    final_std = {
        c: (round(float(rows[c][-1]), 3) if len(rows[c]) and math.isfinite(rows[c][-1]) else None)
        for c in tracker.STD_COLUMNS
    }
    return {
        "mode": "wearable",
        "device": device,
        "cycles": [],  # contract §6's key: the wearable mode has no robot cycles
        "summary": {
            "rows": len(rows["t"]),
            "lines": n_lines,
            "start": float(rows["t"][0]) if len(rows["t"]) else None,
            "end": float(rows["t"][-1]) if len(rows["t"]) else None,
            "movements": len(clin["movements"]),
        },
        "rom": rom(rows),
        "confidence_at_end_deg": final_std,
        "data_quality": {
            "rejected": dict(sorted((rejected + state.rejected).items())),
            "flagged_rows": {
                name: int(((flags & bit) > 0).sum()) for bit, name in _FLAG_NAMES.items()
            },
        },
        "params": {
            "side": params.side,
            "filter": params.filter,
            "model": params.model,
            "upper_arm_length_m": params.upper_arm_length_m,
            "forearm_length_m": params.forearm_length_m,
        },
        **clin,
    }


def load_params(obj: dict[str, Any]) -> WearableParams:
    """Parameters from the file's object; SystemExit with a clear message if unusable."""
    try:
        return WearableParams.from_json(obj)
    except WearableParamsError as exc:
        raise SystemExit(f"rehab: bad wearable parameters: {exc}") from None


def cmd_analyze(recording_path: Path, obj: dict[str, Any], out: str, device: str | None) -> int:
    """``rehab analyze`` for ``"mode": "wearable"``; prints a one-line summary."""
    params = load_params(obj)
    report = analyze(recording_path, params, out, device)
    rej = sum(report["data_quality"]["rejected"].values())
    print(
        f"{report['device'] or '(no device)'}: {report['summary']['rows']} joint-angle rows "
        f"(wearable, {params.filter.upper()} model {params.model}), {rej} rejections -> {out}"
    )
    return 0
