"""Pipeline snapshots: a takeover restores the newest valid snapshot and replays only the
recording's tail. The files come out byte for byte as the uninterrupted run, a takeover by
full replay and ``rehab analyze`` make them; a damaged or foreign snapshot is skipped
(counted) and the takeover falls back to the whole recording."""

from __future__ import annotations

import time
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import orjson
import pytest

from backend.analysis import CSV_HEADER, DETAILS_HEADER, analyze, dump_report
from backend.deps import SessionInfo
from backend.live import snapshot
from backend.live.devices import DeviceStats
from backend.live.files import SessionFiles
from backend.live.ingest import RawMessage
from backend.live.node import replay
from backend.live.run import LiveRun, SessionContext, rows_ready
from estimators import state
from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from protocol import keys, recording, wire
from simulator import SimConfig, simulate

DEVICE = "sn01"
EVERY_S = 20.0


def _messages(seconds: float, seed: int = 11) -> list[tuple[str, bytes]]:
    sim = simulate(SimConfig(seed=seed, duration_s=seconds, device=DEVICE))
    return [(k, orjson.dumps(p)) for k, p in sim.messages]


def _context(sid: int = 1) -> SessionContext:
    info = SessionInfo(id=sid, device=DEVICE, patient_id=1, params={}, started_at=datetime.now(UTC))
    return SessionContext(info, PipelineParams(), None)


def _feed(run: LiveRun, key: str, payload: bytes, timer: bool = False) -> None:
    run.ingest(RawMessage(key, payload, len(payload), 0.0, keys.parse(key).kind))
    if run.fed_since_poll and (timer or rows_ready(run.pipeline)):
        run.poll()


def _holder(data_dir: Path, msgs: list[tuple[str, bytes]], epoch: int = 1) -> SessionFiles:
    """The first holder: runs and snapshots every EVERY_S of data, then dies (flushed,
    nothing closed)."""
    files = SessionFiles(data_dir, 1)
    run = LiveRun(DEVICE, "rehab", DeviceStats(DEVICE), _context(), files)
    due: float | None = None
    for i, (key, payload) in enumerate(msgs):
        _feed(run, key, payload, timer=i % 5 == 0)
        t = run.latest_t
        if t is not None:
            if due is None:
                due = t + EVERY_S
            elif t >= due:
                due = t + EVERY_S
                snapshot.write(*snapshot.capture(run, epoch))
    files.flush()
    return files


def _take_over(
    data_dir: Path, rest: list[tuple[str, bytes]], epoch: int = 2
) -> tuple[snapshot.Prepared, Counter[str], float]:
    rejected: Counter[str] = Counter()
    t0 = time.perf_counter()
    ready = snapshot.prepare(data_dir, _context(), DEVICE, "rehab", f"epoch{epoch}", rejected)
    path = data_dir / "recordings" / "1.jsonl.gz"
    replay(ready.run, path, "rehab", ready.skip)
    ready.files.promote()
    seconds = time.perf_counter() - t0
    run = ready.run
    for i, (key, payload) in enumerate(rest):
        _feed(run, key, payload, timer=i % 7 == 0)
    _, report = run.finish()
    report["data_quality"]["other_devices"] = {}
    ready.files.close(report)
    return ready, rejected, seconds


def _outputs(data_dir: Path) -> dict[str, object]:
    rec = data_dir / "recordings" / "1.jsonl.gz"
    out = data_dir / "recordings" / "1"
    return {
        "recording": [(k, bytes(p)) for k, p in recording.read(rec)],
        "estimates": (out / "estimates.csv").read_text(),
        "details": (out / "details.csv").read_text(),
        "report": (out / "report.json").read_text(),
    }


def _uninterrupted(data_dir: Path, msgs: list[tuple[str, bytes]]) -> dict[str, object]:
    files = SessionFiles(data_dir, 1)
    run = LiveRun(DEVICE, "rehab", DeviceStats(DEVICE), _context(), files)
    for i, (key, payload) in enumerate(msgs):
        _feed(run, key, payload, timer=i % 3 == 0)
    _, report = run.finish()
    report["data_quality"]["other_devices"] = {}
    files.close(report)
    return _outputs(data_dir)


@pytest.fixture(scope="module")
def msgs() -> list[tuple[str, bytes]]:
    return _messages(100.0)


def test_takeover_from_a_snapshot_equals_the_uninterrupted_run_and_a_full_replay(
    tmp_path: Path, msgs: list[tuple[str, bytes]]
) -> None:
    cut = len(msgs) * 3 // 4
    _holder(tmp_path / "a", msgs[:cut])
    snaps = snapshot.candidates(tmp_path / "a" / "recordings" / "1.jsonl.gz")
    assert len(snaps) == 1, "one kept per holder: the newest"
    ready, rejected, _ = _take_over(tmp_path / "a", msgs[cut:])
    assert ready.snapshot is not None and ready.skip > len(msgs) // 2, "resumed from it"
    assert not rejected
    from_snapshot = _outputs(tmp_path / "a")

    # the same death, no snapshot: the whole recording replayed
    _holder(tmp_path / "b", msgs[:cut])
    for p in snapshot.candidates(tmp_path / "b" / "recordings" / "1.jsonl.gz"):
        p.unlink()
    ready_b, _, _ = _take_over(tmp_path / "b", msgs[cut:])
    assert ready_b.snapshot is None and ready_b.skip == 0
    full_replay = _outputs(tmp_path / "b")

    uninterrupted = _uninterrupted(tmp_path / "c", msgs)
    assert from_snapshot == uninterrupted
    assert full_replay == uninterrupted
    assert from_snapshot["recording"] == msgs

    rec = tmp_path / "a" / "recordings" / "1.jsonl.gz"
    want_run, want = analyze(rec, PipelineParams())
    assert from_snapshot["estimates"] == CSV_HEADER + "\n" + "".join(
        x + "\n" for x in want_run.est_lines
    )
    assert from_snapshot["details"] == DETAILS_HEADER + "\n" + "".join(
        x + "\n" for x in want_run.det_lines
    )
    assert from_snapshot["report"] == dump_report(want)
    # the session ended: its snapshots went with it
    assert sorted(p.name for p in (tmp_path / "a" / "recordings").iterdir()) == [
        "1",
        "1.jsonl.gz",
    ]


def test_a_second_takeover_resumes_from_the_second_holders_snapshot(
    tmp_path: Path, msgs: list[tuple[str, bytes]]
) -> None:
    """Holder 1 dies, holder 2 takes over from holder 1's snapshot, snapshots itself and
    dies; holder 3 resumes from holder 2's. Holder 1's later snapshot (written after the
    takeover point, as a stale holder would) describes bytes the files no longer hold: it is
    refused (the fence), never resumed from."""
    a, b = len(msgs) // 3, len(msgs) * 2 // 3
    _holder(tmp_path, msgs[:a], epoch=1)
    rejected: Counter[str] = Counter()
    ready = snapshot.prepare(tmp_path, _context(), DEVICE, "rehab", "epoch2", rejected)
    assert ready.snapshot is not None
    path = tmp_path / "recordings" / "1.jsonl.gz"
    replay(ready.run, path, "rehab", ready.skip)
    ready.files.promote()
    run2 = ready.run
    due = (run2.latest_t or 0.0) + EVERY_S
    for i, (key, payload) in enumerate(msgs[a:b]):
        _feed(run2, key, payload, timer=i % 4 == 0)
        if run2.latest_t is not None and run2.latest_t >= due:
            due = run2.latest_t + EVERY_S
            snapshot.write(*snapshot.capture(run2, 2))
    ready.files.flush()

    # a stale epoch-1 snapshot far ahead, as if holder 1 had gone on in its own files
    stale_files = SessionFiles(tmp_path / "stale", 1)
    stale = LiveRun(DEVICE, "rehab", DeviceStats(DEVICE), _context(), stale_files)
    for key, payload in msgs[: len(msgs) - 5]:
        _feed(stale, key, payload)
    stale_path, content = snapshot.capture(stale, 1)
    snapshot.write(path.with_name("1.state") / stale_path.name, content)

    ready3, rejected3, _ = _take_over(tmp_path, msgs[b:], epoch=3)
    assert ready3.snapshot is not None and ready3.snapshot.name.endswith(".e2.snap")
    assert rejected3 == Counter({"files_moved_on": 1})
    assert _outputs(tmp_path) == _uninterrupted(tmp_path / "c", msgs)


@pytest.mark.parametrize("damage", ["flip", "truncate", "version", "code", "params"])
def test_a_damaged_or_foreign_snapshot_falls_back_to_the_full_replay(
    tmp_path: Path, msgs: list[tuple[str, bytes]], damage: str
) -> None:
    cut = len(msgs) // 2
    _holder(tmp_path, msgs[:cut])
    (snap,) = snapshot.candidates(tmp_path / "recordings" / "1.jsonl.gz")
    data = bytearray(snap.read_bytes())
    if damage == "flip":
        data[-100] ^= 0x40
    elif damage == "truncate":
        del data[len(data) // 2 :]
    else:
        head_at = len(snapshot.MAGIC) + 4
        old = {
            "version": b'"version":1',
            "code": b'"code":"' + snapshot.fingerprint().encode(),
            "params": b'"params":"' + snapshot.params_digest({}).encode(),
        }[damage]
        new = old[:-1] + (b"2" if damage == "version" else b"x")
        i = data.index(old, head_at)
        data[i : i + len(old)] = new
    snap.write_bytes(bytes(data))
    want = {
        "flip": "damaged",
        "truncate": "damaged",
        "version": "other_version",
        "code": "other_version",
        "params": "other_session",
    }[damage]
    ready, rejected, _ = _take_over(tmp_path, msgs[cut:])
    assert ready.snapshot is None and ready.skip == 0
    assert rejected == Counter({want: 1})
    assert _outputs(tmp_path) == _uninterrupted(tmp_path / "c", msgs)


def test_state_round_trip_keeps_shared_objects_and_refuses_code(tmp_path: Path) -> None:
    p = Pipeline(PipelineParams())
    for key, payload in _messages(12.0)[:400]:
        m = wire.decode(key, payload, "rehab")
        if m is not None:
            p.feed(m)
    p.poll()
    q = state.load(state.dump(p))
    assert q.quality is q._heading.quality, "one Quality object, shared as before"
    assert np.array_equal(q._imu.buf.view(), p._imu.buf.view())
    with pytest.raises(state.StateError):
        state.dump({"f": len})  # a function is code, not state
    bad = state.dump(p).replace(
        b"estimators.pipeline", b"subprocess\x00\x00\x00\x00\x00\x00\x00\x00\x00"
    )
    with pytest.raises(state.StateError):
        state.load(bad)


@pytest.mark.slow
def test_failover_of_a_twenty_minute_session_resumes_within_two_seconds(
    tmp_path: Path,
) -> None:
    """20 min of data, fast-forwarded through the holder with snapshots every 30 s; the
    takeover (snapshot, copies, tail replay, promote) takes < 2 s, where a full replay
    costs ~0.7 % of the session's length."""
    msgs = _messages(1200.0, seed=3)
    cut = len(msgs) - 1000  # died 20 s after... somewhere past the last snapshot
    global EVERY_S
    every, EVERY_S = EVERY_S, 30.0
    try:
        _holder(tmp_path, msgs[:cut])
    finally:
        EVERY_S = every
    ready, rejected, seconds = _take_over(tmp_path, msgs[cut:])
    print(f"takeover of a 20-minute session: {seconds:.2f} s, {ready.skip} lines skipped")
    assert ready.snapshot is not None and not rejected
    assert seconds < 2.0
    rec = tmp_path / "recordings" / "1.jsonl.gz"
    want_run, want = analyze(rec, PipelineParams())
    out = tmp_path / "recordings" / "1"
    assert (out / "report.json").read_text() == dump_report(want)
    assert (out / "estimates.csv").read_text() == CSV_HEADER + "\n" + "".join(
        x + "\n" for x in want_run.est_lines
    )


def test_the_holder_snapshots_by_stream_time_off_the_loop(
    tmp_path: Path, msgs: list[tuple[str, bytes]]
) -> None:
    """The worker's side: after each turn, a snapshot once ``every_s`` of data has passed
    since the last (the first due ``phase(device) * every_s`` after the session's first
    sample), written by a thread; none while the lease is not surely held; a takeover
    resumes from it."""
    import asyncio

    first = snapshot.phase(DEVICE) * EVERY_S
    assert 0 < first < 30  # the 100 s below: due at first, first + 20 (held), ...
    assert first + EVERY_S < 50 < first + 2 * EVERY_S

    async def run_holder() -> snapshot.Snapshotter:
        snaps = snapshot.Snapshotter(every_s=EVERY_S, gap_s=0.0)
        files = SessionFiles(tmp_path, 1)
        run = LiveRun(DEVICE, "rehab", DeviceStats(DEVICE), _context(), files)
        held = [True]
        for i, (key, payload) in enumerate(msgs):
            _feed(run, key, payload)
            if i == len(msgs) // 2:
                held[0] = False  # lease paused: the due snapshot is not taken
            snaps.after_turn(run, 4, lambda: held[0])
            await asyncio.sleep(0)
        for _ in range(200):
            if not snaps._busy:
                break
            await asyncio.sleep(0.01)
        files.flush()
        return snaps

    snaps = asyncio.run(run_holder())
    # 100 s of data: due at `first` and 20 s later (held), then twice with the lease not held
    assert snaps.counts["written"] == 2, snaps.counts
    (only,) = snapshot.candidates(tmp_path / "recordings" / "1.jsonl.gz")
    assert only.name.endswith(".e4.snap")
    ready, rejected, _ = _take_over(tmp_path, [], epoch=5)
    assert ready.snapshot == only and not rejected
    assert _outputs(tmp_path) == _uninterrupted(tmp_path / "c", msgs)


def test_a_workers_captures_are_spread_and_never_back_to_back(
    tmp_path: Path, msgs: list[tuple[str, bytes]]
) -> None:
    """Devices that start together capture at different moments of the interval (their
    phase), and a capture due within ``gap_s`` of the worker's previous one waits for a
    later turn of its device: it is deferred, not skipped."""
    import asyncio

    names = [f"bench{i:03d}" for i in range(50)]
    phases = sorted(snapshot.phase(n) for n in names)
    assert phases[0] < 0.1 and phases[-1] > 0.9  # spread over the whole interval
    assert len(set(phases)) == len(phases)

    async def two_devices() -> tuple[snapshot.Snapshotter, list[float]]:
        snaps = snapshot.Snapshotter(every_s=EVERY_S, gap_s=3600.0)
        runs = [
            LiveRun(DEVICE, "rehab", DeviceStats(DEVICE), _context(sid), SessionFiles(d, sid))
            for sid, d in ((1, tmp_path / "a"), (2, tmp_path / "b"))
        ]
        for key, payload in msgs[: len(msgs) // 2]:  # 50 s: both due (same device name)
            for run in runs:
                _feed(run, key, payload)
                snaps.after_turn(run, 1, lambda: True)
            await asyncio.sleep(0)
        while snaps._busy:
            await asyncio.sleep(0.01)
        snaps.gap_s = 0.0  # the gap has passed: the deferred one goes on the next turn
        snaps.after_turn(runs[1], 1, lambda: True)
        while snaps._busy:
            await asyncio.sleep(0.01)
        for run in runs:
            run.files.flush()
        return snaps, [snaps._next[1], snaps._next[2]]

    snaps, due = asyncio.run(two_devices())
    assert snaps.counts["written"] == 2, snaps.counts  # the first at once, then the deferred
    assert snaps.counts["deferred"] > 0
    # the first is next due one interval after it was taken; the deferred one after its own
    assert due[0] < due[1]
    assert len(snapshot.candidates(tmp_path / "a" / "recordings" / "1.jsonl.gz")) == 1
    assert len(snapshot.candidates(tmp_path / "b" / "recordings" / "2.jsonl.gz")) == 1
