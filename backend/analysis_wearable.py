"""``rehab analyze`` for a wearable recording (contract §8): DIR/joints.csv and DIR/report.json
(the command runs it in two processes: the tracker in one, the rest in the other).

Chosen by the parameter file's ``"mode": "wearable"`` before the robot pipeline's parameters
are read. Messages are validated by :mod:`protocol.wire` (the one schema); every line that
cannot be used is counted by reason in the report, never a crash.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import queue
import threading
import traceback
from collections import Counter
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from backend import clinical, csv_text
from backend.report_json import dump_report
from estimators.cycles import PathAndReach
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
        if isinstance(msg, wire.ImuMessage) and msg.segment in ("upperarm", "forearm"):
            kind: tracker.Kind = "upperarm" if msg.segment == "upperarm" else "forearm"
            self.feed_track(kind, msg.t, msg.gyr, msg.acc)
        elif isinstance(msg, wire.CameraMessage):
            self.feed_track("camera", msg.t, msg.elbow, msg.wrist)
        elif isinstance(msg, wire.EventMessage) and msg.type == "cycle_start":
            self.cycle_starts.append(msg.t)  # the movements, if the device marks them
        else:  # a trunk IMU, a robot, an event: counted as the key's kind
            kind_name = {wire.ImuMessage: "imu", wire.RobotMessage: "robot"}.get(type(msg), "event")
            self.reject(f"ignored_{kind_name}")
            return False
        return True

    def feed_track(self, kind: tracker.Kind, t: F64, u: F64, v: F64) -> None:
        """A message's arrays (validated by :mod:`protocol.wire`) into the tracker."""
        block = tracker.feed_block(self.params, self.state, kind, t, u, v)
        if block.shape[1]:
            self.parts.append(block)

    def finish(self) -> None:
        """End of data: the upper-arm samples still waiting for a forearm partner."""
        if self.finished:
            return
        self.finished = True
        block = tracker.flush_block(self.params, self.state)
        if block.shape[1]:
            self.parts.append(block)

    def pending(self) -> int:
        """How many messages' blocks of rows :meth:`take` would hand over."""
        return len(self.parts) - self._taken

    def take_block(self) -> F64:
        """The rows completed since the last call as one (19, N) block (N may be 0)."""
        new = self.parts[self._taken :]
        if len(self.parts) >= 256:  # all taken now: merged (a part per message costs memory)
            self.parts = [tracker.join_blocks(self.parts)]
        self._taken = len(self.parts)
        return tracker.join_blocks(new)

    def take(self) -> tracker.Rows | None:
        """The rows completed since the last call (None if there are none)."""
        block = self.take_block()
        return tracker.block_rows(block) if block.shape[1] else None

    def rows(self) -> tracker.Rows:
        return tracker.block_rows(tracker.join_blocks(self.parts))

    def info(self) -> RunInfo:
        """What the report needs besides the rows."""
        return RunInfo(
            self.device,
            self.lines,
            dict(sorted((self.rejected + self.state.rejected).items())),
            list(self.cycle_starts),
        )

    def report(self) -> dict[str, Any]:
        return make_report(self.rows(), self.info(), self.params)


@dataclasses.dataclass(frozen=True)
class RunInfo:
    """A run's facts for its report besides the rows: the device, the recording lines read,
    the rejections by reason (the lines' and the tracker's) and the ``cycle_start`` events."""

    device: str | None
    lines: int
    rejected: dict[str, int]
    cycle_starts: list[float]


class ReportWriter:
    """A run's outputs written as its rows come: joints.csv's lines at once, the movements
    of the wrist path found as it goes (:class:`estimators.cycles.PathAndReach`, the same
    boundaries as one pass over the whole path), report.json at :meth:`finish`: the same
    bytes as :func:`joint_lines` and :meth:`WearableRun.report` of all the rows at the end.
    It may run in a process of its own (:func:`analyze`'s ``parallel``)."""

    def __init__(self, params: WearableParams, out: Path) -> None:
        out.mkdir(parents=True, exist_ok=True)
        self.params = params
        self.out = out
        self._fh = open(out / JOINTS_NAME, "w", encoding="utf-8")  # noqa: SIM115 (finish closes)
        self._fh.write(JOINTS_HEADER + "\n")
        self._parts: list[F64] = []
        self._moves = PathAndReach()

    def add(self, block: F64) -> None:
        """Rows (a (19, N) block, in time order after the previous ones)."""
        if not block.shape[1]:
            return
        self._parts.append(block)
        rows = tracker.block_rows(block)
        self._fh.writelines(line + "\n" for line in joint_lines(rows))
        # clinical.wearable_sections' movements: the rows past the rest window with a wrist
        usable = (rows["flags"].astype(np.int64) & tracker.INITIALISING) == 0
        wrist = np.stack([rows["wrist_x"], rows["wrist_y"], rows["wrist_z"]], axis=1)
        ok = usable & np.all(np.isfinite(wrist), axis=1)
        self._moves.update(rows["t"][ok], wrist[ok])

    def finish(self, info: RunInfo) -> dict[str, Any]:
        """joints.csv closed, report.json written; returns the report."""
        self._fh.close()
        rows = tracker.block_rows(tracker.join_blocks(self._parts))
        movements = None  # the events mark the movements when there are any
        if not info.cycle_starts:
            movements = clinical.most_movements((self._moves.path, self._moves.reach))
        report = make_report(rows, info, self.params, movements)
        (self.out / REPORT_NAME).write_text(dump_report(report))  # the live service's bytes too
        return report


def analyze(
    path: str | Path,
    params: WearableParams,
    out: str | Path,
    device: str | None = None,
    parallel: bool = False,
) -> dict[str, Any]:
    """Run the wearable tracker over a recording; write joints.csv and report.json.

    ``parallel`` (``rehab analyze``): in two processes, the tracker in this one and the rest
    in a second one (:func:`_read_and_write`): the same bytes, sooner on two cores. Forked
    where the platform can and this process runs no other thread, else spawned (it then
    imports this module before it starts). The service does not use it."""
    if parallel:
        return _analyze_in_two(Path(path), params, Path(out), device)
    run = WearableRun(params, device)
    writer = ReportWriter(params, Path(out))
    for key, payload in recording.read(path):
        run.feed_line(key, payload)
        if run.pending() >= _BATCH:
            writer.add(run.take_block())
    run.finish()
    writer.add(run.take_block())
    return writer.finish(run.info())


_BATCH = 64  # messages a process hands over at a time


class _Reader(WearableRun):
    """A run's lines (:meth:`WearableRun.feed_line`'s checks and counts) whose tracker inputs
    are collected for another process, not tracked: :meth:`pack` hands them over."""

    def __init__(self, params: WearableParams, device: str | None) -> None:
        super().__init__(params, device)
        self.batch: list[tuple[tracker.Kind, F64, F64, F64]] = []

    def feed_track(self, kind: tracker.Kind, t: F64, u: F64, v: F64) -> None:
        self.batch.append((kind, t, u, v))

    def pack(self) -> tuple[str, list[tracker.Kind], list[int], F64, F64, F64]:
        """``("tracks", kinds, ends, t, u, v)``: the batch's arrays joined (one pickle, not
        three per message); message ``i`` is rows ``ends[i-1]:ends[i]``."""
        batch, self.batch = self.batch, []
        ends = np.cumsum([len(b[1]) for b in batch]).tolist()
        t, u, v = (np.concatenate([b[i] for b in batch]) for i in (1, 2, 3))
        return "tracks", [b[0] for b in batch], ends, t, u, v


def _analyze_in_two(
    path: Path, params: WearableParams, out: Path, device: str | None
) -> dict[str, Any]:
    """:func:`analyze` split in two processes: the second reads and checks the lines and
    hands the tracker's inputs over, then writes the rows handed back (:class:`ReportWriter`)
    and the report; this one only tracks (the bottleneck: about half the single process's
    time is elsewhere). The tracker's own rejections go over at the end, so the counts are
    the single process's."""
    # forked (no imports to wait for) unless another thread could hold a lock the copy needs
    fork = "fork" in multiprocessing.get_all_start_methods() and threading.active_count() == 1
    ctx = multiprocessing.get_context("fork") if fork else multiprocessing.get_context("spawn")
    to_parent: multiprocessing.Queue[tuple[Any, ...]] = ctx.Queue()
    to_child: multiprocessing.Queue[F64 | dict[str, int]] = ctx.Queue()
    child = ctx.Process(
        target=_read_and_write,
        args=(path, params, str(out), device, to_parent, to_child),
        name="rehab-analyze-io",
        daemon=True,
    )
    child.start()
    done = False
    try:
        run = WearableRun(params, device)
        while (item := _next(to_parent, child))[0] == "tracks":
            _, kinds, ends, t, u, v = item
            start = 0
            for kind, end in zip(kinds, ends, strict=True):
                run.feed_track(kind, t[start:end], u[start:end], v[start:end])
                start = end
            if run.pending() >= _BATCH:
                to_child.put(run.take_block())
        if item[0] == "end":
            run.finish()
            to_child.put(run.take_block())
            to_child.put(dict(run.state.rejected))
            item = _next(to_parent, child)
        if item[0] != "report":
            raise RuntimeError(f"rehab analyze's second process failed:\n{item[1]}")
        report: dict[str, Any] = item[1]
        done = True
        return report
    finally:
        if not done:  # either failed: the second process stopped, if it has not ended
            child.terminate()
        child.join()
        for q in (to_parent, to_child):  # what a failed process left unread: not waited for
            q.cancel_join_thread()
            q.close()


_T = TypeVar("_T")


def _next(q: multiprocessing.Queue[_T], other: BaseProcess | None) -> _T:
    """The next item from the other process; an error if it has ended without one."""
    while True:
        try:
            return q.get(timeout=1.0)
        except queue.Empty:
            if other is not None and not other.is_alive():
                raise RuntimeError(
                    f"rehab analyze's {other.name} process ended (exit code {other.exitcode})"
                ) from None


def _read_and_write(
    path: Path,
    params: WearableParams,
    out: str,
    device: str | None,
    to_parent: multiprocessing.Queue[tuple[Any, ...]],
    to_child: multiprocessing.Queue[F64 | dict[str, int]],
) -> None:
    """:func:`_analyze_in_two`'s second process."""
    try:
        reader = _Reader(params, device)
        for key, payload in recording.read(path):
            reader.feed_line(key, payload)
            if len(reader.batch) >= _BATCH:
                to_parent.put(reader.pack())
        if reader.batch:
            to_parent.put(reader.pack())
        to_parent.put(("end",))
        writer = ReportWriter(params, Path(out))
        while not isinstance(item := _next(to_child, multiprocessing.parent_process()), dict):
            writer.add(item)
        info = reader.info()  # its tracker never ran: the tracker's rejections are the parent's
        rejected = Counter(info.rejected) + Counter(item)
        info = dataclasses.replace(info, rejected=dict(sorted(rejected.items())))
        to_parent.put(("report", writer.finish(info)))
    except BaseException:  # to the parent, which raises it
        to_parent.put(("error", traceback.format_exc()))


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
    info: RunInfo,
    params: WearableParams,
    movements: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """report.json of a wearable session: the §8 ROM (``rom``), confidence, data quality,
    and the clinical sections of :func:`backend.clinical.wearable_sections` (anatomical ROM
    per session and per movement, movement quality of the wrist path, key figures);
    ``movements`` if found already (:class:`ReportWriter`), else from the rows."""
    flags = rows["flags"].astype(np.int64)
    usable = (flags & tracker.INITIALISING) == 0
    clin = clinical.wearable_sections(
        rows["t"],
        rows,
        usable,
        movements=movements,
        event_times=info.cycle_starts,
        side=params.side,
    )
    final_std = {
        c: (round(float(rows[c][-1]), 3) if len(rows[c]) and math.isfinite(rows[c][-1]) else None)
        for c in tracker.STD_COLUMNS
    }
    return {
        "mode": "wearable",
        "device": info.device,
        "cycles": [],  # contract §6's key: the wearable mode has no robot cycles
        "summary": {
            "rows": len(rows["t"]),
            "lines": info.lines,
            "start": float(rows["t"][0]) if len(rows["t"]) else None,
            "end": float(rows["t"][-1]) if len(rows["t"]) else None,
            "movements": len(clin["movements"]),
        },
        "rom": rom(rows),
        "confidence_at_end_deg": final_std,
        "data_quality": {
            "rejected": dict(info.rejected),
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
    report = analyze(recording_path, params, out, device, parallel=True)
    rej = sum(report["data_quality"]["rejected"].values())
    print(
        f"{report['device'] or '(no device)'}: {report['summary']['rows']} joint-angle rows "
        f"(wearable, {params.filter.upper()} model {params.model}), {rej} rejections -> {out}"
    )
    return 0
