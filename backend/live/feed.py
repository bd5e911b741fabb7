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
``heading_converged``, ``convergence_progress``, ``online`` and ``tolerance_m`` only,
``estimate`` rows with
``t, wrist_x..z, shoulder_displacement_m, dx, dy, state``.

Estimate rows are parallel arrays, nulls where a value is not available (NaN).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson
from numpy.typing import NDArray

Rows = dict[str, list[Any]]

# Contract §7 float columns, in the order of estimates.csv (heading_converged and state are
# not floats: they travel beside the block)
CONTRACT_FLOATS = (
    "t", "elbow_x", "elbow_y", "elbow_z", "shoulder_x", "shoulder_y", "shoulder_z",
    "elbow_angle_deg", "heading_offset_deg", "shoulder_displacement_m",
)
DISPLAY_EXTRA = (
    "upper_arm_elevation_deg", "upper_arm_azimuth_deg", "heading_confidence",
    "nominal_x", "nominal_y", "nominal_z", "wrist_x", "wrist_y", "wrist_z",
)
OVERLAY_COLUMNS = (
    "t", "wrist_x", "wrist_y", "wrist_z", "shoulder_displacement_m", "dx", "dy", "state",
)
_OVERLAY_FLOATS = OVERLAY_COLUMNS[:-1]
# pipeline state code (-1 none yet, 0 ok, 1 outside, 2 warning) + 1 → its name
_STATE_NAMES = np.array([None, "ok", "outside", "warning"], dtype=object)


@dataclass(frozen=True, slots=True)
class Block:
    """Rows of one or more polls as the feeds send them.

    The float columns are the rows of one C-contiguous array: one numpy call builds it,
    and orjson writes it without a Python float per value (NaN as null). Per-column lists
    were a large part of the live loop's cost per poll.
    """

    names: tuple[str, ...]
    values: NDArray[np.float64]  # (len(names), rows)
    state: list[str | None]
    converged: NDArray[np.int8] | None = None  # heading_converged 0/1, if a column

    def columns(self, upto: int | None = None) -> dict[str, Any]:
        """Column name → values, for orjson with ``OPT_SERIALIZE_NUMPY``; ``upto``: only the
        first float columns (the contract's, from a display block)."""
        n = len(self.names) if upto is None else upto
        cols: dict[str, Any] = dict(zip(self.names[:n], self.values[:n], strict=True))
        if self.converged is not None:
            cols["heading_converged"] = self.converged
        cols["state"] = self.state
        return cols


def estimate_block(rows: Mapping[str, NDArray[Any]], display: bool) -> Block:
    """Contract §7 columns and, if ``display``, the dashboard's (contract first)."""
    parts = [
        rows["t"][None], rows["elbow"].T, rows["shoulder"].T, rows["elbow_angle_deg"][None],
        rows["heading_offset_deg"][None], rows["shoulder_displacement_m"][None],
    ]
    if display:
        parts += [
            rows["upper_arm_elevation_deg"][None], rows["upper_arm_azimuth_deg"][None],
            rows["heading_confidence"][None], rows["nominal_shoulder"].T, rows["wrist"].T,
        ]
    return Block(
        CONTRACT_FLOATS + DISPLAY_EXTRA if display else CONTRACT_FLOATS,
        _rows_of(parts),
        _STATE_NAMES[rows["state"] + 1].tolist(),
        np.ascontiguousarray(rows["heading_converged"], dtype=np.int8),  # astype keeps strides
    )


def overlay_block(rows: Mapping[str, NDArray[Any]]) -> Block:
    """What the game needs to draw the shoulder indicator and the hand, nothing else."""
    d = rows["shoulder"][:, :2] - rows["nominal_shoulder"][:, :2]
    return Block(
        _OVERLAY_FLOATS,
        _rows_of([rows["t"][None], rows["wrist"].T, rows["shoulder_displacement_m"][None], d.T]),
        _STATE_NAMES[rows["state"] + 1].tolist(),
    )


def _rows_of(parts: list[NDArray[Any]]) -> NDArray[np.float64]:
    # into a C-ordered array: concatenate alone keeps the transposed inputs' column-major
    # layout, whose rows orjson refuses
    out = np.empty((sum(len(p) for p in parts), parts[0].shape[1]))
    return np.concatenate(parts, out=out)


def join(blocks: Sequence[Block]) -> Block:
    """Consecutive blocks of the same columns as one."""
    if len(blocks) == 1:
        return blocks[0]
    convs = [b.converged for b in blocks if b.converged is not None]
    values = np.empty((len(blocks[0].names), sum(b.values.shape[1] for b in blocks)))
    return Block(
        blocks[0].names,
        np.concatenate([b.values for b in blocks], axis=1, out=values),
        [s for b in blocks for s in b.state],
        np.concatenate(convs) if convs else None,
    )


def dumps(obj: Any) -> bytes:
    """JSON with numpy arrays (NaN and infinities become null)."""
    return orjson.dumps(obj, option=orjson.OPT_SERIALIZE_NUMPY)


def as_rows(block: Block) -> Rows:
    """Plain lists, None for NaN (for Python consumers such as the 3D view)."""
    out: Rows = {
        name: [x if math.isfinite(x) else None for x in v]
        for name, v in zip(block.names, block.values.tolist(), strict=True)
    }
    if block.converged is not None:
        out["heading_converged"] = block.converged.tolist()
    out["state"] = list(block.state)
    return out


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
        "online": status.get("online", False),
        "tolerance_m": status.get("tolerance_m"),  # the indicator's circle
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
