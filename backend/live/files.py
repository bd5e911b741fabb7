"""A session's files: its raw recording and, beside it, what ``rehab analyze`` writes.

    data_dir/recordings/<id>.jsonl.gz          every raw message of the device, as received
    data_dir/recordings/<id>/estimates.csv     written live (flushed with the recording)
    data_dir/recordings/<id>/details.csv       written live (flushed with the recording)
    data_dir/recordings/<id>/report.json       written when the session stops

The directory holds exactly what ``rehab analyze <id>.jsonl.gz --out <id>`` produces, so a
session whose service died (no report) is completed by running that analysis.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import shutil
import zlib
from collections.abc import Iterable
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, NamedTuple

from backend.analysis import CSV_HEADER, DETAILS_HEADER, analyze
from backend.analysis_wearable import JOINTS_HEADER
from backend.report_json import dump_report
from estimators.params import PipelineParams
from protocol import recording

log = logging.getLogger(__name__)

RECORDINGS_DIR = "recordings"
ROBOT_CSV = (("estimates.csv", CSV_HEADER), ("details.csv", DETAILS_HEADER))
WEARABLE_CSV = (("joints.csv", JOINTS_HEADER),)
SUFFIX = ".jsonl.gz"


def csv_of(params: object) -> tuple[tuple[str, str], ...]:
    """The live CSV files of a session with these parameters (robot or wearable)."""
    from estimators.wearable.params import WearableParams

    return WEARABLE_CSV if isinstance(params, WearableParams) else ROBOT_CSV


def recording_relpath(session_id: int) -> str:
    """Relative to data_dir (what the sessions table stores)."""
    return f"{RECORDINGS_DIR}/{session_id}{SUFFIX}"


def outputs_dir(recording_path: Path) -> Path:
    """``recordings/<id>.jsonl.gz`` → ``recordings/<id>``."""
    name = recording_path.name
    stem = name[: -len(SUFFIX)] if name.endswith(SUFFIX) else recording_path.stem
    return recording_path.with_name(stem)


def state_dir(recording_path: Path) -> Path:
    """``recordings/<id>.jsonl.gz`` → ``recordings/<id>.state`` (pipeline snapshots)."""
    out = outputs_dir(recording_path)
    return out.with_name(f"{out.name}.state")


class FileMarks(NamedTuple):
    """Where a session's three files stood at a snapshot."""

    recording: recording.Mark
    estimates: recording.Mark
    details: recording.Mark


def _write_header(path: Path, header: str) -> recording.Mark:
    data = (header + "\n").encode()
    with open(path, "xb") as fh:
        fh.write(data)
    return recording.Mark(len(data), zlib.crc32(data), 0)


def resolve(data_dir: Path, relpath: str) -> Path:
    """A stored recording path, refusing anything that leaves data_dir."""
    base = data_dir.resolve()
    path = (base / relpath).resolve()
    if not path.is_relative_to(base):
        raise ValueError(f"recording path {relpath!r} is outside the data directory")
    return path


def _set_aside(path: Path) -> None:
    """A file left by an earlier database with the same session id: keep it, renamed."""
    if path.exists():
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
        path.rename(path.with_name(f"{path.name}.{stamp}.orphan"))


_NOTHING = recording.Mark(0, 0, 0)  # an empty file


class LineSink(list[str]):
    """Stands in for ``DeviceRun.est_lines``/``det_lines``: only counts the lines
    (``len()`` is what the report reads) and writes them through to a file at each
    :meth:`flush`, so a session of hours does not hold its CSV in memory and a poll does not
    pay for a file write."""

    def __init__(self, fh: IO[str] | None, start: recording.Mark = _NOTHING) -> None:
        """``start``: what the file holds already (its header, or a takeover's copy).
        ``fh`` None: a sink that keeps nothing (a wearable session has no estimates.csv)."""
        super().__init__()
        self._fh = fh
        self._n = start.lines
        self._pending: list[str] = []
        self.written = start.size  # the file's bytes and their CRC-32 (snapshot marks)
        self.written_crc = start.crc

    def extend(self, lines: Iterable[str]) -> None:
        before = len(self._pending)
        self._pending.extend(lines)
        self._n += len(self._pending) - before

    def append(self, line: str) -> None:
        self._pending.append(line)
        self._n += 1

    def flush(self) -> None:
        if self._pending:
            if self._fh is not None:
                text = "\n".join(self._pending) + "\n"
                data = text.encode()
                self.written += len(data)
                self.written_crc = zlib.crc32(data, self.written_crc)
                self._fh.write(text)
            self._pending.clear()

    def mark(self) -> recording.Mark:
        """Where the file stands once flushed (call :meth:`flush` first)."""
        return recording.Mark(self.written, self.written_crc, self._n)

    def __len__(self) -> int:
        return self._n


class SessionFiles:
    """The files of one running session (opened at start, closed at stop)."""

    def __init__(
        self,
        data_dir: Path,
        session_id: int,
        staging: str | None = None,
        resume: FileMarks | None = None,
        csv: tuple[tuple[str, str], ...] | None = None,
    ) -> None:
        """``staging``: a takeover's files, written beside the session's under this suffix
        and put in their place by :meth:`promote` once the recording is replayed.
        ``resume`` (with ``staging``): the staged files begin as copies of the session's
        files up to these marks (a snapshot's); ``ValueError`` if they do not hold them.
        ``csv``: the live CSV files as (name, header); default estimates.csv and details.csv
        (a wearable session: joints.csv, :data:`WEARABLE_CSV`)."""
        self.relpath = recording_relpath(session_id)
        self.recording_path = data_dir / self.relpath
        self.out = outputs_dir(self.recording_path)
        self.state_dir = state_dir(self.recording_path)
        self.recording_path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        self._staging = staging
        rec, out = self.recording_path, self.out
        if staging is None:
            _set_aside(rec)
            _set_aside(out)
            shutil.rmtree(self.state_dir, ignore_errors=True)  # snapshots of a former life
        else:
            rec = rec.with_name(f"{session_id}.{staging}{SUFFIX}")  # still .gz
            out = out.with_name(f"{out.name}.{staging}")
            # left by an earlier takeover attempt of this holder and epoch, which failed:
            # no one else writes under this name (the epoch is this holder's alone)
            rec.unlink(missing_ok=True)
            shutil.rmtree(out, ignore_errors=True)
        out.mkdir(mode=0o700)
        kept = (
            {}
            if resume is None
            else {"estimates.csv": resume.estimates, "details.csv": resume.details}
        )
        rec_start = None
        if resume is not None:
            assert staging is not None
            rec_start = recording.copy_prefix(self.recording_path, rec, resume.recording)
        # level 1: a third of level 6's CPU for ~20 % more bytes (the live loop is the
        # scarce resource; a recording can be recompressed offline)
        self.recorder = recording.Writer(
            rec, "x" if rec_start is None else "a", compresslevel=1, start=rec_start
        )
        self._fhs: list[IO[str]] = []
        self.sinks: dict[str, LineSink] = {}
        for name, header in csv or ROBOT_CSV:
            if resume is None:
                start = _write_header(out / name, header)
            elif name in kept:
                start = recording.copy_prefix(self.out / name, out / name, kept[name])
            else:  # snapshots are of robot sessions' files only
                raise ValueError(f"a snapshot holds no mark for {name}")
            fh = open(out / name, "a", encoding="utf-8")  # noqa: SIM115
            self._fhs.append(fh)
            self.sinks[name] = LineSink(fh, start)
        # a wearable session's files have no estimates/details: these sinks then keep nothing
        self.estimates = self.sinks.get("estimates.csv", LineSink(None))
        self.details = self.sinks.get("details.csv", LineSink(None))
        self.closed = False

    def marks(self) -> FileMarks:
        """Flush everything, then where each file stands (for a snapshot)."""
        self.flush()
        return FileMarks(self.recorder.mark(), self.estimates.mark(), self.details.mark())

    def promote(self) -> None:
        """A takeover's replayed files in place of the previous holder's (one rename each:
        a stale holder still writing would write into the files set aside, never into
        these)."""
        if self._staging is None:
            return
        self.flush()
        suffix, self._staging = self._staging, None
        rec_tmp = self.recording_path.with_name(
            f"{outputs_dir(self.recording_path).name}.{suffix}{SUFFIX}"
        )
        out_tmp = self.out.with_name(f"{self.out.name}.{suffix}")
        os.replace(rec_tmp, self.recording_path)
        old = self.out.with_name(f"{self.out.name}.{suffix}.old")
        if self.out.exists():
            self.out.rename(old)
        out_tmp.rename(self.out)
        shutil.rmtree(old, ignore_errors=True)
        self.recorder.path = self.recording_path

    def abandon(self) -> None:
        """The lease is lost: never write again (the new holder rebuilds the files)."""
        self.closed = True

    def flush(self) -> None:
        """Everything so far to the OS (the service does it every 0.25 s)."""
        if not self.closed:
            self.recorder.flush()
            for sink in self.sinks.values():
                sink.flush()
            for fh in self._fhs:
                fh.flush()

    def close(self, report: dict[str, Any] | None) -> None:
        if self.closed:
            return
        self.closed = True
        for sink in self.sinks.values():
            sink.flush()
        self.recorder.close()
        for fh in self._fhs:
            fh.close()
        if report is not None:
            (self.out / "report.json").write_text(dump_report(report))
            shutil.rmtree(self.state_dir, ignore_errors=True)  # the session is complete


# --------------------------------------------------------------------------- after a crash


def regenerate(recording_path: Path, params: dict[str, Any], device: str) -> dict[str, Any]:
    """``rehab analyze`` of a session's recording into its directory; returns the report
    (a wearable session's, contract §8, by its parameters' ``"mode"``)."""
    if params.get("mode") == "wearable":
        from backend import analysis_wearable

        return analysis_wearable.analyze(
            recording_path,
            analysis_wearable.load_params(params),
            outputs_dir(recording_path),
            device,
        )
    _, report = analyze(
        recording_path, PipelineParams.from_json(params), outputs_dir(recording_path), device=device
    )
    return report


_locks: dict[Path, asyncio.Lock] = {}


async def ensure_outputs(
    recording_path: Path, params: dict[str, Any], device: str
) -> dict[str, Any] | None:
    """The session's report, regenerated from its recording when missing (a session the
    service did not stop: killed, or shut down mid-write). ``None`` without a recording."""
    report_path = outputs_dir(recording_path) / "report.json"
    lock = _locks.setdefault(recording_path, asyncio.Lock())
    async with lock:
        if report_path.exists():
            loaded: dict[str, Any] = json.loads(report_path.read_text())
            return loaded
        if not recording_path.exists():
            return None
        log.info("regenerating the outputs of %s from its recording", recording_path.name)
        return await asyncio.to_thread(regenerate, recording_path, params, device)
