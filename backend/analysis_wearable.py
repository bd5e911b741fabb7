"""``rehab analyze`` for a wearable recording (contract §8): DIR/joints.csv and DIR/report.json.

Chosen by the parameter file's ``"mode": "wearable"`` before the robot pipeline's parameters
are read. Messages are validated by :mod:`protocol.wire` (the one schema); every line that
cannot be used is counted by reason in the report, never a crash.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from backend import clinical, csv_text
from backend.analysis import dump_report
from estimators.wearable import tracker
from estimators.wearable.dh import F64
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


class WearableRun:
    """One wearable device's analysis, fed one recording line at a time: what
    :func:`analyze` runs over a file and the live service runs over a session's messages
    (the same lines, in the same order, decoded the same way: the same joints, by
    construction). Rows are kept in (19, N) blocks (:func:`tracker.feed_block`), made rows
    when asked for; :meth:`take` hands over those not taken yet."""

    def __init__(
        self, params: WearableParams, device: str | None = None, prefix: str = keys.DEFAULT_PREFIX
    ) -> None:
        self.params = params
        self.device = device  # None: the first device with an IMU or camera line
        self.prefix = prefix
        self.state = tracker.initial_state(params)
        self.rejected: Counter[str] = Counter()
        self.parts: list[F64] = []  # the rows' blocks
        self.lines = 0
        self._taken = 0  # parts handed over by take()
        self.finished = False
        self.last_reason = ""  # of the newest rejection
        self.cycle_starts: list[float] = []  # contract cycle_start events

    def reject(self, reason: str) -> None:
        self.rejected[reason] += 1
        self.last_reason = reason

    def feed_line(self, key: str | None, payload: Any) -> wire.Message | None:
        """One recording line; returns the decoded message if it was used."""
        self.lines += 1
        if key is None:
            self.reject("malformed_line")
            return None
        try:
            parsed = keys.parse(key, self.prefix)
        except keys.KeyError_:
            self.reject("unknown_key")
            return None
        if self.device is None and parsed.kind in ("imu", "camera"):
            self.device = parsed.device
        if parsed.device != self.device:
            self.reject("other_device")
            return None
        try:
            msg = wire.decode(key, payload, self.prefix)
        except wire.WireError as exc:
            self.reject(exc.reason)
            return None
        return msg if self.feed(msg) else None

    def feed(self, msg: wire.Message) -> bool:
        """A decoded message into the tracker; False (counted) if this mode has no use for it."""
        params, state = self.params, self.state
        if isinstance(msg, wire.ImuMessage) and msg.segment in ("upperarm", "forearm"):
            kind: tracker.Kind = "upperarm" if msg.segment == "upperarm" else "forearm"
            block = tracker.feed_block(params, state, kind, msg.t, msg.gyr, msg.acc)
        elif isinstance(msg, wire.CameraMessage):
            block = tracker.feed_block(params, state, "camera", msg.t, msg.elbow, msg.wrist)
        elif isinstance(msg, wire.EventMessage) and msg.type == "cycle_start":
            self.cycle_starts.append(msg.t)  # the movements, if the device marks them
            return True
        else:  # a trunk IMU, a robot, an event: counted as the key's kind
            kind_name = {wire.ImuMessage: "imu", wire.RobotMessage: "robot"}.get(type(msg), "event")
            self.reject(f"ignored_{kind_name}")
            return False
        if block.shape[1]:
            self.parts.append(block)
        return True

    def finish(self) -> None:
        """End of data: the upper-arm samples still waiting for a forearm partner."""
        if self.finished:
            return
        self.finished = True
        block = tracker.flush_block(self.params, self.state)
        if block.shape[1]:
            self.parts.append(block)

    def take(self) -> tracker.Rows | None:
        """The rows completed since the last call (None if there are none)."""
        new = self.parts[self._taken :]
        if len(self.parts) >= 256:  # all taken now: merged (a part per message costs memory)
            self.parts = [tracker.join_blocks(self.parts)]
        self._taken = len(self.parts)
        if not new:
            return None
        return tracker.block_rows(tracker.join_blocks(new))

    def rows(self) -> tracker.Rows:
        return tracker.block_rows(tracker.join_blocks(self.parts))

    def report(self) -> dict[str, Any]:
        return make_report(
            self.rows(),
            self.state,
            self.rejected,
            self.device,
            self.params,
            self.lines,
            self.cycle_starts,
        )


def analyze(
    path: str | Path, params: WearableParams, out: str | Path, device: str | None = None
) -> dict[str, Any]:
    """Run the wearable tracker over a recording; write joints.csv and report.json."""
    run = WearableRun(params, device)
    for key, payload in recording.read(path):
        run.feed_line(key, payload)
    run.finish()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_joints(run.rows(), out / JOINTS_NAME)
    report = run.report()
    (out / REPORT_NAME).write_text(dump_report(report))  # the live service's bytes too
    return report


JOINTS_HEADER = ",".join(tracker.COLUMNS)
_DIGITS = (6, *([3] * 5), *([4] * 6))


_JOINTS_FMT = ",".join(f"%.{d}f" for d in _DIGITS)


def joint_lines(rows: tracker.Rows) -> list[str]:
    """joints.csv's lines (no newline) of some rows: empty cells where not available
    (NaN or ±inf; the shared formatter empties NaN cells)."""
    cols: list[csv_text.Column] = []
    for c in tracker.COLUMNS:
        v = np.asarray(rows[c], dtype=np.float64)
        cols.append(v if np.isfinite(v).all() else np.where(np.isfinite(v), v, np.nan))
    return csv_text.lines(_JOINTS_FMT, cols)


def write_joints(rows: tracker.Rows, path: Path) -> None:
    """Contract §8's joints.csv: exact header, empty cells where a value is not available."""
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(JOINTS_HEADER + "\n")
        for line in joint_lines(rows):
            fh.write(line + "\n")


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


CAMERA_DROPOUT_S = 0.5  # rows without a camera position this long, after one had some


class CameraWatch:
    """Counts the camera's dropouts in the rows (sample time): a run of rows without a
    camera position (flag ``camera_used`` clear) of at least :data:`CAMERA_DROPOUT_S`, once
    the camera had been used. The same count fed all rows at once or poll by poll."""

    def __init__(self) -> None:
        self.seen = False  # the camera was used once
        self.last_used: float = -math.inf
        self.out = False  # in a dropout now
        self.dropouts = 0

    def update(self, t: np.ndarray, flags: np.ndarray) -> CameraWatch:
        used = (flags.astype(np.int64) & tracker.CAMERA_USED) > 0
        for ti, u in zip(t.tolist(), used.tolist(), strict=True):
            if u:
                self.seen, self.last_used, self.out = True, ti, False
            elif self.seen and not self.out and ti - self.last_used >= CAMERA_DROPOUT_S:
                self.out = True
                self.dropouts += 1
        return self


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
            "camera_dropouts": CameraWatch().update(rows["t"], flags).dropouts,
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
