"""Pipeline snapshots: a takeover replays only the tail of a session's recording.

The holder of a device writes, every ``every_s`` seconds of the device's data (stream time,
never the wall clock), the complete state of the session's :class:`LiveRun` (pipeline,
report accumulators, the run's own book-keeping; :mod:`estimators.state`) together with the
marks of its three files at that instant (bytes, CRC-32 and lines of the recording and the
two CSV files: :class:`backend.live.files.FileMarks`)::

    data_dir/recordings/<id>.state/<lines, 12 digits>.e<epoch>.snap

A takeover (:func:`prepare`) takes the newest snapshot that is valid: the right format and
code version, an intact body (SHA-256 and size), the session's parameters, and files that
still begin with exactly the bytes its marks describe. The last check is the fence: the
snapshot of a holder that has lost its lease describes bytes that the files put in place by
the next holder no longer hold (that holder ended the recording's gzip member at its own
point), so it can never be resumed from. The staged files start as copies of those prefixes
(no recompression), the run is restored, and only the recording's lines after the mark are
replayed. Anything not valid is skipped with a counted warning; without a valid snapshot the
whole recording is replayed, as before. Either way the files come out byte for byte as an
uninterrupted run and ``rehab analyze`` make them (tests/live/test_snapshot.py).

Format: ``MAGIC``, a 4-byte length, a JSON header (version, code fingerprint, session,
epoch, stream time, marks, parameter digest, body size and SHA-256), then the body. No
pickle: the body is :func:`estimators.state.dump`'s plain data.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import math
import os
import shutil
import struct
import time
import zlib
from collections import Counter
from dataclasses import dataclass
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from backend.live import files
from backend.live.devices import DeviceStats
from backend.live.run import LiveRun, SessionContext
from backend.live.wearable_run import WearableLiveRun
from estimators import state
from protocol import recording

log = logging.getLogger(__name__)

VERSION = 1
MAGIC = b"REHAB-SNAPSHOT\n"
EVERY_S = 30.0  # default interval, seconds of the device's data
# A worker's captures at least this far apart (loop time, never seen by a pipeline): a
# capture holds the loop tens of ms, so two in a row would delay every device's turn twice.
GAP_S = 0.1
SUFFIX = ".snap"
# the classes a session's run is made of (the pipeline's, the report's, the run's)
MODULES = (
    "estimators.",
    "backend.analysis",
    "backend.clock_guard",
    "backend.clinical",
    "backend.live.run",
    "backend.live.budget",
)
_CODE = (
    "estimators",
    "backend/analysis.py",
    "backend/clock_guard.py",
    "backend/clinical.py",
    "backend/live/run.py",
    "backend/live/budget.py",
    "backend/live/snapshot.py",
)


class Invalid(Exception):
    """A snapshot that cannot be resumed from; ``reason`` is what is counted."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


@cache
def fingerprint() -> str:
    """The code a snapshot's state belongs to: the sources of the modules whose objects it
    holds, and the numeric libraries' versions. Any change (an upgrade, a stage gaining a
    field) makes older snapshots "another version": skipped, never misread."""
    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha256()
    for rel in _CODE:
        p = root / rel
        for f in sorted(p.rglob("*.py")) if p.is_dir() else [p]:
            h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes())
    for dist in ("numpy", "vqf"):
        h.update(f"{dist}={metadata.version(dist)}".encode())
    h.update(np.dtype(np.float64).str.encode())
    return h.hexdigest()[:32]


def params_digest(params: dict[str, Any]) -> str:
    """The session's stored parameters (as the database holds them)."""
    return hashlib.sha256(msgspec.json.encode(params, order="sorted")).hexdigest()[:32]


class _Header(msgspec.Struct, forbid_unknown_fields=True):
    version: int
    code: str
    session: int
    epoch: int
    t: float
    params: str
    marks: tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]
    size: int
    sha256: str


@dataclass(frozen=True)
class Snapshot:
    path: Path
    session: int
    epoch: int
    t: float
    marks: files.FileMarks
    params: str
    body: bytes


def _externals(run: LiveRun) -> dict[str, Any]:
    """What a run holds that is context, not state (supplied again on restore)."""
    assert run.session is not None and run.files is not None
    return {
        "stats": run.stats,
        "session": run.session,
        "params": run.params,
        "files": run.files,
        "estimates": run.files.estimates,
        "details": run.files.details,
    }


@dataclass(frozen=True)
class Taken:
    """A run's state at one instant (:func:`take`), not yet sealed into a file's content
    (:func:`seal`: the body's digest and the header, in a thread)."""

    path: Path
    header: dict[str, Any]  # every field of the header but the body's size and digest
    body: bytes


def take(run: LiveRun, epoch: int) -> Taken:
    """The run's state now (its files flushed first): what must happen on the device's turn
    (the state must not move meanwhile). Raises :class:`estimators.state.StateError` if the
    state is not plain data (a bug: counted by the caller, the session goes on)."""
    assert run.session is not None and run.files is not None
    # the rows waiting to be formatted (up to 1024 polls' worth of small arrays) go into the
    # state as one block: formatting them here (half the capture's time) would hold every
    # device of the worker for it; they are formatted on a later turn, to the same text
    run.run.pack_rows()
    marks = run.files.marks()
    body = state.dump(run, _externals(run), MODULES)
    info = run.session.info
    header = {
        "version": VERSION,
        "code": fingerprint(),
        "session": info.id,
        "epoch": epoch,
        "t": float(run.latest_t if run.latest_t is not None else float("nan")),
        "params": params_digest(dict(info.params)),
        "marks": (tuple(marks.recording), tuple(marks.estimates), tuple(marks.details)),
    }
    name = f"{marks.recording.lines:012d}.e{epoch}{SUFFIX}"
    return Taken(run.files.state_dir / name, header, body)


def seal(taken: Taken) -> bytes:
    """The snapshot file's content (hashing a 3.6 MB body takes ~7 ms: off the turn)."""
    body = taken.body
    header = _Header(**taken.header, size=len(body), sha256=hashlib.sha256(body).hexdigest())
    head = msgspec.json.encode(header)
    return MAGIC + struct.pack("<I", len(head)) + head + body


def capture(run: LiveRun, epoch: int) -> tuple[Path, bytes]:
    """The run's snapshot file now: ``(path, content)`` (:func:`take` and :func:`seal`)."""
    taken = take(run, epoch)
    return taken.path, seal(taken)


def write_taken(taken: Taken) -> None:
    """:func:`seal`, then :func:`write` (the holder's thread)."""
    write(taken.path, seal(taken))


def write(path: Path, content: bytes) -> None:
    """Atomically (a reader sees the whole file or none), then the same holder's older
    snapshots of the session go (one kept per epoch: the newest)."""
    path.parent.mkdir(mode=0o700, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(content)
    os.replace(tmp, path)
    if (files.outputs_dir(_recording_of(path)) / "report.json").exists():
        shutil.rmtree(path.parent, ignore_errors=True)  # the session ended meanwhile
        return
    epoch = path.name.split(".")[1]
    for old in path.parent.glob(f"*.{epoch}{SUFFIX}"):
        if old.name < path.name:
            old.unlink(missing_ok=True)


def _recording_of(snapshot_path: Path) -> Path:
    d = snapshot_path.parent  # recordings/<id>.state
    return d.with_name(d.name.removesuffix(".state") + files.SUFFIX)


def read(path: Path) -> Snapshot:
    """A snapshot file, checked (format, version, code, size, SHA-256)."""
    data = path.read_bytes()
    if not data.startswith(MAGIC) or len(data) < len(MAGIC) + 4:
        raise Invalid("damaged", "not a snapshot")
    (n,) = struct.unpack_from("<I", data, len(MAGIC))
    start = len(MAGIC) + 4
    try:
        h = msgspec.json.decode(data[start : start + n], type=_Header)
    except msgspec.DecodeError as exc:
        # a header of another version may fail to decode as this one: say which it is
        try:
            version = msgspec.json.decode(data[start : start + n]).get("version")
        except Exception:
            raise Invalid("damaged", str(exc)) from exc
        raise Invalid("other_version" if version != VERSION else "damaged", str(exc)) from exc
    if h.version != VERSION:
        raise Invalid("other_version", f"format {h.version}")
    if h.code != fingerprint():
        raise Invalid("other_version", "written by other code")
    body = data[start + n :]
    if len(body) != h.size or hashlib.sha256(body).hexdigest() != h.sha256:
        raise Invalid("damaged", "body does not match its digest")
    marks = files.FileMarks(*(recording.Mark(*m) for m in h.marks))
    return Snapshot(path, h.session, h.epoch, h.t, marks, h.params, body)


def candidates(recording_path: Path) -> list[Path]:
    """The session's snapshot files, newest (most lines) first."""
    d = files.state_dir(recording_path)
    if not d.is_dir():
        return []
    return sorted(d.glob(f"*{SUFFIX}"), key=lambda p: p.name, reverse=True)


@dataclass
class Prepared:
    run: LiveRun | WearableLiveRun  # a wearable run: fresh (snapshots are of robot runs)
    files: files.SessionFiles
    skip: int  # recording lines the run has seen already (replay the rest)
    snapshot: Path | None


def prepare(
    data_dir: Path,
    context: SessionContext,
    device: str,
    prefix: str,
    staging: str,
    rejected: Counter[str] | None = None,
) -> Prepared:
    """A takeover's staged files and run: from the newest valid snapshot, else fresh (the
    whole recording to replay). Each snapshot skipped is counted in ``rejected`` by reason
    and logged. Blocking (file copies): run it in a thread."""
    info = context.info
    rec_path = data_dir / files.recording_relpath(info.id)
    digest = params_digest(dict(info.params))
    for path in candidates(rec_path):
        try:
            snap = read(path)
            if snap.session != info.id or snap.params != digest:
                raise Invalid("other_session", "session or parameters differ")
            try:
                staged = files.SessionFiles(data_dir, info.id, staging=staging, resume=snap.marks)
            except (ValueError, OSError) as exc:
                raise Invalid("files_moved_on", str(exc)) from exc
            stats = DeviceStats(device)
            try:
                run = state.load(
                    snap.body,
                    {
                        "stats": stats,
                        "session": context,
                        "params": context.params,
                        "files": staged,
                        "estimates": staged.estimates,
                        "details": staged.details,
                    },
                    MODULES,
                )
                if not isinstance(run, LiveRun):
                    raise state.StateError("not a run")
            except state.StateError as exc:
                staged.close(None)
                raise Invalid("damaged", str(exc)) from exc
            return Prepared(run, staged, snap.marks.recording.lines, path)
        except Invalid as exc:
            if rejected is not None:
                rejected[exc.reason] += 1
            log.warning("device %s: snapshot %s not used (%s)", device, path.name, exc)
        except OSError as exc:
            if rejected is not None:
                rejected["unreadable"] += 1
            log.warning("device %s: snapshot %s not readable (%s)", device, path.name, exc)
    staged = files.SessionFiles(data_dir, info.id, staging=staging)
    return Prepared(LiveRun(device, prefix, DeviceStats(device), context, staged), staged, 0, None)


def phase(device: str) -> float:
    """Where in the interval a device's first snapshot falls, in [0, 1): devices that
    start together (a clinic's morning, a benchmark) do not all capture in the same
    seconds, every interval after (each capture holds the worker's loop tens of ms)."""
    return zlib.crc32(device.encode()) / 2**32


class Snapshotter:
    """The holder's side: a snapshot of each running session every ``every_s`` seconds of
    its data (the first ``phase(device) * every_s`` after the holder's first turn of the
    session), taken on the device's turn (the state is copied), sealed and written by a
    thread. A worker's captures are ``GAP_S`` apart at least (a due one waits for a later
    turn). At most one write per session in flight (a slow disk skips, counted). Counts in
    ``counts``: written, busy (skipped), deferred (waited for the gap), failed."""

    def __init__(self, every_s: float = EVERY_S, gap_s: float = GAP_S) -> None:
        self.every_s = every_s
        self.gap_s = gap_s
        if every_s > 0:
            fingerprint()  # now, not on a device's turn
        self.counts: Counter[str] = Counter()
        self._next: dict[int, float] = {}  # session → stream time of its next snapshot
        self._busy: set[int] = set()
        self._last = -math.inf  # loop time of the last capture
        self.taken_s: list[float] = []  # loop time of each capture (the worker's log clears it)

    def after_turn(self, run: LiveRun, epoch: int, alive: Any) -> None:
        """Called after each turn of a device: a snapshot if one is due."""
        if self.every_s <= 0 or run.session is None or run.files is None:
            return
        t = run.latest_t
        if t is None or run.files.closed:
            return
        sid = run.session.info.id
        due = self._next.get(sid)
        if due is None or t < due:
            if due is None:
                self._next[sid] = t + self.every_s * phase(run.device)
            return
        now = time.perf_counter()
        if now - self._last < self.gap_s:
            self.counts["deferred"] += 1
            return  # due still: the device's next turn tries again
        self._next[sid] = t + self.every_s
        if sid in self._busy:
            self.counts["busy"] += 1
            return
        if not alive():
            return
        self._last = now
        try:
            taken = take(run, epoch)
            if len(self.taken_s) < 1000:
                self.taken_s.append(time.perf_counter() - now)
        except Exception:
            self.counts["failed"] += 1
            log.exception("session %d: snapshot not taken", sid)
            return
        self._busy.add(sid)
        loop = asyncio.get_running_loop()
        fut = loop.run_in_executor(None, write_taken, taken)

        def done(f: asyncio.Future[None]) -> None:
            self._busy.discard(sid)
            if f.exception() is not None:
                self.counts["failed"] += 1
                log.warning("session %d: snapshot not written: %s", sid, f.exception())
            else:
                self.counts["written"] += 1

        fut.add_done_callback(done)
