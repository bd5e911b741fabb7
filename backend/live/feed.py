"""The WebSocket messages (the protocol the dashboard and the game overlay code against),
built as the typed dicts of :mod:`backend.schemas.live`, where they are defined.

Therapist feed (``/api/ws/live``)::

    {"type": "hello", "devices": [...]}                                  once
    {"type": "status", "device", "online", "session_id", "patient", ...Pipeline.status(),
     "rates_hz": {"imu", "robot"}, "ingest": {...}, "tolerance_m",
     "max_outside_fraction"}                                             on change, ≥ 1/s
    {"type": "estimate", "device", "rows": {column: [...]}}              ≤ 30/s per device
    {"type": "state", "device", "t", "state"}                            immediately
    {"type": "cycle", "device", "start", "end", "outside_fraction", "compensatory", "index"}

Overlay feed (``/api/ws/overlay``; the page's first message is ``{"type": "auth", "token"}``,
the link's token, never in the URL): ``state`` and ``cycle`` as above, ``status`` with
``heading_converged``, ``convergence_progress``, ``online`` and ``tolerance_m`` only,
``estimate`` rows with
``t, wrist_x..z, shoulder_displacement_m, dx, dy, state``.

Estimate rows are parallel arrays, nulls where a value is not available (NaN).

A wearable device (contract §8) sends ``{"type": "joints", "device", "rows": {column: [...]}}``
instead of ``estimate`` (columns :data:`JOINTS_COLUMNS`: joints.csv's, each angle's standard
deviation, flags), and its ``status`` carries ``mode: "wearable"``, ``angles_std_deg``,
``angles_sure``, ``messages`` and the ROM tests (:meth:`WearableLiveRun.status`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import orjson
from numpy.typing import NDArray

from backend.schemas.live import CycleMsg, IndicatorState, OverlayStatusMsg, StateMsg, StatusMsg
from estimators.output import RowTable, column_index
from estimators.wearable.tracker import STD_COLUMNS
from protocol.wire import JOINT_COLUMNS

Rows = dict[str, list[Any]]

# Contract §7 float columns, in the order of estimates.csv (heading_converged and state are
# not floats: they travel beside the block)
CONTRACT_FLOATS = (
    "t",
    "elbow_x",
    "elbow_y",
    "elbow_z",
    "shoulder_x",
    "shoulder_y",
    "shoulder_z",
    "elbow_angle_deg",
    "heading_offset_deg",
    "shoulder_displacement_m",
)
DISPLAY_EXTRA = (
    "upper_arm_elevation_deg",
    "upper_arm_azimuth_deg",
    "heading_confidence",
    "nominal_x",
    "nominal_y",
    "nominal_z",
    "wrist_x",
    "wrist_y",
    "wrist_z",
)
OVERLAY_COLUMNS = (
    "t",
    "wrist_x",
    "wrist_y",
    "wrist_z",
    "shoulder_displacement_m",
    "dx",
    "dy",
    "state",
)
_OVERLAY_FLOATS = OVERLAY_COLUMNS[:-1]
# pipeline state code (-1 none yet, 0 ok, 1 outside, 2 warning) + 1 → its name
_STATE_NAMES = np.array([None, "ok", "outside", "warning"], dtype=object)
_STATE_LIST: list[str | None] = _STATE_NAMES.tolist()
# Below this many rows a block's columns are Python lists, above numpy arrays: orjson writes
# the same text for both (NaN as null), and for a live poll's row or two a few tolist()
# calls cost a third of building and slicing one array; per value, arrays are cheaper.
LIST_ROWS = 64

Column = list[float] | NDArray[np.float64]


@dataclass(slots=True)
class Block:
    """Rows of one or more polls as the feeds send them, built once per poll and
    serialised once per send (without a Python check per value: orjson writes NaN as
    null). Treated as immutable."""

    names: tuple[str, ...]
    values: list[Column]  # one per name: lists (few rows) or float64 arrays
    state: list[str | None]
    converged: list[int] | NDArray[np.int8] | None = None  # heading_converged 0/1, if a column

    def columns(self, upto: int | None = None) -> dict[str, Any]:
        """Column name → values, for orjson with ``OPT_SERIALIZE_NUMPY``; ``upto``: only the
        first float columns (the contract's, from a display block)."""
        names = self.names if upto is None else self.names[:upto]
        cols: dict[str, Any] = dict(zip(names, self.values, strict=False))  # upto: the first
        if self.converged is not None:
            cols["heading_converged"] = self.converged
        cols["state"] = self.state
        return cols


_ROW_SOURCES = (
    "t",
    "elbow",
    "shoulder",
    "elbow_angle_deg",
    "heading_offset_deg",
    "shoulder_displacement_m",
)
_DISPLAY_SOURCES = (
    "upper_arm_elevation_deg",
    "upper_arm_azimuth_deg",
    "heading_confidence",
    "nominal_shoulder",
    "wrist",
)
# matrix columns of a pipeline row table: the float columns, then heading_converged
_CONTRACT_INDEX = column_index((*_ROW_SOURCES, "heading_converged"))
_DISPLAY_INDEX = column_index((*_ROW_SOURCES, *_DISPLAY_SOURCES, "heading_converged"))


def estimate_block(rows: Mapping[str, NDArray[Any]], display: bool) -> Block:
    """Contract §7 columns and, if ``display``, the dashboard's (contract first)."""
    t = rows["t"]
    if isinstance(rows, RowTable) and len(t) < LIST_ROWS:
        cols = rows.column_lists(_DISPLAY_INDEX if display else _CONTRACT_INDEX)
        flags = cols.pop()  # heading_converged, 1.0/0.0 in the matrix
        return Block(
            CONTRACT_FLOATS + DISPLAY_EXTRA if display else CONTRACT_FLOATS,
            list[Column](cols),
            _states(rows["state"]),
            [1 if f > 0.5 else 0 for f in flags],
        )
    if len(t) < LIST_ROWS:
        values: list[Column] = [
            t.tolist(),
            *rows["elbow"].T.tolist(),
            *rows["shoulder"].T.tolist(),
            rows["elbow_angle_deg"].tolist(),
            rows["heading_offset_deg"].tolist(),
            rows["shoulder_displacement_m"].tolist(),
        ]
        if display:
            values += [
                rows["upper_arm_elevation_deg"].tolist(),
                rows["upper_arm_azimuth_deg"].tolist(),
                rows["heading_confidence"].tolist(),
                *rows["nominal_shoulder"].T.tolist(),
                *rows["wrist"].T.tolist(),
            ]
        converged: list[int] | NDArray[np.int8] = rows["heading_converged"].astype(np.int8).tolist()
    else:
        parts = [
            t[None],
            rows["elbow"].T,
            rows["shoulder"].T,
            rows["elbow_angle_deg"][None],
            rows["heading_offset_deg"][None],
            rows["shoulder_displacement_m"][None],
        ]
        if display:
            parts += [
                rows["upper_arm_elevation_deg"][None],
                rows["upper_arm_azimuth_deg"][None],
                rows["heading_confidence"][None],
                rows["nominal_shoulder"].T,
                rows["wrist"].T,
            ]
        values = list(_rows_of(parts))
        # astype keeps strides
        converged = np.ascontiguousarray(rows["heading_converged"], dtype=np.int8)
    return Block(
        CONTRACT_FLOATS + DISPLAY_EXTRA if display else CONTRACT_FLOATS,
        values,
        _states(rows["state"]),
        converged,
    )


def overlay_block(rows: Mapping[str, NDArray[Any]]) -> Block:
    """What the game needs to draw the shoulder indicator and the hand, nothing else."""
    d = rows["shoulder"][:, :2] - rows["nominal_shoulder"][:, :2]
    parts = [rows["t"][None], rows["wrist"].T, rows["shoulder_displacement_m"][None], d.T]
    values: list[Column] = (
        [c for p in parts for c in p.tolist()] if len(d) < LIST_ROWS else list(_rows_of(parts))
    )
    return Block(_OVERLAY_FLOATS, values, _states(rows["state"]))


def overlay_columns(rows: Mapping[str, Sequence[Any]]) -> dict[str, list[Any]] | None:
    """The overlay's columns from a dashboard estimate message's rows (as decoded JSON,
    null for NaN): what :func:`overlay_block` gives from the pipeline's rows, for an API node
    that gets the dashboard's rows from a worker. ``None`` if the rows lack a column the
    overlay draws (a device whose estimates carry no shoulder)."""
    try:
        shoulder = rows["shoulder_x"], rows["shoulder_y"]
        nominal = rows["nominal_x"], rows["nominal_y"]
        out = {name: list(rows[name]) for name in OVERLAY_COLUMNS if name not in ("dx", "dy")}
    except KeyError:
        return None
    for name, s, n in zip(("dx", "dy"), shoulder, nominal, strict=True):
        out[name] = [None if a is None or b is None else a - b for a, b in zip(s, n, strict=True)]
    return {name: out[name] for name in OVERLAY_COLUMNS}


def _states(codes: NDArray[Any]) -> list[str | None]:
    if len(codes) < LIST_ROWS:
        names = _STATE_LIST
        return [names[c + 1] for c in codes.tolist()]
    states: list[str | None] = _STATE_NAMES[codes + 1].tolist()
    return states


def _rows_of(parts: list[NDArray[Any]]) -> NDArray[np.float64]:
    # into a C-ordered array: concatenate alone keeps the transposed inputs' column-major
    # layout, whose rows orjson refuses
    out = np.empty((sum(len(p) for p in parts), parts[0].shape[1]))
    return np.concatenate(parts, out=out)


def join(blocks: Sequence[Block]) -> Block:
    """Consecutive blocks of the same columns as one."""
    if len(blocks) == 1:
        return blocks[0]
    first = blocks[0]
    values: list[Column]
    if all(isinstance(v, list) for b in blocks for v in b.values):
        values = [[x for b in blocks for x in b.values[j]] for j in range(len(first.names))]
    else:
        values = list(
            np.concatenate(
                [np.asarray(b.values, dtype=np.float64) for b in blocks],
                axis=1,
            )
        )
    convs = [b.converged for b in blocks if b.converged is not None]
    converged: list[int] | NDArray[np.int8] | None = None
    if convs:
        converged = (
            [c for part in convs for c in part]
            if all(isinstance(c, list) for c in convs)
            else np.concatenate([np.asarray(c, dtype=np.int8) for c in convs])
        )
    return Block(first.names, values, [s for b in blocks for s in b.state], converged)


# A wearable device's rows (``{"type": "joints", "device", "rows": {column: [...]}}``):
# contract §8's columns, then each angle's standard deviation (its confidence) and flags
JOINTS_EXTRA = (*STD_COLUMNS, "flags")
JOINTS_COLUMNS = (*JOINT_COLUMNS, *JOINTS_EXTRA)


def joints_view(rows: Mapping[str, list[Any]]) -> Rows:
    """A wearable device's rows for the 3D view: the DH model's elbow and wrist are in S,
    whose origin is the shoulder joint centre."""
    zero = [0.0] * len(rows["t"])
    return {**rows, "shoulder_x": zero, "shoulder_y": zero, "shoulder_z": zero}


def joints_block(rows: Mapping[str, NDArray[Any]]) -> Block:
    """A wearable run's rows as a block (no pipeline state: ``state`` is null)."""
    values: list[Column] = [np.asarray(rows[c], dtype=np.float64).tolist() for c in JOINTS_COLUMNS]
    return Block(JOINTS_COLUMNS, values, [None] * len(rows["t"]))


def dumps(obj: Any) -> bytes:
    """JSON with numpy arrays (NaN and infinities become null)."""
    return orjson.dumps(obj, option=orjson.OPT_SERIALIZE_NUMPY)


def as_rows(block: Block) -> Rows:
    """Plain lists, None for NaN (for Python consumers such as the 3D view)."""
    out: Rows = {
        name: [x if math.isfinite(x) else None for x in _list(v)]
        for name, v in zip(block.names, block.values, strict=True)
    }
    if block.converged is not None:
        out["heading_converged"] = _list(block.converged)
    out["state"] = list(block.state)
    return out


def _list(v: Any) -> list[Any]:
    return v.tolist() if isinstance(v, np.ndarray) else list(v)


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
) -> StatusMsg:
    quality = dict(pipeline.get("quality", {}))
    gaps = quality.get("gaps", [])
    quality["gaps"] = gaps[-20:]  # the latest; all of them are in the report
    # the pipeline's status keys are checked against the model by the live tests
    msg: dict[str, Any] = {
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
    return cast(StatusMsg, msg)


def overlay_status(status: StatusMsg) -> OverlayStatusMsg:
    return {
        "type": "status",
        "device": status["device"],
        "heading_converged": status["heading_converged"],
        "convergence_progress": status["convergence_progress"],
        "online": status["online"],
        "tolerance_m": status["tolerance_m"],  # the indicator's circle
    }


def state_message(device: str, t: float, state: IndicatorState) -> StateMsg:
    return {"type": "state", "device": device, "t": t, "state": state}


def cycle_message(device: str, fb: dict[str, Any], index: int) -> CycleMsg:
    return {
        "type": "cycle",
        "device": device,
        "start": fb["start"],
        "end": fb["end"],
        "outside_fraction": fb["outside_fraction"],
        "compensatory": fb["compensatory"],
        "index": index,
    }
