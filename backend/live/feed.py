"""The WebSocket messages (the protocol the dashboard and the game overlay code against).

Therapist feed (``/api/ws/live``)::

    {"type": "hello", "devices": [...]}                                  once
    {"type": "status", "device", "online", "session_id", "patient", ...Pipeline.status(),
     "rates_hz": {"imu", "robot"}, "ingest": {...}, "tolerance_m",
     "max_outside_fraction"}                                             on change, ≥ 1/s
    {"type": "estimate", "device", "rows": {column: [...]}}              ≤ 30/s per device
    {"type": "state", "device", "t", "state"}                            immediately
    {"type": "cycle", "device", "start", "end", "outside_fraction", "compensatory", "index"}

Overlay feed (``/api/ws/overlay``): ``state`` and ``cycle`` as above, ``status`` with
``heading_converged`` and ``convergence_progress`` only, ``estimate`` rows with
``t, wrist_x..z, shoulder_displacement_m, dx, dy, state``.

Estimate rows are parallel arrays, nulls where a value is not available (NaN).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

Rows = dict[str, list[Any]]

DISPLAY_EXTRA = (
    "upper_arm_elevation_deg", "upper_arm_azimuth_deg", "heading_confidence",
    "nominal_x", "nominal_y", "nominal_z", "wrist_x", "wrist_y", "wrist_z",
)
OVERLAY_COLUMNS = (
    "t", "wrist_x", "wrist_y", "wrist_z", "shoulder_displacement_m", "dx", "dy", "state",
)


def col(a: np.ndarray) -> list[float | None]:
    return [x if math.isfinite(x) else None for x in a.tolist()]


def display_rows(rows: dict[str, np.ndarray], contract: Rows) -> Rows:
    """Contract §7 columns (``contract``, already built for Zenoh) plus the dashboard's."""
    out = dict(contract)
    out["upper_arm_elevation_deg"] = col(rows["upper_arm_elevation_deg"])
    out["upper_arm_azimuth_deg"] = col(rows["upper_arm_azimuth_deg"])
    out["heading_confidence"] = col(rows["heading_confidence"])
    nom, wr = rows["nominal_shoulder"], rows["wrist"]
    for j, axis in enumerate("xyz"):
        out[f"nominal_{axis}"] = col(nom[:, j])
    for j, axis in enumerate("xyz"):
        out[f"wrist_{axis}"] = col(wr[:, j])
    return out


def overlay_rows(rows: dict[str, np.ndarray], contract: Rows) -> Rows:
    """What the game needs to draw the shoulder indicator and the hand, nothing else."""
    d = rows["shoulder"] - rows["nominal_shoulder"]
    wr = rows["wrist"]
    return {
        "t": contract["t"],
        "wrist_x": col(wr[:, 0]),
        "wrist_y": col(wr[:, 1]),
        "wrist_z": col(wr[:, 2]),
        "shoulder_displacement_m": contract["shoulder_displacement_m"],
        "dx": col(d[:, 0]),
        "dy": col(d[:, 1]),
        "state": contract["state"],
    }


def extend_rows(into: Rows, rows: Rows) -> None:
    for k, v in rows.items():
        into.setdefault(k, []).extend(v)


def status_message(
    device: str,
    *,
    online: bool,
    session_id: int | None,
    patient: str | None,
    pipeline: dict[str, Any],
    rates_hz: dict[str, float],
    ingest: dict[str, Any],
    tolerance_m: float,
    max_outside_fraction: float,
) -> dict[str, Any]:
    quality = dict(pipeline.get("quality", {}))
    gaps = quality.get("gaps", [])
    quality["gaps"] = gaps[-20:]  # the latest; all of them are in the report
    return {
        "type": "status",
        "device": device,
        "online": online,
        "session_id": session_id,
        "patient": patient,
        **pipeline,
        "quality": quality,
        "rates_hz": rates_hz,
        "ingest": ingest,
        "tolerance_m": tolerance_m,  # of the running parameters (the indicator's circle)
        "max_outside_fraction": max_outside_fraction,
    }


def overlay_status(status: dict[str, Any]) -> dict[str, Any]:
    return {
        "type": "status",
        "device": status["device"],
        "heading_converged": status.get("heading_converged", False),
        "convergence_progress": status.get("convergence_progress", 0.0),
    }


def state_message(device: str, t: float, state: str) -> dict[str, Any]:
    return {"type": "state", "device": device, "t": t, "state": state}


def cycle_message(device: str, fb: dict[str, Any], index: int) -> dict[str, Any]:
    return {
        "type": "cycle",
        "device": device,
        "start": fb["start"],
        "end": fb["end"],
        "outside_fraction": fb["outside_fraction"],
        "compensatory": fb["compensatory"],
        "index": index,
    }
