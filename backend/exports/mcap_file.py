"""A session's recording and estimates as an MCAP file (JSON messages with JSON Schemas), which
Foxglove opens as it is.

Topics:
- every key of the recording (contract §1), its messages as recorded (contract §2
  payloads), logged at the time of their first sample (``t``, seconds of the device clock,
  as nanoseconds); a line the recording could not parse goes to ``/rejected`` as text;
- ``<prefix>/<device>/estimate``: one message per robot sample (the row of ``estimates.csv``,
  contract §7's columns, empty cells as null);
- ``<prefix>/<device>/cycle``: one message per judged cycle, as the report has it, logged at
  its end; the movement quality of the cycle beside the verdict.
- a wearable session (contract §8): ``<prefix>/<device>/joints``, one message per row of
  ``joints.csv`` (the contract's live key for them), and ``<prefix>/<device>/movement``, one
  per movement with its ROM's elevation and elbow ranges and its movement quality.

What Foxglove needs, checked by the tests: ``json`` message encoding, ``jsonschema`` schema
encoding, a JSON Schema per channel that each of its messages validates against, and an
indexed file (chunk and message indexes, summary) so it reads the messages in log-time order
although they are written source by source. Every channel's own log times never go back.
Messages carry their source order in ``sequence`` (per file), so a reader can restore it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.writer import Writer

from backend.analysis import CSV_HEADER
from backend.exports import ExportMeta
from estimators.wearable.tracker import COLUMNS as JOINT_COLUMNS
from protocol import recording

_NUM = {"type": "number"}
_VEC = {"type": "array", "items": _NUM, "minItems": 3, "maxItems": 3}
_SERIES = {"type": "array", "items": _NUM}
_VECS = {"type": "array", "items": _VEC}
SCHEMAS: dict[str, dict[str, Any]] = {
    "rehab.Imu": {
        "type": "object",
        "properties": {"t": _SERIES, "gyr": _VECS, "acc": _VECS, "seq": {"type": "integer"}},
    },
    "rehab.Robot": {
        "type": "object",
        "properties": {
            "t": _SERIES,
            "wrist": _VECS,
            "proximal": _VECS,
            "elbow": _VECS,
            "seq": {"type": "integer"},
        },
    },
    "rehab.Camera": {
        "type": "object",
        "properties": {"t": _SERIES, "elbow": _VECS, "wrist": _VECS, "shoulder": _VECS},
    },
    "rehab.Event": {
        "type": "object",
        "properties": {"t": _NUM, "type": {"type": "string"}, "point": _VEC},
    },
    "rehab.Message": {"type": "object"},
    "rehab.Rejected": {"type": "object", "properties": {"line": {"type": "string"}}},
    "rehab.Estimate": {
        "type": "object",
        "properties": {
            "t": _NUM,
            **{
                k: {"type": ["number", "null"]}
                for k in CSV_HEADER.split(",")[1:-1]  # contract §6, between t and state
            },
            "state": {"type": ["string", "null"]},
        },
    },
    "rehab.Cycle": {
        "type": "object",
        "properties": {
            "start": _NUM,
            "end": _NUM,
            "outside_fraction": _NUM,
            "compensatory": {"type": ["boolean", "null"]},
        },
    },
    "rehab.Joints": {
        "type": "object",
        "properties": {k: {"type": ["number", "null"]} for k in JOINT_COLUMNS},
        "required": ["t"],
    },
    "rehab.Movement": {
        "type": "object",
        "properties": {
            "start": _NUM,
            "end": _NUM,
            "shoulder_elevation_range_deg": {"type": ["number", "null"]},
            "elbow_flexion_range_deg": {"type": ["number", "null"]},
        },
        "required": ["start", "end"],
    },
}


def _schema_of(key: str) -> str:
    kind = key.split("/")[2] if key.count("/") >= 2 else ""
    return {
        "imu": "rehab.Imu",
        "robot": "rehab.Robot",
        "camera": "rehab.Camera",
        "event": "rehab.Event",
    }.get(kind, "rehab.Message")


def _first_t(payload: Any) -> float | None:
    t = payload.get("t") if isinstance(payload, dict) else None
    if isinstance(t, list) and t:
        t = t[0]
    if isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t) and t >= 0:
        return float(t)
    return None


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


class _Out:
    def __init__(self, fh: IO[bytes], meta: ExportMeta) -> None:
        self.w = Writer(fh)
        self.w.start(profile="", library="rehab-tracking")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.seq = 0
        self.meta = meta

    def channel(self, topic: str, schema: str) -> int:
        if topic not in self.channels:
            if schema not in self.schemas:
                self.schemas[schema] = self.w.register_schema(
                    name=schema, encoding="jsonschema", data=json.dumps(SCHEMAS[schema]).encode()
                )
            self.channels[topic] = self.w.register_channel(
                topic=topic, message_encoding="json", schema_id=self.schemas[schema]
            )
        return self.channels[topic]

    def add(self, topic: str, schema: str, t_ns: int, data: bytes) -> None:
        cid = self.channel(topic, schema)
        self.w.add_message(
            channel_id=cid, log_time=t_ns, publish_time=t_ns, data=data, sequence=self.seq
        )
        self.seq += 1


def write(
    out: Path | IO[bytes],
    recording_path: Path,
    report: Mapping[str, Any],
    estimates: Mapping[str, np.ndarray] | None,
    meta: ExportMeta,
    prefix: str = "rehab",
    joints: Mapping[str, np.ndarray] | None = None,
) -> int:
    """Write the MCAP file; returns the number of messages. ``estimates``: the columns of
    ``estimates.csv`` (:func:`backend.analysis.read_estimates`), or None to leave them out;
    ``joints``: a wearable session's ``joints.csv`` columns
    (:func:`backend.analysis_wearable.read_joints`), or None."""
    if isinstance(out, Path):
        with out.open("wb") as fh:
            return write(fh, recording_path, report, estimates, meta, prefix, joints)
    o = _Out(out, meta)
    last_ns = 0
    for key, payload in recording.read(recording_path):
        if key is None:
            o.add("/rejected", "rehab.Rejected", last_ns, json.dumps({"line": payload}).encode())
            continue
        raw = bytes(payload)
        try:
            t = _first_t(json.loads(raw))
        except ValueError:
            t = None
        last_ns = _ns(t) if t is not None else last_ns
        o.add(key, _schema_of(key), last_ns, raw)
    base = f"{prefix}/{meta.device}"
    for row in _estimate_rows(estimates):
        o.add(f"{base}/estimate", "rehab.Estimate", _ns(row["t"]), json.dumps(row).encode())
    quality = {
        (c["start"], c["end"]): c for c in report.get("movement_quality", {}).get("cycles", [])
    }
    for c in report.get("cycles", []):
        mq = {k: v for k, v in quality.get((c["start"], c["end"]), {}).items() if k != "path_xy"}
        msg = {**c, **{k: v for k, v in mq.items() if k not in c}}
        o.add(f"{base}/cycle", "rehab.Cycle", _ns(c["end"]), json.dumps(msg).encode())
    for row in _joint_rows(joints):
        o.add(f"{base}/joints", "rehab.Joints", _ns(row["t"]), json.dumps(row).encode())
    rom = {
        (c["start"], c["end"]): c["angles"]
        for c in report.get("anatomical_rom", {}).get("cycles", [])
    }
    for m in report.get("movements", []):
        span = (m["start"], m["end"])
        angles = rom.get(span, {})
        msg = {
            "start": m["start"],
            "end": m["end"],
            "shoulder_elevation_range_deg": angles.get("shoulder_elevation_deg", {}).get("range"),
            "elbow_flexion_range_deg": angles.get("elbow_flexion_deg", {}).get("range"),
            **{
                k: v
                for k, v in quality.get(span, {}).items()
                if k not in ("path_xy", "start", "end", "compensatory")
            },
        }
        o.add(f"{base}/movement", "rehab.Movement", _ns(m["end"]), json.dumps(msg).encode())
    o.w.finish()  # type: ignore[no-untyped-call]
    return o.seq


def _joint_rows(joints: Mapping[str, np.ndarray] | None) -> Iterable[dict[str, Any]]:
    if not joints or "t" not in joints:
        return
    names = [k for k in JOINT_COLUMNS if k in joints]
    for values in zip(*(joints[k].tolist() for k in names), strict=True):
        yield {k: (None if v != v else v) for k, v in zip(names, values, strict=True)}


def _estimate_rows(est: Mapping[str, np.ndarray] | None) -> Iterable[dict[str, Any]]:
    if not est or "t" not in est:
        return
    names = list(est)
    cols = [est[k].tolist() for k in names]
    for values in zip(*cols, strict=True):
        row: dict[str, Any] = {}
        for k, v in zip(names, values, strict=True):
            if k == "state":
                row[k] = v or None
            elif k == "heading_converged":
                row[k] = None if v != v else int(v)
            else:
                row[k] = None if v != v else v
        yield row
