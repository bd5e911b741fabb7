"""``rehab analyze``: the live pipeline run offline over a recording (contract §6).

The same code feeds the service: :class:`DeviceRun` wraps one device's pipeline with the
decoder's rejection counters and accumulates what the report needs, so a live session
and an offline analysis of its recording produce identical files.
"""

from __future__ import annotations

import csv
import gc
import io
import math
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import Any

import numpy as np

from backend import clinical, csv_text
from backend.clock_guard import ClockGuard, Verdict
from backend.csv_text import Column
from backend.report_json import dump_report
from estimators.output import Output, RowTable, concat_rows
from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from protocol import keys, recording, wire

CSV_HEADER = (
    "t,elbow_x,elbow_y,elbow_z,shoulder_x,shoulder_y,shoulder_z,elbow_angle_deg,"
    "heading_offset_deg,heading_converged,shoulder_displacement_m,state"
)
DETAILS_HEADER = (
    "t,q_w,q_x,q_y,q_z,heading_std_deg,heading_confidence,upper_arm_elevation_deg,"
    "upper_arm_azimuth_deg,nominal_x,nominal_y,nominal_z,conv_elbow_angle_deg,"
    "wrist_x,wrist_y,wrist_z,upper_arm_length_m"
)
STATE_NAMES = {-1: "", 0: "ok", 1: "outside", 2: "warning"}
_FEED = Verdict.FEED  # a module global: checked for every stream message


_EST_FMT = "%r,%.5f,%.5f,%.5f,%.5f,%.5f,%.5f,%.3f,%.3f,%d,%.5f,%s"
_DET_FMT = "%r,%.6f,%.6f,%.6f,%.6f,%.3f,%.4f,%.3f,%.3f,%.5f,%.5f,%.5f,%.3f,%.5f,%.5f,%.5f,%.4f"


def estimate_lines(rows: Mapping[str, np.ndarray], t: list[str] | None = None) -> list[str]:
    """Rows of ``estimates.csv`` (contract §6); empty cells where no value exists yet.
    ``t``: the texts of ``rows["t"]`` if made already (:func:`csv_text.texts`)."""
    el, sh = rows["elbow"], rows["shoulder"]
    cols: list[Column] = [
        rows["t"],
        *(el[:, j] for j in range(3)),
        *(sh[:, j] for j in range(3)),
        rows["elbow_angle_deg"],
        rows["heading_offset_deg"],
        rows["heading_converged"].astype(np.int64),
        rows["shoulder_displacement_m"],
        list(map(STATE_NAMES.__getitem__, rows["state"].tolist())),
    ]
    return csv_text.lines(_EST_FMT, cols, t)


def detail_lines(rows: Mapping[str, np.ndarray], t: list[str] | None = None) -> list[str]:
    """Rows of ``details.csv``; ``t`` as for :func:`estimate_lines`."""
    m = np.concatenate(
        [
            rows["t"][:, None],
            rows["q_ra"],
            rows["heading_std_deg"][:, None],
            rows["heading_confidence"][:, None],
            rows["upper_arm_elevation_deg"][:, None],
            rows["upper_arm_azimuth_deg"][:, None],
            rows["nominal_shoulder"],
            rows["conv_elbow_angle_deg"][:, None],
            rows["wrist"],
            rows["upper_arm_length_m"][:, None],
        ],
        axis=1,
    )
    return csv_text.lines(_DET_FMT, [m[:, j] for j in range(m.shape[1])], t)


_FORMAT_ROWS = 1024  # rows formatted together (about 40 s of a live device)
_STAT_COLUMNS = (
    "t",
    "shoulder_displacement_m",
    "elbow_angle_deg",
    "upper_arm_elevation_deg",
    "upper_arm_azimuth_deg",
    "heading_converged",
    "state",
    *clinical.COLUMNS,
)


@dataclass
class DeviceRun:
    """One device's pipeline plus everything the report and the CSV files need."""

    device: str
    params: PipelineParams
    pipeline: Pipeline = field(init=False)
    decode_rejected: dict[str, int] = field(default_factory=dict)
    est_lines: list[str] = field(default_factory=list)
    det_lines: list[str] = field(default_factory=list)
    cycles: list[dict[str, Any]] = field(default_factory=list)
    episodes: list[dict[str, Any]] = field(default_factory=list)
    unjudged: list[dict[str, Any]] = field(default_factory=list)
    _stats: dict[str, list[np.ndarray]] = field(default_factory=dict)
    _clinical: clinical.Cache = field(default_factory=dict)  # each cycle measured once
    # rows not yet formatted: a RowTable as its (matrix, state), which the cyclic collector
    # does not track (a live service holds ~1000 polls per device here; as objects, every
    # full collection walked them all: 100+ ms pauses of the live loop at 50 devices)
    _waiting: list[tuple[np.ndarray, np.ndarray] | Mapping[str, np.ndarray]] = field(
        default_factory=list
    )
    _waiting_n: int = 0
    _format_at: int = field(init=False)  # rows waiting before the next format_rows()
    # far jumps of the device's clock: rejected, or a reset (backend.clock_guard)
    clock: ClockGuard = field(default_factory=ClockGuard)
    keep_rows: bool = True  # a reset takes the finished pipeline's rows (not a live preview)
    _nominal_event: tuple[str, Any] | None = None  # the last one fed: carried over a reset

    def __post_init__(self) -> None:
        self.pipeline = Pipeline(self.params)
        self._format_at = _FORMAT_ROWS

    def reject(self, reason: str) -> None:
        self.decode_rejected[reason] = self.decode_rejected.get(reason, 0) + 1

    def admit_stream(self, t0: float, t1: float) -> bool:
        """The clock guard on an IMU/robot message (stamps ``t0``..``t1``): False if it is
        rejected (counted); a reset restarts the pipeline first (:meth:`restart`)."""
        verdict = self.clock.stream(t0, t1)
        if verdict is _FEED:
            return True
        if verdict is Verdict.REJECT:
            self.reject(self.clock.reason)
            return False
        self.restart(t0)
        return True

    def admit_event(self, msg: wire.EventMessage) -> bool:
        if not self.clock.event(msg.t):
            self.reject(self.clock.reason)
            return False
        if msg.type in ("shoulder_reference", "nominal_reset"):
            self._nominal_event = (msg.type, msg.point)
        return True

    def restart(self, t: float) -> None:
        """The device's clock changed for good: finish the pipeline (its rows are kept),
        start a fresh one at ``t`` with the counters and the last nominal-shoulder event."""
        old = self.pipeline
        if self.keep_rows:
            self.take(old.poll())
            self.take(old.finish())
        self.pipeline = Pipeline(self.params)
        self.pipeline.quality = old.quality
        self.reject("clock_reset")
        if self._nominal_event is not None:
            etype, point = self._nominal_event
            self.pipeline.feed_event(t, etype, point)

    def take(self, out: Output) -> None:
        """Accumulate a poll's output (rows for the files, cycles, statistics)."""
        if out.n:
            # rows wait to be formatted many at a time: per row, one column-wise call on
            # 1024 rows costs a sixth of formatting a live poll's row alone (~30 µs)
            rows = out.rows
            self._waiting.append((rows.m, rows["state"]) if isinstance(rows, RowTable) else rows)
            self._waiting_n += out.n
            if self._waiting_n >= self._format_at:
                self.format_rows()
                self._format_at = _FORMAT_ROWS
        for e in out.episodes:
            self.episodes.append(
                {
                    "start": e.start,
                    "end": e.end,
                    "duration_s": e.duration_s,
                    "max_displacement_m": _finite(e.max_displacement_m),
                }
            )
        for v in out.cycles:
            d = {
                "start": v.start,
                "end": v.end,
                "outside_fraction": v.outside_fraction,
                "compensatory": v.compensatory,
                "coverage": v.coverage,
                "max_displacement_m": _finite(v.max_displacement_m),
                "mean_displacement_m": _finite(v.mean_displacement_m),
            }
            (self.cycles if v.compensatory is not None else self.unjudged).append(d)

    def pack_rows(self) -> None:
        """The waiting rows as one block, still unformatted (a snapshot: two arrays in its
        state instead of up to 1024 polls' small ones, and the text made later on an
        ordinary turn, the same text: formatting is batch-invariant)."""
        parts = self._waiting
        if len(parts) < 2:
            return
        tables = [p for p in parts if isinstance(p, tuple)]
        if len(tables) == len(parts):
            m = np.concatenate([m for m, _ in tables])
            st = np.concatenate([s for _, s in tables])
            self._waiting = [(m, st)]
        else:  # a finished pipeline's rows among them (a clock reset): rare, format them
            self.format_rows()

    def format_rows(self) -> None:
        """The waiting rows into the CSV lines and the report's statistics (``report()``
        does it; the live service also before a file is read mid-session)."""
        if not self._waiting:
            return
        parts, self._waiting, self._waiting_n = self._waiting, [], 0
        rows: Mapping[str, np.ndarray]
        tables = [p for p in parts if isinstance(p, tuple)]
        if len(tables) == len(parts):
            rows = RowTable(
                np.concatenate([m for m, _ in tables]), np.concatenate([s for _, s in tables])
            )
        else:
            rows = concat_rows([RowTable(*p) if isinstance(p, tuple) else p for p in parts])
        # both files start with t: its texts (a repr per value, their costliest) made once
        t = csv_text.texts("%r", rows["t"]) if len(rows["t"]) >= csv_text.VECTOR_ROWS else None
        self.est_lines.extend(estimate_lines(rows, t))
        self.det_lines.extend(detail_lines(rows, t))
        for k in _STAT_COLUMNS:  # copies: a view would keep every column of the rows alive
            self._stats.setdefault(k, []).append(np.array(rows[k]))

    def report(self) -> dict[str, Any]:
        self.format_rows()
        p = self.pipeline
        st = {k: np.concatenate(v) for k, v in self._stats.items()} if self._stats else {}
        conv = st.get("heading_converged", np.zeros(0, bool)).astype(bool)

        def rng(name: str) -> dict[str, float | None]:
            a = st.get(name, np.zeros(0))[conv] if len(conv) else np.zeros(0)
            a = a[np.isfinite(a)]
            if not len(a):
                return {"min": None, "max": None, "p5": None, "p95": None, "range": None}
            p5, p95 = np.percentile(a, [5, 95])
            return {
                "min": float(a.min()),
                "max": float(a.max()),
                "p5": float(p5),
                "p95": float(p95),
                "range": float(p95 - p5),
            }

        disp = st.get("shoulder_displacement_m", np.zeros(0))
        disp = disp[np.isfinite(disp)]
        states = st.get("state", np.zeros(0, np.int8))
        n_comp = sum(1 for c in self.cycles if c["compensatory"])
        durations = [c["end"] - c["start"] for c in self.cycles]
        quality = p.quality.as_dict()
        quality["rejected"] = {**quality["rejected"]}
        # by time: the pipeline notes a robot gap when polled, an IMU gap when fed, so the
        # list's order followed the polls (a live run, a takeover's replay, an analysis)
        quality["gaps"] = sorted(quality.get("gaps", []), key=lambda g: (g["t"], g["stream"]))
        for k, n in self.decode_rejected.items():
            quality["rejected"][k] = quality["rejected"].get(k, 0) + n
        return {
            "device": self.device,
            "cycles": self.cycles,
            "unjudged_cycles": self.unjudged,
            # non-repetitive tasks: outside for longer than the tolerated time (paper §5)
            "compensatory_episodes": self.episodes,
            "summary": {
                "rows": len(self.est_lines),
                "cycles": len(self.cycles),
                "compensatory_cycles": n_comp,
                "compensatory_share": (n_comp / len(self.cycles)) if self.cycles else None,
                "time_outside_share": float(np.mean(states >= 1)) if np.any(states >= 0) else None,
            },
            "heading": {
                "method": self.params.method,
                "first_motion_t": p.first_motion_time,
                "converged_t": p.convergence_time,
            },
            "upper_arm_length_m": p.arm_length_estimate or self.params.upper_arm_length_m,
            "upper_arm_length_estimated": p.arm_length_estimate is not None,
            "shoulder_displacement_m": {
                "median": float(np.median(disp)) if len(disp) else None,
                "p95": float(np.percentile(disp, 95)) if len(disp) else None,
                "max": float(disp.max()) if len(disp) else None,
            },
            "elbow_flexion_deg": rng("elbow_angle_deg"),
            "upper_arm_elevation_deg": rng("upper_arm_elevation_deg"),
            "upper_arm_azimuth_deg": rng("upper_arm_azimuth_deg"),
            "cycle_duration_s": {
                "median": float(np.median(durations)) if durations else None,
                "min": min(durations) if durations else None,
                "max": max(durations) if durations else None,
            },
            "data_quality": quality,
            "params": self.params.to_json(),
            # ROM in anatomical terms, movement quality, key figures (backend/clinical.py)
            **clinical.sections(st, self.cycles, self.params.to_json(), self._clinical),
        }


def decode_stream(
    lines: Iterable[bytes], prefix: str = keys.DEFAULT_PREFIX
) -> Iterator[tuple[str | None, wire.Message | wire.WireError]]:
    """Decode recording lines (:func:`recording.lines`); yield ``(device, message or
    error)`` (device None if unknown)."""
    for batch, cols in decode_batches(lines, prefix):
        for dev, item in batch:
            yield dev, item.message(cols) if isinstance(item, wire.Span) else item


def decode_batches(
    lines: Iterable[bytes], prefix: str = keys.DEFAULT_PREFIX
) -> Iterator[tuple[list[wire.Decoded], dict[str, wire.Columns]]]:
    """:func:`decode_stream` a batch at a time, stream messages left as spans of the
    batch's columns (:func:`wire.decode_lines`)."""
    it = iter(lines)
    # batches: a few hundred lines, so that few decoded objects are alive at once for the
    # cyclic collector to scan and promote (with it on, 256 cost least of 64..1024)
    while chunk := list(islice(it, _DECODE_BATCH)):
        yield wire.decode_lines(chunk, prefix)


_DECODE_BATCH = 256


@contextmanager
def gc_paused() -> Iterator[None]:
    """The cyclic garbage collector off for one batch run (``rehab analyze``).

    The pipeline makes no reference cycles worth collecting mid-run, but it holds tens of
    thousands of live message objects that every full collection walks again (about a
    sixth of the run). Not for the service: it pauses the whole process.
    """
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def analyze(
    path: str | Path,
    params: PipelineParams,
    out_dir: str | Path | None = None,
    device: str | None = None,
    progress: bool = False,
) -> tuple[DeviceRun, dict[str, Any]]:
    """Run the pipeline over a recording; write the contract's files if ``out_dir``."""
    lines: Iterable[bytes] = recording.lines(path)
    if progress:
        from tqdm import tqdm

        lines = tqdm(lines, unit=" msg", desc="analyze", mininterval=0.5, leave=False)
    run: DeviceRun | None = None
    run_dev: str | None = None
    orphan: dict[str, int] = {}
    others: dict[str, int] = {}
    span, feed_span = wire.Span, _feed_span  # locals: looked up once, not per message
    for batch, cols in decode_batches(lines):
        for dev, item in batch:
            if dev != run_dev or run is None:  # not the run's device (or no run yet)
                if run is None and dev is not None and (device is None or dev == device):
                    run = DeviceRun(dev, params)
                    run_dev, pipeline = dev, run.pipeline
                else:
                    if dev is None:
                        assert isinstance(item, wire.WireError)
                        orphan[item.reason] = orphan.get(item.reason, 0) + 1
                    else:
                        others[dev] = others.get(dev, 0) + 1
                    continue
            if type(item) is span:
                kind = item.key.kind
                if kind != "camera":
                    tl = cols[kind].tl
                    if not run.admit_stream(tl[item.i0], tl[item.i1 - 1]):
                        continue
                pipeline = run.pipeline  # a new one after a clock reset
                feed_span(pipeline, item, cols)
            elif isinstance(item, wire.WireError):
                run.reject(item.reason)
            elif admit(run, item):
                pipeline = run.pipeline
                pipeline.feed(item)
    if run is None:
        run = DeviceRun(device or "", params)
    for reason, n in orphan.items():
        run.decode_rejected[reason] = run.decode_rejected.get(reason, 0) + n
    run.take(run.pipeline.poll())
    run.take(run.pipeline.finish())
    rep = run.report()
    rep["data_quality"]["other_devices"] = others
    if out_dir is not None:
        write_outputs(run, rep, Path(out_dir))
    return run, rep


def admit(run: DeviceRun, msg: wire.Message | wire.Span) -> bool:
    """The clock guard's verdict on a decoded message (see :mod:`backend.clock_guard`)."""
    if isinstance(msg, wire.EventMessage):
        return run.admit_event(msg)
    if isinstance(msg, (wire.ImuMessage, wire.RobotMessage)):
        return run.admit_stream(float(msg.t[0]), float(msg.t[-1]))
    return True


def _feed_span(p: Pipeline, s: wire.Span, cols: dict[str, wire.Columns]) -> None:
    """``p.feed(s.message(cols))``, without making the message's arrays."""
    pk = s.key
    kind = pk.kind
    if kind == "imu":
        k = cols[kind]
        p.feed_imu_rows(k.t, k.tl, k.a, k.b, s.i0, s.i1, s.seq, pk.segment or "upperarm")
    elif kind == "robot":
        k = cols[kind]
        p.feed_robot_rows(k.t, k.tl, k.a, k.b, k.c, s.i0, s.i1, s.seq)
    else:
        p.feed(s.message(cols))


def write_outputs(run: DeviceRun, report: dict[str, Any], out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    # [*lines, ""]: every line newline-terminated
    (out / "estimates.csv").write_text("\n".join([CSV_HEADER, *run.est_lines, ""]))
    (out / "details.csv").write_text("\n".join([DETAILS_HEADER, *run.det_lines, ""]))
    (out / "report.json").write_text(dump_report(report))


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def read_estimates(path: str | Path) -> dict[str, np.ndarray]:
    """Load an ``estimates.csv`` (empty cells → NaN; state as strings)."""
    text = Path(path).read_text()
    rd = csv.reader(io.StringIO(text))
    header = next(rd)
    rows = list(rd)
    out: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        col = [r[j] for r in rows]
        if name == "state":
            out[name] = np.array(col, dtype=object)
        else:
            out[name] = np.array([float(x) if x else np.nan for x in col])
    return out
